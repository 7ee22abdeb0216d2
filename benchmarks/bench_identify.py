"""Identification speed: end-to-end `stickslip identify` on the fixtures, cold and
warm, and against scipy.optimize.least_squares over the same JAX residuals.

    .venv/bin/python benchmarks/bench_identify.py --json out/bench_identify.json

0. Issue #28: `stickslip identify fixtures/identification --out OUT --fix Ms=0.0247`
   (the profile's start, figures included) in fresh processes, --runs times with the
   persistent compilation cache off (cold), then once to fill an empty cache and
   --runs times with it (warm): medians and each run's wall and CPU time (user + system
   of the child), with the load average before each run. Target: both at most 20 s.
1. End to end: `stickslip identify fixtures/identification --fix Ms=0.0247` from the
   start the tests use (truth x 1.4/0.6/1.5/0.65/0.6, z_ba x1.4/0.65, PI x1.3), in a
   fresh process with the persistent compilation cache off: compilation included.
2. Issue #3 (a), from the same start: scipy least_squares(method='trf',
   jac='2-point', x_scale='jac') fits all 42 parameters jointly on the 17 recordings
   with this package's own joint residual (time traces in units of each recording's
   noise) and parameterisation (log / cumulative-log PI), over the same jitted JAX
   simulator. Its target is the same final cost: identify's fitted parameters scored
   with that residual. Timed to its first evaluation at or below that cost
   (compilation of the residual before the timer; a budget of --max-evaluations
   simulator runs, Jacobian columns included; its whole run, a lower bound, if it
   never gets there). The speed-up is scipy's time over identify's end-to-end wall.
   This is the measurement benchmark (b) (bench_identify_numba.py) makes with the
   numba loop, so (a) and (b) differ only in the simulator scipy calls.
3. The joint step alone (42 parameters, 17 recordings), from the optimum of the first three
   steps, solved (a) by this package (optimistix LM, forward-mode dense Jacobian) and
   (b) by scipy least_squares(method='trf', jac='2-point', x_scale='jac') over the very
   same jitted residual function and parameterisation. Both runs record every residual
   evaluation's cost and time; "time to target" is when a run first reaches the LM's
   final cost x (1 + 1e-6), so both are compared at the same final cost. Compilation
   of the residual function is done before either timer starts.
Target (issue #3): end to end under 60 s; this package at least 3x faster than scipy
(2). Item 3 isolates the last step, where both start next to the optimum (information).
Every JAX simulation here (identify, and the residuals scipy calls) runs at the
simulator's default stepping (``Stepping()``: a step from the model's fastest mode,
located slip reversals, refined intervals), planned once per residual from its start.
"""

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.identify import identify  # noqa: E402
from stickslip_jax.identify.dataset import Dataset  # noqa: E402
from stickslip_jax.identify.parameters import ParameterMap  # noqa: E402
from stickslip_jax.identify.residuals import TraceResiduals  # noqa: E402
from stickslip_jax.identify.solve import solve_least_squares  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

ROOT = Path(__file__).resolve().parent.parent
FIX = ROOT / "fixtures" / "identification"
FACTORS = {"Mp": 1.4, "Dp": 0.6, "Kp": 1.5, "Ds": 0.65, "rho0": 0.6,
           "z_ba_forward": 1.4, "z_ba_backward": 0.65}
JOINT = ["Mp", "Dp", "Kp", "Ds", "rho0", "pi_weights", "z_ba_forward", "z_ba_backward"]


def start_params() -> dict:
    p = json.loads((FIX / "truth.json").read_text())
    for k, f in FACTORS.items():
        p[k] *= f
    p["pi_weights"] = [w * 1.3 for w in p["pi_weights"]]
    return p


def end_to_end() -> dict:
    """`stickslip identify` in a fresh process (compilation cache off), timed whole.

    Also returns the fitted parameters (``params``, the contents of params.json, None
    if the fit failed) and the sum of the steps' solve times from fit.json
    (``steps_wall_s``: compilation included; loading, uncertainty, figures excluded).
    """
    with tempfile.TemporaryDirectory() as tmp:
        init, out = Path(tmp) / "init.json", Path(tmp) / "out"
        init.write_text(json.dumps(start_params()))
        cmd = [str(Path(sys.executable).parent / "stickslip"), "identify", str(FIX), "--out",
               str(out), "--init", str(init), "--fix", "Ms=0.0247"]
        t0 = time.perf_counter()
        run = subprocess.run(cmd, env={**os.environ, "STICKSLIP_CACHE_DIR": "off"},
                             capture_output=True, text=True)
        wall = time.perf_counter() - t0
        fitted = out / "params.json"
        params = json.loads(fitted.read_text()) if fitted.exists() else None
        fit = out / "fit.json"
        steps = json.loads(fit.read_text())["steps"] if fit.exists() else []
    return {"wall_s": wall, "exit_code": run.returncode,
            "steps_wall_s": sum(s["wall_s"] for s in steps), "params": params,
            "summary": [ln for ln in run.stdout.splitlines() if "NRMSE" in ln]}


def timed_identify(cache: str, out: Path) -> dict:
    """One `stickslip identify fixtures/identification --out OUT --fix Ms=0.0247` in a
    fresh process with ``STICKSLIP_CACHE_DIR=cache``: wall and CPU seconds, exit code,
    and the 1-minute load average just before it."""
    cmd = [str(Path(sys.executable).parent / "stickslip"), "identify", str(FIX), "--out",
           str(out), "--fix", "Ms=0.0247", "--force"]
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    run = subprocess.run(cmd, env={**os.environ, "STICKSLIP_CACHE_DIR": cache},
                         capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "exit_code": run.returncode, "load_1min": load}


def cold_and_warm(runs: int) -> dict:
    """Issue #28's measurement (module doc, 0): ``runs`` cold runs, one run filling an
    empty cache, ``runs`` warm runs."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        cold = [timed_identify("off", out) for _ in range(runs)]
        cache = Path(tmp) / "cache"
        cache.mkdir()
        fill = timed_identify(str(cache), out)
        warm = [timed_identify(str(cache), out) for _ in range(runs)]
    result = {"command": "stickslip identify fixtures/identification --out OUT "
                         "--fix Ms=0.0247", "fill": fill}
    for name, rs in (("cold", cold), ("warm", warm)):
        result[name] = {"runs": rs,
                        "median_wall_s": statistics.median(r["wall_s"] for r in rs),
                        "median_cpu_s": statistics.median(r["cpu_s"] for r in rs),
                        "all_exit_0": all(r["exit_code"] == 0 for r in rs)}
    return result


class OutOfBudget(Exception):
    """Raised by :class:`Recorder` when its evaluation budget is spent."""


class Recorder:
    """Wraps a residual function; records (seconds since start, cost) per call and
    raises :class:`OutOfBudget` past ``budget`` calls."""

    def __init__(self, fn, budget: int | None = None):
        self.fn, self.log, self.t0, self.budget = fn, [], None, budget

    def __call__(self, theta):
        if self.budget is not None and len(self.log) >= self.budget:
            raise OutOfBudget
        r = np.asarray(self.fn(jnp.asarray(theta)))
        self.log.append((time.perf_counter() - self.t0, float(np.sum(r**2))))
        return r

    def time_to(self, target: float) -> float | None:
        for t, c in self.log:
            if c <= target:
                return t
        return None


def joint_residuals(actuator, data: Dataset) -> TraceResiduals:
    """identify's joint-step residual (all recordings, each sample in units of its
    recording's noise) with the joint step's free parameters around ``actuator``."""
    return TraceResiduals.make(ParameterMap.make(actuator, JOINT), data, whiten=True)


def from_start_comparison(fitted: dict, identify_wall_s: float, max_evaluations: int) -> dict:
    """Issue #3 (a): scipy from identify's start to identify's final cost (module doc, 2)."""
    data = Dataset.from_recordings(ss.load_recordings(FIX))
    truth = ss.load_params(FIX / "truth.json")
    res = joint_residuals(ss.actuator_from_params(start_params()), data)
    fn = jax.jit(lambda th: res(th))
    theta0 = res.pmap.zeros()
    t0 = time.perf_counter()
    r0 = np.asarray(fn(theta0))  # compile before any timer
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    fn(theta0).block_until_ready()
    eval_s = time.perf_counter() - t0

    def cost_of(actuator) -> float:
        other = joint_residuals(actuator, data)
        return float(np.sum(np.asarray(jax.jit(lambda th: other(th))(other.pmap.zeros()))**2))

    target = cost_of(ss.actuator_from_params(fitted))
    truth_cost = cost_of(truth)
    print(f"(a) scipy over the JAX residuals from the start: cost {float(r0 @ r0):.4e}, "
          f"target (identify's) {target:.4e}, truth {truth_cost:.4e}; one evaluation "
          f"{eval_s:.3f} s (compile {compile_s:.1f} s, not timed)", flush=True)
    rec = Recorder(fn, budget=max_evaluations)
    rec.t0 = time.perf_counter()
    try:
        sp = scipy.optimize.least_squares(rec, np.asarray(theta0), method="trf",
                                          jac="2-point", x_scale="jac", max_nfev=10**6)
        status, message = int(sp.status), sp.message
    except OutOfBudget:
        status, message = -10, f"stopped at the budget of {max_evaluations} evaluations"
    wall = time.perf_counter() - rec.t0
    reached = rec.time_to(target * (1 + 1e-6))
    scipy_s = reached if reached is not None else wall
    return {
        "parameters": int(res.pmap.size), "residuals": int(r0.size),
        "compile_s": compile_s, "evaluation_s": eval_s,
        "cost_start": float(r0 @ r0), "target_cost": target, "truth_cost": truth_cost,
        "scipy_trf_2point": {"wall_s": wall, "evaluations": len(rec.log), "status": status,
                             "message": message,
                             "cost_best": min(c for _, c in rec.log),
                             "time_to_target_s": reached,
                             "time_to_noise_floor_s": rec.time_to(1.05 * truth_cost)},
        "identify_end_to_end_s": identify_wall_s,
        "speedup": scipy_s / identify_wall_s,
        "speedup_is_lower_bound": reached is None,
    }


def joint_comparison(max_nfev: int) -> dict:
    recs = ss.load_recordings(FIX)
    start = ss.actuator_from_params(start_params())
    first = identify(recs, init=start, fix={"Ms": 0.0247},
                     steps=("dynamics", "hysteresis", "friction"))
    res = joint_residuals(first.actuator, first.data)
    pmap = res.pmap
    fn = jax.jit(lambda th: res(th))
    theta0 = pmap.zeros()
    fn(theta0).block_until_ready()  # compile the residual before any timer
    # this package
    t0 = time.perf_counter()
    ours = solve_least_squares(res, theta0)
    wall_a = time.perf_counter() - t0
    target = ours.cost_end * (1 + 1e-6)
    # scipy TRF with 2-point finite differences over the same residuals
    rec = Recorder(fn)
    rec.t0 = time.perf_counter()
    sp = scipy.optimize.least_squares(rec, np.asarray(theta0), method="trf", jac="2-point",
                                      x_scale="jac", max_nfev=max_nfev)
    wall_b = time.perf_counter() - rec.t0
    reached = rec.time_to(target)
    return {
        "parameters": int(pmap.size), "residuals": int(fn(theta0).shape[0]),
        "ours": {"wall_s": wall_a, "iterations": ours.iterations, "converged": ours.converged,
                 "cost_start": ours.cost_start, "cost_end": ours.cost_end},
        "scipy_trf_2point": {"wall_s": wall_b, "nfev": int(sp.nfev), "status": int(sp.status),
                             "message": sp.message, "cost_end": float(2 * sp.cost),
                             "time_to_target_s": reached},
        "target_cost": target,
        "speedup": (reached / wall_a) if reached is not None else None,
        "speedup_lower_bound": wall_b / wall_a if reached is None else None,
    }


def write_json(path: Path | None, out: dict) -> None:
    """The figures so far to ``path`` (if given)."""
    if path:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(out, indent=1, default=str))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--max-nfev", type=int, default=1500,
                    help="scipy's evaluation budget (each Jacobian costs n_params + 1)")
    ap.add_argument("--max-evaluations", type=int, default=4000,
                    help="scipy's budget of simulator runs in (a) from the start "
                         "(Jacobian columns count)")
    ap.add_argument("--runs", type=int, default=3,
                    help="cold and warm runs of issue #28's command (0 skips them)")
    ap.add_argument("--skip-end-to-end", action="store_true",
                    help="also skips (a) from the start, which needs identify's result")
    ap.add_argument("--skip-joint", action="store_true")
    args = ap.parse_args(argv)
    out = {"jax": jax.__version__, "scipy": scipy.__version__, "cpus": os.cpu_count()}
    if args.runs > 0:
        out["cold_and_warm"] = cw = cold_and_warm(args.runs)
        for name in ("cold", "warm"):
            c = cw[name]
            walls = ", ".join(f"{r['wall_s']:.1f}" for r in c["runs"])
            print(f"identify {name}: median {c['median_wall_s']:.1f} s wall, "
                  f"{c['median_cpu_s']:.1f} s CPU over {args.runs} runs ({walls} s; "
                  f"target ≤ 20 s: "
                  f"{'PASS' if c['median_wall_s'] <= 20 and c['all_exit_0'] else 'MISS'})",
                  flush=True)
        write_json(args.json, out)
    if not args.skip_end_to_end:
        out["end_to_end"] = e = end_to_end()
        fitted = e.pop("params")
        print(f"end to end: {e['wall_s']:.1f} s (exit {e['exit_code']}; target < 60 s: "
              f"{'PASS' if e['wall_s'] < 60 and e['exit_code'] == 0 else 'MISS'})", flush=True)
        if fitted is not None:
            out["from_start"] = a = from_start_comparison(fitted, e["wall_s"],
                                                          args.max_evaluations)
            s = a["scipy_trf_2point"]
            print(f"  scipy: {s['wall_s']:.1f} s, {s['evaluations']} evaluations, "
                  f"{s['message']}; best cost {s['cost_best']:.4e}; time to identify's cost "
                  f"{s['time_to_target_s']}, to the truth's +5 % {s['time_to_noise_floor_s']}")
            print(f"  speed-up of identify end to end at equal cost: "
                  f"{'≥ ' if a['speedup_is_lower_bound'] else ''}{a['speedup']:.2f} "
                  f"(target ≥ 3: {'PASS' if a['speedup'] >= 3 else 'MISS'})", flush=True)
    write_json(args.json, out)  # (a) is kept even if the joint step fails
    if args.skip_joint:
        return 0
    out["joint"] = j = joint_comparison(args.max_nfev)
    print(f"joint step, {j['parameters']} parameters, {j['residuals']} residuals:")
    print(f"  optimistix LM (this package): {j['ours']['wall_s']:.1f} s, "
          f"{j['ours']['iterations']} steps, cost {j['ours']['cost_end']:.6e}")
    s = j["scipy_trf_2point"]
    print(f"  scipy trf 2-point: {s['wall_s']:.1f} s, nfev {s['nfev']}, cost {s['cost_end']:.6e}, "
          f"time to the LM's cost: {s['time_to_target_s']}")
    if j["speedup"] is not None:
        print(f"  ratio at equal cost: {j['speedup']:.2f} (information; the target is (a))")
    else:
        print(f"  scipy did not reach the LM's cost within --max-nfev; speed-up ≥ "
              f"{j['speedup_lower_bound']:.2f}")
    write_json(args.json, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

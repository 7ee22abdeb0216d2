"""A rejected point's cost: Jacobian at every point tried (eager) against a value-only
evaluation first and the Jacobian at accepted points only (lazy, the solver's
``value``, the default of the identification steps and the diagnosis's fits).

    .venv/bin/python benchmarks/experiments/bench_lazy_jacobian.py \\
        --json out/bench_lazy_jacobian.json

The data: the diagnosis tests' reduced protocol (8 recordings of 0.02-0.06 s at
25 kHz, 1 nm noise, seed 7) with a creep hidden in it (fixture form), as
tests/test_diagnose.py makes it. The fits, each through the shared programs of a
diagnosis :class:`~stickslip_jax.diagnose.problem.Problem`, with the diagnosis's
solver settings (Gauss-Newton test, initial damping 1):

- ``baseline_polish``: the baseline's quantities from the truth without the effect, at
  most 60 steps: the polish the reduced diagnosis starts with (it ends stalled, five
  rejected steps in a row, as most of the diagnosis's fits do);
- ``drive_low_pass``: the baseline and a first-order drive low-pass (the wrong entry,
  attached at a tenth of its probe's lag), 25 steps at most.

Each fit runs --repeats times each way, the two ways alternating, after one warm-up
of each (compilation out of the timings). Both ways must take the same steps to the
same cost (checked). Reported: medians of the walls, their ratio, and the counts of
Jacobian and value evaluations.
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: results_record
from results_record import write_record  # noqa: E402

import stickslip_jax as ss  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

import jax.numpy as jnp  # noqa: E402

from stickslip_jax.diagnose.catalogue import candidate  # noqa: E402
from stickslip_jax.diagnose.problem import Problem, baseline_free  # noqa: E402
from stickslip_jax.identify.dataset import Dataset  # noqa: E402
from stickslip_jax.identify.solve import solve_least_squares  # noqa: E402
from stickslip_jax.identify.steps import JOINT_GN_TOL  # noqa: E402
from stickslip_jax.synthetic import paper_protocol, simulate_set  # noqa: E402
from stickslip_jax.testing.concealed import with_effect  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TRUTH = ROOT / "fixtures" / "identification" / "truth.json"
MAX_STEPS = 25


def _problem(truth):
    specs = paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(100.0, 500.0),
                           step_duration_s=0.03, sine_periods=2)
    recs = simulate_set(with_effect(truth, "creep"), specs, noise_m=1e-9, seed=7)
    data = Dataset.from_recordings(recs)
    return Problem(data, np.full(len(recs), 1e-9), {"Ms": float(truth.slider.Ms)}, None)


def _fits(problem, truth):
    """``{name: (start actuator, names, specs, max_steps)}``."""
    names = baseline_free(truth, problem.data, problem.fix)
    entry = candidate("drive_bandwidth")
    probe = entry.probes(truth, {})[0]  # the low-pass
    drive, specs = entry.attach(truth, 0.1, probe)
    return {"baseline_polish": (truth, names, {}, 60),
            "drive_low_pass": (drive, names + list(specs), specs, MAX_STEPS)}


def _solve(problem, start, names, specs, max_steps: int, lazy: bool):
    program = problem.program(start, names, specs)
    counts = {"jacobian": 0, "value": 0}

    def jacobian(theta):
        counts["jacobian"] += 1
        return program(theta)

    value = program.value

    def value_only(theta):
        counts["value"] += 1
        return value(theta)

    t0 = time.perf_counter()
    out = solve_least_squares(program.residuals, jnp.asarray(program.pmap.zeros()),
                              max_steps=max_steps, gn_tol=JOINT_GN_TOL,
                              jacobian=jacobian, value=value_only if lazy else None,
                              label="bench")
    wall = time.perf_counter() - t0
    return wall, out, counts


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    truth = ss.load_params(TRUTH)
    problem = _problem(truth)
    rows = []
    for name, (start, names, specs, steps) in _fits(problem, truth).items():
        for lazy in (False, True):  # warm-up: compile both ways' programs
            _solve(problem, start, names, specs, steps, lazy)
        walls = {False: [], True: []}
        outs = {}
        for _ in range(args.repeats):
            for lazy in (False, True):
                wall, out, counts = _solve(problem, start, names, specs, steps, lazy)
                walls[lazy].append(wall)
                outs[lazy] = (out, counts)
        (eager, c_eager), (lazy, c_lazy) = outs[False], outs[True]
        same = (eager.iterations == lazy.iterations
                and np.allclose(eager.theta, lazy.theta, rtol=1e-9, atol=1e-12))
        row = {"fit": name, "columns": int(np.size(eager.theta)), "steps": eager.iterations,
               "message": lazy.message, "cost_start": eager.cost_start,
               "cost_end": {"eager": eager.cost_end, "lazy": lazy.cost_end},
               "same_path": bool(same),
               "evaluations": {"eager": c_eager, "lazy": c_lazy},
               "wall_s": {"eager": walls[False], "lazy": walls[True]},
               "median_s": {"eager": statistics.median(walls[False]),
                            "lazy": statistics.median(walls[True])}}
        row["lazy_over_eager"] = row["median_s"]["lazy"] / row["median_s"]["eager"]
        rows.append(row)
        print(f"{name:15s} {row['columns']:3d} columns, {row['steps']:2d} steps "
              f"({lazy.message[:40]}); Jacobians {c_eager['jacobian']} -> "
              f"{c_lazy['jacobian']} (+{c_lazy['value']} values); median "
              f"{row['median_s']['eager']:.2f} -> {row['median_s']['lazy']:.2f} s "
              f"(x{row['lazy_over_eager']:.2f}); same path: {same}", flush=True)
    write_record(args.json, repeats=args.repeats, rows=rows)


if __name__ == "__main__":
    main()

"""GPU smoke check of the simulator's new stepping (run on a lent GPU machine).

Times, after compilation, on whatever JAX's default backend is:
- ``simulate_batch`` of 17 rows of a 40 V, 500 Hz trace (``GPU_CHECK_DURATION`` s,
  default 1) (vmapped on an
  accelerator) at the default stepping and at the stepping before event location
  (RK4, 16 sub-steps per sample, nothing located or refined);
- a velocity map (``velocity_map``: 200 points, 10 periods; 8 points, 4 periods when
  the duration is under 0.5 s) at both;
- ``jax.jacfwd`` of one 0.2 s trace over 3 parameters.
Writes JSON to ``$OUT/gpu_check.json`` when ``OUT`` is set.

    PYTHONPATH=. python3 benchmarks/gpu_check.py
"""

from __future__ import annotations

import json
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402

TODAY = ss.Stepping.uniform(16, ss.RK4.with_events(False))


def timed(fn, repeats=3):
    jax.block_until_ready(fn())
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        out.append(time.perf_counter() - t0)
    return float(np.median(out))


def main():
    res = {"backend": jax.default_backend(), "devices": [str(d) for d in jax.devices()],
           "jax": jax.__version__}
    print(res, flush=True)
    act = ss.lu2015_slc1720()
    duration = float(os.environ.get("GPU_CHECK_DURATION", "1.0"))
    res["duration_s"] = duration
    u = ss.sawtooth(40.0, 500.0, duration_s=duration)[1]
    volts = np.stack([u] * 17)
    for name, st in (("default", None), ("today", TODAY)):
        t0 = time.perf_counter()
        q = ss.simulate_batch(act, volts, dt=4e-5, stepping=st)
        first = time.perf_counter() - t0
        res[f"batch17_{name}_s"] = timed(lambda st=st: ss.simulate_batch(act, volts, dt=4e-5,
                                                                           stepping=st))
        res[f"batch17_{name}_first_s"] = first
        res[f"batch17_{name}_finite"] = bool(np.all(np.isfinite(np.asarray(q))))
        print(name, "batch17", res[f"batch17_{name}_s"], "first", first, flush=True)
    small = duration < 0.5
    grid = (ss.DriveGrid.make([40.0, 60.0], [500.0, 1000.0], "both") if small else
            ss.DriveGrid.make(np.linspace(10, 80, 10), np.geomspace(50, 1000, 10), "both"))
    for name, st in (("default", None), ("today", TODAY)):
        t0 = time.perf_counter()
        periods = 4 if small else 10
        vm = ss.velocity_map(act, grid, periods=periods, stepping=st)
        res[f"sweep200_{name}_first_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        vm = ss.velocity_map(act, grid, periods=periods, stepping=st)
        res[f"sweep200_{name}_s"] = time.perf_counter() - t0
        v = vm.velocity_m_s
        res[f"sweep200_{name}_finite"] = bool(np.all(np.isfinite(v)))
        print(name, "sweep200", res[f"sweep200_{name}_s"], flush=True)
    plan = ss.plan_steps(act, 4e-5)
    u2 = jnp.asarray(ss.sawtooth(60.0, 500.0, duration_s=min(duration, 0.2))[1])

    def q_of(d):
        a = eqx.tree_at(lambda a: (a.piezo.Mp, a.piezo.Kp, a.friction.rho0), act,
                        (act.piezo.Mp * (1 + d[0]), act.piezo.Kp * (1 + d[1]),
                         act.friction.rho0 * (1 + d[2])))
        return ss.simulate(a, u2, dt=4e-5, stepping=plan)

    jac = jax.jit(jax.jacfwd(q_of))
    res["jacfwd3_s"] = timed(lambda: jac(jnp.zeros(3)))
    res["jacfwd3_finite"] = bool(np.all(np.isfinite(np.asarray(jac(jnp.zeros(3))))))
    print("jacfwd3", res["jacfwd3_s"], flush=True)
    out = os.environ.get("OUT")
    if out:
        with open(os.path.join(out, "gpu_check.json"), "w") as f:
            json.dump(res, f, indent=1)
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()

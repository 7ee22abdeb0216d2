"""Cost of a drive (input) stage: integrated apart from the mechanics (the default,
stickslip_jax/drive_path.py) against inside the mechanical Runge-Kutta step
(``Stepping(stage_apart=False)``, where the sub-steps must resolve its poles).

    .venv/bin/python benchmarks/bench_drive_stage.py --json out/bench_drive_stage.json

The paper's 17-recording protocol as one padded batch, on the default profile, with no
stage and with amplifiers of several bandwidths. Per case and mode: the plan (coarse
sub-steps per sample, the stage's own steps per gap), the median wall of a value pass
and of a forward-mode Jacobian with 4 columns (Mp, Dp, Kp and the stage's time
constant or slew), each over ``--runs`` repeats after one compiling call, their ratio to
the no-stage case, and the RMS difference between the two modes' traces [nm]. The
issue: a drive refit's Jacobian step took 7.4 s against 1.3 s for the other entries
(#27), because a 1 µs amplifier sets 80 sub-steps per sample against 8. The tanh slew
limit also by RK4 steps of its rate ("_rk4"), as before its exact step
(stickslip_jax/model/slew_exact.py), side by side, at 1 µs and 0.1 µs.
"""

import argparse
import json
import statistics
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.model.base import AbstractInputStage  # noqa: E402
from stickslip_jax.model.extensions import (  # noqa: E402
    LowPassInput,
    SecondOrderInput,
    SlewLimitedInput,
)
from stickslip_jax.simulate import pad_voltages  # noqa: E402
from stickslip_jax.synthetic import paper_protocol  # noqa: E402

ss.fast_cpu_loops()



class SteppedSlew(SlewLimitedInput):
    """The tanh slew limit by RK4 steps of its rate (before its exact step)."""

    advance = AbstractInputStage.advance


CASES = {
    "none": None,
    "low_pass_20us": LowPassInput(20e-6),
    "low_pass_5us": LowPassInput(5e-6),
    "low_pass_1us": LowPassInput(1e-6),
    "slew_1.2V_per_us": SlewLimitedInput(1.2e6, 1e-6),
    "slew_1.2V_per_us_rk4": SteppedSlew(1.2e6, 1e-6),
    "slew_0.1us": SlewLimitedInput(1.2e6, 0.1e-6),
    "slew_0.1us_rk4": SteppedSlew(1.2e6, 0.1e-6),
    "two_pole_60kHz": SecondOrderInput(60e3, 0.5),
}
MODES = {"apart": ss.Stepping(), "inside": ss.Stepping(stage_apart=False)}
APART_ONLY = ("slew_1.2V_per_us_rk4", "slew_0.1us", "slew_0.1us_rk4")
"""Cases whose "inside" mode is another case's (the same model) or too slow to time
(0.1 µs: 800 mechanical sub-steps per sample)."""


def stage_leaf(a):
    st = a.input_stage
    return st.frequency if isinstance(st, SecondOrderInput) else (
        st.slew if isinstance(st, SlewLimitedInput) else st.tau)


def median_time(fn, runs):
    jax.block_until_ready(fn())
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    recs = [d.recording() for d in paper_protocol()]
    volts, _ = pad_voltages([r.voltage_V for r in recs])
    volts = jnp.asarray(volts)
    dt = recs[0].dt
    base = ss.lu2015_slc1720()
    rows, traces = [], {}
    for case, stage in CASES.items():
        act = base if stage is None else eqx.tree_at(lambda a: a.input_stage, base, stage)
        getters = [lambda a: a.piezo.Mp, lambda a: a.piezo.Dp, lambda a: a.piezo.Kp]
        if stage is not None:
            getters.append(stage_leaf)
        for mode, stepping in MODES.items():
            if (stage is None or case in APART_ONLY) and mode == "inside":
                continue
            plan = ss.plan_steps(act, dt, stepping=stepping)

            def value(act=act, plan=plan):
                return ss.simulate_batch(act, volts, dt=dt, stepping=plan)

            def jacobian(act=act, plan=plan, getters=getters):
                theta = jnp.ones(len(getters))

                def scaled(th):
                    a = act
                    for g, f in zip(getters, th, strict=True):
                        a = eqx.tree_at(g, a, g(act) * f)
                    return ss.simulate_batch(a, volts, dt=dt, stepping=plan)

                return jax.jacfwd(scaled)(theta)

            t_value, value_runs = median_time(value, args.runs)
            t_jac, jac_runs = median_time(jacobian, args.runs)
            traces[(case, mode)] = np.asarray(value())
            rows.append({"case": case, "mode": mode, "substeps": plan.substeps,
                         "stage_substeps": plan.stage_substeps, "value_s": t_value,
                         "jacobian_s": t_jac, "value_runs": value_runs,
                         "jacobian_runs": jac_runs})
            print(f"{case:18s} {mode:6s} sub-steps {plan.substeps:4d} (stage {plan.stage_substeps})"
                  f"  value {t_value:7.3f} s  jacobian(4) {t_jac:7.3f} s", flush=True)
    ref = {r["mode"]: r for r in rows if r["case"] == "none"}["apart"]
    for r in rows:
        r["value_ratio_to_none"] = r["value_s"] / ref["value_s"]
        r["jacobian_ratio_to_none"] = r["jacobian_s"] / ref["jacobian_s"]
        other = traces.get((r["case"], "inside"))
        if r["mode"] == "apart" and other is not None:
            d = traces[(r["case"], "apart")] - other
            r["rms_apart_minus_inside_nm"] = float(np.sqrt(np.mean(d**2)) * 1e9)
    print("\ncase               mode   value/none  jacobian/none  apart−inside [nm RMS]")
    for r in rows:
        diff = r.get("rms_apart_minus_inside_nm")
        print(f"{r['case']:18s} {r['mode']:6s} {r['value_ratio_to_none']:10.2f} "
              f"{r['jacobian_ratio_to_none']:14.2f}  "
              + ("" if diff is None else f"{diff:.4f}"))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"rows": rows, "runs": args.runs}, indent=1))


if __name__ == "__main__":
    main()

"""Identify one set of the random split from the default profile, as ``stickslip
diagnose`` does (``--fix Ms=0.0247``, steps dynamics, hysteresis, friction, joint), and
print where its work went: each step's plans of sub-steps with the evaluations made at
each and their counted work [sample-evaluations], then the piezo's identified values
with their standard errors. For looking at how an unmodelled effect bends the
identification (the baseline of a diagnosis) on development draws.

    .venv/bin/python scripts/identify_split_set.py --split dev --index 39 --scale -6

``--scale`` multiplies the drawn effect strength (development analogues; the frozen test
split is reported as drawn, so the scale is refused there).
"""

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import stickslip_jax as ss
from stickslip_jax.diagnose import budget
from stickslip_jax.diagnose.problem import segment_work
from stickslip_jax.identify.steps import identify
from stickslip_jax.testing import random_sets as rs

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_diagnose import protocol  # noqa: E402
from bench_diagnose_split import SEEDS  # noqa: E402

PIEZO = ("Mp", "Dp", "Kp", "Ds", "rho0", "z_ba_forward", "z_ba_backward")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=sorted(SEEDS), default="dev")
    ap.add_argument("--index", type=int, required=True)
    ap.add_argument("--scale", type=float, default=1.0,
                    help="the drawn effect strength times this (dev only)")
    args = ap.parse_args()
    if args.scale != 1.0 and args.split not in ("dev", "dev2"):
        sys.exit("--scale is for development analogues: the test split is used as drawn")
    seed, design = rs.SPLITS[args.split]
    spec = rs.draw_set(seed, args.index, design)
    spec = dataclasses.replace(spec, strength=spec.strength * args.scale)
    print(f"{spec.name}: {spec.effect} ({spec.form}), {spec.strength_name} "
          f"{spec.strength:.4g} {spec.strength_unit}, {spec.others}")
    recs = rs.make_recordings(spec, protocol(False))
    t0 = time.perf_counter()
    ident = identify(recs, init=ss.lu2015_slc1720(), fix={"Ms": 0.0247},
                     steps=("dynamics", "hysteresis", "friction", "joint"),
                     echo=lambda s: None if "accepted" in s else print("   ", s, flush=True))
    print(f"wall {time.perf_counter() - t0:.1f} s")
    stage = ident.actuator.input_stage
    total = 0.0
    for st, seg, work in segment_work(ident, ident.data,
                                      lambda plan: budget.plan_factor(plan, stage)):
        total += work
        print(f"{st.name:11s} sub-steps {seg.plan.substeps:4d}  Jacobians "
              f"{seg.jacobians:3d}  values {seg.values:3d}  work {work:.3g}")
    print(f"steps' work {total:.3g} sample-evaluations")
    truth = spec.truth
    found = ident.uncertainty.as_dict() if ident.uncertainty is not None else {}
    for name in PIEZO:
        f = found.get(name)
        if f is None:
            continue
        rel = f["relative_error"]
        print(f"{name:13s} {f['value']:.4g} (truth {truth.get(name, float('nan')):.4g}), "
              f"relative SE {rel if rel is None else f'{rel:.3g}'}, "
              f"determined {f['determined']}")


if __name__ == "__main__":
    main()

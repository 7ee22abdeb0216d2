"""The identification's verdict on its own fit (issue #65), on random development sets:
is a model that lacks the hidden effect called misspecified, one that lacks nothing
left alone, and does the leave-one-regime-out spread cover the truth where the
standard errors do not?

    .venv/bin/python benchmarks/bench_model_check.py --sets 0,1,2,3 \\
        --json benchmarks/results/model_check_dev.json

Each set is drawn by :func:`stickslip_jax.testing.random_sets.draw_set` from the
development seed (never the frozen test split) and simulated in memory, 16x finer than
fits use (:func:`~stickslip_jax.testing.random_sets.make_recordings`): the paper's 17
recordings from a random truth, one hidden effect or none, white noise 0.5-2 nm. It is
identified as ``stickslip identify DIR --fix Ms=0.0247`` does (the four steps from the
default profile, the regime spread when misspecified). Per set: the hidden effect, its
size over the noise, the verdict (adequate, mismatch, misspecified), the mean (e/σ)²,
and for the piezo's values the largest ``|fit − truth|`` in standard errors and, where
the spread was computed, in spreads. Rows are appended as sets end (an interrupted run
resumes); the summary counts verdicts against the hidden effect.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)


import stickslip_jax as ss  # noqa: E402
from stickslip_jax.identify.steps import identify  # noqa: E402
from stickslip_jax.params import params_from_actuator  # noqa: E402
from stickslip_jax.testing import random_sets as rs  # noqa: E402

ss.fast_cpu_loops()

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_diagnose import protocol  # noqa: E402
from results_record import write_record  # noqa: E402

PIEZO = ("Mp", "Dp", "Kp", "Ds", "rho0", "z_ba_forward", "z_ba_backward")


def run_set(index: int) -> dict:
    """One development set identified and judged (module docstring)."""
    spec = rs.draw_set(rs.DEV_SEED, index)
    recs = rs.make_recordings(spec, protocol(False))
    size = 0.0 if spec.effect == "none" else rs.effect_size(spec, protocol(False))["to_noise"]
    t0 = time.perf_counter()
    ident = identify(recs, init=ss.lu2015_slc1720(), fix={"Ms": 0.0247},
                     spread_if_mismatch=True)
    wall = time.perf_counter() - t0
    truth = params_from_actuator(rs.truth_actuator(spec))
    unc = ident.uncertainty.as_dict()
    spread = ident.regime_spread.spread if ident.regime_spread is not None else {}
    z_se, z_spread = {}, {}
    for name in PIEZO:
        if name not in unc or name not in truth:
            continue
        err = abs(unc[name]["value"] - truth[name])
        se = unc[name]["std_error"]
        z_se[name] = err / se if se else None
        if spread.get(name):
            z_spread[name] = err / spread[name]
    check = ident.model_check
    return {"set": spec.name, "index": index, "effect": spec.effect, "form": spec.form,
            "noise_nm": spec.noise_m * 1e9,
            "effect_to_noise": float(size),
            "verdict": check.verdict, "chi2": check.chi2_overall,
            "tolerance_chi2": check.significance.tolerance,
            "misspecified_recordings": list(check.misspecified_recordings),
            "converged": ident.converged, "max_z_se": max(
                (z for z in z_se.values() if z is not None), default=None),
            "max_z_spread": max(z_spread.values(), default=None),
            "z_se": z_se, "z_spread": z_spread, "wall_s": round(wall, 1)}


def summary(rows: list[dict]) -> dict:
    """Verdicts against the hidden effect: nulls called misspecified, effects called
    each verdict."""
    null = [r for r in rows if r["effect"] == "none"]
    hidden = [r for r in rows if r["effect"] != "none"]
    count = {v: sum(r["verdict"] == v for r in hidden)
             for v in ("adequate", "mismatch", "misspecified")}
    return {"sets": len(rows), "nulls": len(null),
            "nulls_misspecified": sum(r["verdict"] == "misspecified" for r in null),
            "nulls_adequate": sum(r["verdict"] == "adequate" for r in null),
            "hidden_by_verdict": count}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", required=True, help="comma-separated development indices")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    rows = []
    if args.json is not None and args.json.exists():
        rows = json.loads(args.json.read_text()).get("rows", [])
    done = {r["index"] for r in rows}
    for index in (int(i) for i in args.sets.split(",")):
        if index in done:
            continue
        row = run_set(index)
        rows.append(row)
        print(f"{row['set']:8s} {row['effect']:22s} size {row['effect_to_noise']:.3g} "
              f"{row['verdict']:12s} chi2 "
              f"{row['chi2']:.3g}  max|z| SE {row['max_z_se']}  spread "
              f"{row['max_z_spread']}  {row['wall_s']} s", flush=True)
        write_record(args.json, rows=rows, summary=summary(rows))
    print(json.dumps(summary(rows), indent=1))


if __name__ == "__main__":
    main()

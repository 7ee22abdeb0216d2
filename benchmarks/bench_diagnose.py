"""Diagnosis on every concealed set: which effect it names, the fit before and after, time.

    .venv/bin/python benchmarks/bench_diagnose.py --json out/bench_diagnose.json
    .venv/bin/python benchmarks/bench_diagnose.py --sets set_03,set_09 --from-profile

For each folder of fixtures/concealed/ (17 recordings, the identification protocol with
one hidden effect, see fixtures/concealed/README.md) run :func:`diagnose` and compare
with ``answers.json``. The baseline starts from the identification truth without the
effect (``fixtures/identification/truth.json``) and is polished on the data; with
``--from-profile`` it is identified from the default profile first (the paper's three
steps plus joint, as `stickslip diagnose` does without ``--skip-identify``), which is
the end-to-end timing of the issue (target: < 10 min per 17-recording set).

Columns: hidden effect, named effect (first accepted; ``unexplained`` when the verdict
is the unexplained residual; ``-`` when nothing was named), verdict, mean NRMSE before
and after, the noise floor (mean σ/peak-to-peak), the share of the NRMSE excess over the
floor removed, wall time (compilation included).
"""

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.diagnose import diagnose  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CONCEALED = ROOT / "fixtures" / "concealed"


def run_set(folder: Path, *, from_profile: bool, max_rounds: int) -> dict:
    recs = ss.load_recordings([folder])
    if from_profile:
        init, steps = ss.lu2015_slc1720(), ("dynamics", "hysteresis", "friction", "joint")
    else:
        init, steps = ss.load_params(ROOT / "fixtures" / "identification" / "truth.json"), ()
    t0 = time.perf_counter()
    d = diagnose(recs, init=init, fix={"Ms": 0.0247}, identify_steps=steps,
                 max_rounds=max_rounds, echo=lambda s: print("   ", s, flush=True))
    wall = time.perf_counter() - t0
    floor = float(np.mean([a.noise_m / np.ptp(r.position_m)
                           for a, r in zip(d.analyses_baseline, recs, strict=True)]))
    before, after = float(d.nrmse_baseline.mean()), float(d.nrmse_final.mean())
    excess = before - floor
    named = [c.name for c in d.accepted]
    return {
        "set": folder.name, "verdict": d.verdict, "named": named,
        "first": ("unexplained" if d.verdict == "unexplained residual" and not named
                  else named[0] if named else "-"),
        "indistinguishable_from": d.accepted[0].indistinguishable_from if named else [],
        "nrmse_before": before, "nrmse_after": after, "noise_floor_nrmse": floor,
        "excess_removed": (before - after) / excess if excess > 0 else None,
        "chi2_before": d.chi2_baseline, "chi2_after": d.chi2_final,
        "unexplained_depends_on": (d.unexplained or {}).get("depends_on"),
        "wall_s": wall, "timings_s": d.timings,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="", help="comma-separated set folders (default all)")
    ap.add_argument("--from-profile", action="store_true",
                    help="identify the baseline from the default profile first")
    ap.add_argument("--max-rounds", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    answers = json.loads((CONCEALED / "answers.json").read_text())["sets"]
    chosen = [s for s in args.sets.split(",") if s] or sorted(answers)
    rows = []
    for name in chosen:
        print(f"== {name}", flush=True)
        row = run_set(CONCEALED / name, from_profile=args.from_profile,
                      max_rounds=args.max_rounds)
        row["hidden"] = answers[name]
        rows.append(row)
        print(json.dumps({k: row[k] for k in ("set", "hidden", "first", "verdict",
                                              "nrmse_before", "nrmse_after", "wall_s")}),
              flush=True)
    print("\n| set | hidden effect | named first | verdict | NRMSE before | NRMSE after | "
          "floor | excess removed | wall |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        ex = "" if r["excess_removed"] is None else f"{100 * r['excess_removed']:.0f} %"
        print(f"| {r['set']} | {r['hidden']} | {r['first']} | {r['verdict']} | "
              f"{100 * r['nrmse_before']:.4f} % | {100 * r['nrmse_after']:.4f} % | "
              f"{100 * r['noise_floor_nrmse']:.4f} % | {ex} | {r['wall_s']:.0f} s |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"rows": rows, "from_profile": args.from_profile,
                                         "jax": jax.__version__}, indent=1, default=float))
    sys.exit(0)


if __name__ == "__main__":
    main()

"""One arm of ``bench_design_loop.py`` diagnosed again under another configuration:
does the designed arm's answer on a set change with an opt-in refit pass or another
work budget?

The set's recordings, its first diagnosis (read from ``--work DIR/set_NN/diag0``, as
``bench_design_loop.py`` wrote it), the plan and the arm's new recordings (the same
seeds) are made as that benchmark makes them; only the last diagnosis runs with the
change. It is written to ``--out``.

```sh
.venv/bin/python benchmarks/experiments/design_arm_rerun.py --split dev2 --set 47 \\
    --work out/design_loop --with-pass carry_on --work-budget 0 --out out/arm47_nobudget
```
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.diagnose.config import DiagnoseConfig  # noqa: E402
from stickslip_jax.diagnose.report import write_diagnosis  # noqa: E402
from stickslip_jax.testing import random_sets as rs  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench_design_loop import ARM_SEEDS, FIX, arm_recordings  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="dev2", choices=("dev", "dev2"))  # never a test split
    ap.add_argument("--set", type=int, required=True, help="the set's number (47: set_47)")
    ap.add_argument("--work", type=Path, required=True,
                    help="bench_design_loop.py's --work folder (its set_NN/diag0 is read)")
    ap.add_argument("--arm", default="designed", choices=sorted(ARM_SEEDS))
    ap.add_argument("--with-pass", default="", help="opt-in refit passes, comma-separated")
    ap.add_argument("--work-budget", type=float, default=None,
                    help="the diagnosis's work budget (0: no limit; default: the default)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    ss.fast_cpu_loops()
    name = f"set_{args.set:02d}"
    spec = rs.split_sets(args.split, args.set + 1)[args.set]  # drawn per index
    diag0 = args.work / name / "diag0"
    if not (diag0 / "diagnosis.json").is_file():
        sys.exit(f"{diag0}/diagnosis.json: run bench_design_loop.py on {name} first")
    recs = rs.make_recordings(spec)
    plan = ss.design_experiment(recs, diag0, fix=FIX, echo=lambda s: None)
    new = arm_recordings(spec, recs, plan, args.arm)
    config = DiagnoseConfig()
    if args.with_pass:
        config = config.with_passes(*args.with_pass.split(","))
    if args.work_budget is not None:
        config = config.replace(work_budget=args.work_budget)
    t0 = time.perf_counter()
    d = ss.diagnose(recs + new, init=ss.lu2015_slc1720(), fix=FIX, config=config,
                    echo=lambda s: print("   ", s, flush=True))
    args.out.mkdir(parents=True, exist_ok=True)
    write_diagnosis(d, args.out, figures=False)
    content = json.loads((args.out / "diagnosis.json").read_text())
    named = [(m["name"], m["evidence"].get("indistinguishable_from", []))
             for m in content["missing_physics"]]
    print(f"{name} ({', '.join(spec.hidden)}, {spec.form}), the {args.arm} arm: "
          f"{content['verdict']}, named {named or 'nothing'}, mean (e/σ)² "
          f"{content['final']['chi2_per_sample']:.4g}, work {d.work['spent']:.3g}, "
          f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()

"""Is a plan's first-order evidence what a refit finds (issue #68)?

The plan (:mod:`stickslip_jax.design`) predicts each question's evidence ``λ`` (the
excess cost of the wrong model refitted to the truth's traces) from Jacobians at the
fitted models: the linearised refit. Here the truth's traces are simulated without
noise on the recordings so far and on those plus the plan's, and the rival is refitted
to them by the diagnosis's own Levenberg-Marquardt fit (every baseline quantity and its
parts' free); its cost is the evidence, to compare with ``ratio × τ``. For an entry
not named, also at the detection limit the plan states: the entry at that strength,
on the recordings with the plan's, should cost the refitted rival ``τ``.

```sh
.venv/bin/python benchmarks/bench_design_linear.py fixtures/identification \\
    --diagnosis out/diag_null --entry stribeck --json out/design_linear.json
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

import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.diagnose.problem import Problem, baseline_free  # noqa: E402
from stickslip_jax.identify.dataset import Dataset  # noqa: E402
from stickslip_jax.simulate import simulate_recordings  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results_record import commit_of  # noqa: E402


def refit_cost(truth, rival, drives, sigmas, fix, max_steps) -> tuple[float, float, float]:
    """The rival's whitened cost on the truth's noise-free traces of ``drives``,
    before and after its refit, and the refit's wall time [s]."""
    q = simulate_recordings(truth, drives)
    data = Dataset.from_recordings([d.with_position_m(x) for d, x in zip(drives, q,
                                                                        strict=True)])
    problem = Problem(data, sigmas, fix, lambda s: print("   ", s, flush=True))
    before = problem.evaluate(rival.actuator)[0]
    names = baseline_free(rival.actuator, data, fix) + list(rival.specs)
    t0 = time.perf_counter()
    _, after, _ = problem.fit(rival.actuator, names, rival.specs, label="refit",
                              max_steps=max_steps)
    return float(before), float(after), time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--diagnosis", type=Path, required=True)
    ap.add_argument("--entry", required=True)
    ap.add_argument("--fix", default="Ms=0.0247")
    ap.add_argument("--max-steps", type=int, default=40)
    ap.add_argument("--json", type=Path, required=True)
    args = ap.parse_args()
    ss.fast_cpu_loops()
    fix = {k: float(v) for k, v in (item.split("=") for item in args.fix.split(",") if item)}
    recs = ss.load_recordings([args.data])
    plan = ss.design_experiment(recs, args.diagnosis, fix=fix, entries=[args.entry],
                                echo=lambda s: print(s, flush=True))
    rows = []
    sig_old = np.array([ss.noise_sigma(r) for r in recs])
    new = [r.drive.recording(plan.limits.sample_rate_Hz) for r in plan.recordings]
    for outcome, q in zip(plan.questions, plan.asked, strict=True):
        ways = [(q.truth, q.rival)] + ([(q.rival, q.truth)] if q.both_ways else [])
        for truth, rival in ways:
            for label, drives, ratio, tol in (
                    ("now", list(recs), outcome.ratio_now, plan.tolerances[0]),
                    ("plan", list(recs) + new, outcome.ratio_designed, plan.tolerances[2])):
                sigmas = np.concatenate([sig_old, np.full(len(drives) - len(recs),
                                                          plan.noise_nm * 1e-9)])
                before, after, wall = refit_cost(truth.actuator, rival, drives, sigmas, fix,
                                                 args.max_steps)
                row = {"question": outcome.label, "truth": truth.label,
                       "rival": rival.label, "recordings": label,
                       "predicted": ratio * tol, "refitted": after,
                       "rival_cost_unrefitted": before, "refit_s": wall}
                print(json.dumps(row), flush=True)
                rows.append(row)
        if q.kind == "limit" and np.isfinite(outcome.limit_designed):
            # The limit the plan states: the entry at it should just reach the tolerance
            # on the recordings with the plan's (a small effect: where first order holds).
            drives = list(recs) + new
            sigmas = np.concatenate([sig_old, np.full(len(new), plan.noise_nm * 1e-9)])
            before, after, wall = refit_cost(q.at_strength(outcome.limit_designed), q.rival,
                                             drives, sigmas, fix, args.max_steps)
            row = {"question": outcome.label, "truth": f"{q.entry} at the limit after",
                   "strength": outcome.limit_designed, "rival": q.rival.label,
                   "recordings": "plan", "predicted": plan.tolerances[2],
                   "refitted": after, "rival_cost_unrefitted": before, "refit_s": wall}
            print(json.dumps(row), flush=True)
            rows.append(row)
    ss.files.atomic_write_text(args.json, json.dumps(
        {"what": __doc__.split("\n\n")[0], "data": str(args.data), "entry": args.entry,
         "plan": [r.drive.name + f" x{r.units}" for r in plan.recordings],
         "tolerance_rss": {"now": plan.tolerances[0], "plan": plan.tolerances[2]},
         "commit": commit_of(), "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()

"""Two checkouts side by side on an ``ss.identify`` call the command line cannot make
(by default the dynamics step alone without the uncertainty, as a diagnosis's
re-identification or a notebook runs it), cold: wall time and the mean NRMSE.

    .venv/bin/python benchmarks/experiments/bench_identify_api_checkouts.py \\
        /tmp/before . --pairs 3 --json out/identify_api.json

Each run is a fresh process of this virtual environment with ``PYTHONPATH`` set to the
checkout and a new, empty compilation cache and program store (what a first run
pays); the bundled fixtures of this repository, ``fix Ms=0.0247``, XLA's native loops
on (``fast_cpu_loops``, as the command line). Runs alternate which checkout goes
first. Reported: each checkout's walls (the ``identify`` call alone), their medians and
ratio, and the mean NRMSE of each run (equal where the arithmetic is).
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from checkout_process import run_in_checkout

ROOT = Path(__file__).resolve().parents[2]

RUN = """
import json, sys, tempfile, time
import stickslip_jax as ss
ss.fast_cpu_loops()
import jax
jax.config.update("jax_enable_x64", True)
from pathlib import Path
from stickslip_jax.compilation_cache import use_compilation_cache
use_compilation_cache(tempfile.mkdtemp(prefix="bench_identify_api_"))
folder = Path(sys.argv[1])
recs = [ss.load_recording(p) for p in sorted(folder.glob("*.csv"))]
base = ss.load_params(folder / "truth.json")
steps = tuple(sys.argv[2].split(","))
t0 = time.perf_counter()
ident = ss.identify(recs, init=base, fix={"Ms": 0.0247}, steps=steps,
                    uncertainty=sys.argv[3] == "on")
wall = time.perf_counter() - t0
print(json.dumps({"wall_s": wall, "nrmse_mean": float(ident.nrmse.mean()),
                  "module": ss.__file__}))
"""


def one_run(checkout: Path, steps: str, uncertainty: str) -> dict:
    """One cold ``identify`` of ``checkout`` in a fresh process."""
    return run_in_checkout(checkout, RUN, (ROOT / "fixtures" / "identification", steps,
                                           uncertainty))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path, help="checkout A (e.g. a `git worktree`)")
    ap.add_argument("after", type=Path, help="checkout B")
    ap.add_argument("--pairs", type=int, default=3, help="recorded runs of each checkout")
    ap.add_argument("--steps", default="dynamics", help="identify's steps, comma-separated")
    ap.add_argument("--uncertainty", choices=("on", "off"), default="off")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    rows = {"before": [], "after": []}
    for i in range(args.pairs):
        order = ("before", "after") if i % 2 == 0 else ("after", "before")
        for which in order:
            row = one_run(getattr(args, which), args.steps, args.uncertainty)
            rows[which].append(row)
            print(f"pair {i + 1} {which}: {row['wall_s']:.2f} s, mean NRMSE "
                  f"{row['nrmse_mean']:.12g}", flush=True)
    medians = {k: statistics.median(r["wall_s"] for r in v) for k, v in rows.items()}
    summary = {"steps": args.steps, "uncertainty": args.uncertainty,
               "before": str(args.before), "after": str(args.after),
               "median_wall_s": medians, "ratio": medians["after"] / medians["before"],
               "runs": rows}
    print(f"median {medians['before']:.2f} s -> {medians['after']:.2f} s, ratio "
          f"{summary['ratio']:.2f}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()

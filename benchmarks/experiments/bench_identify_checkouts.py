"""Two checkouts side by side on ``stickslip identify`` of the bundled fixtures: wall
time cold and warm, and how far apart the identified parameters are.

    .venv/bin/python benchmarks/experiments/bench_identify_checkouts.py /tmp/before . \\
        --pairs 3 --json out/identify_checkouts.json

Each run is a fresh process of this virtual environment with ``PYTHONPATH`` set to the
checkout, the command as the README gives it (``identify fixtures/identification --fix
Ms=0.0247``, figures included) run from the checkout's folder. *Cold*: a new, empty
compilation cache for the run (what a first run pays). *Warm*: one cache per checkout,
filled by one unrecorded run of each before the recorded ones (what a second run
pays). A checkout's own cache, never the other's: the traced-program store keeps
programs of the code that traced them. Runs alternate which checkout goes first.
Reported: each checkout's median walls, their ratios, and the largest relative
difference between the two checkouts' ``params.json`` (the last warm runs').

A checkout from before the console entry moved out of the package (``stickslip_cli.py``)
is run through ``stickslip_jax.cli.main:app``, as its ``stickslip`` command was.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # results_record
sys.path.insert(0, str(HERE))  # bench_checkouts
from bench_checkouts import differences  # noqa: E402
from results_record import commit_of, write_record  # noqa: E402

ARGS = ["identify", "fixtures/identification", "--fix", "Ms=0.0247"]


def entry(checkout: Path) -> str:
    """The ``python -c`` program that is the checkout's ``stickslip`` command."""
    if (checkout / "stickslip_cli.py").exists():
        return "import sys, stickslip_cli; sys.exit(stickslip_cli.main())"
    return "from stickslip_jax.cli.main import app; app()"


def run_once(checkout: Path, cache: Path, out: Path) -> float:
    """Wall seconds of one identify of the fixtures by ``checkout`` into ``out``."""
    env = dict(os.environ, PYTHONPATH=str(checkout), MPLBACKEND="Agg",
               STICKSLIP_CACHE_DIR=str(cache))
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", entry(checkout), *ARGS, "--out", str(out)],
                          env=env, cwd=checkout, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{checkout}: identify failed:\n{done.stderr[-3000:]}")
    return wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path, help="checkout A (e.g. a `git worktree`)")
    ap.add_argument("after", type=Path, help="checkout B")
    ap.add_argument("--pairs", type=int, default=3, help="recorded runs of each checkout")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    checkouts = {"before": args.before.resolve(), "after": args.after.resolve()}
    walls = {k: {"cold": [], "warm": []} for k in checkouts}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for k, checkout in checkouts.items():
            wall = run_once(checkout, tmp / f"cache_{k}", tmp / f"warm-up_{k}")
            print(f"{k} warm-up: {wall:.1f} s", flush=True)
        for i in range(1, args.pairs + 1):
            order = list(checkouts) if i % 2 else list(reversed(checkouts))
            for k in order:
                for mode in ("cold", "warm"):
                    cache = tmp / (f"cold_{k}_{i}" if mode == "cold" else f"cache_{k}")
                    wall = run_once(checkouts[k], cache, tmp / f"{mode}_{k}_{i}")
                    walls[k][mode].append(wall)
                    print(f"{k} {mode} {i}: {wall:.1f} s", flush=True)
        last = {k: json.loads((tmp / f"warm_{k}_{args.pairs}" / "params.json").read_text())
                for k in checkouts}
    worst, where, other = differences(last["before"], last["after"])
    median = {k: {m: statistics.median(v) for m, v in w.items()} for k, w in walls.items()}
    ratio = {m: median["after"][m] / median["before"][m] for m in ("cold", "warm")}
    for m in ("cold", "warm"):
        print(f"{m}: median {median['before'][m]:.1f} -> {median['after'][m]:.1f} s "
              f"({ratio[m]:.2f}x)")
    print(f"params.json: largest relative difference {worst:.2g} at {where or '-'}; "
          f"keys in one only: {other or 'none'}")
    write_record(args.json, before=str(args.before), after=str(args.after),
                 before_commit=commit_of(args.before), after_commit=commit_of(args.after),
                 wall_s=walls, median_s=median, ratio=ratio,
                 largest_relative_difference=worst, where=where, other_differences=other)


if __name__ == "__main__":
    main()

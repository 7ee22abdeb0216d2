"""Two checkouts side by side on the diagnosis tests' reduced sets: wall time and every
number of the diagnosis.

    .venv/bin/python benchmarks/experiments/bench_checkouts.py /tmp/before . \\
        --effects uncatalogued,structural_mode --pairs 2 --json out/checkouts.json

Each run is a fresh process (``PYTHONPATH`` set to the checkout; the same virtual
environment and, where ``$STICKSLIP_CACHE_DIR`` names one, the same compilation cache),
diagnosing the reduced set of ``tests/test_diagnose.py`` (8 recordings; the baseline
polished from the truth, one round, two refits, 20 steps) with one hidden ``effect``
(``uncatalogued`` and ``none`` with the fallback, as their tests run them; the others
without). Runs alternate which checkout goes first, after one unrecorded warm-up run of
each (the traced-program store and the compilation cache filled); with ``--cold`` no
cache at all and no warm-up (every run compiles everything). Reported per effect:
the median wall of each checkout and their ratio, and how far apart every number of
the two checkouts' ``diagnosis.json`` content is (timings left out): the largest
relative difference and where, and whether any decision (a name, a status, a verdict)
differs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))  # results_record
from results_record import commit_of, write_record  # noqa: E402

CHILD = """
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import stickslip_jax as ss
ss.fast_cpu_loops()
from stickslip_jax.compilation_cache import cache_dir_from_env, use_compilation_cache
use_compilation_cache(cache_dir_from_env(default=None))
sys.path.insert(0, sys.argv[3])
import test_diagnose as td
from stickslip_jax.diagnose.report import diagnosis_dict
effect = sys.argv[1]
kw = {} if effect in ("uncatalogued", "none") else {"fallback": False}
t0 = time.perf_counter()
recs, d = td.run(ss.load_params(td.TRUTH), effect, **kw)
wall = time.perf_counter() - t0
content = diagnosis_dict(d)
content.pop("timings_s", None)
json.dump({"wall_s": wall, "diagnosis": content, "package": ss.__file__},
          open(sys.argv[2], "w"), default=str)
"""


def run_once(checkout: Path, effect: str, out: Path, cold: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout.resolve()), MPLBACKEND="Agg")
    if cold:  # no compilation cache, no traced-program store: every program compiled
        env["STICKSLIP_CACHE_DIR"] = "off"
    # Run from the output's folder: ``python -c`` puts its working directory first on
    # sys.path, and a checkout there would win over PYTHONPATH.
    subprocess.run([sys.executable, "-c", CHILD, effect, str(out), str(ROOT / "tests")],
                   env=env, check=True, stdout=subprocess.DEVNULL, cwd=out.parent)
    got = json.loads(out.read_text())
    if not Path(got["package"]).resolve().is_relative_to(checkout.resolve()):
        raise RuntimeError(f"{checkout} ran the package at {got['package']}")
    return got


def differences(a, b, path: str = "") -> tuple[float, str, list[str]]:
    """(largest relative difference of two numbers, where, paths of other differences)
    between two ``diagnosis.json`` contents; wall times left out."""
    worst, where, other = 0.0, "", []
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                other.append(f"{path}/{k}")
                continue
            w, p, o = differences(a[k], b[k], f"{path}/{k}")
            other += o
            if w > worst:
                worst, where = w, p
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            w, p, o = differences(x, y, f"{path}[{i}]")
            other += o
            if w > worst:
                worst, where = w, p
    elif isinstance(a, float) and isinstance(b, (int, float)):
        if "wall" in path or a == b or (math.isnan(a) and math.isnan(float(b))):
            return 0.0, "", []
        return abs(a - b) / max(abs(a), abs(b)), path, []
    elif a != b:
        other.append(path)
    return worst, where, other


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path, help="checkout A (e.g. a `git worktree`)")
    ap.add_argument("after", type=Path, help="checkout B")
    ap.add_argument("--effects", default="uncatalogued,structural_mode")
    ap.add_argument("--pairs", type=int, default=2, help="recorded runs of each checkout")
    ap.add_argument("--cold", action="store_true",
                    help="every run compiles everything (STICKSLIP_CACHE_DIR=off), no "
                         "warm-up: what a first run and the tests pay")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    checkouts = {"before": args.before, "after": args.after}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for effect in args.effects.split(","):
            walls = {k: [] for k in checkouts}
            last = {}
            first = 1 if args.cold else 0  # warm: the first pair fills the caches
            for i in range(first, args.pairs + 1):
                order = list(checkouts) if i % 2 == first % 2 else list(reversed(checkouts))
                for k in order:
                    got = run_once(checkouts[k], effect, Path(tmp) / f"{k}.json", args.cold)
                    last[k] = got["diagnosis"]
                    if i:
                        walls[k].append(got["wall_s"])
                    print(f"{effect} {k} {'warm-up' if not i else i}: {got['wall_s']:.1f} s",
                          flush=True)
            worst, where, other = differences(last["before"], last["after"])
            med = {k: statistics.median(v) for k, v in walls.items()}
            rows.append({"effect": effect, "wall_s": walls, "median_s": med,
                         "ratio": med["after"] / med["before"],
                         "largest_relative_difference": worst, "where": where,
                         "other_differences": other,
                         "verdict": [last["before"]["verdict"], last["after"]["verdict"]]})
            print(f"{effect}: median {med['before']:.1f} -> {med['after']:.1f} s "
                  f"({med['after'] / med['before']:.2f}x); largest relative difference "
                  f"{worst:.2g} at {where or '-'}; other differences: {other or 'none'}")
    write_record(args.json, before=str(args.before), after=str(args.after), cold=args.cold,
                 before_commit=commit_of(args.before), after_commit=commit_of(args.after),
                 rows=rows)


if __name__ == "__main__":
    main()

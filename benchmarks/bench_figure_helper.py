"""What the figure helper process saves: warm `stickslip identify` on the bundled
fixtures (21 figures) with the helper (``STICKSLIP_FIGURE_HELPER=1``, the default) and
without it (``0``), in fresh processes, alternating which goes first in each pair so
that the machine's load weighs on both alike.

    .venv/bin/python benchmarks/bench_figure_helper.py --json benchmarks/results/figure_helper.json

Each run's wall time and CPU time (user + system of the command and its helper) are
recorded, with the load average before it; the medians and their ratio are printed.
One warm-up run of each arm fills the compilation cache first. The two arms' last
outputs are compared: every figure and params.json byte for byte, fit.json without its
wall times. The helper must change nothing but the time.
"""

import argparse
import json
import os
import resource
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from results_record import write_record

ROOT = Path(__file__).resolve().parent.parent
COMMAND = [str(ROOT / ".venv" / "bin" / "stickslip"), "identify",
           str(ROOT / "fixtures" / "identification"), "--fix", "Ms=0.0247"]
ARMS = {"helper": "1", "no helper": "0"}


def run(arm: str, out: Path) -> dict:
    """One identify in a fresh process; its wall and CPU time [s]."""
    env = dict(os.environ, STICKSLIP_FIGURE_HELPER=ARMS[arm])
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([*COMMAND, "--out", str(out), "--force"], env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "load_before": load}


def _without_walls(value):
    """A JSON value without its ``wall_s`` entries (timings differ run to run)."""
    if isinstance(value, dict):
        return {k: _without_walls(v) for k, v in value.items() if k != "wall_s"}
    if isinstance(value, list):
        return [_without_walls(v) for v in value]
    return value


def same_output(a: Path, b: Path) -> bool:
    """Whether two output files hold the same: JSON without its timings, others bytes."""
    if not (a.is_file() and b.is_file()):
        return False
    if a.suffix == ".json":
        return _without_walls(json.loads(a.read_text())) == _without_walls(
            json.loads(b.read_text()))
    return a.read_bytes() == b.read_bytes()


def differing_files(a: Path, b: Path) -> list[str]:
    """Output files (relative paths) that differ between folders ``a`` and ``b``."""
    names = {p.relative_to(a) for p in a.rglob("*") if p.is_file()}
    names |= {p.relative_to(b) for p in b.rglob("*") if p.is_file()}
    return sorted(str(n) for n in names if not same_output(a / n, b / n))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="pairs of runs")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rows = {arm: [] for arm in ARMS}
    with tempfile.TemporaryDirectory() as tmp:
        outs = {arm: Path(tmp) / arm.replace(" ", "_") for arm in ARMS}
        for arm in ARMS:  # warm-up: the compilation cache and the traced programs
            run(arm, outs[arm])
        for i in range(args.runs):
            order = list(ARMS) if i % 2 == 0 else list(reversed(ARMS))
            for arm in order:
                rows[arm].append(run(arm, outs[arm]))
                print(f"{arm:10s} wall {rows[arm][-1]['wall_s']:6.2f} s  cpu "
                      f"{rows[arm][-1]['cpu_s']:6.2f} s  load "
                      f"{rows[arm][-1]['load_before']:.2f}", flush=True)
        differ = differing_files(outs["helper"], outs["no helper"])
    median = {arm: {k: statistics.median(r[k] for r in rows[arm])
                    for k in ("wall_s", "cpu_s")} for arm in ARMS}
    ratio = median["helper"]["wall_s"] / median["no helper"]["wall_s"]
    for arm in ARMS:
        print(f"{arm:10s} median wall {median[arm]['wall_s']:.2f} s, cpu "
              f"{median[arm]['cpu_s']:.2f} s")
    print(f"helper / no helper (wall): {ratio:.2f}; files that differ: {differ or 'none'}")
    write_record(args.json, what="warm stickslip identify on the fixtures, figure helper "
                 "on and off, alternating", command=" ".join(COMMAND[1:]), runs=rows,
                 median=median, ratio_wall_helper_over_none=ratio, files_differ=differ)


if __name__ == "__main__":
    main()

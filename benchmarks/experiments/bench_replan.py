"""The identification with and without re-planning its sub-steps inside a step
(``identify.steps.REPLAN_FACTOR``), side by side: wall time, the joint step's steps and
time, its final cost and the sub-steps it ended at.

    .venv/bin/python benchmarks/experiments/bench_replan.py --sets set_04,dev5,delay_8us \\
        --repeats 2 --json out/bench_replan.json

Each (set, setting, repeat) runs in a fresh Python process, so each compiles its own
programs (no persistent cache: ``STICKSLIP_CACHE_DIR=off``), in the order off, on, on,
off, ... so that a drift of the machine's load falls on both. A set is a concealed
fixture folder (``set_04``), a development set of the random split (``dev5``: index 5,
the full protocol) or a variant of the concealed sets (``delay_8us``), identified from
the default profile as ``stickslip diagnose`` does (``--fix Ms=0.0247``). The summary
gives per set the median of each setting and their ratio.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
BENCHMARKS = HERE.parent  # bench_diagnose.py
ROOT = BENCHMARKS.parent

CHILD = r"""
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
sys.path.insert(0, {benchmarks!r})
import stickslip_jax as ss
from stickslip_jax.identify import steps as identify_steps
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.residuals import dataset_plan
ss.fast_cpu_loops()
name, replan = {name!r}, {replan!r}
if not replan:
    identify_steps.REPLAN_FACTOR = float("inf")
import bench_diagnose as b
if name.startswith("set_"):
    recs = ss.load_recordings([b.CONCEALED / name])
elif name.startswith("dev"):
    from stickslip_jax.testing import random_sets as rs
    recs = rs.make_recordings(rs.draw_set(rs.DEV_SEED, int(name[3:])), b.protocol(False))
else:
    from stickslip_jax.testing.concealed import VARIANTS
    recs = b.variant_recordings(name, reduced=False, seed=9000 + 17 * list(VARIANTS).index(name))
t0 = time.perf_counter()
ident = ss.identify(recs, init=ss.lu2015_slc1720(), fix={{"Ms": 0.0247}}, max_steps=60)
wall = time.perf_counter() - t0
joint = ident.steps[-1].result
print("ROW " + json.dumps({{
    "set": name, "replan": replan, "wall_s": wall, "joint_steps": joint.iterations,
    "joint_s": joint.wall_s, "joint_jacobians": joint.jacobians,
    "joint_cost": joint.cost_end, "joint_message": joint.message,
    "converged": bool(ident.converged),
    "substeps_end": dataset_plan(ident.actuator, Dataset.from_recordings(recs)).substeps,
    "nrmse_mean": float(np.mean(ident.nrmse)),
    "Mp": float(ident.actuator.piezo.Mp)}}), flush=True)
"""


def run_child(name: str, replan: bool) -> dict:
    env = {**os.environ, "STICKSLIP_CACHE_DIR": "off",
           "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    child = CHILD.format(benchmarks=str(BENCHMARKS), name=name, replan=replan)
    out = subprocess.run([sys.executable, "-c", child],
                         capture_output=True, text=True, env=env, check=False)
    rows = [line[4:] for line in out.stdout.splitlines() if line.startswith("ROW ")]
    if out.returncode != 0 or not rows:
        raise RuntimeError(f"{name} (replan={replan}) failed:\n{out.stderr[-3000:]}")
    return json.loads(rows[-1])


def summary(rows: list[dict]) -> list[dict]:
    out = []
    for name in dict.fromkeys(r["set"] for r in rows):
        med = {}
        for replan in (False, True):
            mine = [r for r in rows if r["set"] == name and r["replan"] == replan]
            med[replan] = {k: statistics.median(r[k] for r in mine)
                           for k in ("wall_s", "joint_s", "joint_steps", "joint_cost")}
            med[replan]["substeps_end"] = mine[-1]["substeps_end"]
        out.append({"set": name, "off": med[False], "on": med[True],
                    "wall_ratio_on_off": med[True]["wall_s"] / med[False]["wall_s"],
                    "joint_ratio_on_off": med[True]["joint_s"] / med[False]["joint_s"],
                    "joint_cost_relative_change":
                        med[True]["joint_cost"] / med[False]["joint_cost"] - 1})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", default="set_04,dev5,delay_8us")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    if args.repeats < 1:
        sys.exit("--repeats must be at least 1")
    rows = []
    for name in [s for s in args.sets.split(",") if s]:
        for k in range(args.repeats):
            for replan in ((False, True) if k % 2 == 0 else (True, False)):
                t0 = time.perf_counter()
                row = run_child(name, replan)
                rows.append(row)
                print(f"{name:12s} replan={'on ' if replan else 'off'} wall {row['wall_s']:7.1f} s "
                      f"joint {row['joint_steps']:3d} steps {row['joint_s']:7.1f} s cost "
                      f"{row['joint_cost']:.7e} sub-steps {row['substeps_end']:3d} "
                      f"(process {time.perf_counter() - t0:.0f} s)", flush=True)
    s = summary(rows)
    for r in s:
        print(f"{r['set']:12s} wall on/off {r['wall_ratio_on_off']:.2f}  joint on/off "
              f"{r['joint_ratio_on_off']:.2f}  joint cost change "
              f"{r['joint_cost_relative_change']:+.2e}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"rows": rows, "summary": s,
                                         "load_average": os.getloadavg()}, indent=1))


if __name__ == "__main__":
    main()

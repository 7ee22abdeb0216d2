"""What the traced-program store saves (stickslip_jax/program_store.py, issue #64): warm
runs in fresh processes with the store on and off, side by side.

    .venv/bin/python benchmarks/bench_program_store.py --json out/bench_program_store.json

Two jobs, each in a fresh process per run, sharing one compilation cache (a temporary
folder; both arms warm, so that only tracing and lowering differ):

- ``identify``: ``stickslip identify fixtures/identification --out OUT --fix Ms=0.0247``
  (figures included, as the README runs it; ``--no-figures`` with ``--no-figures``);
- ``diagnose``: the reduced diagnosis of tests/test_diagnose.py for ``--effect``
  (default sensor_delay: 8 recordings, the baseline from the truth, one round).

Each job runs once per arm to fill the caches, then ``--runs`` times per arm, the arms
interleaved (on, off, on, off, ...) so that a change in the machine's load falls on
both. Reported: medians, each run's wall time, the ratio of the medians, and whether
both arms' results agree to the last bit (the identify parameters file; the diagnosis's
verdict, names and final (e/σ)²).
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

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from results_record import write_record  # noqa: E402

CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
arm, job, out = sys.argv[1], sys.argv[2], sys.argv[3]
import stickslip_jax.compilation_cache as cc
if arm == "off":
    cc.use_program_store = lambda path: False  # the compilation cache alone
if job == "identify":
    from stickslip_jax.cli.main import app
    try:
        app(args=["identify", "fixtures/identification", "--out", out, "--fix",
                  "Ms=0.0247", "--force", *sys.argv[5:]], prog_name="stickslip")
    except SystemExit as done:
        assert not done.code, done.code
    result = json.loads(open(out + "/params.json").read())
else:
    import jax
    jax.config.update("jax_enable_x64", True)
    import stickslip_jax as ss
    ss.fast_cpu_loops()
    cc.use_compilation_cache(cc.cache_dir_from_env())
    sys.path.insert(0, "tests")
    from test_diagnose import run
    base = ss.load_params("fixtures/identification/truth.json")
    _, d = run(base, sys.argv[4], fallback=False)
    result = {"verdict": str(d.verdict), "named": [c.name for c in d.accepted],
              "chi2_final": repr(float(d.chi2_final))}
print("RESULT " + json.dumps({"wall_s": time.perf_counter() - t0, "result": result}))
"""


def run_child(arm: str, job: str, cache: Path, effect: str, extra: list[str]) -> dict:
    env = dict(os.environ, STICKSLIP_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", CHILD, arm, job, tmp + "/out", effect,
                               *extra], cwd=ROOT, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{job} ({arm}) failed:\n{proc.stderr[-3000:]}")
    line = next(s for s in proc.stdout.splitlines() if s.startswith("RESULT "))
    out = json.loads(line[len("RESULT "):])
    out["process_wall_s"] = wall
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="warm runs per arm and job")
    ap.add_argument("--jobs", default="identify,diagnose")
    ap.add_argument("--effect", default="sensor_delay", help="the reduced diagnosis's effect")
    ap.add_argument("--no-figures", action="store_true", help="identify without figures")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    extra = ["--no-figures"] if args.no_figures else []
    report = {"runs": args.runs, "effect": args.effect, "figures": not args.no_figures,
              "jobs": {}}
    with tempfile.TemporaryDirectory() as cache_root:
        cache = Path(cache_root) / "cache"
        for job in args.jobs.split(","):
            for arm in ("on", "off"):  # fill the caches
                run_child(arm, job, cache, args.effect, extra)
            walls: dict[str, list[float]] = {"on": [], "off": []}
            results = {}
            for _ in range(args.runs):
                for arm in ("on", "off"):
                    out = run_child(arm, job, cache, args.effect, extra)
                    walls[arm].append(out["process_wall_s"])
                    results.setdefault(arm, out["result"])
                    print(f"{job} {arm}: {out['process_wall_s']:.1f} s", flush=True)
            med = {arm: statistics.median(w) for arm, w in walls.items()}
            report["jobs"][job] = {
                "wall_s": walls, "median_s": med, "on_over_off": med["on"] / med["off"],
                "same_result": results["on"] == results["off"], "result": results["on"]}
            print(f"{job}: store on {med['on']:.1f} s, off {med['off']:.1f} s "
                  f"(ratio {med['on'] / med['off']:.2f}); same result: "
                  f"{results['on'] == results['off']}", flush=True)
    write_record(args.json, **report)


if __name__ == "__main__":
    main()

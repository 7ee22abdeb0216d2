"""Where a reduced diagnosis's running time goes: the wall time inside the shared
per-recording programs (``RecordingPrograms``), by program kind (value-only, or
tangents and how many per call), stepping plan and number of recordings, against the
diagnosis's own phase timings.

    .venv/bin/python benchmarks/experiments/diagnose_program_calls.py uncatalogued \\
        --cache out/diag_cache --json out/diagnose_program_calls.json

The data and settings are tests/test_diagnose.py's (its ``run``: the reduced protocol,
one round, the two best refitted, 20 steps, three sized). ``--cache`` a compilation
cache folder (run twice with the same one: the second run is the warm figure; do not
edit the package while it runs, or the program store, rightly, stops reading stored
programs and the run compiles again). Per program: its calls, the recordings run
(a call runs one task per recording and tangent share), the seconds in all calls and
in the first (which holds the compiling or the loading from the cache).
"""

import argparse
import collections
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))  # results_record
sys.path.insert(0, str(ROOT / "tests"))  # test_diagnose: the tests' reduced protocol
from results_record import write_record  # noqa: E402

import stickslip_jax as ss  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from stickslip_jax.compilation_cache import use_compilation_cache  # noqa: E402
from stickslip_jax.identify import sensitivities  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("effect", help="the hidden effect (tests/test_diagnose.py's names)")
    ap.add_argument("--cache", type=Path, default=None, help="compilation cache folder")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    use_compilation_cache(args.cache)
    calls = collections.defaultdict(lambda: {"calls": 0, "tasks": 0, "s": 0.0,
                                             "first_s": 0.0})
    run_programs = sensitivities.RecordingPrograms._run

    def timed(self, tasks, call, key):
        tasks = list(tasks)
        t0 = time.perf_counter()
        out = run_programs(self, tasks, call, key)
        row = calls[(key[0], repr(key[1]), key[2] if key[0] == "tangents" else 0,
                     len(self.data))]
        elapsed = time.perf_counter() - t0
        if row["calls"] == 0:
            row["first_s"] = elapsed
        row["calls"] += 1
        row["tasks"] += len(tasks)
        row["s"] += elapsed
        return out

    sensitivities.RecordingPrograms._run = timed
    import test_diagnose

    base = ss.load_params(test_diagnose.TRUTH)
    t0 = time.perf_counter()
    _, d = test_diagnose.run(base, args.effect)
    wall = time.perf_counter() - t0
    rows = [{"kind": k[0], "plan": k[1], "tangents_per_call": k[2], "recordings": k[3],
             **v} for k, v in sorted(calls.items(), key=lambda kv: -kv[1]["s"])]
    print(f"{args.effect}: {wall:.1f} s, verdict {d.verdict.value}, accepted "
          f"{[c.name for c in d.accepted]}")
    print("phases:", {k: round(v, 1) for k, v in d.timings.items()})
    for r in rows:
        print(f"{r['s']:7.1f} s (first {r['first_s']:5.1f}) calls {r['calls']:4d} tasks "
              f"{r['tasks']:5d}  {r['kind']} {r['plan']} x{r['tangents_per_call']}")
    print(f"in the programs: {sum(r['s'] for r in rows):.1f} s of {wall:.1f} s")
    write_record(args.json, effect=args.effect, wall_s=wall, timings=d.timings,
                 programs=rows, compilation_cache=str(args.cache) if args.cache else None,
                 entries=[{"name": r.name, "status": r.status.value, "wall_s": r.wall_s}
                          for r in d.rounds[0]])


if __name__ == "__main__":
    main()

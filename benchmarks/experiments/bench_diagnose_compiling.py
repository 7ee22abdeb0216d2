"""Where a reduced diagnosis's time goes: JAX's tracing, lowering and XLA compiling per
program name, against the wall time, for diagnoses run one after the other in one
process (as a test worker runs them).

    .venv/bin/python benchmarks/experiments/bench_diagnose_compiling.py creep sensor_delay \\
        --json out/bench_diagnose_compiling.json

The data and settings are tests/test_diagnose.py's: the reduced protocol (8 recordings
of 0.02-0.06 s), 1 nm noise, seed 7, the named effect hidden in the identification
truth (fixture form), the baseline from the truth without it, one round, the two best
refitted, 20 steps, three sized, no fallback refits. Compiling is summed from
``jax.monitoring``'s ``/jax/core/compile/*`` duration events by their ``fun_name``.
No persistent cache unless ``$STICKSLIP_CACHE_DIR`` names a folder (then, with a
cache a first run filled, what is left is tracing and lowering; the JSON records it).
"""

import argparse
import collections
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: results_record
from results_record import write_record  # noqa: E402

import stickslip_jax as ss  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

import jax  # noqa: E402

from stickslip_jax.compilation_cache import (  # noqa: E402
    cache_dir_from_env,
    use_compilation_cache,
)
from stickslip_jax.synthetic import paper_protocol, simulate_set  # noqa: E402
from stickslip_jax.testing.concealed import with_effect  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CACHE_DIR = cache_dir_from_env(default=None)
CACHE_ON = use_compilation_cache(CACHE_DIR)
TRUTH = ROOT / "fixtures" / "identification" / "truth.json"
STAGES = ("jaxpr_trace_duration", "jaxpr_to_mlir_module_duration",
          "backend_compile_duration")


class ProgramClock:
    """Seconds and counts of each compile stage per program name, since the last
    :meth:`reset`."""

    def __init__(self):
        self.reset()
        jax.monitoring.register_event_duration_secs_listener(self._listen)

    def reset(self):
        self.seconds = collections.Counter()
        self.counts = collections.Counter()

    def _listen(self, event: str, duration: float, **kw):
        stage = event.rsplit("/", 1)[-1]
        if event.startswith("/jax/core/compile/") and stage in STAGES:
            key = (stage, str(kw.get("fun_name", "?")))
            self.seconds[key] += duration
            self.counts[key] += 1


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("effects", nargs="+", help="hidden effects, run in this order")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    jax.config.update("jax_enable_x64", True)
    base = ss.load_params(TRUTH)
    specs = paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(100.0, 500.0),
                           step_duration_s=0.03, sine_periods=2)
    clock = ProgramClock()
    rows = []
    for effect in args.effects:
        recs = simulate_set(with_effect(base, effect), specs, noise_m=1e-9, seed=7)
        clock.reset()
        t0 = time.perf_counter()
        d = ss.diagnose(recs, init=base, fix={"Ms": 0.0247}, identify_steps=(),
                        max_rounds=1, top=2, max_steps=20, size_at_most=3, fallback=False)
        wall = time.perf_counter() - t0
        per_program = [{"stage": st, "program": name, "seconds": sec,
                        "count": clock.counts[(st, name)]}
                       for (st, name), sec in clock.seconds.most_common()]
        row = {"effect": effect, "verdict": d.verdict.value,
               "named": [c.name for c in d.accepted], "wall_s": wall,
               "compiling_s": sum(clock.seconds.values()),
               "programs": sum(c for (st, _), c in clock.counts.items()
                               if st == "backend_compile_duration"),
               "per_program": per_program}
        rows.append(row)
        print(f"{effect}: {row['verdict']} {row['named']}, wall {wall:.1f} s, compiling "
              f"{row['compiling_s']:.1f} s, {row['programs']} programs", flush=True)
        for p in per_program[:10]:
            print(f"    {p['stage']:32s} {p['program'][:40]:40s} {p['seconds']:6.1f} s "
                  f"({p['count']})", flush=True)
    write_record(args.json, rows=rows, compilation_cache=str(CACHE_DIR) if CACHE_ON else None)


if __name__ == "__main__":
    main()

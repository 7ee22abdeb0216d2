"""Two checkouts side by side on the shared per-recording programs' calls, warm: what a
call costs beside the simulation itself (keying the program, building the arguments),
which short recordings feel most.

    .venv/bin/python benchmarks/experiments/bench_program_calls_checkouts.py \\
        /tmp/before . --pairs 4 --json out/program_calls.json

Each run is a fresh process of this virtual environment with ``PYTHONPATH`` set to the
checkout, a compilation cache of its own per checkout (made in a first, unrecorded
run of each), XLA's native loops on (``fast_cpu_loops``, as the command line). The
set: the tests' reduced diagnosis protocol (8 recordings of 1000 samples, the
identification truth). Timed in each run, medians of repeated calls through
``RecordingPrograms`` on the default threads: the value-only program over the 8
recordings, and three tangents one per call (24 one-tangent calls). Runs alternate
which checkout goes first; reported are each checkout's medians over the runs, their
ratio, and a digest of the outputs (equal where the arithmetic is).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path

from checkout_process import run_in_checkout

ROOT = Path(__file__).resolve().parents[2]

RUN = """
import hashlib, json, sys, time
import stickslip_jax as ss
ss.fast_cpu_loops()
import jax
jax.config.update("jax_enable_x64", True)
import equinox as eqx
import numpy as np
from stickslip_jax.compilation_cache import use_compilation_cache
use_compilation_cache(sys.argv[2])
from stickslip_jax.identify import sensitivities as S
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.residuals import dataset_plan
from stickslip_jax.synthetic import paper_protocol, simulate_set
base = ss.load_params(sys.argv[1])
specs = paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(100.0, 500.0),
                       step_duration_s=0.03, sine_periods=2)
data = Dataset.from_recordings(simulate_set(base, specs, noise_m=1e-9, seed=1))
mask = S.perturbed_mask(base, ["Mp", "Dp", "Kp", "rho0", "z_ba_forward", "pi_weights"])
programs = S.RecordingPrograms(data, base, mask)
plan = dataset_plan(base, data)
three = jax.tree.map(lambda x: np.ones((3,) + np.shape(x)), eqx.filter(base, mask))
q = programs.simulate(base, plan)
qt, dq = programs.sensitivities(base, three, plan)

def median_ms(f, n):
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t)
    return 1e3 * float(np.median(ts))

value = median_ms(lambda: programs.simulate(base, plan), 40)
singly = median_ms(lambda: programs.sensitivities(base, three, plan), 20)
digest = hashlib.sha256(q.tobytes() + qt.tobytes() + dq.tobytes()).hexdigest()[:16]
print(json.dumps({"value_ms": value, "three_singly_ms": singly, "digest": digest,
                  "width": programs.width, "module": ss.__file__}))
"""

FIGURES = ("value_ms", "three_singly_ms")


def one_run(checkout: Path, cache: Path) -> dict:
    """One warm measurement of ``checkout`` in a fresh process."""
    return run_in_checkout(checkout, RUN, (ROOT / "fixtures" / "identification" / "truth.json",
                                           cache), OPENBLAS_NUM_THREADS="1")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path, help="checkout A (e.g. a `git worktree`)")
    ap.add_argument("after", type=Path, help="checkout B")
    ap.add_argument("--pairs", type=int, default=4, help="recorded runs of each checkout")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    caches = {k: Path(tempfile.mkdtemp(prefix=f"bench_program_calls_{k}_"))
              for k in ("before", "after")}
    for which in ("before", "after"):  # compile once per checkout, unrecorded
        one_run(getattr(args, which), caches[which])
    rows = {"before": [], "after": []}
    for i in range(args.pairs):
        order = ("before", "after") if i % 2 == 0 else ("after", "before")
        for which in order:
            row = one_run(getattr(args, which), caches[which])
            rows[which].append(row)
            print(f"pair {i + 1} {which}: value {row['value_ms']:.1f} ms, three tangents "
                  f"singly {row['three_singly_ms']:.1f} ms, digest {row['digest']}",
                  flush=True)
    medians = {k: {f: statistics.median(r[f] for r in v) for f in FIGURES}
               for k, v in rows.items()}
    ratios = {f: medians["after"][f] / medians["before"][f] for f in FIGURES}
    digests = {r["digest"] for v in rows.values() for r in v}
    summary = {"before": str(args.before), "after": str(args.after), "median_ms": medians,
               "ratio": ratios, "same_outputs": len(digests) == 1, "runs": rows}
    for f in FIGURES:
        print(f"{f}: median {medians['before'][f]:.1f} -> {medians['after'][f]:.1f} ms, "
              f"ratio {ratios[f]:.2f}")
    print("outputs", "identical" if summary["same_outputs"] else f"differ: {digests}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()

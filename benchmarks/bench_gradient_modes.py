"""A gradient through the simulator in reverse mode against forward mode: compile time
and run time, with XLA's native CPU loops (:func:`stickslip_jax.fast_cpu_loops`, the
setting of the CLI, the tests and the notebooks).

    .venv/bin/python benchmarks/bench_gradient_modes.py --json out/bench_gradient_modes.json

Two gradients, each on two traces (default profile, 25 kHz): "3 periods" (60 V 200 Hz
forward sawtooth, 376 samples, the length of notebook 06) and "1 s" (40 V 50 Hz, 25 001
samples, the simulator benchmark's trace):

- ``actuator``: ``eqx.filter_grad`` of mean(q²) over every floating leaf of the
  actuator (85 scalars: 35 PI weights, 35 thresholds, 15 others). ``reverse``:
  ``ForwardSensitivities(max_directions=64)``, which hands 85 directions to plain
  reverse mode; ``forward``: ``ForwardSensitivities(max_directions=128)``, Jᵀ·c from
  85 forward sensitivities.
- ``waveform``: ``jax.grad`` of the step over the last period of a drive made of
  8 knots per period (notebook 06's design problem): ``reverse``: plain ``jax.grad``
  (the voltage keeps reverse mode in the simulator's rule); ``forward``: the same
  function wrapped in :func:`stickslip_jax.with_forward_jacobian`.

Each case runs in its own process (nothing compiled is shared): the first call's
wall (trace, compile, run) and the median of --repeats further calls; "compile" is
their difference. The two modes' gradients must agree (relative difference printed).
"""

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from results_record import write_record

ROOT = Path(__file__).resolve().parent.parent
FS = 25_000.0
TRACES = {"3 periods": (60.0, 200.0, 3), "1 s": (40.0, 50.0, 50)}
GRADIENTS = ("actuator", "waveform")
MODES = ("reverse", "forward")
KNOTS = 8


def _case(trace: str, gradient: str, mode: str, repeats: int, out: Path) -> None:
    """Run one case in this process and write its figures (JSON) and gradient (npy)."""
    import stickslip_jax as ss

    ss.fast_cpu_loops()
    import equinox as eqx
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    act = ss.lu2015_slc1720()
    amplitude, frequency, periods = TRACES[trace]
    per = int(round(FS / frequency))
    n = periods * per + 1
    drive = ss.DriveContext.make(amplitude=amplitude, frequency=frequency)
    if gradient == "actuator":
        limit = 64 if mode == "reverse" else 128
        u = amplitude * jnp.mod(frequency * jnp.arange(n) / FS, 1.0)

        def loss(a):
            q = ss.simulate(a, u, dt=1 / FS, drive=drive,
                            adjoint=ss.ForwardSensitivities(max_directions=limit))
            return jnp.mean((q / 1e-6) ** 2)

        fn, x = eqx.filter_jit(eqx.filter_grad(loss)), act
    else:
        def waveform(theta):
            knots = jnp.concatenate([jnp.zeros(1), amplitude * jax.nn.sigmoid(theta)])
            one = jnp.interp(jnp.arange(per) / per, jnp.linspace(0, 1, KNOTS + 1), knots)
            return jnp.concatenate([jnp.tile(one, periods), jnp.zeros(1)])

        def step(theta):
            q = ss.simulate(act, waveform(theta), dt=1 / FS, drive=drive)
            return (q[-1] - q[-1 - per]) / 1e-9

        if mode == "forward":
            step = ss.with_forward_jacobian(step)
        fn, x = jax.jit(jax.grad(step)), jnp.linspace(-2.0, 1.5, KNOTS)
    t0 = time.perf_counter()
    grad = jax.block_until_ready(fn(x))
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(x))
        runs.append(time.perf_counter() - t0)
    flat = np.concatenate([np.ravel(v) for v in jax.tree.leaves(eqx.filter(grad,
                                                                          eqx.is_array))])
    np.save(out.with_suffix(".npy"), flat)
    median = statistics.median(runs)
    out.write_text(json.dumps({"first_s": first, "runs_s": runs, "median_s": median,
                               "compile_s": first - median, "scalars": int(flat.size)}))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--case", nargs=4, metavar=("TRACE", "GRADIENT", "MODE", "OUT"),
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        trace, gradient, mode, out = args.case
        _case(trace, gradient, mode, args.repeats, Path(out))
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for trace in TRACES:
            for gradient in GRADIENTS:
                row = {"trace": trace, "gradient": gradient}
                grads = {}
                for mode in MODES:
                    out = Path(tmp) / f"{trace}_{gradient}_{mode}.json".replace(" ", "_")
                    subprocess.run([sys.executable, __file__, "--repeats", str(args.repeats),
                                    "--case", trace, gradient, mode, str(out)], check=True)
                    row[mode] = json.loads(out.read_text())
                    grads[mode] = np.load(out.with_suffix(".npy"))
                scale = np.abs(grads["reverse"]).max()
                row["max_relative_difference"] = float(
                    np.abs(grads["forward"] - grads["reverse"]).max() / scale)
                row["compile_reverse_over_forward"] = (row["reverse"]["compile_s"]
                                                       / row["forward"]["compile_s"])
                row["run_reverse_over_forward"] = (row["reverse"]["median_s"]
                                                   / row["forward"]["median_s"])
                rows.append(row)
                r, f = row["reverse"], row["forward"]
                print(f"{trace:9s} {gradient:8s} ({r['scalars']} scalars): compile "
                      f"{r['compile_s']:6.1f} / {f['compile_s']:5.1f} s, run "
                      f"{r['median_s']:.3f} / {f['median_s']:.3f} s (reverse / forward); "
                      f"difference {row['max_relative_difference']:.1e}", flush=True)
    write_record(args.json, repeats=args.repeats, rows=rows)


if __name__ == "__main__":
    main()

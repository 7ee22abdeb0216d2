"""The step-ringing grid fit (``identify.initial.measured_step_mode``) with einsum, as
it was, against the module's batched matrix products: the grid point each chooses, and
the time per call.

    .venv/bin/python benchmarks/experiments/step_mode_products.py \\
        --json benchmarks/experiments/results/step_mode_products.json

On every bundled step recording and on synthetic steps of the development split's first
30 random truths (two noise levels each): both must return the same (frequency, damping
ratio), the grid's values, so the identification that starts from them is unchanged.
"""

import argparse
import glob
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))  # results_record
from results_record import write_record  # noqa: E402

from stickslip_jax.identify.initial import measured_step_mode  # noqa: E402
from stickslip_jax.io import load_recording  # noqa: E402
from stickslip_jax.synthetic import paper_protocol, simulate_set  # noqa: E402
from stickslip_jax.testing import random_sets  # noqa: E402


def by_einsum(step, band=(100.0, 6000.0), window_s=0.01):
    """``measured_step_mode`` as it was before the change (einsum's loops)."""
    q = np.asarray(step.position_m, dtype=float)
    k0 = int(np.argmax(np.abs(np.diff(q)))) + 2
    seg = q[k0:k0 + max(int(window_s / step.dt), 16)]
    if len(seg) < 16:
        return None
    seg = seg - seg.mean()
    t = np.arange(len(seg)) * step.dt
    zetas = np.linspace(0.02, 0.9, 45)
    best = (np.inf, np.nan, np.nan)
    for f in np.geomspace(band[0], min(band[1], 0.45 / step.dt), 500):
        w = 2 * np.pi * f
        decay = np.exp(-np.outer(zetas * w / np.sqrt(1 - zetas**2), t))
        basis = np.stack([np.ones_like(decay), decay * np.cos(w * t), decay * np.sin(w * t)],
                         axis=-1)
        gram = np.einsum("zli,zlj->zij", basis, basis)
        rhs = np.einsum("zli,l->zi", basis, seg)
        coef = np.linalg.solve(gram + 1e-30 * np.eye(3), rhs[..., None])[..., 0]
        cost = np.sum((np.einsum("zli,zi->zl", basis, coef) - seg) ** 2, axis=1)
        i = int(np.argmin(cost))
        if cost[i] < best[0]:
            best = (float(cost[i]), float(f), float(zetas[i]))
    if not best[0] < 0.5 * float(np.sum(seg**2)):
        return None
    return best[1], best[2]


def steps() -> list:
    """The bundled step recordings, then synthetic ones of random truths."""
    recs = [load_recording(p)
            for p in sorted(glob.glob(str(ROOT / "fixtures" / "**" / "step*.csv"),
                                      recursive=True))]
    drive = [d for d in paper_protocol() if d.waveform == "step"][:1]
    for k, spec in enumerate(random_sets.draw_split(seed=12345, n=30)):
        for j, noise in enumerate((1e-9, 5e-9)):
            recs += simulate_set(random_sets.hidden_actuator(spec), drive, noise_m=noise,
                                 seed=2 * k + j)
    return recs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    times = {"einsum": [], "products": []}
    differ = []
    for rec in steps():
        t0 = time.perf_counter()
        a = by_einsum(rec)
        t1 = time.perf_counter()
        b = measured_step_mode(rec)
        times["einsum"].append(t1 - t0)
        times["products"].append(time.perf_counter() - t1)
        if a != b:
            differ.append({"recording": rec.name, "einsum": a, "products": b})
    medians = {k: statistics.median(v) for k, v in times.items()}
    n = len(times["einsum"])
    print(f"{n} step recordings: {n - len(differ)} choose the same grid point; median per "
          f"call einsum {medians['einsum'] * 1e3:.0f} ms, products "
          f"{medians['products'] * 1e3:.0f} ms ({medians['products'] / medians['einsum']:.2f}x)")
    write_record(args.json, recordings=n, differ=differ, median_s=medians)


if __name__ == "__main__":
    main()

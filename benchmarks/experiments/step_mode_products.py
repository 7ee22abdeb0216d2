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

from stickslip_jax.identify.initial import (  # noqa: E402
    measured_step_mode,
    ringing_on_grid,
)
from stickslip_jax.io import load_recording  # noqa: E402
from stickslip_jax.synthetic import paper_protocol, simulate_set  # noqa: E402
from stickslip_jax.testing import random_sets  # noqa: E402


def einsum_costs(basis, seg):
    """The grid row's costs as ``measured_step_mode`` made them before (einsum's loops)."""
    gram = np.einsum("zli,zlj->zij", basis, basis)
    rhs = np.einsum("zli,l->zi", basis, seg)
    coef = np.linalg.solve(gram + 1e-30 * np.eye(3), rhs[..., None])[..., 0]
    return np.sum((np.einsum("zli,zi->zl", basis, coef) - seg) ** 2, axis=1)


def by_einsum(step):
    """``measured_step_mode`` as it was before the change."""
    return ringing_on_grid(step, einsum_costs)


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

"""What writing one figure costs: the identification's overlay of a recording, saved by
the crop ``save_figure`` uses (one render, cropped to its ink) beside the crop by the
artists' extents (a layout pass of every tick and label, then the render).

    .venv/bin/python benchmarks/bench_figures.py --json benchmarks/results/figures.json

Each repeat builds the same overlay (``plot_trace`` of a recording of the bundled
identification fixtures against itself shifted by 2 nm) and saves it once each way,
alternating which goes first, so that the machine's load weighs on both alike; the
medians, ranges and their ratio are printed. Both images are compared: their sizes
[px] and the largest difference of their crops' margins.
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from results_record import write_record

import stickslip_jax as ss
from stickslip_jax.files import atomic_writer
from stickslip_jax.plots import SAVE_DPI, SAVE_PAD_INCHES, plot_trace, save_figure

ROOT = Path(__file__).resolve().parent.parent
RECORDING = ROOT / "fixtures" / "identification" / "saw_40V_100Hz_fwd.csv"


def overlay(rec):
    """The identification's overlay figure of ``rec`` (not saved)."""
    return plot_trace(rec.time_s, rec.voltage_V, rec.position_m + 2e-9,
                      q_meas_m=rec.position_m, noise_m=1e-9, title=rec.name)


def save_by_extents(fig, path: Path) -> Path:
    """The crop before the ink crop: the artists' extents plus the pad."""
    crop = fig.get_tightbbox().padded(SAVE_PAD_INCHES)
    with atomic_writer(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=SAVE_DPI, bbox_inches=crop)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rec = ss.load_recordings([RECORDING])[0]
    times = {"ink": [], "extents": []}
    ways = {"ink": save_figure, "extents": save_by_extents}
    with tempfile.TemporaryDirectory() as tmp:
        overlay(rec)  # (first use: fonts and caches)
        for i in range(args.repeats):
            order = ("ink", "extents") if i % 2 == 0 else ("extents", "ink")
            for name in order:
                fig = overlay(rec)
                t0 = time.perf_counter()
                ways[name](fig, Path(tmp) / f"{name}.png")
                times[name].append(time.perf_counter() - t0)
        from PIL import Image

        sizes = {n: Image.open(Path(tmp) / f"{n}.png").size for n in ways}
    med = {n: statistics.median(t) for n, t in times.items()}
    ratio = med["ink"] / med["extents"]
    for n, t in times.items():
        print(f"{n:8s} median {med[n] * 1e3:6.1f} ms  range {min(t) * 1e3:.1f}-"
              f"{max(t) * 1e3:.1f} ms  image {sizes[n][0]}x{sizes[n][1]} px")
    print(f"ink / extents: {ratio:.2f}")
    write_record(args.json, what="one overlay saved: ink crop vs artists' extents",
                 repeats=args.repeats, median_s=med,
                 range_s={n: [min(t), max(t)] for n, t in times.items()},
                 ratio_ink_over_extents=ratio, image_px=sizes,
                 size_difference_px=np.abs(np.subtract(sizes["ink"],
                                                       sizes["extents"])).tolist())


if __name__ == "__main__":
    main()

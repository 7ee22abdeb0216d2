"""Sweep memory: peak resident memory of `stickslip sweep` against grid size and --chunk.

    .venv/bin/python benchmarks/bench_sweep_memory.py --json out/bench_sweep_memory.json \
        [--figure out/bench_sweep_memory.png] [--repeats 3]

Each run is a fresh process (`python -m stickslip_jax.cli.main sweep ...`, 10 periods at
25 kHz, both directions, frequencies evenly spaced in 50..1000 Hz) whose peak RSS is read
from the OS (getrusage of the child). Grids of 200, 800 and 3200 points, each with the
automatic slot count and with --chunk 16 and 64. The sweep keeps only ``chunk`` traces
alive (a point's trace is reduced to its velocity as soon as it is done), so peak
memory should depend on the chunk, not on the grid size; wall time is reported too.
Medians over --repeats runs.
"""

import argparse
import json
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GRIDS = {200: (10, 10), 800: (20, 20), 3200: (40, 40)}
CHUNKS = (None, 16, 64)


def run_once(n_a: int, n_f: int, chunk: int | None) -> tuple[float, float, str]:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", "from stickslip_jax.cli.main import app; app()", "sweep",
               "--amplitudes", f"10:80:{n_a}", "--frequencies", f"50:1000:{n_f}",
               "--directions", "both", "--periods", "10", "--out", tmp, "--force"]
        if chunk is not None:
            cmd += ["--chunk", str(chunk)]
        t0 = time.perf_counter()
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        wall = time.perf_counter() - t0
        peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    # ru_maxrss of RUSAGE_CHILDREN is the largest child so far: runs go from small to
    # large within one grid, so a smaller later peak would be hidden; each measurement
    # is therefore taken in its own interpreter (see main).
    return peak_kb / 1024.0, wall, out.stdout.strip().splitlines()[-1] if out.stdout else ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, required=True)
    ap.add_argument("--figure", type=Path)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--one", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:  # a single measurement, in a fresh interpreter
        n_a, n_f, chunk = int(args.one[0]), int(args.one[1]), args.one[2]
        peak, wall, _ = run_once(n_a, n_f, None if chunk == "auto" else int(chunk))
        print(json.dumps({"peak_rss_MiB": peak, "wall_s": wall}))
        return
    rows = []
    for points, (n_a, n_f) in GRIDS.items():
        for chunk in CHUNKS:
            peaks, walls = [], []
            for _ in range(args.repeats):
                res = subprocess.run([sys.executable, __file__, "--json", "-", "--one",
                                      str(n_a), str(n_f), "auto" if chunk is None
                                      else str(chunk)], capture_output=True, text=True,
                                     check=True)
                m = json.loads(res.stdout.strip().splitlines()[-1])
                peaks.append(m["peak_rss_MiB"])
                walls.append(m["wall_s"])
            row = {"points": points, "chunk": chunk or "auto",
                   "peak_rss_MiB_median": float(sorted(peaks)[len(peaks) // 2]),
                   "wall_s_median": float(sorted(walls)[len(walls) // 2]),
                   "peak_rss_MiB_runs": peaks, "wall_s_runs": walls}
            rows.append(row)
            print(f"{points:5d} points, chunk {str(chunk or 'auto'):>4s}: peak RSS "
                  f"{row['peak_rss_MiB_median']:7.1f} MiB, wall {row['wall_s_median']:6.1f} s "
                  f"(process start and compilation included)", flush=True)
    payload = {"machine": platform.platform(), "python": platform.python_version(),
               "repeats": args.repeats, "rows": rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(payload, indent=1) + "\n")
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
        for chunk in CHUNKS:
            sel = [r for r in rows if r["chunk"] == (chunk or "auto")]
            x = [r["points"] for r in sel]
            axes[0].plot(x, [r["peak_rss_MiB_median"] for r in sel], "-o",
                         label=f"--chunk {chunk or 'auto'}")
            axes[1].plot(x, [r["wall_s_median"] for r in sel], "-o",
                         label=f"--chunk {chunk or 'auto'}")
        for ax, lab in zip(axes, ("peak RSS [MiB]", "wall [s]"), strict=True):
            ax.set_xscale("log")
            ax.set_xlabel("grid points")
            ax.set_ylabel(lab)
            ax.legend(fontsize=8)
        axes[0].set_title("memory is set by the chunk, not the grid", fontsize=10)
        axes[1].set_title("time grows linearly with the grid", fontsize=10)
        fig.tight_layout()
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.figure, dpi=120)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()

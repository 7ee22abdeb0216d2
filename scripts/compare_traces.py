"""Print the NRMSE of each simulated trace against its recording (docs/model.md "Fit quality").

Usage: python scripts/compare_traces.py RECORDING_DIR SIMULATION_DIR
(simulations are named <recording>.sim.csv).
"""

import sys
from pathlib import Path

import numpy as np

from stickslip_jax.io import load_recording


def main(rec_dir: str, sim_dir: str) -> int:
    rows = []
    for rec_path in sorted(Path(rec_dir).glob("*.csv")):
        sim_path = Path(sim_dir) / f"{rec_path.stem}.sim.csv"
        if not sim_path.exists():
            continue
        meas = load_recording(rec_path).position_m
        sim = load_recording(sim_path).position_m
        nrmse = np.sqrt(np.mean((sim - meas) ** 2)) / np.ptp(meas)
        rows.append((rec_path.stem, nrmse))
    print(f"{'recording':28s} NRMSE [%]")
    for name, value in rows:
        print(f"{name:28s} {100 * value:.4f}")
    return 0 if rows else 1


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))

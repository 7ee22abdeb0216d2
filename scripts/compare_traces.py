"""Print the NRMSE of each simulated trace against its recording (docs/model.md "Fit quality").

Usage: python scripts/compare_traces.py RECORDING_DIR SIMULATION_DIR [--plot]
(simulations are named <recording>.sim.csv). With ``--plot`` it also draws each pair
to SIMULATION_DIR/<recording>.png, labelled as the conformance traces of
fixtures/reference are: a reference from an independent implementation, not a
measurement (noiseless, so the residual panel has no noise band).
"""

import argparse
import sys
from pathlib import Path

import numpy as np

from stickslip_jax.io import load_recording

REFERENCE_LABEL = "reference (independent implementation)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rec_dir", type=Path)
    ap.add_argument("sim_dir", type=Path)
    ap.add_argument("--plot", action="store_true",
                    help="also draw SIM_DIR/<recording>.png (reference vs simulated)")
    args = ap.parse_args(argv)
    rows = []
    for rec_path in sorted(args.rec_dir.glob("*.csv")):
        sim_path = args.sim_dir / f"{rec_path.stem}.sim.csv"
        if not sim_path.exists():
            continue
        ref = load_recording(rec_path)
        sim = load_recording(sim_path).position_m
        rms = float(np.sqrt(np.mean((sim - ref.position_m) ** 2)))
        nrmse = rms / np.ptp(ref.position_m)
        rows.append((rec_path.stem, nrmse, rms))
        if args.plot:
            from stickslip_jax.plots import plot_trace

            plot_trace(ref.time_s, ref.voltage_V, sim, q_meas_m=ref.position_m, noise_m=0.0,
                       meas_label=REFERENCE_LABEL,
                       title=f"{ref.name}: NRMSE {100 * nrmse:.4f} % against the reference",
                       path=args.sim_dir / f"{rec_path.stem}.png")
    print(f"{'recording':28s} {'NRMSE [%]':>10s} {'RMS [nm]':>9s}")
    for name, value, rms in rows:
        print(f"{name:28s} {100 * value:10.2e} {rms * 1e9:9.4f}")
    return 0 if rows else 1


if __name__ == "__main__":
    sys.exit(main())

"""Regenerate fixtures/identification/: the paper's protocol simulated from a known truth.

    .venv/bin/python scripts/make_identification_fixtures.py [--force]

Truth: ``truth.json`` (written next to the recordings), the default profile with its
dynamics, hysteresis and friction moved by 5-20 % so that recovering it is not the
same as recovering the default. Noise: 1 nm white (seed 2015). 25 kHz.
"""

import argparse
import json
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)


import stickslip_jax as ss  # noqa: E402
from stickslip_jax.synthetic import paper_protocol, simulate_set  # noqa: E402
from stickslip_jax.testing.truth import identification_truth  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

OUT = Path(__file__).resolve().parent.parent / "fixtures" / "identification"


def truth_params() -> dict:
    """The documented truth of the identification fixtures (docs/model.md names, SI):
    :func:`stickslip_jax.testing.truth.identification_truth`."""
    return identification_truth()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--force", action="store_true", help="replace existing files")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    truth = truth_params()
    actuator = ss.actuator_from_params(truth)
    ss.save_params(actuator, OUT / "truth.json", force=args.force)
    recs = simulate_set(actuator, paper_protocol(), noise_m=1e-9, seed=2015)
    for rec in recs:
        ss.save_recording(rec, OUT / f"{rec.name}.csv", force=args.force)
    size = sum(f.stat().st_size for f in OUT.iterdir())
    print(f"wrote {len(recs)} recordings + truth.json to {OUT} ({size / 1e6:.2f} MB)")
    print(json.dumps({r.name: r.n for r in recs}))


if __name__ == "__main__":
    main()

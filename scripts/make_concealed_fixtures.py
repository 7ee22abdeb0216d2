"""Regenerate fixtures/concealed/: the identification protocol with one hidden effect per set.

    .venv/bin/python scripts/make_concealed_fixtures.py [--force]

Every set is the 17 recordings of the identification fixtures' protocol (Lu 2015 §IV,
25 kHz, 1 nm white noise, its own noise seed) simulated from the identification truth
plus one effect of :mod:`stickslip_jax.testing.concealed` (or none: the null set).
Set folders are numbered in a shuffled order and the recordings carry the same names
and metadata in every set, so nothing but the traces tells the effect; the answers
are in ``answers.json`` at the top of the folder (never read by the tool).
"""

import argparse
import json
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.synthetic import paper_protocol, simulate_set  # noqa: E402
from stickslip_jax.testing.concealed import CANNOT_SHOW, EFFECTS, with_effect  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_identification_fixtures import truth_params  # noqa: E402

OUT = Path(__file__).resolve().parent.parent / "fixtures" / "concealed"


def set_names() -> dict[str, str]:
    """``effect → folder`` in a fixed shuffled order (seed 5)."""
    order = np.random.default_rng(5).permutation(len(EFFECTS))
    return {EFFECTS[i]: f"set_{k + 1:02d}" for k, i in enumerate(order)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--force", action="store_true", help="replace existing files")
    args = ap.parse_args()
    base = ss.actuator_from_params(truth_params())
    names = set_names()
    for k, effect in enumerate(EFFECTS):
        folder = OUT / names[effect]
        folder.mkdir(parents=True, exist_ok=True)
        recs = simulate_set(with_effect(base, effect), paper_protocol(), noise_m=1e-9,
                            seed=3000 + 17 * k)
        for rec in recs:
            ss.save_recording(rec, folder / f"{rec.name}.csv", force=args.force)
        print(f"{folder.name}: {len(recs)} recordings")
    answers = {"sets": {v: k for k, v in sorted(names.items(), key=lambda kv: kv[1])},
               "cannot_show_in_this_protocol": CANNOT_SHOW,
               "truth_baseline": "fixtures/identification/truth.json"}
    path = OUT / "answers.json"
    ss.files.check_output_path(path, force=args.force)
    ss.files.atomic_write_text(path, json.dumps(answers, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

"""When does sensor_periodic offer a fringe offset per recording? Its gate
(`fringe_start`: a BIC scaled by the rotated fit's overdispersion) on the residual
of the truth without the effect, on the 17-recording protocol at 1 nm noise:

- every concealed effect (and two variants) hidden, the error absent (should offer
  nothing: a misfit of another physics is not a fringe phase);
- the error read from a random point of the fringe per recording (0.5-2.5 nm), alone
  and with an unfitted creep or sensor delay beside it.

Also the plain BIC (the misfits not scaled), the rule the scaling replaced.

    .venv/bin/python benchmarks/experiments/fringe_start_gate.py \
        --json benchmarks/experiments/results/fringe_start_gate.json
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.diagnose.catalogue import sensor_periodic as sp  # noqa: E402
from stickslip_jax.model.extensions import HENE_FRINGE_M, PeriodicSensorError  # noqa: E402
from stickslip_jax.simulate import simulate_recordings  # noqa: E402
from stickslip_jax.synthetic import paper_protocol, simulate_set  # noqa: E402
from stickslip_jax.testing.concealed import (  # noqa: E402
    read_from_fringe_starts,
    with_effect,
    with_variant,
)

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from results_record import write_record  # noqa: E402

TRUTH = Path(__file__).resolve().parents[2] / "fixtures" / "identification" / "truth.json"
EFFECTS = ("none", "creep", "sensor_delay", "structural_mode", "stribeck",
           "viscous_friction", "rate_dependent_hysteresis", "drive_bandwidth",
           "uncatalogued", "variant:interferometer_periodic", "variant:mode_2k")


def gate(hints: dict) -> dict:
    """``fringe_start`` on ``hints``, with the misfits it compared (recorded by
    wrapping its alignment) and the plain BIC's verdict beside it."""
    seen = []
    aligned = sp._aligned

    def spy(*args):
        mean, misfit = aligned(*args)
        seen.append(misfit)
        return mean, misfit

    sp._aligned = spy
    try:
        start = sp.fringe_start(hints)
    finally:
        sp._aligned = aligned
    if not seen:
        return {"offered": False, "why": "fewer than two recordings move a fringe"}
    m = sum(1 for q in hints["outputs_m"] if np.ptp(q) >= HENE_FRINGE_M)
    log_n = math.log(sum(q.size for q in hints["outputs_m"]))
    shared, rotated = seen[0], seen[-1]
    return {"offered": start is not None, "shared_misfit": shared,
            "rotated_misfit": rotated, "offsets": m - 1,
            "plain_bic_offers": shared - rotated > (m - 1) * log_n,
            "qbic_gain": None if start is None else start.bic_gain}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    ss.fast_cpu_loops()
    base = ss.load_params(TRUTH)
    specs = paper_protocol()
    sim = [np.asarray(q) for q in simulate_recordings(base, [s.recording() for s in specs])]

    def hints_of(recs):
        return {"outputs_m": tuple(sim),
                "residuals_m": tuple(r.position_m - q for r, q in zip(recs, sim, strict=True)),
                "noise_m": (1e-9,) * len(recs)}

    rows = []
    for name in EFFECTS:
        act = (with_variant(base, name.removeprefix("variant:")) if name.startswith("variant:")
               else with_effect(base, name))
        for seed in (1, 2):
            recs = simulate_set(act, specs, noise_m=1e-9, seed=seed)
            rows.append({"hidden": name, "fringe_starts": False, "seed": seed,
                         **gate(hints_of(recs))})
    for beside in ("none", "creep", "sensor_delay"):
        clean = simulate_set(with_effect(base, beside), specs, noise_m=0.0)
        for amplitude in (2.5e-9, 1e-9, 0.5e-9):
            recs, _ = read_from_fringe_starts(
                clean, lambda o, a=amplitude: PeriodicSensorError(a, offset=o),
                noise_m=1e-9, seed=3)
            rows.append({"hidden": f"periodic {amplitude * 1e9:g} nm"
                         + ("" if beside == "none" else f" + {beside}"),
                         "fringe_starts": True, "seed": 3, **gate(hints_of(recs))})
    print("| hidden | read from random fringe starts | seed | misfit, one phase | misfit, "
          "rotated | plain BIC offers | offered (QBIC) |\n|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['hidden']} | {'yes' if r['fringe_starts'] else 'no'} | {r['seed']} | "
              f"{r.get('shared_misfit', float('nan')):.0f} | "
              f"{r.get('rotated_misfit', float('nan')):.0f} | "
              f"{'yes' if r.get('plain_bic_offers') else 'no'} | "
              f"{'yes' if r['offered'] else 'no'} |")
    if args.json:
        write_record(args.json, what=__doc__.splitlines()[0], rows=rows)


if __name__ == "__main__":
    main()

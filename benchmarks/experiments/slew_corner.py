"""Can the tanh slew limit reach the noise on a hard-limited amplifier's recordings?

    .venv/bin/python benchmarks/experiments/slew_corner.py [--set fixtures/concealed/set_03]

Concealed set_03 hides a current-limited amplifier (``ClippedSlewInput``, 1.2 V/µs after
an 8 µs small-signal lag). With every baseline quantity at the fixtures' truth, only the
drive stage's own parameters are fitted (scipy's least squares, finite differences in
the logarithms): the tanh form (slew, τ) and the shaped form (slew, τ, corner
sharpness p), and the mean (e/σ)² each reaches is printed beside the truth's own (the
data's noise, 1 nm). Backed the drive entry's refined form (``ShapedSlewInput``,
``diagnose/form_refinement.py``): the tanh stops at 3.27, the shaped form reaches the
truth's 1.009 with p in the hundreds.
"""

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.testing.truth import identification_truth  # noqa: E402

ss.fast_cpu_loops()
NOISE_M = 1e-9
"""The concealed sets' noise level [m]."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", type=Path, default=Path("fixtures/concealed/set_03"))
    args = ap.parse_args()
    recs = ss.load_recordings(sorted(args.set.glob("*.csv")))
    base = ss.actuator_from_params(identification_truth())

    def whitened(stage):
        act = eqx.tree_at(lambda a: a.input_stage, base, stage)
        parts = []
        for q, rec in zip(ss.simulate_recordings(act, recs), recs, strict=True):
            d = q - rec.position_m
            parts.append((d - d.mean()) / NOISE_M)
        return np.concatenate(parts)

    truth = np.mean(whitened(ss.ClippedSlewInput(1.2e6, 8e-6)) ** 2)
    print(f"truth (hard limit): mean (e/σ)² {truth:.4g}", flush=True)
    for name, make, x0 in (("tanh", lambda x: ss.SlewLimitedInput(*x), [1.2e6, 8e-6]),
                           ("shaped", lambda x: ss.ShapedSlewInput(*x), [1.2e6, 8e-6, 4.0])):
        t0 = time.perf_counter()
        fit = least_squares(lambda z, make=make: whitened(make(np.exp(z))), np.log(x0),
                            diff_step=1e-4,
                            max_nfev=60)
        print(f"{name}: {np.exp(fit.x)} → mean (e/σ)² {np.mean(fit.fun ** 2):.4g} "
              f"({fit.nfev} evaluations, {time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()

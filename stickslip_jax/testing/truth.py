"""Known truths for synthetic recording sets (test data, not part of the model).

:func:`identification_truth` is the documented truth of ``fixtures/identification/``
(``scripts/make_identification_fixtures.py`` writes it as ``truth.json``; the
concealed sets add their effects to it). It lives here so that the testing
generators (:mod:`.random_sets`) use it without importing ``scripts/``.

:func:`draw_truth` moves it at random within stated ranges (the random-set
generator's truths; see :data:`TRUTH_RANGES`).
"""

from __future__ import annotations

import numpy as np

from ..model.profiles import lu2015_slc1720
from ..params import params_from_actuator

PI_TAIL_DECAY_V = 12.0
"""Decay [V] of the identification truth's PI tail weights, ``∝ exp(−r/12 V)``."""


def log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A draw uniform in log between ``lo`` and ``hi`` (positive)."""
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def pi_weights(linear: float, tail_total: float, thresholds, decay_V: float) -> list[float]:
    """PI weights [m/V]: ``linear`` on the zero threshold, then ``tail_total`` spread over
    the other thresholds [V] as ``exp(−r/decay_V)``."""
    r = np.asarray(thresholds, dtype=float)
    tail = np.exp(-r[1:] / decay_V)
    return [float(linear)] + [float(w) for w in tail_total * tail / tail.sum()]


def identification_truth() -> dict:
    """The truth of the identification fixtures (docs/model.md names, SI): the default
    profile with its dynamics, hysteresis and friction moved by 5-20 %."""
    p = params_from_actuator(lu2015_slc1720())
    p.update(
        Mp=2.8e-4, Dp=14.0, Kp=2.4e6, Ms=0.0247, Ds=70.0, rho0=3.2e5,
        z_ba=0.42e-6, z_ba_forward=0.42e-6, z_ba_backward=0.48e-6, zba_ratio=0.667,
        pi_weights=pi_weights(1.9e-8, 0.6e-8, p["pi_thresholds"], PI_TAIL_DECAY_V),
    )
    return p


TRUTH_RANGES: dict[str, tuple[float, float]] = {
    "Mp": (0.8, 1.25),
    "Dp": (0.75, 1.33),
    "Kp": (0.8, 1.25),
    "Ds": (0.75, 1.33),
    "rho0": (0.75, 1.33),
    "z_ba_forward": (0.8, 1.25),
    "z_ba_backward": (0.8, 1.25),
    "pi_linear": (0.8, 1.25),
    "pi_tail": (0.7, 1.43),
    "pi_decay_V": (0.67, 1.5),
}
"""Log-uniform factors ``(low, high)`` on the identification truth's values drawn by
:func:`draw_truth`. ``pi_linear``: the first PI weight (1.9e-8 m/V); ``pi_tail``: the
sum of the other weights (0.6e-8 m/V); ``pi_decay_V``: the tail's decay (12 V). Held:
Ms (0.0247 kg, the mass scale every fit fixes), zba_ratio (0.667, the paper's), the
PI thresholds, Kact2·N = 0, no load."""


PI_GRIDS = ("sparse", "dense", "scaled")
"""The kinds of PI operator grid :func:`draw_pi_grid` draws, equally likely."""

PI_GRID_RANGES: dict[str, tuple[float, float]] = {
    "sparse_operators": (4, 12),
    "sparse_top": (0.6, 1.2),
    "dense_operators": (60, 120),
    "dense_top": (0.8, 1.25),
    "scaled": (0.7, 1.4),
}
"""What :func:`draw_pi_grid` draws: operator counts (uniform integers, both ends
included) and factors (log-uniform) on the fit grid's highest threshold (57.8 V) or on
the whole grid."""


def draw_pi_grid(rng: np.random.Generator, params: dict, factors: dict) -> tuple[dict, dict]:
    """``params`` (a truth of :func:`draw_truth`, drawn with ``factors``) with its own PI
    operators instead of the fit grid's 35: the hysteresis's *shape* drawn too, so that a
    null set tests the case where the fit's threshold grid cannot follow it exactly
    (issue #63). One of :data:`PI_GRIDS`, equally likely:

    - ``sparse``: 4-12 operators, thresholds 0 and the others uniform at random below a
      top of 0.6-1.2 times the fit grid's highest;
    - ``dense``: 60-120 operators evenly spaced up to 0.8-1.25 times it (a nearly
      continuous threshold density);
    - ``scaled``: the fit grid times 0.7-1.4 (rate-scaled thresholds).

    The weights follow the truth's own law (linear weight, tail sum, tail decay:
    :func:`pi_weights`), so the stroke per volt stays in the truth's range. Returns
    ``(params, drawn)``, ``drawn`` saying what was drawn (``pi_grid``, ``pi_operators``
    and the factor)."""
    base = np.asarray(params["pi_thresholds"], dtype=float)
    kind = PI_GRIDS[int(rng.integers(len(PI_GRIDS)))]

    if kind == "sparse":
        n = int(rng.integers(PI_GRID_RANGES["sparse_operators"][0],
                             PI_GRID_RANGES["sparse_operators"][1] + 1))
        factor = log_uniform(rng, *PI_GRID_RANGES["sparse_top"])
        thresholds = np.concatenate([[0.0], np.sort(rng.uniform(0.0, factor * base[-1], n - 1))])
    elif kind == "dense":
        n = int(rng.integers(PI_GRID_RANGES["dense_operators"][0],
                             PI_GRID_RANGES["dense_operators"][1] + 1))
        factor = log_uniform(rng, *PI_GRID_RANGES["dense_top"])
        thresholds = np.linspace(0.0, factor * base[-1], n)
    else:
        factor = log_uniform(rng, *PI_GRID_RANGES["scaled"])
        thresholds = base * factor
    p = dict(params)
    p["pi_thresholds"] = [float(r) for r in thresholds]
    p["pi_weights"] = pi_weights(1.9e-8 * factors["pi_linear"], 0.6e-8 * factors["pi_tail"],
                                 thresholds, PI_TAIL_DECAY_V * factors["pi_decay_V"])
    return p, {"pi_grid": kind, "pi_operators": int(thresholds.size), "pi_grid_factor": factor}


def draw_truth(rng: np.random.Generator) -> tuple[dict, dict[str, float]]:
    """A truth drawn around :func:`identification_truth` (:data:`TRUTH_RANGES`):
    ``(params, factors)``, the parameter dictionary and the factor drawn per entry."""
    p = identification_truth()
    factors = {k: log_uniform(rng, lo, hi) for k, (lo, hi) in TRUTH_RANGES.items()}
    for k in ("Mp", "Dp", "Kp", "Ds", "rho0", "z_ba_forward", "z_ba_backward"):
        p[k] = float(p[k] * factors[k])
    p["z_ba"] = p["z_ba_forward"]
    p["pi_weights"] = pi_weights(1.9e-8 * factors["pi_linear"], 0.6e-8 * factors["pi_tail"],
                                 p["pi_thresholds"], PI_TAIL_DECAY_V * factors["pi_decay_V"])
    return p, factors

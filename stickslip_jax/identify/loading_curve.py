"""The hysteresis as the data determine it: the initial loading curve at its knots.

Neighbouring play operators of a Prandtl-Ishlinskii model trade off against each
other: a little more weight on one threshold and a little less on the next changes
the loop by far less than the noise, so individual weights carry large, strongly
anti-correlated errors (on the identification fixtures most are undetermined). What
the recordings do fix is the loop's shape. It is reported as the initial loading
curve, the stroke Γ(u) = Σ_i w_i·max(u − r_i, 0) [m] reached from rest at each knot
u = r_1 … r_(n−1) and at the top of the recorded voltage, and its slopes between
knots, Σ_(i≤k) w_i [m/V] (non-negative: the fit keeps the loop monotone, see the
``pi_cumlog`` transform), each with its standard error by the delta method.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from .parameters import ParameterMap
from .uncertainty import Uncertainty


def loading_curve(thresholds, weights, voltages):
    """Stroke Γ [m] on the initial loading curve at ``voltages`` [V] (≥ 0, from rest):
    Σ_i w_i·max(u − r_i, 0)."""
    u = jnp.asarray(voltages, dtype=float)[:, None]
    r = jnp.asarray(thresholds, dtype=float)[None, :]
    w = jnp.asarray(weights, dtype=float)[None, :]
    return jnp.sum(w * jnp.maximum(u - r, 0.0), axis=1)


@dataclass(frozen=True)
class LoadingCurve:
    """The loading curve at its knots with standard errors (see the module docstring).

    ``voltage_V`` (k,) the knots; ``stroke_m``, ``stroke_se_m`` and ``stroke_determined``
    the stroke there; ``slope_m_per_V``, ``slope_se_m_per_V`` and ``slope_determined``
    the slope on each interval [r_i, r_(i+1)) (the last up to the top voltage)."""

    voltage_V: np.ndarray
    stroke_m: np.ndarray
    stroke_se_m: np.ndarray
    stroke_determined: np.ndarray
    slope_m_per_V: np.ndarray
    slope_se_m_per_V: np.ndarray
    slope_determined: np.ndarray

    def as_dict(self) -> dict:
        def clean(x):
            return [float(v) if np.isfinite(v) else None for v in np.asarray(x)]

        return {"voltage_V": clean(self.voltage_V), "stroke_m": clean(self.stroke_m),
                "stroke_std_error_m": clean(self.stroke_se_m),
                "stroke_determined": [bool(v) for v in self.stroke_determined],
                "slope_m_per_V": clean(self.slope_m_per_V),
                "slope_std_error_m_per_V": clean(self.slope_se_m_per_V),
                "slope_determined": [bool(v) for v in self.slope_determined]}


def loading_curve_uncertainty(pmap: ParameterMap, theta, unc: Uncertainty,
                              u_top: float) -> LoadingCurve | None:
    """The fitted loading curve up to ``u_top`` [V] (the largest recorded voltage) with
    errors from ``unc`` (whose θ is ``pmap``'s); None when the PI weights are not free.

    Both the strokes and the slopes are linear in the weights, so their gradients in θ
    are those maps times the weights' (:meth:`~.parameters.ParameterMap.value_jacobian`),
    in numpy."""
    if "pi_weights" not in pmap.names:
        return None
    theta = np.asarray(theta, dtype=float)
    thresholds = np.asarray(pmap.start.hysteresis.thresholds, dtype=float)  # never fitted
    knots = np.append(thresholds[1:][thresholds[1:] < u_top], u_top)
    rows = pmap.slices()["pi_weights"]
    weights = pmap.physical(theta)["pi_weights"]
    dw = pmap.value_jacobian(theta)[rows]  # (weights, θ)
    stroke_map = np.maximum(knots[:, None] - thresholds[None, :], 0.0)  # Γ = map·w
    slope_map = np.tril(np.ones((knots.size, thresholds.size)))  # cumulative sums
    out = []
    for linear in (stroke_map, slope_map):
        value = linear @ weights
        se, det = unc.of(linear @ dw, value)
        out += [value, se, det]
    return LoadingCurve(knots, *out)

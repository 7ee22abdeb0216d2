"""Hysteresis-only configuration: a piezo stage without slider or friction.

For a positioning stage driven slowly (well below its first resonance) the sensed
output is the piezo stroke alone, seen through an uncalibrated sensor::

    o_k = s·Γ[U]_k + c,        y_k = (1 − λ)·o_k + λ·o_{k−1}

with Γ the Prandtl-Ishlinskii operator (weights in sensor volts per volt), ``s = ±1``
the sensor's sign (fixed from a straight-line fit: the PI loop is kept monotone, so
its slope is positive), ``c`` an offset [sensor V] and ``λ ∈ [0, 1]`` a fractional
one-sample lag (a sensor that lags by up to one sample, as the Aye 2018 data's
README says). The linear-gain baseline is ``y = a·U + b``.

The PI memory starts at rest at the first sample of the whole recording; residuals
may be taken on a window only (one drive cycle), so the memory entering the window
is the one the recorded history left.
"""

from __future__ import annotations

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..model.hysteresis import PrandtlIshlinskii, default_thresholds
from .parameters import FreeParameter
from .solve import SolveResult, solve_least_squares


class HysteresisOnlyModel(eqx.Module):
    """``y = lag(s·Γ[U] + c)`` (see the module docstring). Units: U [V], y [sensor
    units]; ``weights`` [sensor units / V]; ``offset`` [sensor units]; ``lag`` [-]."""

    hysteresis: PrandtlIshlinskii
    offset: jax.Array
    lag: jax.Array
    sign: float = eqx.field(static=True, default=1.0)

    def output(self, voltage) -> jax.Array:
        """Sensor output at every sample of ``voltage`` [V], from rest at sample 0."""
        gamma = self.hysteresis.along(voltage)
        o = self.sign * gamma + self.offset
        previous = jnp.concatenate([o[:1], o[:-1]])
        return (1.0 - self.lag) * o + self.lag * previous


def nrmse(y_model, y_measured) -> float:
    """RMS of the residual over the peak-to-peak of the measurement [-]
    (docs/model.md "Fit quality")."""
    y_model, y_measured = np.asarray(y_model), np.asarray(y_measured)
    return float(np.sqrt(np.mean((y_model - y_measured) ** 2)) / np.ptp(y_measured))


@dataclass(frozen=True)
class LinearBaseline:
    """``y = slope·U + intercept`` fitted by least squares on the training window."""

    slope: float
    intercept: float

    @staticmethod
    def fit(voltage, sensor) -> LinearBaseline:
        a, b = np.polyfit(np.asarray(voltage, float), np.asarray(sensor, float), 1)
        return LinearBaseline(float(a), float(b))

    def output(self, voltage) -> np.ndarray:
        return self.slope * np.asarray(voltage, float) + self.intercept


@dataclass(frozen=True)
class HysteresisFit:
    """A fitted :class:`HysteresisOnlyModel`, its linear baseline and the solve."""

    model: HysteresisOnlyModel
    baseline: LinearBaseline
    solve: SolveResult
    train_nrmse: float
    baseline_train_nrmse: float


def fit_hysteresis_only(voltage, sensor, window: slice, *, n_pi: int = 35,
                        fit_lag: bool = True, max_steps: int = 200) -> HysteresisFit:
    """Fit PI weights, offset (and the lag) to ``sensor`` on ``window`` of a recording.

    ``voltage`` [V] and ``sensor`` cover the whole recording (the PI runs from its
    start); residuals are taken on ``window`` only. Thresholds: ``n_pi`` non-uniform
    ones up to half the voltage span in the window (a play of larger threshold never
    moves within it). The start is the straight-line fit: ``w_0`` = |slope|, the other
    weights 1e-3 of it.
    """
    u = np.asarray(voltage, dtype=float)
    y = np.asarray(sensor, dtype=float)
    if u.shape != y.shape or u.ndim != 1:
        raise ValueError("voltage and sensor must be 1-D arrays of one length")
    baseline = LinearBaseline.fit(u[window], y[window])
    sign = 1.0 if baseline.slope >= 0 else -1.0
    span = float(np.ptp(u[window]))
    if span <= 0:
        raise ValueError("the voltage does not vary in the training window")
    thresholds = default_thresholds(n_pi, span / 2)
    w0 = np.full(n_pi, 1e-3 * abs(baseline.slope))
    w0[0] = abs(baseline.slope)
    weights = FreeParameter("pi_weights", "pi_cumlog", n_pi, w0)
    y_win = jnp.asarray(y[window])
    scale = float(np.ptp(y[window]))
    u_j = jnp.asarray(u)

    def model_of(theta):
        w = weights.to_physical(theta[:n_pi])
        offset = baseline.intercept + scale * theta[n_pi]
        lag = jax.nn.sigmoid(theta[n_pi + 1]) if fit_lag else jnp.asarray(0.0)
        return HysteresisOnlyModel(PrandtlIshlinskii(thresholds, w), offset, lag, sign)

    def residuals(theta):
        return (model_of(theta).output(u_j)[window] - y_win) / scale

    # Lag starts at 0.5 (sigmoid(0)); the offset at the baseline's intercept.
    theta0 = jnp.zeros(n_pi + 2)
    out = solve_least_squares(residuals, theta0, max_steps=max_steps, label="hysteresis")
    model = model_of(jnp.asarray(out.theta))
    return HysteresisFit(
        model, baseline, out,
        nrmse(model.output(u_j)[window], y[window]),
        nrmse(baseline.output(u[window]), y[window]),
    )

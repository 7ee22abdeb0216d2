"""The interferometer's periodic error: the reading is off by an error periodic in the
position it reads, of the fringe's period and its harmonics, in whatever shape.

The class, not one form: the refit fits a cosine and a sine coefficient per harmonic of
the fringe (:class:`~stickslip_jax.model.extensions.SensorOutput`'s ``periodic``), so
that any shape of error within a period (a polarisation-mixing sine, its second-order
companion at half the period, a double-pass interferometer's fringe, which is the
single-pass one's second harmonic) and any phase are special cases. The score test
probes both coefficients of the first :data:`HARMONICS` harmonics as one vector
quantity (linear in them: the derivative at 0 is what it is anywhere); the refit starts
from the best probe's coefficient with the others at 0. A fitted error that leaves the
model beyond the noise gets one more harmonic as its refined form, up to
:data:`MAX_HARMONICS`.

The phase is that of the read position 0: each recording's first sample in the
simulated protocols, one phase for the set. A real set, where every recording starts
at another fringe phase, needs a phase per recording (not done).
"""

from __future__ import annotations

import dataclasses
import math
from typing import final

import equinox as eqx
import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.actuator import Actuator
from ...model.extensions import HENE_FRINGE_M
from ..form_band import draw_band
from .base import CatalogueEntry, Probe
from .slots import carry_output_map, with_sensor

HARMONICS = 2
"""Harmonics of the fringe probed and fitted at first: the first-order error (a
single-pass interferometer's polarisation mixing) and the second (its second-order
term, and a double-pass interferometer's first-order one, whose fringe is λ/4)."""

MAX_HARMONICS = 4
"""Harmonics a refined form reaches at most (one more per refinement)."""

PROBE_SCALE_M = 1e-9
"""θ = 1 of a probe: a coefficient of 1 nm (periodic errors of commercial
interferometers are 0.1-10 nm)."""


def coefficient_name(index: int) -> str:
    """The reported name of the ``index``-th coefficient (cosine then sine, by
    harmonic)."""
    harmonic, odd = divmod(index, 2)
    return f"periodic_{'sin' if odd else 'cos'}_{harmonic + 1}"


def with_periodic(act: Actuator, harmonics: int = HARMONICS) -> Actuator:
    """``act`` with a :class:`SensorOutput` whose periodic error has ``harmonics``
    harmonics (the fitted ones kept, new ones at 0), its other quantities as they
    were."""
    act = with_sensor(act)
    have = act.output_map.periodic
    if len(have) >= 2 * harmonics:
        return act
    return _with_coefficients(act, have + (0.0,) * (2 * harmonics - len(have)))


def _with_coefficients(act: Actuator, coefficients) -> Actuator:
    """``act`` (its output map a :class:`SensorOutput`) with the periodic error's
    ``coefficients``, its other quantities as they were."""
    return eqx.tree_at(lambda a: a.output_map, act,
                       dataclasses.replace(act.output_map, periodic=tuple(coefficients)))


def _coefficient(index: int):
    return lambda a: a.output_map.periodic[index]


def _specs(count: int, scale: float) -> dict[str, ParameterSpec]:
    return {coefficient_name(i): ParameterSpec(_coefficient(i), "linear", scale, "m")
            for i in range(count)}


@final
class SensorPeriodicEntry(CatalogueEntry):
    """The :class:`~stickslip_jax.model.extensions.SensorOutput`'s periodic error:
    cosine and sine coefficients [m] of the fringe's harmonics (either sign); the refit
    frees them all."""

    name = "sensor_periodic"
    slot = "output_map"
    signature = ("residual periodic in the position read, of the laser's fringe "
                 f"({HENE_FRINGE_M * 1e9:.4g} nm) or its harmonics, in every regime alike")

    def needs(self, recordings):
        spans = [float(np.ptp(r.position_m)) for r in recordings
                 if r.position_m is not None and r.position_m.size]
        if not spans or max(spans) < HENE_FRINGE_M:
            return (f"indistinguishable: no recording moves one fringe "
                    f"({HENE_FRINGE_M * 1e9:.4g} nm); within a fringe a periodic error of "
                    f"the reading is a smooth bend of the stroke")
        return None

    def probes(self, act, hints):
        # One spec for all: the coefficients are one vector quantity of the score test.
        spec = ParameterSpec(lambda a: a.output_map.periodic, "linear", PROBE_SCALE_M, "m")
        return [Probe(f"periodic {coefficient_name(i).removeprefix('periodic_')}",
                      with_periodic, spec, 0, {"index": i})
                for i in range(2 * HARMONICS)]

    def attach(self, act, strength, probe):
        start = [0.0] * (2 * HARMONICS)
        start[probe.setting["index"]] = strength
        new = _with_coefficients(with_sensor(act), start)
        return new, _specs(len(start), probe.strength_scale(strength))

    def refined_forms(self, act, hints):
        """One more harmonic (at 0: the fitted error itself), every coefficient
        freed; none once :data:`MAX_HARMONICS` are fitted."""
        have = len(getattr(act.output_map, "periodic", ())) // 2
        if not have or have >= MAX_HARMONICS:
            return []
        coef = np.abs(np.asarray(act.output_map.periodic, dtype=float))
        scale = float(coef.max()) if coef.max() > 0 else PROBE_SCALE_M
        return [(with_periodic(act, have + 1), _specs(2 * (have + 1), scale))]

    def carry(self, init, fitted):
        return carry_output_map(init, fitted)

    def implausible(self, params):
        slope = _max_slope(_coefficients(params))
        if slope >= 1.0:
            return (f"the error's slope reaches {slope:.3g} of the position's: the reading "
                    f"would run backwards within a fringe; not an interferometer's "
                    f"periodic error")
        return ""

    def describe(self, params):
        coef = _coefficients(params)
        if not coef.size:
            return ""
        amps = np.hypot(coef[:, 0], coef[:, 1])
        p = np.linspace(0.0, HENE_FRINGE_M, 400)
        curve = _error(coef, p)
        parts = ", ".join(f"{a * 1e9:.3g} nm at {HENE_FRINGE_M / (k + 1) * 1e9:.4g} nm"
                          for k, a in enumerate(amps))
        return (f"interferometer periodic error: {parts}; "
                f"{np.ptp(curve) * 1e9:.3g} nm peak to peak over a fringe")

    def plot_form(self, ax, params, draws=None):
        coef = _coefficients(params)
        if not coef.size:
            return False
        p = np.linspace(0.0, 2.0 * HENE_FRINGE_M, 400)
        draw_band(ax, p * 1e9, lambda q: _error(_coefficients(q), p), params, draws,
                  scale=1e9)
        ax.plot(p * 1e9, _error(coef, p) * 1e9, color="tab:blue", label="error found")
        ax.plot(p * 1e9, _error(coef[:1], p) * 1e9, color="0.5", ls="--", lw=0.8,
                label="first harmonic")
        ax.set_xlabel("position read [nm]")
        ax.set_ylabel("reading error [nm]")
        ax.set_title(f"interferometer periodic error ({len(coef)} harmonics)", fontsize=9)
        ax.legend(fontsize=7)
        return True


def _coefficients(params: dict[str, float]) -> np.ndarray:
    """The refitted coefficients in ``params`` as rows ``(c_k, s_k)`` by harmonic."""
    count = sum(1 for k in params if k.startswith("periodic_"))
    return np.array([params.get(coefficient_name(i), 0.0)
                     for i in range(count - count % 2)]).reshape(-1, 2)


def _error(coef: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The periodic error [m] of rows ``coef`` at read positions ``p`` [m]."""
    k = np.arange(1, len(coef) + 1)
    phase = 2.0 * math.pi * p[:, None] * k / HENE_FRINGE_M
    return np.sum(coef[:, 0] * np.cos(phase) + coef[:, 1] * np.sin(phase), axis=1)


def _max_slope(coef: np.ndarray) -> float:
    """The error's largest slope [-] over a fringe (its derivative, on a grid of 2048
    points per fringe)."""
    if not coef.size:
        return 0.0
    k = np.arange(1, len(coef) + 1)
    phase = 2.0 * math.pi * np.linspace(0.0, HENE_FRINGE_M, 2049)[:, None] * k / HENE_FRINGE_M
    rate = 2.0 * math.pi * k / HENE_FRINGE_M
    return float(np.max(np.abs(np.sum(rate * (coef[:, 1] * np.cos(phase)
                                               - coef[:, 0] * np.sin(phase)), axis=1))))


__all__ = ["HARMONICS", "MAX_HARMONICS", "SensorPeriodicEntry", "coefficient_name",
           "with_periodic"]

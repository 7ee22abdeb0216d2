"""Rate-dependent hysteresis: a stroke lag that grows with the voltage rate, in whatever
form.

The class, not one form: the score test probes the first-order lag at the drive's time
constants (:data:`TAUS`), and the refit fits :class:`~stickslip_jax.model.extensions.
RateLagForm` from the best one: the voltage lag ``d = u − s`` of a first-order follower
shapes the stroke's lag as a linear term beside saturating terms ``g·V·tanh(d/V)`` on a
fixed grid of voltages (:data:`SAT_VOLTS`) with non-negative gains. A lag that grows with
the rate without bound is the linear term; one that stops growing beyond some volts of
lag is a saturating term (or two neighbours); the time constant is freed with them.
"""

from __future__ import annotations

from typing import final

import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.extensions import RateDependentStroke, RateLagForm
from ..form_band import draw_band
from .base import CatalogueEntry
from .slots import carry_extensions, ext, first_order_probes

TAUS = (0.05e-3, 0.1e-3, 0.2e-3, 0.4e-3, 0.8e-3)
"""Probed time constants [s]: the drive's time scale, faster than creep's
(:mod:`.slots`)."""

SAT_VOLTS = (0.3, 1.0, 3.0, 10.0)
"""The refit's grid of saturation voltages [V], half a decade apart: the voltage lags
``τ·|u̇|`` the drives make span them (a 0.1-0.8 ms lag of the protocol's 20-60 V
sawtooth ramps is 1-40 V; its sines' less). A term saturating far above the largest lag
is the linear term; one far below it, a constant offset of each ramp the PI loop
already takes."""

START_SHARE = 0.01
"""Each saturating gain starts at this share of the first-order gain: inside the
softplus's curve, where the fit can raise it or let it fall to 0."""


def sat_name(volts: float) -> str:
    """The reported name of the saturating gain at ``volts`` [V]."""
    return f"rate_sat_gain_{volts:g}V"


@final
class RateDependentHysteresisEntry(CatalogueEntry):
    """The lag :class:`~stickslip_jax.model.extensions.RateLagForm`: its linear gain
    [m/V], time constant [s] and saturating gains [m/V] on :data:`SAT_VOLTS`, every
    one freed (the saturating ones non-negative)."""

    name = "rate_dependent_hysteresis"
    slot = "extension"
    signature = ("stroke lag growing with the voltage rate: loop width and phase of sine "
                 "and ramp phases")

    def probes(self, act, hints):
        return first_order_probes(act, RateDependentStroke, "rate lag", TAUS)

    def attach(self, act, strength, probe):
        scale = probe.strength_scale(strength)
        sat = (START_SHARE * scale,) * len(SAT_VOLTS)
        new = act.with_extension(RateLagForm(strength, probe.setting["tau"], sat, SAT_VOLTS))
        g = ext(RateLagForm)
        specs = {"rate_gain": ParameterSpec(lambda a: g(a).gain, "linear", scale, "m/V"),
                 "rate_tau": ParameterSpec(lambda a: g(a).tau, "log", 1.0, "s")}
        specs |= {sat_name(v): ParameterSpec(lambda a, i=i: g(a).sat_gains[i], "nonneg",
                                             scale, "m/V")
                  for i, v in enumerate(SAT_VOLTS)}
        return new, specs

    def carry(self, init, fitted):
        return carry_extensions(init, fitted)

    def _form(self, params):
        return RateLagForm(params.get("rate_gain", 0.0), params.get("rate_tau", 1e-4),
                           [params.get(sat_name(v), 0.0) for v in SAT_VOLTS], SAT_VOLTS)

    def describe(self, params: dict[str, float]) -> str:
        form = self._form(params)
        at = np.array([1.0, 10.0, 30.0])
        lag = np.asarray(form.lag(at))
        sats = [f"{params.get(sat_name(v), 0.0) * 1e9:.3g} nm/V to {v:g} V" for v in SAT_VOLTS
                if params.get(sat_name(v), 0.0) > 1e-3 * max(
                    [params.get(sat_name(w), 0.0) for w in SAT_VOLTS] + [1e-30])]
        return (f"rate lag: time constant {params.get('rate_tau', float('nan')) * 1e3:.3g} "
                f"ms, linear {params.get('rate_gain', 0.0) * 1e9:.3g} nm/V"
                + (", saturating " + ", ".join(sats) if sats else "")
                + "; the stroke lags by " + ", ".join(
                    f"{x * 1e9:.3g} nm at {d:g} V" for d, x in zip(at, lag, strict=True))
                + " of voltage lag")

    def plot_form(self, ax, params, draws=None):
        form = self._form(params)
        d = np.linspace(0.0, 40.0, 300)
        draw_band(ax, d, lambda p: np.asarray(self._form(p).lag(d)), params, draws,
                  scale=1e9)
        ax.plot(d, np.asarray(form.lag(d)) * 1e9, color="tab:blue", label="lag found")
        ax.plot(d, params.get("rate_gain", 0.0) * d * 1e9, color="0.5", ls="--", lw=0.8,
                label="linear term")
        ax.set_xlabel("voltage lag u − s [V]")
        ax.set_ylabel("stroke lag [nm]")
        ax.set_title("rate-dependent hysteresis", fontsize=9)
        ax.legend(fontsize=7)
        return True

"""Creep: the stroke's slow settling after each voltage change, in whatever form.

The class, not one form: the refit fits a relaxation spectrum, first-order creep
terms on a fixed logarithmic grid of time constants (:data:`SPECTRUM_TAUS`) with
non-negative weights (:class:`~stickslip_jax.model.extensions.CreepSpectrum`). A
first-order creep is one weight; a logarithmic or fractional law, or several
modes, are spread weights. The score test still probes first-order creep at the
grid's coarse points (:data:`TAUS`): to first order any monotone creep projects on
them, and the refit starts from the best one's strength at its time constant.
"""

from __future__ import annotations

from typing import final

import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.extensions import Creep, CreepSpectrum
from ..form_band import band
from .base import CatalogueEntry
from .slots import carry_extensions, ext, first_order_probes

TAUS = (1.5e-3, 4e-3, 10e-3, 30e-3)
"""Probed time constants [s]: slower than the rate lag's (:mod:`.slots`)."""

SPECTRUM_TAUS = (1.5e-3, 2.45e-3, 4e-3, 6.3e-3, 10e-3, 17e-3, 30e-3, 50e-3, 80e-3, 130e-3,
                 210e-3, 340e-3)
"""The refit's grid of time constants [s]: the probes' with their geometric means
between them and more at the same ratio above (about 1.6, at which one first-order
creep between two grid points is matched to 0.05 % of its amplitude by its
neighbours), from the rate lag's upper end (:mod:`.slots`: a faster relaxation is
the rate lag's time scale) to about three times the longest recording (100 ms in the
paper's protocol): a slower mode still bends a recording's drift, and one far slower
is a gain and a linear drift, which the baseline and the sensor's drift take."""

START_SHARE = 0.01
"""Each weight but the probe's starts at this share of the first-order strength:
inside the softplus's curve, where the fit can raise it or let it fall to 0 (a
weight at exactly 0 would have no derivative)."""


def weight_name(tau: float) -> str:
    """The reported name of the spectrum's weight at ``tau`` [s]."""
    return f"creep_weight_{tau * 1e3:g}ms"


def _weights(params: dict[str, float]) -> np.ndarray:
    """The spectrum's weights [m/V] in grid order, from refitted ``params``."""
    return np.array([params.get(weight_name(t), 0.0) for t in SPECTRUM_TAUS])


@final
class CreepEntry(CatalogueEntry):
    """Creep as a relaxation spectrum: :class:`~stickslip_jax.model.extensions.
    CreepSpectrum` on :data:`SPECTRUM_TAUS`, every weight [m/V] freed, non-negative."""

    name = "creep"
    slot = "extension"
    signature = ("slow drift of the stroke after each voltage change: step-response "
                 "tail, period-to-period trend of low-frequency drives")

    def probes(self, act, hints):
        return first_order_probes(act, Creep, "creep", TAUS)

    def attach(self, act, strength, probe):
        scale = probe.strength_scale(strength)
        main = int(np.argmin(np.abs(np.log(np.asarray(SPECTRUM_TAUS) / probe.setting["tau"]))))
        gains = [START_SHARE * scale] * len(SPECTRUM_TAUS)
        gains[main] = max(strength, START_SHARE * scale)
        new = act.with_extension(CreepSpectrum(gains, SPECTRUM_TAUS))
        g = ext(CreepSpectrum)
        return new, {weight_name(tau): ParameterSpec(lambda a, i=i: g(a).gains[i], "nonneg",
                                                     scale, "m/V")
                     for i, tau in enumerate(SPECTRUM_TAUS)}

    def carry(self, init, fitted):
        return carry_extensions(init, fitted)

    def plot_form(self, ax, params, draws=None):
        weights = _weights(params)
        taus_ms = np.asarray(SPECTRUM_TAUS) * 1e3
        ax.vlines(taus_ms, 0.0, weights * 1e12, color="tab:blue", lw=3)
        ax.plot(taus_ms, weights * 1e12, "o", color="tab:blue", ms=4)
        spread = band(_weights, params, draws)
        if spread is not None:  # each weight's 95 % interval, beside its bar
            ax.vlines(taus_ms * 1.12, spread[0] * 1e12, spread[1] * 1e12, color="0.35",
                      lw=1, label="95 % interval (the refit's errors)")
            ax.legend(fontsize=7)
        ax.set_xscale("log")
        ax.set_xlabel("time constant τ [ms]")
        ax.set_ylabel("weight [pm/V]")
        ax.set_title(f"creep spectrum ({weights.sum() * 1e12:.3g} pm/V in all)", fontsize=9)
        return True

    def describe(self, params: dict[str, float]) -> str:
        weights = _weights(params)
        total = float(np.sum(weights))
        if total <= 0:
            return "creep spectrum: no weight"
        taus = np.asarray(SPECTRUM_TAUS)
        centre = float(np.exp(np.sum(weights * np.log(taus)) / total))
        kept = taus[weights >= 0.1 * weights.max()]
        return (f"creep spectrum: total gain {total:.3g} m/V, centred at {centre * 1e3:.3g} ms, "
                f"weights of at least a tenth of the largest from {kept[0] * 1e3:g} to "
                f"{kept[-1] * 1e3:g} ms ({kept.size} of {taus.size})")

"""External load: a force on the slider, constant or growing with its travel.

The class, not one form: the load against the slider's position from where each
recording starts, ``F_ext − k_load·x2``: a constant force (a gravity component, a
cable's pull), a spring (a flexure, a force sensor, a preloaded cable that stretches)
or both. The score test probes each (a spring's force grows with the travel, which a
constant one's signature does not have); the refit frees both.
"""

from __future__ import annotations

from typing import final

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ...identify.parameters import ParameterSpec
from ..form_band import draw_band
from .base import CatalogueEntry, Probe

PROBE_STIFFNESS_SCALE = 100.0
"""θ unit of the spring probe [N/m]: a stiffness that, over the 10-100 µm a
recording travels, pulls by 1-10 mN, the order of the contact's friction."""


FIGURE_TRAVEL_M = 100e-6
"""The form's figure shows the load over ±this travel from a recording's start [m]
(the paper protocol's recordings travel 10-100 µm)."""


def load_force(params: dict[str, float], travel) -> np.ndarray:
    """The load on the slider [N] at ``travel`` [m] from a recording's start, from
    refitted ``params``: ``F_ext − k_load·x2``."""
    return params.get("F_ext", 0.0) - params.get("k_load", 0.0) * np.asarray(travel,
                                                                              dtype=float)


def _slider_f_ext(a):
    return a.slider.F_ext


def _slider_k_load(a):
    return a.slider.k_load


@final
class ExternalLoadEntry(CatalogueEntry):
    """The slider's external force F_ext [N] (either sign) and load stiffness k_load
    [N/m] (either sign; :class:`~stickslip_jax.model.slider.Slider`), added to the
    baseline's; the refit frees both."""

    name = "external_load"
    slot = "slider"
    signature = ("direction asymmetry of step lengths, offset of stick; a spring's "
                 "grows with the travel")

    def probes(self, act, hints):
        return [Probe("constant force", lambda a: a,
                      ParameterSpec(_slider_f_ext, "linear", 0.01, "N"), 0,
                      {"field": "F_ext"}),
                Probe("spring load", lambda a: a,
                      ParameterSpec(_slider_k_load, "linear", PROBE_STIFFNESS_SCALE, "N/m"),
                      0, {"field": "k_load"})]

    def attach(self, act, strength, probe):
        spring = probe.setting.get("field") == "k_load"
        f_ext = float(act.slider.F_ext) + (0.0 if spring else strength)
        k_load = float(act.slider.k_load) + (strength if spring else 0.0)
        new = eqx.tree_at(lambda a: (a.slider.F_ext, a.slider.k_load), act,
                          (jnp.asarray(f_ext), jnp.asarray(k_load)))
        force_scale = 0.01 if spring else probe.strength_scale(strength)
        stiffness_scale = (probe.strength_scale(strength) if spring
                           else PROBE_STIFFNESS_SCALE)
        return new, {"F_ext": ParameterSpec(_slider_f_ext, "linear", force_scale, "N"),
                     "k_load": ParameterSpec(_slider_k_load, "linear", stiffness_scale,
                                             "N/m")}

    def carry(self, init, fitted):
        return eqx.tree_at(lambda a: (a.slider.F_ext, a.slider.k_load), init,
                           (fitted.slider.F_ext, fitted.slider.k_load))

    def describe(self, params: dict[str, float]) -> str:
        return (f"external load: {params.get('F_ext', 0.0) * 1e3:.3g} mN constant and "
                f"{params.get('k_load', 0.0):.3g} N/m against the slider's travel")

    def plot_form(self, ax, params, draws=None):
        if "F_ext" not in params and "k_load" not in params:
            return False
        x = np.linspace(-FIGURE_TRAVEL_M, FIGURE_TRAVEL_M, 200)
        draw_band(ax, x * 1e6, lambda p: load_force(p, x), params, draws, scale=1e3)
        ax.plot(x * 1e6, load_force(params, x) * 1e3, color="tab:blue", label="load found")
        ax.plot(x * 1e6, np.full_like(x, params.get("F_ext", 0.0) * 1e3), color="0.5",
                ls="--", lw=0.8, label="its constant part")
        ax.set_xlabel("slider travel from the recording's start [µm]")
        ax.set_ylabel("load on the slider [mN]")
        ax.set_title("external load against the travel", fontsize=9)
        ax.legend(fontsize=7)
        return True

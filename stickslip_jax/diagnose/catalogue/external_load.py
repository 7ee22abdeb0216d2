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

from ...identify.parameters import ParameterSpec
from .base import CatalogueEntry, Probe

PROBE_STIFFNESS_SCALE = 100.0
"""θ unit of the spring probe [N/m]: a stiffness that, over the 10-100 µm a
recording travels, pulls by 1-10 mN, the order of the contact's friction."""


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

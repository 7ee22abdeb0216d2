"""Stribeck: friction that falls from breakaway towards sliding as the slider speeds up."""

from __future__ import annotations

from typing import final

import equinox as eqx
import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.actuator import Actuator
from ...model.friction import ElastoPlastic, StribeckElastoPlastic
from ..form_band import draw_band
from .base import CatalogueEntry, Probe
from .slots import carry_friction, friction_attr, set_value

FIGURE_SPEEDS = 6.0
"""The form's figure runs to this many Stribeck velocities (the excess down to 3 %)."""


def friction_ratio(params: dict[str, float], speeds) -> np.ndarray:
    """Friction in steady sliding over its sliding (Coulomb) value [-] at ``speeds``
    [m/s], from refitted ``params``: the law's ``1 + (r − 1)/(1 + (v/v_s)²)``
    (:class:`~stickslip_jax.model.friction.StribeckElastoPlastic`; ``stribeck_excess``
    holds the ratio r itself)."""
    ratio, v_s = params.get("stribeck_excess", 1.0), params.get("v_s", 1.0)
    return 1.0 + (ratio - 1.0) / (1.0 + (np.asarray(speeds, dtype=float) / v_s) ** 2)


def _with_stribeck(act: Actuator, v_s: float) -> Actuator:
    """``act`` with its elasto-plastic law extended to :class:`StribeckElastoPlastic`
    (ratio 1: no Stribeck effect yet; velocity ``v_s`` [m/s]), unless it is one."""
    f = act.friction
    if isinstance(f, StribeckElastoPlastic):
        return act
    if not isinstance(f, ElastoPlastic):
        raise ValueError("stribeck extends the elasto-plastic law")
    new = StribeckElastoPlastic(f.rho0, f.z_ba_forward, f.z_ba_backward, stribeck_ratio=1.0,
                                v_s=v_s, zba_ratio=f.zba_ratio, rho1=f.rho1, rho2=f.rho2)
    return eqx.tree_at(lambda a: a.friction, act, new)


@final
class StribeckEntry(CatalogueEntry):
    """The Stribeck law's ratio f_max/f_c [-] (friction at rest over Coulomb friction)
    above 1, at a Stribeck velocity v_s [m/s]; the refit frees the excess and v_s."""

    name = "stribeck"
    slot = "friction"
    signature = ("velocity-dependent steady state: slip phases of stepping, more where "
                 "slip is fast")

    def probes(self, act, hints):
        return [Probe(f"stribeck v_s={v * 1e3:g} mm/s", lambda a, v=v: _with_stribeck(a, v),
                      ParameterSpec(friction_attr("stribeck_ratio"), "linear", 0.1, "-"), +1,
                      {"v_s": v})
                for v in (2e-3,)]

    def attach(self, act, strength, probe):
        new = _with_stribeck(act, probe.setting["v_s"])
        new = set_value(friction_attr("stribeck_ratio"), 1.0 + max(strength, 1e-3))(new)
        return new, {"stribeck_excess": ParameterSpec(
                         lambda a: a.friction.stribeck_ratio, "linear", max(strength, 1e-3),
                         "-"),
                     "v_s": ParameterSpec(friction_attr("v_s"), "log", 1.0, "m/s")}

    def carry(self, init, fitted):
        return carry_friction(init, fitted)

    def describe(self, params):
        if "stribeck_excess" not in params or "v_s" not in params:
            return ""
        return (f"Stribeck friction: at rest {params['stribeck_excess']:.3g}x the sliding "
                f"friction, the excess halved at v_s = {params['v_s'] * 1e3:.3g} mm/s")

    def plot_form(self, ax, params, draws=None):
        if "stribeck_excess" not in params or "v_s" not in params:
            return False
        v = np.linspace(0.0, FIGURE_SPEEDS * params["v_s"], 200)
        draw_band(ax, v * 1e3, lambda p: friction_ratio(p, v), params, draws)
        ax.plot(v * 1e3, friction_ratio(params, v), color="tab:blue", label="friction found")
        ax.axhline(1.0, color="0.5", ls="--", lw=0.8, label="sliding (Coulomb) friction")
        ax.set_xlabel("sliding speed |ẋ| [mm/s]")
        ax.set_ylabel("steady friction / sliding friction [-]")
        ax.set_title("Stribeck: friction against the sliding speed", fontsize=9)
        ax.legend(fontsize=7)
        return True

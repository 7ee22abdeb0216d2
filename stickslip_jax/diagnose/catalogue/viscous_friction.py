"""Viscous friction: a force against the sliding velocity, in whatever rising form.

The class, not one form: the refit fits the law's linear viscous coefficient rho2
beside saturating terms on a fixed grid of speeds (:data:`SPEEDS`,
:class:`~stickslip_jax.model.extensions.SaturatingViscosity`) with non-negative
slopes, so that a linear, a saturating or a nearly constant drag against the
sliding velocity are all special cases. The score test probes rho2: at rest every
term is a viscous slope, which is what any of them adds to first order.
"""

from __future__ import annotations

from typing import final

import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.extensions import SaturatingViscosity
from .base import CatalogueEntry
from .slots import carry_extensions, carry_friction, damping_attach, damping_probes, ext

SPEEDS = (0.3e-3, 1e-3, 3e-3, 10e-3, 30e-3)
"""The saturation speeds of the refit's terms [m/s]: half decades over the sliding
speeds of stepping (slips of a few mm/s; 30 mm/s is linear at all of them)."""

START_SHARE = 0.01
"""Each saturating slope starts at this share of the first-order rho2 step: inside
the softplus's curve, where the fit can raise it or let it fall to 0."""


def slope_name(speed: float) -> str:
    """The reported name of the saturating term at ``speed`` [m/s]."""
    return f"viscous_slope_{speed * 1e3:g}mm/s"


def _slopes(params: dict[str, float]) -> np.ndarray:
    """The saturating terms' slopes [N·s/m] in grid order, from refitted ``params``."""
    return np.array([params.get(slope_name(v), 0.0) for v in SPEEDS])


def force_curve(params: dict[str, float], speeds) -> np.ndarray:
    """The friction the refit adds at sliding ``speeds`` [m/s] [N]: rho2's share beyond
    the baseline's is not known here, so the linear part is rho2 whole."""
    speeds = np.asarray(speeds, dtype=float)[..., None]
    grid = np.asarray(SPEEDS)
    return params.get("rho2", 0.0) * speeds[..., 0] + np.sum(
        _slopes(params) * grid * np.tanh(speeds / grid), axis=-1)


@final
class ViscousFrictionEntry(CatalogueEntry):
    """Friction rising with the sliding velocity: the law's rho2 [N·s/m], raised from
    the baseline's, and :class:`~stickslip_jax.model.extensions.SaturatingViscosity`
    on :data:`SPEEDS`; every slope freed, non-negative."""

    name = "viscous_friction"
    slot = "friction"
    signature = ("force rising with the sliding velocity: slip phases, step length "
                 "falling with drive rate")

    def probes(self, act, hints):
        return damping_probes("rho2")

    def attach(self, act, strength, probe):
        new, specs = damping_attach(act, strength, "rho2")
        scale = max(strength, 0.05)
        new = new.with_extension(SaturatingViscosity([START_SHARE * scale] * len(SPEEDS),
                                                     SPEEDS))
        g = ext(SaturatingViscosity)
        return new, specs | {slope_name(v): ParameterSpec(lambda a, i=i: g(a).gains[i],
                                                          "nonneg", scale, "N·s/m")
                             for i, v in enumerate(SPEEDS)}

    def carry(self, init, fitted):
        return carry_extensions(carry_friction(init, fitted), fitted)

    def describe(self, params):
        at = np.array([1e-3, 3e-3, 10e-3])
        force = force_curve(params, at)
        return ("friction against sliding velocity: rho2 " f"{params.get('rho2', 0.0):.3g} "
                "N·s/m and saturating slopes " + ", ".join(
                    f"{c:.3g} to {v * 1e3:g} mm/s" for c, v in zip(_slopes(params), SPEEDS,
                                                                  strict=True) if c > 0)
                + "; force at " + ", ".join(f"{v * 1e3:g} mm/s {f * 1e3:.3g} mN"
                                            for v, f in zip(at, force, strict=True)))

    def plot_form(self, ax, params):
        v = np.linspace(0.0, 20e-3, 200)
        ax.plot(v * 1e3, force_curve(params, v) * 1e3, color="tab:blue")
        slopes = _slopes(params)
        ax.plot(v * 1e3, params.get("rho2", 0.0) * v * 1e3, color="0.5", ls="--",
                lw=0.8, label="rho2 alone")
        ax.set_xlabel("sliding velocity ẋ [mm/s]")
        ax.set_ylabel("friction added [mN]")
        ax.set_title(f"friction against velocity ({int(np.sum(slopes > 0))} saturating "
                     f"terms)", fontsize=9)
        ax.legend(fontsize=7)
        return True

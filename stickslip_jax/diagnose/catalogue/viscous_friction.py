"""Viscous friction: a force against the sliding velocity ẋ, in whatever rising form
(the law's rho2 and saturating terms, :mod:`.velocity_forms`)."""

from __future__ import annotations

from typing import final

from .base import CatalogueEntry
from .slots import carry_extensions, carry_friction
from .velocity_forms import VelocityForm

FORM = VelocityForm("rho2", speeds=(0.3e-3, 1e-3, 3e-3, 10e-3, 30e-3),
                    probe_speeds=(0.3e-3, 1e-3, 3e-3), prefix="viscous",
                    velocity="sliding velocity ẋ")
"""Half decades over the sliding speeds of stepping: on the 17 recordings of the
paper's protocol at the identification fixtures' truth, |ẋ| at the samples of the
step and sawtooth recordings reaches 13-45 mm/s in the slips (its 99th percentile
0.7-44 mm/s), so a term at 30 mm/s is
linear at nearly all of them and rho2's probe covers it; the probes are the three
speeds where a term bends inside that range."""


@final
class ViscousFrictionEntry(CatalogueEntry):
    """Friction rising with the sliding velocity: the law's rho2 [N·s/m], raised from
    the baseline's, and saturating terms on :data:`FORM`'s speeds; every slope freed,
    non-negative."""

    name = "viscous_friction"
    slot = "friction"
    signature = ("force rising with the sliding velocity: slip phases, step length "
                 "falling with drive rate")

    def probes(self, act, hints):
        return FORM.probes()

    def attach(self, act, strength, probe):
        return FORM.attach(act, strength, probe)

    def carry(self, init, fitted):
        return carry_extensions(carry_friction(init, fitted), fitted)

    def describe(self, params):
        return FORM.describe(params, "friction against sliding velocity")

    def plot_form(self, ax, params, draws=None):
        return FORM.plot(ax, params, "friction against sliding velocity", draws)

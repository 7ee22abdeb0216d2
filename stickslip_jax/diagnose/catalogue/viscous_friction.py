"""Viscous friction: a force proportional to the sliding velocity (rho2)."""

from __future__ import annotations

from typing import final

from .base import CatalogueEntry
from .slots import carry_friction, damping_attach, damping_probes


@final
class ViscousFrictionEntry(CatalogueEntry):
    """The friction law's viscous coefficient rho2 [N·s/m], raised from the baseline's."""

    name = "viscous_friction"
    slot = "friction"
    signature = ("force proportional to sliding velocity: slip phases, step length "
                 "falling with drive rate")

    def probes(self, act, hints):
        return damping_probes("rho2")

    def attach(self, act, strength, probe):
        return damping_attach(act, strength, "rho2")

    def carry(self, init, fitted):
        return carry_friction(init, fitted)

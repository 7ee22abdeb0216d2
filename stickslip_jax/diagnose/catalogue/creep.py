"""Creep: the stroke's slow settling after each voltage change."""

from __future__ import annotations

from typing import final

from ...model.extensions import Creep
from .base import CatalogueEntry
from .slots import carry_extensions, first_order_attach, first_order_probes

TAUS = (1.5e-3, 4e-3, 10e-3, 30e-3)
"""Probed time constants [s]: slower than the rate lag's (:mod:`.slots`)."""


@final
class CreepEntry(CatalogueEntry):
    """A first-order :class:`~stickslip_jax.model.extensions.Creep` (gain [m/V], time
    constant [s]); the refit frees both."""

    name = "creep"
    slot = "extension"
    signature = ("slow drift of the stroke after each voltage change: step-response "
                 "tail, period-to-period trend of low-frequency drives")

    def probes(self, act, hints):
        return first_order_probes(act, Creep, "creep", TAUS)

    def attach(self, act, strength, probe):
        return first_order_attach(act, strength, probe, Creep, "creep")

    def carry(self, init, fitted):
        return carry_extensions(init, fitted)

"""Rate-dependent hysteresis: a stroke lag that grows with the voltage rate."""

from __future__ import annotations

from typing import final

from ...model.extensions import RateDependentStroke
from .base import CatalogueEntry
from .slots import carry_extensions, first_order_attach, first_order_probes

TAUS = (0.05e-3, 0.1e-3, 0.2e-3, 0.4e-3, 0.8e-3)
"""Probed time constants [s]: the drive's time scale, faster than creep's
(:mod:`.slots`)."""


@final
class RateDependentHysteresisEntry(CatalogueEntry):
    """A first-order rate lag :class:`~stickslip_jax.model.extensions.
    RateDependentStroke` (gain [m/V], time constant [s]); the refit frees both."""

    name = "rate_dependent_hysteresis"
    slot = "extension"
    signature = ("stroke lag growing with the voltage rate: loop width and phase of sine "
                 "and ramp phases")

    def probes(self, act, hints):
        return first_order_probes(act, RateDependentStroke, "rate lag", TAUS)

    def attach(self, act, strength, probe):
        return first_order_attach(act, strength, probe, RateDependentStroke, "rate")

    def carry(self, init, fitted):
        return carry_extensions(init, fitted)

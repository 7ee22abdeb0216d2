"""Contact damping: the micro-damping of the contact (rho1)."""

from __future__ import annotations

from typing import final

from .base import CatalogueEntry
from .slots import carry_friction, damping_attach, damping_probes


@final
class ContactDampingEntry(CatalogueEntry):
    """The friction law's contact damping rho1 [N·s/m], raised from the baseline's."""

    name = "contact_damping"
    slot = "friction"
    signature = ("damping of the contact (rho1): decay of stick ringing after the edge, "
                 "step-response damping")

    def probes(self, act, hints):
        return damping_probes("rho1")

    def attach(self, act, strength, probe):
        return damping_attach(act, strength, "rho1")

    def carry(self, init, fitted):
        return carry_friction(init, fitted)

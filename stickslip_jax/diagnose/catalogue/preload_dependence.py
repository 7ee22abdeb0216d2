"""Preload dependence: friction that changes with the normal force (CEIM)."""

from __future__ import annotations

from typing import final

from .base import CatalogueEntry
from .slots import carry_friction


@final
class PreloadDependenceEntry(CatalogueEntry):
    """Named for the report only: a recording states no preload, so the recordings of
    a set are taken at one, and :meth:`needs` always says why the entry cannot show;
    it is never probed or attached."""

    name = "preload_dependence"
    slot = "friction"
    signature = ("step length and breakaway change with the preload (needs recordings at "
                 "several preloads)")

    def needs(self, recordings):
        return ("indistinguishable: all recordings share one preload (normal force); CEIM "
                "preload dependence only shows across preloads")

    def probes(self, act, hints):
        return []

    def attach(self, act, strength, probe):  # pragma: no cover - never probed
        raise ValueError("preload_dependence cannot be attached without several preloads")

    def carry(self, init, fitted):
        return carry_friction(init, fitted)

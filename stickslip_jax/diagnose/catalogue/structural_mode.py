"""Structural mode: a resonance of the mount, guide or base that the sensor sees."""

from __future__ import annotations

from typing import final

from ...identify.parameters import ParameterSpec
from ...model.extensions import StructuralMode
from .base import CatalogueEntry, Probe
from .slots import carry_extensions, ext


@final
class StructuralModeEntry(CatalogueEntry):
    """A :class:`~stickslip_jax.model.extensions.StructuralMode` (frequency [Hz],
    damping [-], compliance [m/N]) at a shared residual peak (the first two; 2 kHz
    when none); the refit frees all three."""

    name = "structural_mode"
    slot = "extension"
    signature = "an extra resonance in the residual PSD, ringing after edges"

    def probes(self, act, hints):
        freqs = list(hints.get("peaks_Hz", []))[:2] or [2000.0]
        return [Probe(f"mode {f:.0f} Hz", None, ParameterSpec(None, "linear", 1e-8, "m/N"),
                      0, {"frequency": f}, StructuralMode(f, 0.03, 0.0), "compliance")
                for f in freqs]

    def attach(self, act, strength, probe):
        new = act.with_extension(StructuralMode(probe.setting["frequency"], 0.03, strength))
        g = ext(StructuralMode)
        return new, {"mode_frequency": ParameterSpec(lambda a: g(a).frequency, "log", 1.0,
                                                     "Hz"),
                     "mode_damping": ParameterSpec(lambda a: g(a).damping, "log", 1.0, "-"),
                     "mode_compliance": ParameterSpec(lambda a: g(a).compliance, "linear",
                                                      probe.strength_scale(strength), "m/N")}

    def carry(self, init, fitted):
        return carry_extensions(init, fitted)

"""Structural mode: a resonance of the mount, guide or base that the sensor sees."""

from __future__ import annotations

import math
from typing import final

import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.extensions import StructuralMode
from .base import CatalogueEntry, Probe
from .slots import carry_extensions, ext

MODE_DAMPING_MAX = 1.0 / (2.0 * math.pi)
"""The largest damping ratio [-] of a mode the entry names: its ringing decays by a
factor e in 1/(2π·ζ) cycles, so above 1/(2π) it dies within one cycle, and what the
refit found is no resonance ringing after edges (the entry's signature) but a
heavily damped second-order filter, which can absorb other misfits of the response's
shape. From the signature's definition, not from a data set."""


@final
class StructuralModeEntry(CatalogueEntry):
    """A :class:`~stickslip_jax.model.extensions.StructuralMode` (frequency [Hz],
    damping [-], compliances [m/N]) at a shared residual peak (the first two; 2 kHz
    when none), probed as excited by the contact force; the refit frees the frequency,
    the damping and both places the mode is excited from: the contact force and the
    stack's push on its base (started at 0; a mode of the base rung by the stack's
    reaction at every drive edge, or both)."""

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
                                                      probe.strength_scale(strength), "m/N"),
                     "mode_stack_compliance": ParameterSpec(
                         lambda a: g(a).stack_compliance, "linear",
                         probe.strength_scale(strength), "m/N")}

    def implausible(self, params):
        zeta = params.get("mode_damping", 0.0)
        if zeta > MODE_DAMPING_MAX:
            return (f"damping ratio {zeta:.3g} > 1/(2π): the mode decays within one "
                    f"cycle, no ringing; not a resonance")
        return ""

    def carry(self, init, fitted):
        return carry_extensions(init, fitted)

    def plot_form(self, ax, params: dict[str, float]) -> bool:
        """The mode's response [nm/N] to each place it is excited from, against the
        frequency: ``|c| / |1 − (f/f0)² + 2iζ·f/f0|``."""
        f0 = params.get("mode_frequency", float("nan"))
        zeta = params.get("mode_damping", float("nan"))
        if not np.isfinite(f0) or not np.isfinite(zeta):
            return False
        f = np.geomspace(0.1 * f0, 10.0 * f0, 400)
        shape = 1.0 / np.abs(1.0 - (f / f0) ** 2 + 2j * zeta * f / f0)
        for key, label, colour in (("mode_compliance", "contact force", "tab:blue"),
                                   ("mode_stack_compliance", "stack's push", "tab:orange")):
            c = abs(params.get(key, 0.0))
            if c > 0:
                ax.loglog(f, c * shape * 1e9, color=colour, label=label)
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("base motion per force [nm/N]")
        ax.set_title(f"structural mode {f0:.4g} Hz, ζ {zeta:.3g}", fontsize=9)
        ax.legend(fontsize=7)
        return True

    def describe(self, params: dict[str, float]) -> str:
        return (f"structural mode: {params.get('mode_frequency', float('nan')):.4g} Hz, "
                f"damping ratio {params.get('mode_damping', float('nan')):.3g}, excited "
                f"by the contact force ({params.get('mode_compliance', 0.0) * 1e9:.3g} "
                f"nm/N) and by the stack's push on its base "
                f"({params.get('mode_stack_compliance', 0.0) * 1e9:.3g} nm/N)")

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
MAX_MODES = 3
"""Modes a bank holds at most (#63: a bank of one to three modes)."""
SEPARATION_OCTAVES = 1.0 / 3.0
"""How far [octaves] a residual peak must lie from every fitted mode to start another:
closer, it is the fitted mode's own misfit (a third of an octave is where a mode of
damping ratio 0.1, the half-power width 2ζ·f, has fallen to a fifth of its peak)."""


def mode_prefix(index: int) -> str:
    """The parameter names' prefix of the ``index``-th mode of the bank: ``mode_`` for
    the first (the entry's own names), ``mode2_``, ``mode3_`` after it."""
    return "mode_" if index == 0 else f"mode{index + 1}_"


def mode_specs(index: int, compliance_scale: float,
               name_index: int | None = None) -> dict[str, ParameterSpec]:
    """The four quantities a refit frees of the ``index``-th :class:`StructuralMode`
    among the extensions: frequency [Hz] and damping [-] (log), both compliances [m/N]
    (linear, θ unit ``compliance_scale``), named as the ``name_index``-th of the bank
    (default ``index``)."""
    g = ext(StructuralMode, index)
    p = mode_prefix(index if name_index is None else name_index)
    return {f"{p}frequency": ParameterSpec(lambda a: g(a).frequency, "log", 1.0, "Hz"),
            f"{p}damping": ParameterSpec(lambda a: g(a).damping, "log", 1.0, "-"),
            f"{p}compliance": ParameterSpec(lambda a: g(a).compliance, "linear",
                                            compliance_scale, "m/N"),
            f"{p}stack_compliance": ParameterSpec(lambda a: g(a).stack_compliance, "linear",
                                                  compliance_scale, "m/N")}


def bank(params: dict[str, float]) -> list[dict[str, float]]:
    """The modes of refitted ``params`` (:func:`mode_prefix` names), each as
    ``frequency``, ``damping``, ``compliance``, ``stack_compliance``."""
    out = []
    for i in range(MAX_MODES):
        p = mode_prefix(i)
        if f"{p}frequency" not in params:
            break
        out.append({k: params.get(f"{p}{k}", 0.0)
                    for k in ("frequency", "damping", "compliance", "stack_compliance")})
    return out


@final
class StructuralModeEntry(CatalogueEntry):
    """A :class:`~stickslip_jax.model.extensions.StructuralMode` (frequency [Hz],
    damping [-], compliances [m/N]) at a shared residual peak (the first two; 2 kHz
    when none), probed as excited by the contact force; the refit frees the frequency,
    the damping and both places the mode is excited from: the contact force and the
    stack's push on its base (started at 0; a mode of the base rung by the stack's
    reaction at every drive edge, or both). Once accepted, a bank of up to
    :data:`MAX_MODES` (:meth:`refined_forms`)."""

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
        # The entry's mode is the last extension; its names are the bank's first.
        return new, mode_specs(-1, probe.strength_scale(strength), name_index=0)

    def refined_forms(self, act, hints):
        """A bank of modes: with fewer than :data:`MAX_MODES` fitted, one more at the
        first shared residual peak of the model holding them (``hints["peaks_Hz"]``,
        taken there) at least :data:`SEPARATION_OCTAVES` from every fitted mode,
        started at zero compliance (the fitted model itself) and freed with every
        mode's quantities. A mount, a guide and a base each have their resonances; one
        fitted mode leaves the others' ringing."""
        modes = [e for e in act.extensions if isinstance(e, StructuralMode)]
        if not modes or len(modes) >= MAX_MODES:
            return []
        fitted = [float(m.frequency) for m in modes]
        peaks = [f for f in hints.get("peaks_Hz", [])
                 if all(abs(math.log2(f / f0)) >= SEPARATION_OCTAVES for f0 in fitted)]
        if not peaks:
            return []
        scale = max(max(abs(float(m.compliance)), abs(float(m.stack_compliance)))
                    for m in modes) or 1e-8
        start = act.with_extension(StructuralMode(peaks[0], 0.03, 0.0))
        specs = {}
        for i in range(len(modes) + 1):
            specs.update(mode_specs(i, scale))
        return [(start, specs)]

    def implausible(self, params):
        for i, mode in enumerate(bank(params)):
            zeta = mode["damping"]
            if zeta > MODE_DAMPING_MAX:
                which = "the mode" if i == 0 else f"mode {i + 1}"
                return (f"damping ratio of {which} {zeta:.3g} > 1/(2π): it decays within "
                        f"one cycle, no ringing; not a resonance")
        return ""

    def carry(self, init, fitted):
        return carry_extensions(init, fitted)

    def plot_form(self, ax, params: dict[str, float], draws=None) -> bool:
        """Each mode's response [nm/N] to each place it is excited from, against the
        frequency: ``|c| / |1 − (f/f0)² + 2iζ·f/f0|``."""
        modes = [m for m in bank(params)
                 if np.isfinite(m["frequency"]) and np.isfinite(m["damping"])]
        if not modes:
            return False
        lo = min(m["frequency"] for m in modes)
        hi = max(m["frequency"] for m in modes)
        f = np.geomspace(0.1 * lo, 10.0 * hi, 600)
        for i, m in enumerate(modes):
            f0, zeta = m["frequency"], m["damping"]
            shape = 1.0 / np.abs(1.0 - (f / f0) ** 2 + 2j * zeta * f / f0)
            for key, label, colour in (("compliance", "contact force", "tab:blue"),
                                       ("stack_compliance", "stack's push", "tab:orange")):
                c = abs(m[key])
                if c > 0:
                    ax.loglog(f, c * shape * 1e9, color=colour, linestyle=("-", "--", ":")[i],
                              label=f"{label}" + (f", mode {i + 1}" if len(modes) > 1 else ""))
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("base motion per force [nm/N]")
        title = ", ".join(f"{m['frequency']:.4g} Hz (ζ {m['damping']:.3g})" for m in modes)
        ax.set_title(f"structural mode{'s' if len(modes) > 1 else ''} {title}", fontsize=9)
        ax.legend(fontsize=7)
        return True

    def describe(self, params: dict[str, float]) -> str:
        modes = bank(params) or [{"frequency": float("nan"), "damping": float("nan"),
                                  "compliance": 0.0, "stack_compliance": 0.0}]
        said = [f"{m['frequency']:.4g} Hz, damping ratio {m['damping']:.3g}, excited "
                f"by the contact force ({m['compliance'] * 1e9:.3g} nm/N) and by the "
                f"stack's push on its base ({m['stack_compliance'] * 1e9:.3g} nm/N)"
                for m in modes]
        if len(said) == 1:
            return f"structural mode: {said[0]}"
        return f"{len(said)} structural modes: " + "; ".join(said)

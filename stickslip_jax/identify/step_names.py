"""Which parameters each identification step fits.

The names follow from the actuator's friction law (each :class:`~stickslip_jax.model.
registry.LawParameter` says its step and direction), so that a new law needs no change
here. A leaf of :mod:`stickslip_jax.identify`: the steps, the informativeness check
and the diagnosis read it, and it reads none of them.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..model.actuator import Actuator
from .parameters import MECHANICS, law_fittable

DYNAMICS = ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0")
"""The dynamics step's names with the paper's law (:func:`dynamics_names` for any)."""


def law_step_names(actuator: Actuator, step: str, also_fit: Sequence[str]) -> list[str]:
    """The friction law's parameters that identification step ``step`` fits
    (on-request ones only when in ``also_fit``)."""
    return [p.name for p in law_fittable(actuator)
            if p.step == step and (not p.on_request or p.name in also_fit)]


def dynamics_names(actuator: Actuator, *, fix=(), also_fit: Sequence[str] = ()) -> list[str]:
    """What the dynamics step fits: the piezo element's and the slider's masses,
    dampings and stiffnesses, then the friction law's parameters flagged for this step
    (on-request ones only when in ``also_fit``), less the fixed ones (``fix``)."""
    return [n for n in MECHANICS + tuple(law_step_names(actuator, "dynamics", also_fit))
            if n not in fix]


def friction_names(actuator: Actuator, *, fix=(), also_fit: Sequence[str] = ()) -> list[str]:
    """What the friction step fits: the law's parameters flagged for it (on-request ones
    only when in ``also_fit``), less the fixed ones (``fix``)."""
    return [n for n in law_step_names(actuator, "friction", also_fit) if n not in fix]


def breakaway_names(actuator: Actuator, recordings, *, fix=()) -> list[str]:
    """The law's per-direction quantities of the directions of ``recordings`` (a step
    response's edge slips, so the dynamics step fits its direction's break-away)."""
    dirs = {"backward" if r.drive.is_backward else "forward" for r in recordings}
    return sorted({p.name for p in law_fittable(actuator)
                   if p.direction in dirs and p.name not in fix})


def without_absent_directions(names: Sequence[str], actuator: Actuator,
                              recordings) -> list[str]:
    """``names`` less the law's backward-only quantities when no recording is backward
    (the forward value also serves sines and steps, so it always stays)."""
    if any(r.drive.is_backward for r in recordings):
        return list(names)
    backward = {p.name for p in law_fittable(actuator) if p.direction == "backward"}
    return [n for n in names if n not in backward]


def requested_names(actuator: Actuator, also_fit: Sequence[str]) -> list[str]:
    """``also_fit`` checked against the law's parameters fitted on request only;
    ValueError naming the allowed ones otherwise."""
    optional = [p.name for p in law_fittable(actuator) if p.step and p.on_request]
    unknown = [n for n in also_fit if n not in optional]
    if unknown:
        raise ValueError(f"{', '.join(unknown)}: not a parameter that the "
                         f"{type(actuator.friction).__name__} law fits on request; "
                         f"those are: {', '.join(optional) or 'none'}")
    return list(also_fit)

"""The models a diagnosis leaves in competition, and what a fit of each may move.

A :class:`Hypothesis` is one model of the recordings: an actuator, and the quantities a
refit of it frees: the baseline's (:func:`~stickslip_jax.diagnose.problem.baseline_free`)
and every quantity of the parts it holds beyond the paper's model (its drive stage,
extensions and sensor, :func:`part_specs`). A :class:`Question` is what the next
recordings should settle between two hypotheses:

- ``tie``: an entry the diagnosis named and a rival it could not tell from it on these
  recordings (``rivals/NAME.json``): either could be the truth, so the evidence counts
  the weaker of the two ways (each the truth, the other refitted to it);
- ``limit``: an entry not named, at the strength of its detection limit on these
  recordings: the truth would be the model with it, the model without it refitted; the
  question is how far new recordings lower that limit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import numpy as np

from ..identify.parameters import ParameterSpec
from ..model.actuator import Actuator
from ..model.extensions import LearnedForce


def parts(actuator: Actuator) -> list[tuple[str, Callable[[Actuator], object]]]:
    """The parts beyond the paper's model, each named as in a parameter file's slots
    (``drive_stage``, ``extensions[i]``, ``sensor``) beside its getter."""
    out: list[tuple[str, Callable[[Actuator], object]]] = [
        ("drive_stage", lambda a: a.input_stage)]
    out += [(f"extensions[{i}]", lambda a, i=i: a.extensions[i])
            for i in range(len(actuator.extensions))]
    out.append(("sensor", lambda a: a.output_map))
    return out


@dataclass(frozen=True)
class Hypothesis:
    """One model of the recordings: ``actuator`` and the specs of its parts' quantities
    a refit frees (:func:`part_specs`), beside the baseline's built-in ones."""

    label: str
    actuator: Actuator
    specs: dict[str, ParameterSpec]

    @classmethod
    def of(cls, label: str, actuator: Actuator) -> Hypothesis:
        return cls(label, actuator, part_specs(actuator))


@dataclass(frozen=True)
class Question:
    """What new recordings should settle (module docstring). ``kind``: ``tie`` or
    ``limit``; ``truth``: the model with the entry (``limit``) or the named one
    (``tie``); ``rival``: the model refitted to the truth's traces; ``entry``: the
    entry asked about; ``strength``, ``unit``: the entry's strength in the truth
    (``limit``: its detection limit on the recordings so far); ``at_strength``
    (``limit``): the truth's actuator with the entry at another strength."""

    kind: str
    entry: str
    truth: Hypothesis
    rival: Hypothesis
    strength: float | None = None
    unit: str = ""
    at_strength: Callable[[float], Actuator] | None = None

    @property
    def both_ways(self) -> bool:
        """Whether either model could be the truth (a tie), so that the evidence is
        the weaker way's."""
        return self.kind == "tie"

    @property
    def label(self) -> str:
        if self.kind == "tie":
            return f"{self.truth.label} or {self.rival.label}"
        unit = "" if self.unit in ("", "-") else f" {self.unit}"
        return f"{self.entry} below {self.strength:.3g}{unit}"


def _leaf_getter(path) -> Callable:
    """The getter of the leaf at a key ``path`` of :func:`jax.tree_util.
    tree_flatten_with_path` (attributes and sequence indices)."""
    def get(node):
        for key in path:
            if isinstance(key, jax.tree_util.GetAttrKey):
                node = getattr(node, key.name)
            elif isinstance(key, jax.tree_util.SequenceKey):
                node = node[key.idx]
            elif isinstance(key, jax.tree_util.DictKey):
                node = node[key.key]
            else:  # pragma: no cover - parts hold attributes and tuples only
                raise TypeError(f"unexpected key {key!r} in a part's tree")
        return node
    return get


INSTRUMENT_CONSTANTS = frozenset({"period"})
"""Quantities of the parts that belong to the instrument, not the actuator, and stay
held: the interferometer's fringe period (half its laser's wavelength)."""


def part_specs(actuator: Actuator) -> dict[str, ParameterSpec]:
    """Every non-zero floating-point quantity of the actuator's parts (:func:`parts`)
    as a ``linear`` spec with its own magnitude as θ unit (at θ = 0 its column is the
    derivative in the quantity times its size, as a ``log`` one's, and the sign is
    free), named ``part.path``. Zeros stay held: a part's zero is the structure it was
    named with (a mode not excited at the stack), not a value fitted. A learned force
    stays held too (a correction, not physics to tell apart), and so do
    :data:`INSTRUMENT_CONSTANTS`."""
    specs: dict[str, ParameterSpec] = {}
    for name, get_part in parts(actuator):
        part = get_part(actuator)
        if isinstance(part, LearnedForce):
            continue
        for path, leaf in jax.tree_util.tree_flatten_with_path(part)[0]:
            value = np.asarray(leaf)
            if not np.issubdtype(value.dtype, np.floating):
                continue
            size = float(np.max(np.abs(value), initial=0.0))
            if not np.isfinite(size) or size == 0.0:
                continue
            if path and getattr(path[-1], "name", None) in INSTRUMENT_CONSTANTS:
                continue
            get = _leaf_getter(path)
            specs[name + jax.tree_util.keystr(path)] = ParameterSpec(
                lambda a, p=get_part, g=get: g(p(a)), "linear", size, "-")
    return specs

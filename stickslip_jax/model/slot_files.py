"""The actuator's slots in a parameter file: its drive stage, its extensions and its
sensor (``"drive_stage"``, ``"extensions"``, ``"sensor"``), as JSON and back.

Each part is one object naming its class (``"type"``) beside the arguments that class
is built from, SI values: ``{"type": "StructuralMode", "frequency": 3300.0,
"damping": 0.03, "compliance": 1.2e-07, "stack_compliance": 0.0}``. A part holding
parts (:class:`~.extensions.ParallelInputs`' stages, :class:`~.extensions.
ChainedOutput`'s maps) holds them as such objects. Only the model's own classes
(:data:`PARTS`) are read: a file names physics, never code to run.

The arguments are read back through each class's constructor, with the names and the
meaning its docstring gives them, so that a part written and read again is the same
part, leaf for leaf (and simulates the same trace to the last bit).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping
from typing import Any

import equinox as eqx
import numpy as np

from .base import AbstractExtension, AbstractInputStage, AbstractOutputMap
from .extensions import (
    ChainedOutput,
    ClippedSlewInput,
    Creep,
    CreepSpectrum,
    ExponentialDrift,
    LearnedForce,
    LowPassInput,
    ParallelInputs,
    PeriodicSensorError,
    PositionRipple,
    RateDependentStroke,
    RateLagForm,
    SaturatingViscosity,
    SecondOrderInput,
    SensorOutput,
    ShapedSlewInput,
    SlewLimitedInput,
    StructuralMode,
)
from .law_parameter import ParameterError
from .stages import IdentityInput, IdentityOutput

PARTS: dict[str, type] = {cls.__name__: cls for cls in (
    IdentityInput, LowPassInput, SecondOrderInput, SlewLimitedInput, ClippedSlewInput,
    ShapedSlewInput, ParallelInputs,
    Creep, CreepSpectrum, RateDependentStroke, RateLagForm, StructuralMode, PositionRipple,
    SaturatingViscosity, LearnedForce,
    IdentityOutput, SensorOutput, ExponentialDrift, PeriodicSensorError, ChainedOutput)}
"""The classes a parameter file may name, by name."""

SLOT_KEYS = ("drive_stage", "extensions", "sensor")
"""The parameter file's names of the slots: one part, a list of parts, one part."""

_ROLES = {"drive_stage": (AbstractInputStage, "a drive stage"),
          "extensions": (AbstractExtension, "an extension"),
          "sensor": (AbstractOutputMap, "a sensor (output map)")}


def _arguments(cls: type) -> list[str]:
    """The names of ``cls``'s constructor arguments (its own, or the dataclass's)."""
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]
    return [p.name for p in params
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]


def _encode(value: Any) -> Any:
    if isinstance(value, eqx.Module):
        return part_to_json(value)
    if isinstance(value, tuple | list):
        return [_encode(v) for v in value]
    if value is None or isinstance(value, bool | str):
        return value
    array = np.asarray(value, dtype=float)
    return float(array) if array.ndim == 0 else array.tolist()


def part_to_json(part: eqx.Module) -> dict[str, Any]:
    """``part`` (a drive stage, an extension or an output map of :data:`PARTS`) as a
    JSON-ready object: its class's name and its constructor's arguments."""
    name = type(part).__name__
    if PARTS.get(name) is not type(part):
        raise ValueError(f"{name} cannot be written to a parameter file: not one of the "
                         f"model's parts ({', '.join(PARTS)})")
    return {"type": name, **{arg: _encode(getattr(part, arg)) for arg in _arguments(type(part))}}


def _decode(value: Any, where: str, source: str | None) -> Any:
    if isinstance(value, Mapping):
        return part_from_json(value, where=where, source=source)
    if isinstance(value, list):
        items = [_decode(v, f"{where}[{i}]", source) for i, v in enumerate(value)]
        # Parts held by a part are a tuple (a static structure); numbers a list.
        return tuple(items) if items and all(isinstance(v, eqx.Module) for v in items) \
            else items
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if not isinstance(value, int | float) or not math.isfinite(value):
        raise ParameterError(f"{where} must be a finite number, got {value!r}.",
                             source=source, fix="write a number (SI units).")
    return value


def part_from_json(obj: Mapping[str, Any], *, where: str = "part",
                   source: str | None = None) -> eqx.Module:
    """The part an object of :func:`part_to_json` describes; ``where`` names it in
    errors (the file's key), ``source`` the file."""
    name = obj.get("type")
    cls = PARTS.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ParameterError(f"{where}: unknown part type {name!r}.", source=source,
                             fix=f"name one of: {', '.join(PARTS)}.")
    allowed = _arguments(cls)
    unknown = [k for k in obj if k != "type" and k not in allowed]
    if unknown:
        raise ParameterError(f"{where} ({name}): unknown name(s) "
                             f"{', '.join(map(repr, unknown))}.", source=source,
                             fix=f"{name} takes: {', '.join(allowed)}.")
    args = {k: _decode(v, f"{where}.{k}", source) for k, v in obj.items() if k != "type"}
    try:
        return cls(**args)
    except (TypeError, ValueError) as err:
        raise ParameterError(f"{where} ({name}): {err}", source=source,
                             fix=f"{name} takes: {', '.join(allowed)}.") from None


def slots_to_json(actuator) -> dict[str, Any]:
    """The parameter file's slot entries of ``actuator`` (:data:`SLOT_KEYS`); a slot at
    its default (identity stage, no extension, identity sensor) is left out."""
    out: dict[str, Any] = {}
    if not isinstance(actuator.input_stage, IdentityInput):
        out["drive_stage"] = part_to_json(actuator.input_stage)
    if actuator.extensions:
        out["extensions"] = [part_to_json(e) for e in actuator.extensions]
    if not isinstance(actuator.output_map, IdentityOutput):
        out["sensor"] = part_to_json(actuator.output_map)
    return out


def _slot_part(obj: Any, key: str, where: str, source: str | None) -> eqx.Module:
    """The part ``obj`` describes, refused unless it belongs in slot ``key``."""
    if not isinstance(obj, Mapping):
        raise ParameterError(f"{where} must be an object with a \"type\".", source=source,
                             fix="e.g. {\"type\": \"StructuralMode\", \"frequency\": 3300.0, "
                                 "...}.")
    part = part_from_json(obj, where=where, source=source)
    base, what = _ROLES[key]
    if not isinstance(part, base):
        raise ParameterError(f"{where}: {type(part).__name__} is not {what}.",
                             source=source, fix=f"put it in the slot it belongs to "
                                                f"({', '.join(SLOT_KEYS)}).")
    return part


def slots_from_json(params: Mapping[str, Any], source: str | None = None) -> dict[str, Any]:
    """The :class:`~.actuator.Actuator` keyword arguments (``input_stage``,
    ``extensions``, ``output_map``) of a parameter file's slot entries."""
    out: dict[str, Any] = {}
    if "drive_stage" in params:
        out["input_stage"] = _slot_part(params["drive_stage"], "drive_stage", "drive_stage",
                                        source)
    if "sensor" in params:
        out["output_map"] = _slot_part(params["sensor"], "sensor", "sensor", source)
    if "extensions" in params:
        exts = params["extensions"]
        if not isinstance(exts, list):
            raise ParameterError("extensions must be a list of objects, each with a "
                                 "\"type\".", source=source,
                                 fix="e.g. [{\"type\": \"StructuralMode\", ...}].")
        out["extensions"] = tuple(_slot_part(e, "extensions", f"extensions[{i}]", source)
                                  for i, e in enumerate(exts))
    return out


__all__ = ["PARTS", "SLOT_KEYS", "part_from_json", "part_to_json", "slots_from_json",
           "slots_to_json"]

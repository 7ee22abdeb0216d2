"""Parameter files (docs/model.md "Parameter files") ↔ :class:`Actuator`.

JSON, one object, SI values. Unknown names are errors, never silently ignored;
masses, stiffnesses and break-away displacements must be positive. The friction law's
entries are the law's own: the file's ``"friction"`` names a law in
:data:`~stickslip_jax.model.registry.FRICTION_LAWS`, whose
:attr:`~stickslip_jax.model.base.AbstractFriction.parameters` say which names it
allows, requires and defaults, and within which bounds.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .files import atomic_write_text, check_output_path
from .model import ceim as _ceim  # noqa: F401  (registers "ceim")
from .model.actuator import Actuator
from .model.friction import DEFAULT_ZBA_RATIO  # noqa: F401  (registers the others)
from .model.hysteresis import PrandtlIshlinskii
from .model.piezo import PiezoElement
from .model.registry import (
    FRICTION_LAWS,
    LawParameter,
    ParameterError,
    friction_law,
    friction_law_name,
    law_values,
    missing_law_parameters,
)
from .model.slider import Slider
from .model.slot_files import SLOT_KEYS, slots_from_json, slots_to_json

__all__ = ["COMMON_REQUIRED", "COMMON_OPTIONAL", "DEFAULT_FRICTION", "FRICTION_LAWS",
           "ParameterError", "actuator_from_params", "allowed_names", "describe_parameters",
           "fit_status_of", "load_params", "params_from_actuator", "parameter_docs",
           "save_params"]

DEFAULT_FRICTION = "elastoplastic"
"""The law of a file without ``"friction"``."""

_POSITIVE = {"lower": 0.0, "lower_open": True}
ACTUATOR_SCALARS = (
    LawParameter("Mp", "kg", "piezo element mass", required=True, **_POSITIVE),
    LawParameter("Dp", "N·s/m", "piezo element damping", required=True, lower=0.0),
    LawParameter("Kp", "N/m", "piezo element stiffness", required=True, **_POSITIVE),
    LawParameter("Ms", "kg", "slider mass", required=True, **_POSITIVE),
    LawParameter("Ds", "N·s/m", "slider (guide) damping", required=True, lower=0.0),
    LawParameter("Kact2", "-", "preload coefficient (Kact2·N is a constant force [N])",
                 default=0.0),
    LawParameter("N", "N", "normal preload (also the CEIM contact's preload)", default=0.0),
    LawParameter("F_ext", "N", "constant external force on the slider along +x", default=0.0),
    LawParameter("k_load", "N/m", "load spring on the slider, from x2 = 0", default=0.0,
                 lower=0.0),
)
"""The actuator's scalar parameters outside the friction law (bounds, defaults, docs)."""

COMMON_REQUIRED = ("Mp", "Dp", "Kp", "Ms", "Ds", "pi_thresholds", "pi_weights")
COMMON_OPTIONAL = {"Kact2": 0.0, "N": 0.0, "F_ext": 0.0, "k_load": 0.0, "friction": None,
                   "fit_status": None}
FIT_STATUS_DOC = ("how the fit that wrote the file (identify, diagnose) judged it (only "
                  "written when it is not a plain result, e.g. 'misspecified: ...', "
                  "'rival: ...'); metadata: no physics reads it")
SLOT_DOCS = {
    "drive_stage": "the drive amplifier between the command and the piezo: one "
                   "{\"type\": ..., arguments} object (LowPassInput, SecondOrderInput, "
                   "SlewLimitedInput, ParallelInputs, ...; default: none)",
    "extensions": "extra physics, a list of {\"type\": ..., arguments} objects "
                  "(StructuralMode, Creep, CreepSpectrum, RateLagForm, "
                  "SaturatingViscosity, ...; default: none)",
    "sensor": "what the sensor reads: one {\"type\": ..., arguments} object "
              "(SensorOutput: delay, drift, periodic error; default: the position)",
}
"""The slots' entries (:mod:`~stickslip_jax.model.slot_files`): what `stickslip
diagnose` adds is written in them."""
_VECTOR_DOCS = {
    "pi_thresholds": "Prandtl-Ishlinskii play thresholds, ascending [V]",
    "pi_weights": "Prandtl-Ishlinskii weights [m/V]",
}


def _friction_doc() -> str:
    names = [f"'{n}'" + (" (default)" if n == DEFAULT_FRICTION else "") for n in FRICTION_LAWS]
    return "the friction law: " + ", ".join(names)


def parameter_docs() -> dict[str, dict[str, str]]:
    """Every parameter name with its doc and unit: ``""`` → the actuator's own names,
    then one entry per registered friction law (name → that law's names)."""
    common = {p.name: p.described for p in ACTUATOR_SCALARS[:5]}
    common.update(_VECTOR_DOCS)
    common.update({p.name: p.described for p in ACTUATOR_SCALARS[5:]})
    common["friction"] = _friction_doc()
    common["fit_status"] = FIT_STATUS_DOC
    common.update(SLOT_DOCS)
    out = {"": common}
    for name, law in FRICTION_LAWS.items():
        out[name] = {p.name: p.described for p in law.parameters}
    return out


def describe_parameters() -> list[str]:
    """The lines ``stickslip params --list`` prints: every name, its doc and unit, and
    for a friction law's names whether they are required, their default and bounds."""
    lines = [f"{name:16s} {doc}" for name, doc in parameter_docs()[""].items()]
    for law_name, law in FRICTION_LAWS.items():
        lines += ["", f"friction '{law_name}':"]
        for p in law.parameters:
            if p.alias_for:
                note = f"sets {' and '.join(p.alias_for)} where not given"
            elif p.required:
                note = "required"
            elif p.default is not None:
                note = f"default {p.default:g}"
            else:
                note = "optional"
            bounds = "" if p.lower is None and p.upper is None else f", in {p.domain}"
            lines.append(f"  {p.name:14s} {p.described} ({note}{bounds})")
    return lines


def _vector(d, name, source):
    value = d[name]
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"'{name}' must be a list of numbers.", source=source,
                             fix=f"write {name} as a JSON list.") from None
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise ParameterError(f"'{name}' must be a non-empty list of finite numbers.",
                             source=source, fix=f"write {name} as a JSON list.")
    return arr


def allowed_names(friction: str = DEFAULT_FRICTION) -> tuple[str, ...]:
    """Every parameter name a file with this friction law may hold."""
    common = COMMON_REQUIRED + tuple(COMMON_OPTIONAL)
    return common + tuple(p.name for p in friction_law(friction).parameters
                          if p.name not in common) + SLOT_KEYS


def actuator_from_params(params: Mapping[str, Any], *, source: str | None = None) -> Actuator:
    """Build an :class:`Actuator` from a parameter dictionary (docs/model.md) (SI units)."""
    if not isinstance(params, Mapping):
        raise ParameterError("a parameter file must hold one JSON object.", source=source)
    friction = params.get("friction", DEFAULT_FRICTION) or DEFAULT_FRICTION
    law = friction_law(friction, source=source)
    allowed = allowed_names(friction)
    unknown = [k for k in params if k not in allowed]
    if unknown:
        raise ParameterError(
            f"unknown parameter name(s) {', '.join(map(repr, unknown))} for friction "
            f"{friction!r}.", source=source,
            fix=f"check the spelling; allowed names are: {', '.join(allowed)}.")
    if not isinstance(params.get("fit_status", ""), str):
        raise ParameterError("'fit_status' must be a string.", source=source,
                             fix="remove it, or write the fit's verdict as text.")
    missing = [k for k in COMMON_REQUIRED if k not in params]
    missing += missing_law_parameters(law, params)
    if missing:
        raise ParameterError(f"missing required parameter(s): {', '.join(missing)}.",
                             source=source, fix="add them (SI units, see docs/model.md).")

    num = {p.name: p.check(params[p.name], source) if p.name in params else p.default
           for p in ACTUATOR_SCALARS}
    thresholds = _vector(params, "pi_thresholds", source)
    weights = _vector(params, "pi_weights", source)
    if thresholds.shape != weights.shape:
        raise ParameterError(
            f"pi_thresholds has {thresholds.size} entries but pi_weights {weights.size}.",
            source=source, fix="give one weight per threshold.")
    if np.any(thresholds < 0) or np.any(np.diff(thresholds) < 0):
        raise ParameterError("pi_thresholds must be ≥ 0 and ascending.", source=source,
                             fix="sort the thresholds (and their weights) in ascending order.")

    piezo = PiezoElement(num["Mp"], num["Dp"], num["Kp"], num["Kact2"], num["N"])
    slider = Slider(num["Ms"], num["Ds"], num["F_ext"], num["k_load"])
    hysteresis = PrandtlIshlinskii(thresholds, weights)
    try:
        contact = law.from_params(law_values(law, params, source=source))
    except ParameterError as err:
        if err.source is not None or source is None:
            raise
        raise ParameterError(err.message, source=source, fix=err.fix) from None
    return Actuator(piezo, hysteresis, slider, contact, **slots_from_json(params, source))


def params_from_actuator(actuator: Actuator) -> dict[str, Any]:
    """The parameter dictionary (docs/model.md) of an actuator (SI units, JSON-ready)."""
    p, s, h, f = actuator.piezo, actuator.slider, actuator.hysteresis, actuator.friction
    out: dict[str, Any] = {
        "Mp": float(p.Mp), "Dp": float(p.Dp), "Kp": float(p.Kp),
        "Ms": float(s.Ms), "Ds": float(s.Ds),
        "Kact2": float(p.Kact2), "N": float(p.N),
        "F_ext": float(s.F_ext), "k_load": float(s.k_load),
        "pi_thresholds": [float(x) for x in np.asarray(h.thresholds)],
        "pi_weights": [float(x) for x in np.asarray(h.weights)],
        "friction": friction_law_name(f),
    }
    out.update(f.to_params())  # a law's own preload (CEIM's N) replaces the piezo's
    out.update(slots_to_json(actuator))  # drive stage, extensions, sensor (if any)
    return out


def load_params(path: str | Path) -> Actuator:
    """Read a parameter JSON file into an :class:`Actuator`."""
    path = Path(path)
    if not path.is_file():
        raise ParameterError("file not found.", source=str(path),
                             fix="check the path given to --params.")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise ParameterError(f"not valid JSON (line {err.lineno}, column {err.colno}: "
                             f"{err.msg}).", source=str(path),
                             fix="fix the JSON syntax at that position.") from None
    return actuator_from_params(data, source=str(path))


def save_params(actuator: Actuator, path: str | Path, *, force: bool = False,
                inputs=(), fit_status: str | None = None) -> Path:
    """Write an actuator's parameters as JSON (atomic; no overwrite without ``force``);
    ``fit_status`` (e.g. ``"misspecified: ..."``) marks parameters that are not a plain
    result (:func:`fit_status_of` reads it back)."""
    path = check_output_path(path, force=force, inputs=inputs)
    content = params_from_actuator(actuator)
    if fit_status:
        content = {"fit_status": fit_status, **content}
    atomic_write_text(path, json.dumps(content, indent=1) + "\n")
    return path


def fit_status_of(path: str | Path) -> str | None:
    """The ``fit_status`` mark of a parameter file (None: unmarked or unreadable; the
    loader reports what is wrong with a file)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    status = data.get("fit_status") if isinstance(data, dict) else None
    return status if isinstance(status, str) and status else None

"""Parameter files (docs/model.md "Parameter files") ↔ :class:`Actuator`.

JSON, one object, SI values. Unknown names are errors, never silently ignored;
masses, stiffnesses and break-away displacements must be positive.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .files import atomic_write_text, check_output_path
from .model.actuator import Actuator
from .model.ceim import CEIMElastoPlastic
from .model.friction import ElastoPlastic, LuGre, StribeckElastoPlastic
from .model.hysteresis import PrandtlIshlinskii
from .model.piezo import PiezoElement
from .model.slider import Slider

COMMON_REQUIRED = ("Mp", "Dp", "Kp", "Ms", "Ds", "pi_thresholds", "pi_weights")
COMMON_OPTIONAL = {"Kact2": 0.0, "N": 0.0, "F_ext": 0.0, "k_load": 0.0, "friction": None}
ELASTOPLASTIC_NAMES = (
    "rho0", "rho1", "rho2", "z_ba", "z_ba_forward", "z_ba_backward", "zba_ratio",
    "stribeck_ratio", "v_s",
)
LUGRE_NAMES = ("sigma0", "sigma1", "sigma2", "F_c", "F_s", "v_s")
CEIM_REQUIRED = ("zba_slope", "zba_0", "sigma0_slope", "sigma0_0", "mu")
CEIM_NAMES = CEIM_REQUIRED + ("f_ba", "sigma1")
FRICTION_LAWS = ("elastoplastic", "lugre", "ceim")
_LAW_NAMES = {"elastoplastic": ELASTOPLASTIC_NAMES, "lugre": LUGRE_NAMES, "ceim": CEIM_NAMES}

PARAMETER_DOCS = {
    "Mp": "piezo element mass [kg]",
    "Dp": "piezo element damping [N·s/m]",
    "Kp": "piezo element stiffness [N/m]",
    "Ms": "slider mass [kg]",
    "Ds": "slider (guide) damping [N·s/m]",
    "pi_thresholds": "Prandtl-Ishlinskii play thresholds, ascending [V]",
    "pi_weights": "Prandtl-Ishlinskii weights [m/V]",
    "Kact2": "preload coefficient [-] (Kact2·N is a constant force [N])",
    "N": "normal preload [N] (also the CEIM contact's preload)",
    "F_ext": "constant external force on the slider along +x [N]",
    "k_load": "load spring on the slider, from x2 = 0 [N/m]",
    "friction": "'elastoplastic' (default), 'lugre' or 'ceim' (preload N > 0)",
    "rho0": "contact stiffness [N/m]",
    "rho1": "contact micro-damping [N·s/m]",
    "rho2": "viscous friction [N·s/m]",
    "z_ba": "break-away displacement, both directions [m]",
    "z_ba_forward": "break-away displacement, forward drive (and sine, step) [m]",
    "z_ba_backward": "break-away displacement, backward drive [m]",
    "zba_ratio": "z_ba/|z_ss| in (0, 1] [-]",
    "stribeck_ratio": "f_max/f_c ≥ 1 (Stribeck steady state when > 1) [-]",
    "v_s": "Stribeck velocity [m/s]",
    "sigma0": "LuGre bristle stiffness [N/m]",
    "sigma1": "LuGre bristle damping [N·s/m]",
    "sigma2": "LuGre viscous friction [N·s/m]",
    "F_c": "LuGre Coulomb level [N]",
    "F_s": "LuGre static level [N]",
    "zba_slope": "CEIM: d z_ba / d preload = a·E* + b [m/N] (Nguyen eq. 14)",
    "zba_0": "CEIM: z_ba at zero preload = c·E* + d [m]",
    "sigma0_slope": "CEIM: d sigma0 / d preload = a_s·E* + b_s [N/m per N] (eq. 19)",
    "sigma0_0": "CEIM: sigma0 at zero preload = c_s·E* + d_s [N/m]",
    "mu": "CEIM: friction coefficient, Coulomb level mu·N [-]",
    "f_ba": "CEIM: z_ba/|z_ss| in (0, 1] [-] (eq. 15)",
}


class ParameterError(ValueError):
    """A parameter file or dictionary that does not follow the contract."""

    def __init__(self, message: str, *, source: str | None = None, fix: str = ""):
        where = f"{source}: " if source else ""
        text = f"{where}{message}"
        if fix:
            text += f" Fix: {fix}"
        super().__init__(text)
        self.source = source
        self.fix = fix


def _number(d, name, source, *, positive=False, nonnegative=False):
    value = d[name]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ParameterError(f"'{name}' must be a number, got {value!r}.", source=source,
                             fix=f"give {name} as a JSON number in SI units.")
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f"'{name}' is not finite ({value}).", source=source,
                             fix=f"give a finite {name}.")
    if positive and value <= 0:
        raise ParameterError(f"'{name}' must be positive, got {value:g} "
                             f"({PARAMETER_DOCS.get(name, '')}).", source=source,
                             fix=f"a {name} ≤ 0 is unphysical; check its sign and unit.")
    if nonnegative and value < 0:
        raise ParameterError(f"'{name}' must not be negative, got {value:g} "
                             f"({PARAMETER_DOCS.get(name, '')}).", source=source,
                             fix=f"check the sign and unit of {name}.")
    return value


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


def allowed_names(friction: str = "elastoplastic") -> tuple[str, ...]:
    """Every parameter name a file with this friction law may hold."""
    return COMMON_REQUIRED + tuple(COMMON_OPTIONAL) + _LAW_NAMES[friction]


def actuator_from_params(params: Mapping[str, Any], *, source: str | None = None) -> Actuator:
    """Build an :class:`Actuator` from a parameter dictionary (docs/model.md) (SI units)."""
    if not isinstance(params, Mapping):
        raise ParameterError("a parameter file must hold one JSON object.", source=source)
    friction = params.get("friction", "elastoplastic") or "elastoplastic"
    if friction not in FRICTION_LAWS:
        raise ParameterError(f"unknown friction law {friction!r}.", source=source,
                             fix=f"use one of {', '.join(FRICTION_LAWS)}.")
    allowed = allowed_names(friction)
    unknown = [k for k in params if k not in allowed]
    if unknown:
        raise ParameterError(
            f"unknown parameter name(s) {', '.join(map(repr, unknown))} for friction "
            f"{friction!r}.", source=source,
            fix=f"check the spelling; allowed names are: {', '.join(allowed)}.")
    law_required = {"elastoplastic": ("rho0",), "lugre": LUGRE_NAMES,
                    "ceim": CEIM_REQUIRED + ("N",)}[friction]
    missing = [k for k in COMMON_REQUIRED + law_required if k not in params]
    if friction == "elastoplastic" and "z_ba" not in params and not (
        "z_ba_forward" in params and "z_ba_backward" in params
    ):
        missing.append("z_ba (or both z_ba_forward and z_ba_backward)")
    if missing:
        raise ParameterError(f"missing required parameter(s): {', '.join(missing)}.",
                             source=source, fix="add them (SI units, see docs/model.md).")

    num = {}
    for k in ("Mp", "Kp", "Ms"):
        num[k] = _number(params, k, source, positive=True)
    for k in ("Dp", "Ds"):
        num[k] = _number(params, k, source, nonnegative=True)
    for k in ("Kact2", "N", "F_ext"):
        num[k] = _number(params, k, source) if k in params else 0.0
    num["k_load"] = _number(params, "k_load", source, nonnegative=True) if "k_load" in params \
        else 0.0

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
    return Actuator(piezo, hysteresis, slider, _friction_from_params(params, friction, source))


def _friction_from_params(params, friction, source):
    if friction == "ceim":
        preload = _number(params, "N", source, positive=True)
        vals = {k: _number(params, k, source, nonnegative=True) for k in CEIM_REQUIRED}
        f_ba = _number(params, "f_ba", source) if "f_ba" in params else 0.667
        if not 0.0 < f_ba <= 1.0:
            raise ParameterError(f"f_ba must lie in (0, 1], got {f_ba:g}.", source=source,
                                 fix="f_ba = z_ba/|z_ss| (Nguyen eq. 15).")
        if vals["mu"] <= 0 or vals["zba_slope"] * preload + vals["zba_0"] <= 0 or \
                vals["sigma0_slope"] * preload + vals["sigma0_0"] <= 0:
            raise ParameterError("CEIM needs mu > 0 and a positive z_ba and sigma0 at the "
                                 "preload N.", source=source,
                                 fix="check zba_slope/zba_0, sigma0_slope/sigma0_0 and N.")
        sigma1 = _number(params, "sigma1", source, nonnegative=True) if "sigma1" in params \
            else 0.0
        return CEIMElastoPlastic(preload, f_ba=f_ba, sigma1=sigma1, **vals)
    if friction == "lugre":
        vals = {k: _number(params, k, source, positive=k in ("sigma0", "F_c", "F_s", "v_s"),
                           nonnegative=True) for k in LUGRE_NAMES}
        if vals["F_s"] < vals["F_c"]:
            raise ParameterError("LuGre needs F_s ≥ F_c.", source=source,
                                 fix="the static level is at least the Coulomb level.")
        return LuGre(**vals)
    rho0 = _number(params, "rho0", source, positive=True)
    base = _number(params, "z_ba", source, positive=True) if "z_ba" in params else None
    zf = _number(params, "z_ba_forward", source, positive=True) if "z_ba_forward" in params \
        else base
    zb = _number(params, "z_ba_backward", source, positive=True) if "z_ba_backward" in params \
        else base
    if zf is None or zb is None:
        raise ParameterError("give z_ba, or both z_ba_forward and z_ba_backward.", source=source)
    ratio = _number(params, "zba_ratio", source) if "zba_ratio" in params else 0.667
    if not 0.0 < ratio <= 1.0:
        raise ParameterError(f"zba_ratio must lie in (0, 1], got {ratio:g}.", source=source,
                             fix="zba_ratio = z_ba/|z_ss|; the paper uses 0.667.")
    rho1 = _number(params, "rho1", source, nonnegative=True) if "rho1" in params else 0.0
    rho2 = _number(params, "rho2", source, nonnegative=True) if "rho2" in params else 0.0
    sratio = _number(params, "stribeck_ratio", source) if "stribeck_ratio" in params else 1.0
    if sratio < 1.0:
        raise ParameterError(f"stribeck_ratio must be ≥ 1, got {sratio:g}.", source=source,
                             fix="f_max/f_c is at least 1 (1 switches the Stribeck effect off).")
    if sratio > 1.0:
        if "v_s" not in params:
            raise ParameterError("stribeck_ratio > 1 needs v_s.", source=source,
                                 fix="add the Stribeck velocity v_s [m/s].")
        v_s = _number(params, "v_s", source, positive=True)
        return StribeckElastoPlastic(rho0, zf, zb, stribeck_ratio=sratio, v_s=v_s,
                                     zba_ratio=ratio, rho1=rho1, rho2=rho2)
    return ElastoPlastic(rho0, zf, zb, zba_ratio=ratio, rho1=rho1, rho2=rho2)


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
    }
    if isinstance(f, LuGre):
        out["friction"] = "lugre"
        out.update({k: float(getattr(f, k)) for k in LUGRE_NAMES})
        return out
    if isinstance(f, CEIMElastoPlastic):
        out["friction"] = "ceim"
        out["N"] = float(f.preload)
        out.update({k: float(getattr(f, k)) for k in CEIM_NAMES})
        return out
    out["friction"] = "elastoplastic"
    out.update({
        "rho0": float(f.rho0), "rho1": float(f.rho1), "rho2": float(f.rho2),
        "z_ba": float(f.z_ba_forward),
        "z_ba_forward": float(f.z_ba_forward), "z_ba_backward": float(f.z_ba_backward),
        "zba_ratio": float(f.zba_ratio),
    })
    if isinstance(f, StribeckElastoPlastic):
        out["stribeck_ratio"] = float(f.stribeck_ratio)
        out["v_s"] = float(f.v_s)
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
                inputs=()) -> Path:
    """Write an actuator's parameters as JSON (atomic; no overwrite without ``force``)."""
    path = check_output_path(path, force=force, inputs=inputs)
    atomic_write_text(path, json.dumps(params_from_actuator(actuator), indent=1) + "\n")
    return path

"""Friction laws by name: what a parameter file, the identification and the CLI know of a law.

A friction law is one final class (a subclass of
:class:`~stickslip_jax.model.base.AbstractFriction`) that carries its own description
of its parameters, :attr:`~stickslip_jax.model.base.AbstractFriction.parameters`, a
tuple of :class:`LawParameter` (file name, unit, doc, default, bounds, how it is fitted
and by which identification step), and registers itself under the name a parameter
file gives in ``"friction"``::

    @register_friction_law("my-law")
    class MyLaw(AbstractFriction):
        parameters = (LawParameter("k", "N/m", "contact stiffness", required=True,
                                   lower=0.0, lower_open=True, step="dynamics",
                                   mass_scaled=True, stiffness=True), ...)
        k: Float[Array, ""]
        ...

Everything else finds it here: :mod:`stickslip_jax.params` reads and writes its file
entries, :mod:`stickslip_jax.identify` fits the parameters it flags, ``stickslip params
--list`` prints them, multi-contact runners split the ones proportional to the normal
force, and the diagnosis keeps the baseline's. No other file changes for a new law.

Why a record per parameter rather than metadata on the Module's fields (dynax's
``boxed_field``): a file name is not always an attribute (``z_ba`` sets both
directions of the elasto-plastic law; CEIM's preload is the file's ``N``), and the
order of the records is the order of the file's keys.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from .base import AbstractFriction


class ParameterError(ValueError):
    """A parameter file or dictionary that does not follow the contract."""

    def __init__(self, message: str, *, source: str | None = None, fix: str = ""):
        where = f"{source}: " if source else ""
        text = f"{where}{message}"
        if fix:
            text += f" Fix: {fix}"
        super().__init__(text)
        self.message = message
        self.source = source
        self.fix = fix


STEPS = ("dynamics", "friction")
"""Identification steps a law parameter may be fitted in (:attr:`LawParameter.step`)."""


@dataclass(frozen=True)
class LawParameter:
    """One parameter of a friction law as a parameter file holds it (SI units).

    Attributes
    ----------
    name: the key in a parameter file (also the name ``--fix`` and fit reports use).
    unit: SI unit, ``-`` for a dimensionless one.
    doc: one line saying what it is (no unit; :attr:`described` adds it).
    required: a file must give it (or an alias of it, ``alias_for``).
    default: value when the file omits it (``None``: no default; then it is required
        or simply absent, e.g. the Stribeck velocity of a law without Stribeck effect).
    attribute: the law's field that holds it ('' for the same as ``name``).
    alias_for: a shorthand that only files know: it sets each of these parameters the
        file does not give itself (``z_ba`` → ``z_ba_forward``, ``z_ba_backward``) and
        is written as the first one's value.
    lower, upper: bounds [unit]; ``lower_open`` excludes ``lower`` (``lower=0`` with
        ``lower_open``: positive), ``upper`` is always included.
    kind: the fitting transform of :class:`~stickslip_jax.identify.parameters.FreeParameter`
        ('' derives it from the bounds: ``log`` for positive, ``softplus`` for
        non-negative, ``logit`` for (0, 1]; a parameter with other bounds is not
        fittable unless its kind is given).
    scale: θ unit of a ``softplus`` parameter that starts at 0, and of ``linear`` [unit].
    step: the identification step that fits it by default ('dynamics': the step
        responses, 'friction': the sawtooth recordings; '' none).
    on_request: fitted in ``step`` only when asked (``identify(also_fit=...)``).
    direction: 'forward' or 'backward' for a quantity per drive direction: the
        dynamics step also fits the one of its step recordings' direction (a step's
        edge slips), the friction step fits a 'backward' one only with backward
        sawtooth data ('forward' also serves sines and steps, so it always counts).
    mass_scaled: position data determine it only up to the common factor of the
        masses (stiffnesses, dampings, forces): one of these must be held fixed.
    stiffness: a contact stiffness: a start moved to a measured step mode scales it
        with the piezo stiffness.
    with_normal_force: proportional to the contact's normal force: a contact that
        carries a share s of a runner's preload has s times it
        (:func:`stickslip_jax.model.contacts.split_contact`).
    """

    name: str
    unit: str
    doc: str
    required: bool = False
    default: float | None = None
    attribute: str = ""
    alias_for: tuple[str, ...] = ()
    lower: float | None = None
    lower_open: bool = False
    upper: float | None = None
    kind: str = ""
    scale: float = 1.0
    step: str = ""
    on_request: bool = False
    direction: str = ""
    mass_scaled: bool = False
    stiffness: bool = False
    with_normal_force: bool = False

    def __post_init__(self):
        if self.step not in ("", *STEPS):
            raise ValueError(f"{self.name}: step must be one of {STEPS} or '', got "
                             f"{self.step!r}")
        if self.direction not in ("", "forward", "backward"):
            raise ValueError(f"{self.name}: direction must be 'forward', 'backward' or ''")
        if self.step and not self.fit_kind:
            raise ValueError(f"{self.name}: a parameter fitted in the {self.step} step "
                             f"needs a kind (or bounds that imply one)")

    @property
    def attr(self) -> str:
        """The law's field that holds this parameter ('' for a file-only alias)."""
        return "" if self.alias_for else (self.attribute or self.name)

    @property
    def positive(self) -> bool:
        return self.lower == 0.0 and self.lower_open and self.upper is None

    @property
    def fit_kind(self) -> str:
        """Transform used when it is fitted ('' if it cannot be)."""
        if self.alias_for:
            return ""
        if self.kind:
            return self.kind
        if self.lower == 0.0 and self.upper is None:
            return "log" if self.lower_open else "softplus"
        if self.lower == 0.0 and self.lower_open and self.upper == 1.0:
            return "logit"
        return ""

    @property
    def domain(self) -> str:
        """The bounds in interval notation, e.g. ``(0, 1]``."""
        lo = "-∞" if self.lower is None else f"{self.lower:g}"
        hi = "∞" if self.upper is None else f"{self.upper:g}"
        left = "(" if self.lower is None or self.lower_open else "["
        right = ")" if self.upper is None else "]"
        return f"{left}{lo}, {hi}{right}"

    @property
    def described(self) -> str:
        """``doc [unit]``, as ``stickslip params --list`` prints it."""
        return f"{self.doc} [{self.unit}]"

    def contains(self, value: float) -> bool:
        """Whether ``value`` lies within the bounds."""
        if self.lower is not None and (value < self.lower or (self.lower_open
                                                              and value == self.lower)):
            return False
        return self.upper is None or value <= self.upper

    def check(self, value: Any, source: str | None = None) -> float:
        """``value`` from a file as a float within the bounds, or a :class:`ParameterError`."""
        name = self.name
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParameterError(f"'{name}' must be a number, got {value!r}.", source=source,
                                 fix=f"give {name} as a JSON number in SI units.")
        value = float(value)
        if not math.isfinite(value):
            raise ParameterError(f"'{name}' is not finite ({value}).", source=source,
                                 fix=f"give a finite {name}.")
        if self.contains(value):
            return value
        if self.positive:
            raise ParameterError(f"'{name}' must be positive, got {value:g} "
                                 f"({self.described}).", source=source,
                                 fix=f"a {name} ≤ 0 is unphysical; check its sign and unit.")
        if self.lower == 0.0 and not self.lower_open and self.upper is None:
            raise ParameterError(f"'{name}' must not be negative, got {value:g} "
                                 f"({self.described}).", source=source,
                                 fix=f"check the sign and unit of {name}.")
        default = "" if self.default is None else f"; default {self.default:g}"
        raise ParameterError(f"'{name}' must lie in {self.domain}, got {value:g} "
                             f"({self.described}).", source=source,
                             fix=f"give {name} within {self.domain} ({self.doc}{default}).")


# ----------------------------------------------------------------------------- registry
FRICTION_LAWS: dict[str, type[AbstractFriction]] = {}
"""Every friction law a parameter file may name, by that name (registration order)."""


def register_friction_law(name: str):
    """Class decorator: make a final friction law known under ``name`` (the value of a
    parameter file's ``"friction"``). Checks the law's :class:`LawParameter` records
    against its fields, so that a mistake shows when the law is defined."""
    if not isinstance(name, str) or not name:
        raise ValueError("a friction law needs a non-empty name")

    def register(cls):
        from .base import AbstractFriction

        if not (isinstance(cls, type) and issubclass(cls, AbstractFriction)):
            raise TypeError(f"{cls!r} is not a subclass of AbstractFriction")
        taken = FRICTION_LAWS.get(name)
        if taken is not None and taken is not cls and (
                taken.__module__, taken.__qualname__) != (cls.__module__, cls.__qualname__):
            raise ValueError(f"the friction law name {name!r} is taken by "
                             f"{taken.__qualname__}")
        _check_parameters(cls)
        FRICTION_LAWS[name] = cls
        return cls

    return register


def _check_parameters(cls) -> None:
    import dataclasses

    try:
        specs = cls.parameters
    except AttributeError:
        raise TypeError(f"{cls.__qualname__} declares no parameters (a tuple of "
                        f"LawParameter)") from None
    names = [p.name for p in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"{cls.__qualname__}: parameter names repeat: {names}")
    fields = {f.name for f in dataclasses.fields(cls)}
    for p in specs:
        if p.alias_for:
            unknown = [t for t in p.alias_for if t not in names]
            if unknown:
                raise ValueError(f"{cls.__qualname__}: alias {p.name!r} sets {unknown}, "
                                 f"which are not parameters of the law")
        elif p.required and p.attr not in fields:
            # An optional one may belong to a variant only (the Stribeck velocity).
            raise ValueError(f"{cls.__qualname__}: required parameter {p.name!r} has no "
                             f"field {p.attr!r}")


def friction_law(name: str, *, source: str | None = None) -> type[AbstractFriction]:
    """The law registered as ``name``, or a :class:`ParameterError` listing the known ones."""
    try:
        return FRICTION_LAWS[name]
    except (KeyError, TypeError):
        raise ParameterError(f"unknown friction law {name!r}.", source=source,
                             fix=f"use one of {', '.join(FRICTION_LAWS)}.") from None


def friction_law_name(law: AbstractFriction) -> str:
    """The name under which ``law`` is written to a parameter file.

    The registered class itself, or a class that shares a registered law's parameter
    tuple (its file form): the Stribeck generalisation of the elasto-plastic law and
    its z_ba-surface variant are written as ``"elastoplastic"`` files.
    """
    cls = type(law)
    for name, registered in FRICTION_LAWS.items():
        if registered is cls:
            return name
    for name, registered in FRICTION_LAWS.items():
        if registered.parameters is cls.parameters:
            return name
    raise ParameterError(f"{cls.__name__} is not a registered friction law, so it has no "
                         f"parameter-file form.",
                         fix="decorate the class with @register_friction_law(name).")


def missing_law_parameters(cls: type[AbstractFriction], values: Mapping[str, Any]) -> list[str]:
    """Required parameters of law ``cls`` that ``values`` lacks (an alias counts for
    its targets), as they would be named in a message."""
    given = set(values)
    aliases = {t: p for p in cls.parameters for t in p.alias_for}
    missing = []
    for p in cls.parameters:
        if not p.required or p.name in given:
            continue
        alias = aliases.get(p.name)
        if alias is None:
            missing.append(p.name)
        elif alias.name not in given:
            text = (f"{alias.name} (or {'both' if len(alias.alias_for) == 2 else 'all of'} "
                    f"{' and '.join(alias.alias_for)})")
            if text not in missing:
                missing.append(text)
    return missing


def law_values(cls: type[AbstractFriction], values: Mapping[str, Any], *,
               source: str | None = None) -> dict[str, float]:
    """The values of law ``cls``'s parameters in ``values`` (a parameter file), each
    checked against its bounds, with aliases resolved and defaults filled in, by file
    name. Required ones must be present (see :func:`missing_law_parameters`)."""
    out = {p.name: p.check(values[p.name], source) for p in cls.parameters if p.name in values}
    for p in cls.parameters:
        if p.alias_for and p.name in out:
            for target in p.alias_for:
                out.setdefault(target, out[p.name])
    for p in cls.parameters:
        if p.name not in out and p.default is not None:
            out[p.name] = float(p.default)
    for p in cls.parameters:
        if p.alias_for:
            out.pop(p.name, None)
    return out


def law_parameter(law: AbstractFriction | type[AbstractFriction], name: str) -> LawParameter:
    """The record of parameter ``name`` of a law (instance or class); KeyError if none."""
    for p in law.parameters:
        if p.name == name:
            return p
    cls = law if isinstance(law, type) else type(law)
    raise KeyError(f"{name!r} is not a parameter of {cls.__name__}")


def held_parameters(law) -> tuple[LawParameter, ...]:
    """The parameters of a law (instance or class) whose field its class has: no file
    aliases, no parameters of a variant only (the Stribeck velocity of the paper's law)."""
    import dataclasses

    cls = law if isinstance(law, type) else type(law)
    fields = {f.name for f in dataclasses.fields(cls)}
    return tuple(p for p in cls.parameters if p.attr and p.attr in fields)

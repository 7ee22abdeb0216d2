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

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from .law_parameter import STEPS, LawParameter, ParameterError

if TYPE_CHECKING:  # pragma: no cover
    from .base import AbstractFriction

__all__ = ["STEPS", "FRICTION_LAWS", "LawParameter", "ParameterError", "friction_law",
           "friction_law_name", "held_parameters", "law_parameter", "law_values",
           "missing_law_parameters", "register_friction_law"]


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

"""One parameter of a friction law as a parameter file holds it (:class:`LawParameter`),
and the error a file that breaks the contract raises (:class:`ParameterError`).

A leaf module: the friction base class (:mod:`.base`) declares its laws' parameters
with it, and the registry (:mod:`.registry`) that finds laws by name reads them, so
neither imports the other at import time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


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

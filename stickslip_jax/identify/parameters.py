"""Free parameters: where they live in the Actuator and how they are transformed.

Least squares has no bounds, so every parameter is fitted in an unconstrained,
well-scaled coordinate ``θ`` that is 0 at the start value:

- ``log``: positive quantities (masses, dampings, stiffnesses, z_ba):
  ``value = start·exp(θ)``, so θ is a relative change and a step of 0.1 is 10 %.
- ``logit``: quantities in (0, 1) (``zba_ratio``): ``value = sigmoid(θ + logit(start))``.
- ``softplus``: non-negative quantities that may start at 0 (``rho1``, ``rho2``):
  ``value = scale·softplus(θ + θ0)`` with the scale of the start (or a default).
- ``nonneg``: the softplus transform for the weights of a spectrum, some started
  small beside others (each on its own start's θ unit, nearly linear while it grows,
  reaching its bound 0 smoothly); its own kind because a refit's criterion counts such
  a weight only off its bound, judged against the spec's ``scale``
  (:func:`~stickslip_jax.diagnose.refit.counted_parameters`).
- ``pi_cumlog``: PI weights with the loop kept monotone: the partial sums
  ``s_k = Σ_{i≤k} w_i`` stay positive as ``s_k = s_k0·exp(θ_k)``, ``w = diff(s)``.

The piezo element's and the slider's quantities and the PI weights are listed here;
a friction law's come from the law itself (its
:class:`~stickslip_jax.model.registry.LawParameter` records: attribute, unit, bounds
and so the transform), so any registered law can be fitted by name.

The position data fix only ratios of the masses, dampings and stiffnesses (scaling
Mp, Dp, Kp, Ms, Ds, rho0, rho1, rho2 together leaves q unchanged), so one of them
must be fixed: by default ``Ms``, at the start value, and the tool says so.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..model.actuator import Actuator
from ..model.friction import ElastoPlastic
from ..model.registry import LawParameter, held_parameters

_COMMON = {  # name: (getter, kind, unit)
    "Mp": (lambda a: a.piezo.Mp, "log", "kg"),
    "Dp": (lambda a: a.piezo.Dp, "log", "N·s/m"),
    "Kp": (lambda a: a.piezo.Kp, "log", "N/m"),
    "Ms": (lambda a: a.slider.Ms, "log", "kg"),
    "Ds": (lambda a: a.slider.Ds, "log", "N·s/m"),
    "pi_weights": (lambda a: a.hysteresis.weights, "pi_cumlog", "m/V"),
}
MECHANICS = ("Mp", "Dp", "Kp", "Ms", "Ds")
"""The piezo element's and the slider's masses, dampings and stiffnesses."""


def _law(law_or_actuator):
    return law_or_actuator.friction if isinstance(law_or_actuator, Actuator) \
        else law_or_actuator


def law_fittable(law_or_actuator) -> tuple[LawParameter, ...]:
    """The parameters of a friction law (or of an actuator's) that can be fitted."""
    return tuple(p for p in held_parameters(_law(law_or_actuator)) if p.fit_kind)


def fittable_names(law_or_actuator) -> tuple[str, ...]:
    """Every name :meth:`ParameterMap.make` accepts for this law (or actuator)."""
    return MECHANICS + tuple(p.name for p in law_fittable(law_or_actuator)) + ("pi_weights",)


def scale_invariant_names(law_or_actuator) -> tuple[str, ...]:
    """Quantities of this law (or actuator) that position data fix only up to the
    common factor of the masses."""
    return MECHANICS + tuple(p.name for p in law_fittable(law_or_actuator) if p.mass_scaled)


def unit_of(name: str, law_or_actuator) -> str:
    """Unit of a fittable quantity for reports ('' if unknown)."""
    if name in _COMMON:
        return _COMMON[name][2]
    return next((p.unit for p in law_fittable(law_or_actuator) if p.name == name), "")


SCALE_INVARIANT = scale_invariant_names(ElastoPlastic)
"""Quantities only identifiable up to one common factor from position data (the
paper's law; :func:`scale_invariant_names` for any)."""

FITTABLE = fittable_names(ElastoPlastic)
"""Names :meth:`ParameterMap.make` accepts with the paper's law (:func:`fittable_names`
for any law)."""

UNITS = {name: unit_of(name, ElastoPlastic) for name in FITTABLE}


def _law_parameter(name: str, actuator: Actuator) -> LawParameter | None:
    return next((p for p in law_fittable(actuator) if p.name == name), None)


def parameter_getter(name: str, actuator: Actuator) -> Callable[[Actuator], jax.Array]:
    """The leaf of ``actuator`` that parameter ``name`` (a file name: ``Mp``,
    ``z_ba_forward``, ``pi_weights``) is stored in, as a function for ``eqx.tree_at``."""
    if name in _COMMON:
        return _COMMON[name][0]
    p = _law_parameter(name, actuator)
    if p is None:
        raise KeyError(f"{name!r} is not a fittable parameter of an actuator with "
                       f"{type(actuator.friction).__name__} friction; fittable: "
                       f"{', '.join(fittable_names(actuator))}")
    return lambda a, attr=p.attr: getattr(a.friction, attr)


def _kind(name: str, actuator: Actuator) -> tuple[str, float | None]:
    """Transform and θ scale of a built-in quantity."""
    if name in _COMMON:
        return _COMMON[name][1], None
    p = _law_parameter(name, actuator)
    return p.fit_kind, p.scale


def set_quantity(getter: Callable, tree, value):
    """``tree`` with the quantity ``getter`` selects set to ``value``. A quantity that
    is a tuple of scalars (coefficients a fit frees one by one, :class:`ParameterSpec`)
    takes ``value``'s last axis, one element per scalar, so that the tree keeps its
    structure."""
    return set_quantities([getter], tree, [value])


def set_quantities(getters: Sequence[Callable], tree, values: Sequence):
    """``tree`` with each quantity ``getters[i]`` selects set to ``values[i]`` (as
    :func:`set_quantity`, in one ``eqx.tree_at``: one copy of the tree, not one per
    quantity; the quantities must be distinct nodes, none inside another)."""
    if not getters:
        return tree
    values = [tuple(v[..., i] for i in range(len(node))) if isinstance(node, tuple) else v
              for node, v in zip((g(tree) for g in getters), values, strict=True)]
    return eqx.tree_at(lambda t: tuple(g(t) for g in getters), tree, tuple(values))


@dataclass(frozen=True)
class ParameterSpec:
    """How to fit a quantity that is not a built-in one (model extensions; a friction
    law's own parameters are built in through its :attr:`parameters`).

    ``getter`` selects the leaf in the :class:`Actuator` (or a tuple of scalar leaves:
    one vector quantity, :func:`set_quantity`); ``kind`` is one of ``log``,
    ``softplus`` (non-negative, may start at 0), ``nonneg`` (non-negative, θ unit its
    start), ``linear`` (signed: ``value = start + scale·θ``); ``scale`` sets the θ
    unit of ``linear`` and ``softplus`` parameters and the size of a ``nonneg`` one's
    spectrum [parameter unit]; ``unit`` is for reports. ``floor`` (``log``
    only; 0: none) [parameter unit]: the value is ``max(start·e^θ, floor)``, for a
    quantity the data cannot resolve below it and whose derivatives vanish on the way
    to 0 (a fit walks such a one off the scale, and no later fit can bring it back;
    one that starts at the floor has its derivative there).
    """

    getter: Callable[[Actuator], jax.Array]
    kind: str = "log"
    scale: float = 1.0
    unit: str = "-"
    floor: float = 0.0


@dataclass(frozen=True)
class FreeParameter:
    """One fitted quantity (scalar or vector) and its transform from θ."""

    name: str
    kind: str
    size: int
    start: np.ndarray  # physical start value(s)
    scale: float | None = None  # θ unit of linear/softplus kinds
    floor: float = 0.0  # least value of a log kind (ParameterSpec)

    def _softplus_scale(self) -> tuple[float, float]:
        """``(scale, θ0)`` of the softplus and nonneg kinds: value = scale·softplus(θ + θ0),
        the start as its scale (θ0 = softplus⁻¹(1)), or the spec's from 0 (θ0 = −20)."""
        scale = float(self.start) if float(self.start) > 0 else (self.scale or 1.0)
        theta0 = np.log(np.expm1(float(self.start) / scale)) if float(self.start) > 0 \
            else -20.0
        return scale, theta0

    def to_physical(self, theta, *, xp=jnp):
        """Physical value(s) from the slice ``theta`` of the parameter vector; ``xp`` is
        ``jax.numpy`` (traceable) or ``numpy`` (for a concrete θ: nothing compiled)."""
        if xp is np:
            # A solver's trial step far off the scale (|θ| in the hundreds along a
            # direction the data barely see) gives an infinite value, and the trial an
            # infinite or NaN cost, which the solver rejects: that is the meaning
            # intended, not an accident to warn about.
            with np.errstate(over="ignore", invalid="ignore"):
                return self._to_physical(theta, np)
        return self._to_physical(theta, xp)

    def _to_physical(self, theta, xp):
        start = xp.asarray(self.start)
        theta = xp.asarray(theta)
        if self.kind == "log":
            value = start * xp.exp(theta)
            if self.floor > 0:
                # where, not maximum: the derivative is whole at the floor itself, where
                # a fit that starts there must see it.
                value = xp.where(value >= self.floor, value, self.floor)
        elif self.kind == "logit":
            value = _sigmoid(theta + xp.log(start / (1.0 - start)), xp)
        elif self.kind == "linear":
            value = start + self.scale * theta
        elif self.kind in ("softplus", "nonneg"):
            scale, theta0 = self._softplus_scale()
            value = scale * (jax.nn.softplus(theta + theta0) if xp is jnp
                             else np.logaddexp(theta + theta0, 0.0))
        elif self.kind == "pi_cumlog":
            sums0 = xp.cumsum(start)
            sums = sums0 * xp.exp(theta)
            value = xp.diff(sums, prepend=0.0)
        else:  # pragma: no cover - guarded by _kind
            raise ValueError(self.kind)
        return value if self.size > 1 else value.reshape(())

    def derivative(self, theta) -> np.ndarray:
        """``∂value_i/∂θ_j`` (size, size) at the slice ``theta`` [value unit per unit of
        θ], in numpy (the transforms' derivatives written out; infinite far off the
        scale, as :meth:`to_physical`)."""
        with np.errstate(over="ignore", invalid="ignore"):
            return self._derivative(theta)

    def _derivative(self, theta) -> np.ndarray:
        theta = np.atleast_1d(np.asarray(theta, dtype=float))
        start = np.atleast_1d(np.asarray(self.start, dtype=float))
        if self.kind == "log":
            value = start * np.exp(theta)
            return np.diag(np.where(value >= self.floor, value, 0.0))
        if self.kind == "logit":
            s = _sigmoid(theta + np.log(start / (1.0 - start)), np)
            return np.diag(s * (1.0 - s))
        if self.kind == "linear":
            return np.diag(np.full(theta.size, float(self.scale)))
        if self.kind in ("softplus", "nonneg"):
            scale, theta0 = self._softplus_scale()
            return np.diag(scale * _sigmoid(theta + theta0, np))
        if self.kind == "pi_cumlog":
            # w_i = s_i − s_(i−1) with s_j = s0_j·exp(θ_j): ∂w_i/∂θ_j = s_j (δ_ij − δ_(i−1)j)
            sums = np.cumsum(start) * np.exp(theta)
            d = np.diag(sums)
            d[np.arange(1, sums.size), np.arange(sums.size - 1)] = -sums[:-1]
            return d
        raise ValueError(self.kind)  # pragma: no cover - guarded by _kind

    def step_bounds(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)``: the steps δθ of this slice (each (size,)) for which the value,
        moved to first order (value + ∂value/∂θ·δθ), stays in its domain: ≥ 0 (log,
        nonneg, softplus; ≥ the floor of a floored log), inside (0, 1) (logit), every
        partial sum ≥ 0 (pi_cumlog); unbounded for linear. A Gauss-Newton step that
        leaves them (:func:`~.solve.gauss_newton_drop`) claims a fall the model cannot
        reach: a weight whose optimum is 0 approaches it only as θ → −∞."""
        theta = np.atleast_1d(np.asarray(theta, dtype=float))
        inf = np.full(theta.size, np.inf)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            if self.kind == "log":
                value = np.atleast_1d(np.asarray(self.start, dtype=float)) * np.exp(theta)
                room = np.maximum(value - self.floor, 0.0) / value
                return np.where(np.isfinite(room), -room, -1.0), inf
            if self.kind in ("softplus", "nonneg"):
                _, theta0 = self._softplus_scale()
                x = theta + theta0
                # softplus(x)/sigmoid(x), written to stay finite far below 0 (→ 1)
                ratio = np.logaddexp(x, 0.0) * (1.0 + np.exp(-x))
                ratio = np.where(x < -30.0, 1.0, ratio)
                return -ratio, inf
            if self.kind == "logit":
                s = _sigmoid(theta + np.log(self.start / (1.0 - self.start)), np)
                return -1.0 / (1.0 - s), 1.0 / s
            if self.kind == "pi_cumlog":
                return np.full(theta.size, -1.0), inf
        return -inf, inf


def _sigmoid(x, xp):
    return jax.nn.sigmoid(x) if xp is jnp else 1.0 / (1.0 + np.exp(-x))


PI_SUM_FLOOR = 1e-9
"""Partial sums of PI weights within this share of the largest one of zero (or below
it, by as little) are rounding, not a fold in the loop: :func:`monotone_pi_start`
lifts them to it."""


def monotone_pi_start(weights: np.ndarray) -> np.ndarray:
    """PI weights [m/V] whose partial sums are all positive, as the ``pi_cumlog``
    transform needs (it fits the logarithm of each partial sum).

    A fit that drove one partial sum toward zero leaves weights whose cumulative sum
    rounds to 0 or to −1e-17 of the others (seen after a 75-step polish of a poor
    baseline): such sums are lifted to ``PI_SUM_FLOOR`` of the largest, a change of
    the loop far below any noise. A partial sum clearly ≤ 0 is a folded loop: error."""
    weights = np.asarray(weights, dtype=float)
    sums = np.cumsum(weights)
    top = float(np.max(np.abs(sums), initial=0.0))
    if np.all(sums > 0):
        return weights
    if top == 0.0 or np.any(sums <= -PI_SUM_FLOOR * top):
        raise ValueError("the starting PI loop is not monotone (a partial sum of "
                         "pi_weights is ≤ 0)")
    return np.diff(np.maximum(sums, PI_SUM_FLOOR * top), prepend=0.0)


class ParameterMap(eqx.Module):
    """Maps a flat vector θ to an :class:`Actuator` (the start actuator with the free
    parameters replaced). θ = 0 reproduces the start."""

    start: Actuator
    free: tuple[FreeParameter, ...] = eqx.field(static=True)
    getters: tuple = eqx.field(static=True, default=())

    @staticmethod
    def make(start: Actuator, names: Sequence[str],
             specs: dict[str, ParameterSpec] | None = None) -> ParameterMap:
        """Free parameters ``names`` (order kept) around the actuator ``start``;
        ``specs`` describes names that are not built in (:func:`fittable_names`)."""
        specs = specs or {}
        free, getters = [], []
        for name in names:
            spec = specs.get(name)
            getter = spec.getter if spec else parameter_getter(name, start)
            getters.append(getter)
            value = np.asarray(getter(start), dtype=float)
            kind, scale = (spec.kind, spec.scale) if spec else _kind(name, start)
            floor = float(spec.floor) if spec else 0.0
            if kind == "log" and np.any(value <= 0):
                raise ValueError(f"{name} must start positive to be fitted, got {value}")
            if floor > 0 and (kind != "log" or np.any(value < floor)):
                raise ValueError(f"{name}: a floor is for a log parameter starting at or "
                                 f"above it, got kind {kind!r}, start {value}, floor {floor}")
            if kind == "pi_cumlog":
                value = monotone_pi_start(value)
            if kind == "nonneg" and (value.size != 1 or float(value) < 0
                                     or not (scale or 0) > 0):
                raise ValueError(f"{name}: a nonneg weight is a scalar starting at 0 or "
                                 f"above with a positive scale, got {value} (scale {scale})")
            if kind == "logit" and not 0 < float(value) < 1:
                raise ValueError(f"{name} must start inside (0, 1) to be fitted, got {value}")
            free.append(FreeParameter(name, kind, int(value.size), value, scale, floor))
        return ParameterMap(start, tuple(free), tuple(getters))

    @property
    def size(self) -> int:
        """Length of θ."""
        return sum(p.size for p in self.free)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.free)

    def slices(self) -> dict[str, slice]:
        """Where each parameter sits in θ."""
        out, i = {}, 0
        for p in self.free:
            out[p.name] = slice(i, i + p.size)
            i += p.size
        return out

    def labels(self) -> list[str]:
        """One label per entry of θ (``pi_weights[3]`` for vector entries)."""
        out = []
        for p in self.free:
            out += [p.name] if p.size == 1 else [f"{p.name}[{i}]" for i in range(p.size)]
        return out

    def zeros(self):
        return jnp.asarray(np.zeros(self.size))  # (no compiled operation for the shape)

    def actuator(self, theta, *, xp=jnp) -> Actuator:
        """The actuator at ``theta``; ``xp=numpy`` evaluates the transforms in numpy (for
        a concrete θ: nothing compiled) and sets the leaves as JAX arrays."""
        sl = self.slices()
        values = [p.to_physical(theta[sl[p.name]], xp=xp) for p in self.free]
        return set_quantities(self.getters, self.start,
                              [v if xp is jnp else jnp.asarray(v) for v in values])

    def physical(self, theta) -> dict[str, np.ndarray]:
        """Physical values of the free parameters at ``theta`` (numpy)."""
        sl = self.slices()
        theta = np.asarray(theta, dtype=float)
        return {p.name: np.asarray(p.to_physical(theta[sl[p.name]], xp=np)) for p in self.free}

    def value_jacobian(self, theta) -> np.ndarray:
        """d(physical values, flattened in label order) / dθ, a square matrix (block
        diagonal, one block per free parameter: :meth:`FreeParameter.derivative`)."""
        sl = self.slices()
        theta = np.asarray(theta, dtype=float)
        out = np.zeros((self.size, self.size))
        for p in self.free:
            out[sl[p.name], sl[p.name]] = p.derivative(theta[sl[p.name]])
        return out

    def step_bounds(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)`` over θ: the steps that keep every value in its domain to first
        order (:meth:`FreeParameter.step_bounds`, slice by slice)."""
        sl = self.slices()
        theta = np.asarray(theta, dtype=float)
        parts = [p.step_bounds(theta[sl[p.name]]) for p in self.free]
        if not parts:
            return np.zeros(0), np.zeros(0)
        return (np.concatenate([lo for lo, _ in parts]),
                np.concatenate([hi for _, hi in parts]))

    def leaf_tangents(self, theta, mask):
        """The derivatives of the ``mask`` leaves of :meth:`actuator` along each
        coordinate of θ: a pytree of the mask's leaves (``eqx.filter(actuator, mask)``)
        with a leading axis of θ's size on each leaf (zeros where a leaf is held), in
        numpy."""
        sl = self.slices()
        theta = np.asarray(theta, dtype=float)
        out = jax.tree.map(lambda x: np.zeros((self.size,) + np.shape(x)),
                           eqx.filter(self.start, mask))
        values = []
        for p, getter in zip(self.free, self.getters, strict=True):
            rows = np.zeros((self.size,) + np.shape(getter(self.start)))
            rows[sl[p.name]] = p.derivative(theta[sl[p.name]]).T.reshape(
                (p.size,) + rows.shape[1:])
            values.append(rows)
        return set_quantities(self.getters, out, values)

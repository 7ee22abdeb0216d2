"""Free parameters: where they live in the Actuator and how they are transformed.

Least squares has no bounds, so every parameter is fitted in an unconstrained,
well-scaled coordinate ``θ`` that is 0 at the start value:

- ``log``: positive quantities (masses, dampings, stiffnesses, z_ba):
  ``value = start·exp(θ)``, so θ is a relative change and a step of 0.1 is 10 %.
- ``logit``: quantities in (0, 1) (``zba_ratio``): ``value = sigmoid(θ + logit(start))``.
- ``softplus``: non-negative quantities that may start at 0 (``rho1``, ``rho2``):
  ``value = scale·softplus(θ + θ0)`` with the scale of the start (or a default).
- ``pi_cumlog``: PI weights with the loop kept monotone: the partial sums
  ``s_k = Σ_{i≤k} w_i`` stay positive as ``s_k = s_k0·exp(θ_k)``, ``w = diff(s)``.

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

SCALE_INVARIANT = ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0", "rho1", "rho2")
"""Quantities only identifiable up to one common factor from position data."""


_PATHS = {
    "Mp": lambda a: a.piezo.Mp, "Dp": lambda a: a.piezo.Dp, "Kp": lambda a: a.piezo.Kp,
    "Ms": lambda a: a.slider.Ms, "Ds": lambda a: a.slider.Ds,
    "rho0": lambda a: a.friction.rho0, "rho1": lambda a: a.friction.rho1,
    "rho2": lambda a: a.friction.rho2,
    "z_ba_forward": lambda a: a.friction.z_ba_forward,
    "z_ba_backward": lambda a: a.friction.z_ba_backward,
    "zba_ratio": lambda a: a.friction.zba_ratio,
    "pi_weights": lambda a: a.hysteresis.weights,
}


def _getter(name: str) -> Callable[[Actuator], jax.Array]:
    if name not in _PATHS:
        raise KeyError(f"{name!r} is not a fittable parameter; fittable: {', '.join(_PATHS)}")
    return _PATHS[name]


FITTABLE = ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0", "rho1", "rho2", "z_ba_forward",
            "z_ba_backward", "zba_ratio", "pi_weights")
UNITS = {"Mp": "kg", "Dp": "N·s/m", "Kp": "N/m", "Ms": "kg", "Ds": "N·s/m", "rho0": "N/m",
         "rho1": "N·s/m", "rho2": "N·s/m", "z_ba_forward": "m", "z_ba_backward": "m",
         "zba_ratio": "-", "pi_weights": "m/V"}


def _kind(name: str) -> str:
    if name == "zba_ratio":
        return "logit"
    if name in ("rho1", "rho2"):
        return "softplus"
    if name == "pi_weights":
        return "pi_cumlog"
    return "log"


_SOFTPLUS_DEFAULT_SCALE = {"rho1": 1.0, "rho2": 1.0}  # N·s/m


@dataclass(frozen=True)
class ParameterSpec:
    """How to fit a quantity that is not one of :data:`FITTABLE` (model extensions).

    ``getter`` selects the leaf in the :class:`Actuator`; ``kind`` is one of ``log``,
    ``softplus`` (non-negative, may start at 0), ``linear`` (signed:
    ``value = start + scale·θ``); ``scale`` sets the θ unit of ``linear`` and
    ``softplus`` parameters [parameter unit]; ``unit`` is for reports.
    """

    getter: Callable[[Actuator], jax.Array]
    kind: str = "log"
    scale: float = 1.0
    unit: str = "-"


@dataclass(frozen=True)
class FreeParameter:
    """One fitted quantity (scalar or vector) and its transform from θ."""

    name: str
    kind: str
    size: int
    start: np.ndarray  # physical start value(s)
    scale: float | None = None  # θ unit of linear/softplus kinds

    def to_physical(self, theta):
        """Physical value(s) from the slice ``theta`` of the parameter vector."""
        start = jnp.asarray(self.start)
        if self.kind == "log":
            value = start * jnp.exp(theta)
        elif self.kind == "logit":
            value = jax.nn.sigmoid(theta + jnp.log(start / (1.0 - start)))
        elif self.kind == "linear":
            value = start + self.scale * theta
        elif self.kind == "softplus":
            scale = float(self.start) if float(self.start) > 0 else \
                (self.scale or _SOFTPLUS_DEFAULT_SCALE[self.name])
            theta0 = np.log(np.expm1(float(self.start) / scale)) if float(self.start) > 0 \
                else -20.0
            value = scale * jax.nn.softplus(theta + theta0)
        elif self.kind == "pi_cumlog":
            sums0 = jnp.cumsum(start)
            sums = sums0 * jnp.exp(theta)
            value = jnp.diff(sums, prepend=0.0)
        else:  # pragma: no cover - guarded by _kind
            raise ValueError(self.kind)
        return value if self.size > 1 else value.reshape(())


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
        ``specs`` describes names that are not in :data:`FITTABLE`."""
        specs = specs or {}
        free, getters = [], []
        for name in names:
            spec = specs.get(name)
            getter = spec.getter if spec else _getter(name)
            getters.append(getter)
            value = np.asarray(getter(start), dtype=float)
            kind = spec.kind if spec else _kind(name)
            if kind == "log" and np.any(value <= 0):
                raise ValueError(f"{name} must start positive to be fitted, got {value}")
            if kind == "pi_cumlog":
                value = monotone_pi_start(value)
            if kind == "logit" and not 0 < float(value) < 1:
                raise ValueError(f"{name} must start inside (0, 1) to be fitted, got {value}")
            free.append(FreeParameter(name, kind, int(value.size), value,
                                      spec.scale if spec else None))
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
        return jnp.zeros(self.size)

    def actuator(self, theta) -> Actuator:
        """The actuator at ``theta``."""
        act = self.start
        sl = self.slices()
        for p, getter in zip(self.free, self.getters, strict=True):
            value = p.to_physical(theta[sl[p.name]])
            act = eqx.tree_at(getter, act, value)
        return act

    def physical(self, theta) -> dict[str, np.ndarray]:
        """Physical values of the free parameters at ``theta``."""
        sl = self.slices()
        return {p.name: np.asarray(p.to_physical(theta[sl[p.name]])) for p in self.free}

    def value_jacobian(self, theta) -> np.ndarray:
        """d(physical values, flattened in label order) / dθ, a square matrix."""
        def flat(th):
            sl = self.slices()
            return jnp.concatenate([jnp.atleast_1d(p.to_physical(th[sl[p.name]]))
                                    for p in self.free])

        return np.asarray(jax.jacfwd(flat)(jnp.asarray(theta)))

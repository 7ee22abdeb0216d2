"""Explicit Runge-Kutta sub-steppers for the fixed-step simulation.

The voltage is evaluated at each stage's own time (first-order hold between
samples), the hysteresis memory is held at its sub-step-start value during the
stages and committed once at the sub-step's end, and the friction state is
saturated after the commit (docs/model.md "State and input"). The default, classic RK4,
was chosen by the convergence study in ``tests/test_convergence.py``.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax


def _axpy(a, x, y):
    """``y + a·x`` over matching pytrees."""
    return jax.tree.map(lambda xi, yi: yi + a * xi, x, y)


class ExplicitRK(eqx.Module):
    """An explicit Runge-Kutta method given by its Butcher tableau (static).

    Attributes: ``c`` stage times as fractions of the sub-step, ``a`` the lower
    triangular coupling rows, ``b`` the weights, ``order`` the classical order,
    ``locate_events``: split a sub-step where the relative velocity changes sign
    during a slip (:mod:`stickslip_jax.simulate`; default on, off only for studies
    of what the location buys).
    """

    name: str = eqx.field(static=True)
    c: tuple[float, ...] = eqx.field(static=True)
    a: tuple[tuple[float, ...], ...] = eqx.field(static=True)
    b: tuple[float, ...] = eqx.field(static=True)
    order: int = eqx.field(static=True)
    locate_events: bool = eqx.field(static=True, default=True)

    @property
    def stage_times(self) -> tuple[float, ...]:
        """The distinct stage times and the step's end, sorted (fractions of the
        sub-step; classic RK4: 0, 1/2, 1): where the vector field is evaluated."""
        return tuple(sorted(set(self.c) | {1.0}))

    def with_events(self, locate: bool) -> ExplicitRK:
        """The same tableau, with or without event location (see ``locate_events``)."""
        return dataclasses.replace(self, locate_events=bool(locate))

    def step(self, f, y, h, k1=None):
        """One step of size ``h`` of ``y' = f(i, y)``; ``i`` is the stage, ``y`` a pytree.

        ``k1``: the first stage ``f(0, y)`` when the caller has it already (explicit
        tableaux start at ``c = 0``, so it does not depend on ``h``).
        """
        ks = [] if k1 is None else [k1]
        for i in range(len(ks), len(self.c)):
            yi = y
            for aij, kj in zip(self.a[i], ks, strict=False):
                if aij != 0.0:
                    yi = _axpy(h * aij, kj, yi)
            ks.append(f(i, yi))
        out = y
        for bi, ki in zip(self.b, ks, strict=True):
            if bi != 0.0:
                out = _axpy(h * bi, ki, out)
        return out


EULER = ExplicitRK("euler", (0.0,), ((),), (1.0,), 1)
HEUN = ExplicitRK("heun", (0.0, 1.0), ((), (1.0,)), (0.5, 0.5), 2)
RK4 = ExplicitRK(
    "rk4",
    (0.0, 0.5, 0.5, 1.0),
    ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
    (1 / 6, 1 / 3, 1 / 3, 1 / 6),
    4,
)

SOLVERS = {s.name: s for s in (EULER, HEUN, RK4)}

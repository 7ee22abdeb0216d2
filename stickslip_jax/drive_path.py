"""The drive path: the voltage reaching the piezo over a sample interval, integrated
apart from the mechanics.

An input stage (an amplifier's low-pass, a slew limit, ...) depends on the recorded
command only, never on the mechanics. The model's Jacobian is then block-triangular
and the stage's poles are eigenvalues of its own block. Integrated inside the
mechanical Runge-Kutta step, the fastest of those poles would set the sub-step of the
whole model: on the default profile a 1 µs amplifier needs 80 sub-steps per sample
where the mechanics need 8. So the simulator integrates the stage on its own, with
its own step (:func:`stage_table`), onto the grid of the mechanical sub-steps' stage
times, and the mechanics read the piezo voltage from that table: exactly at the grid
points, by cubic Hermite interpolation between them where an event splits a sub-step
(:func:`table_voltage`). The stage's states ride along in the integrated vector (the
layout of :class:`~stickslip_jax.model.actuator.Actuator` is unchanged) and are set
from the table at the end of every sub-step.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .model.actuator import N_CORE, Actuator
from .model.base import AbstractInputStage

__all__ = ["HeldInput", "held_mechanics", "stage_slice", "stage_table", "table_voltage"]


class HeldInput(AbstractInputStage):
    """Stand-in for an input stage integrated apart (:func:`held_mechanics`): its
    ``size`` states are carried unchanged by the mechanical step (rate 0) and the
    voltage handed to the vector field is already the piezo voltage [V]."""

    size: int = eqx.field(static=True)

    @property
    def n_states(self) -> int:
        return self.size

    def initial_state(self, u0):
        return jnp.zeros((self.size,)) + 0.0 * jnp.asarray(u0, dtype=float)

    def rate(self, state, u_command):
        return jnp.zeros_like(state)

    def voltage(self, state, u_command):
        return u_command


def separate_stage(actuator: Actuator) -> bool:
    """Whether the actuator's input stage has states to integrate apart."""
    return actuator.input_stage.n_states > 0


def has_closed_form(stage: AbstractInputStage) -> bool:
    """Whether the stage advances in closed form (:meth:`AbstractInputStage.advance`)."""
    return stage.advances_in_closed_form


def held_mechanics(actuator: Actuator) -> Actuator:
    """The actuator with its input stage replaced by :class:`HeldInput`: its vector
    field takes the piezo voltage in place of the command, same state layout."""
    held = HeldInput(actuator.input_stage.n_states)
    return eqx.tree_at(lambda a: a.input_stage, actuator, held)


def stage_slice(actuator: Actuator) -> slice:
    """Where the input stage's states sit in the integrated vector ``y``."""
    return slice(N_CORE, N_CORE + actuator.input_stage.n_states)


def stage_grid(stage_times, substeps: int) -> np.ndarray:
    """The stage times of ``substeps`` equal sub-steps with stage fractions
    ``stage_times`` (first 0, last 1), as fractions of the span, shape
    (substeps, len(stage_times))."""
    return (np.arange(substeps)[:, None] + np.asarray(stage_times)[None, :]) / substeps


def grid_points(stage_times, substeps: int) -> tuple[np.ndarray, np.ndarray]:
    """The sorted distinct points of :func:`stage_grid` (the end of one sub-step is the
    start of the next), and for each sub-step and fraction its index among them,
    shape (substeps, len(stage_times))."""
    times = np.round(stage_grid(stage_times, substeps), 14)
    points = np.unique(times)
    return points, np.searchsorted(points, times)


def stage_table(stage: AbstractInputStage, s0, u_a, du, dt, points, steps: int):
    """The stage integrated alone through ``points`` (increasing fractions of the
    sample interval, the first where it holds ``s0``), the command ``u_a + du·τ`` [V]
    linear over the interval of ``dt`` [s]: in closed form where the stage has one
    (:func:`has_closed_form`; each point straight from ``s0``, all at once, since the
    command is one line over the interval), else by ``steps`` classic RK4 steps per gap.

    Returns the states at every point, the piezo voltage there [V] and its rate per
    unit fraction of the interval [V] (for :func:`table_voltage`).
    """

    def f(tau, s):
        return stage.rate(s, u_a + du * tau) * dt          # per unit fraction

    def gap(s, bounds):
        t0, t1 = bounds
        g = (t1 - t0) / steps

        def rk4(i, s):
            t = t0 + i * g
            k1 = f(t, s)
            k2 = f(t + 0.5 * g, s + 0.5 * g * k1)
            k3 = f(t + 0.5 * g, s + 0.5 * g * k2)
            k4 = f(t + g, s + g * k3)
            return s + g / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

        s = jax.lax.fori_loop(0, steps, rk4, s)
        return s, s

    if has_closed_form(stage):
        start = points[0]
        later = jax.vmap(lambda t: stage.advance(s0, u_a + du * start, u_a + du * t,
                                                 (t - start) * dt))(points[1:])
    else:
        _, later = jax.lax.scan(gap, s0, (points[:-1], points[1:]))
    states = jnp.concatenate([s0[None], later])
    command = u_a + du * points

    def voltage_and_rate(s, u, tau):
        return jax.jvp(stage.voltage, (s, u), (f(tau, s), du * jnp.ones_like(u)))

    volts, rates = jax.vmap(voltage_and_rate)(states, command, points)
    return states, volts, rates


def table_voltage(tau, points, volts, rates):
    """The piezo voltage [V] at fraction ``tau`` of the interval: the cubic Hermite
    interpolant of the table (:func:`stage_table`) on the gap holding ``tau``; the
    table's own value at a point."""
    k = jnp.clip(jnp.searchsorted(points, tau, side="right") - 1, 0, points.shape[0] - 2)
    a, b = points[k], points[k + 1]
    w = b - a
    x = (tau - a) / w
    x2, x3 = x * x, x * x * x
    return ((2 * x3 - 3 * x2 + 1) * volts[k] + (x3 - 2 * x2 + x) * w * rates[k]
            + (3 * x2 - 2 * x3) * volts[k + 1] + (x3 - x2) * w * rates[k + 1])

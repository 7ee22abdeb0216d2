"""How the simulator steps through a sample interval.

The voltage is known at the samples and linear between them, so the simulator
integrates one sample interval at a time (a ``lax.scan`` over samples). Inside an
interval it takes fixed Runge-Kutta sub-steps, with three refinements that make the
result a property of the model rather than of the sample rate or of where the
sub-step boundaries fall:

- **A step size in seconds.** The sub-steps per sample follow from a longest step
  ``max_step`` [s], by default a fixed fraction of the model's fastest time scale:
  ``radians_per_step / ω_max`` with ``ω_max`` the spectral radius of the vector
  field's Jacobian at rest without the input stage (the piezo element's stick mode,
  an extension's mode; :func:`mechanical_rate`). An input stage (the drive
  amplifier) depends on the command only and is integrated apart, at a step that
  resolves its own poles (:mod:`stickslip_jax.drive_path`). The same voltage sampled
  at 1 kHz or 100 kHz is then integrated with the same step.
- **Located events.** Where the relative velocity changes sign during a slip the
  vector field bends (:meth:`~stickslip_jax.model.base.AbstractFriction.velocity_kink`);
  a sub-step across the bend is redone as two steps meeting at it
  (:func:`sample_stepper`).
- **Refined intervals.** Each sub-step carries an embedded error estimate (classic
  RK4 with its last stage reused at the next step's start: ``h/6·|k4 − f(y1)|``, the
  difference to a third-order solution with the same stages). An interval whose summed
  estimate exceeds ``tolerance`` [m] is integrated again with ``refine`` times more
  sub-steps. In a stepping drive that is the abrupt edge and the few intervals of
  ringing after it; the slow ramp keeps the coarse step.

Decisions depend on the computed state only (no clocks), so the same inputs give the
same trace. Where a refinement decision flips between two nearby parameter values
the trace moves by about the tolerance, far below any sensor's noise.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_batching import custom_vmap

from .drive_path import (
    grid_points,
    has_closed_form,
    held_mechanics,
    separate_stage,
    stage_grid,
    stage_slice,
    stage_table,
    table_voltage,
)
from .model.actuator import N_CORE, Actuator
from .model.base import DriveContext
from .program_store import stored_jit
from .solvers import RK4, ExplicitRK

DEFAULT_RADIANS_PER_STEP = 0.5
"""Default coarse step as a phase of the fastest mode: ``max_step = 0.5/ω_max`` [rad]."""

DEFAULT_REFINE = 8
"""Default factor of sub-steps on intervals whose error estimate exceeds the tolerance."""

DEFAULT_TOLERANCE_M = 1e-11
"""Default bound on an interval's summed local error estimate [m] (10 pm)."""

FALLBACK_MAX_STEP_S = 2.5e-6
"""Longest step [s] when the actuator's values are not known (traced under ``jit`` or
``grad``) and no ``max_step`` is given: the default profile's own step, rounded."""

MAX_PLAUSIBLE_MODE_HZ = 1e6
"""A fastest mode above this [Hz] is refused unless the step is given explicitly: no
stick-slip actuator rings at a megahertz, a parameter read in the wrong unit does
(Kp in N/µm read as N/m puts the piezo mode near 16 MHz)."""

MAX_SUBSTEPS_PER_CALL = 400_000_000
"""Refuse a simulation that would take more coarse sub-steps than this (all rows of a
batch together): at about 0.1 µs each that is a minute. Many sub-steps per sample usually
mean a unit slip in a parameter (a stiffness per µm read per m); an ordinary count over
too many samples means a job too large (the message says which)."""

TYPICAL_MODE_HZ = 1e5
"""A fastest mode above this [Hz] makes a refusal for too much work blame the model's
time scale (a unit slip?) rather than the job's size: stick-slip actuators' stick modes
lie at kHz to tens of kHz (the default profile's, 17.5 kHz)."""


MAX_STAGE_STEPS = 1024
"""Refuse an input stage that needs more RK4 steps than this between two of the
mechanical sub-step's stage times (a pole near 100 MHz at the default profile's step)."""


class SteppingError(ValueError):
    """A simulation that cannot be stepped as asked (too many sub-steps)."""


def _concrete(tree) -> bool:
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(tree))


@stored_jit
def _rest_jacobian(actuator: Actuator, drive: DriveContext):
    # Compiled once per model structure: planning runs at every public call.
    y0, memory = actuator.initial_state(0.0, drive)
    stroke = actuator.free_stroke(y0, memory, 0.0)
    return jax.jacfwd(lambda y: actuator.vector_field(y, 0.0, stroke, drive))(y0)


class _RestRates(NamedTuple):
    """Spectral radii [rad/s] of the Jacobian at rest under 0 V: all of it, the
    mechanical block (without the input stage's rows) and the stage's own block."""

    fastest: float
    mechanical: float
    stage: float


def _rest_rates(actuator: Actuator, drive: DriveContext | None = None) -> _RestRates:
    # Concrete values inside someone else's trace too (a loss compiled by an optimiser
    # that closes over a concrete actuator). One Jacobian for all three radii.
    with jax.ensure_compile_time_eval():
        drive = DriveContext.make() if drive is None else drive
        jac = np.asarray(_rest_jacobian(actuator, drive), dtype=float)
    stage = _stage_rows(actuator)
    everything = np.arange(actuator.n_states)

    def radius(rows):
        block = jac[np.ix_(rows, rows)]
        if not np.all(np.isfinite(block)):
            return math.inf
        if block.size == 0:
            return 0.0
        return float(np.max(np.abs(np.linalg.eigvals(block))))

    return _RestRates(radius(everything), radius(np.setdiff1d(everything, stage)),
                      radius(stage))


def _stage_rows(actuator: Actuator) -> np.ndarray:
    return np.arange(N_CORE, N_CORE + actuator.input_stage.n_states)


def fastest_rate(actuator: Actuator, drive: DriveContext | None = None) -> float:
    """Spectral radius of the vector field's Jacobian at rest under 0 V [rad/s].

    The fastest linear time scale of the whole model (piezo stick mode, slider on the
    contact, input-stage poles, extension modes), from concrete parameter values.
    """
    return _rest_rates(actuator, drive).fastest


def mechanical_rate(actuator: Actuator, drive: DriveContext | None = None) -> float:
    """:func:`fastest_rate` without the input stage's poles [rad/s]: the rate the
    mechanical sub-step must follow. The stage depends on the command only, so the
    Jacobian is block-triangular and its eigenvalues are those of the mechanical block
    and of the stage's (:func:`stage_rate`); the stage is integrated apart
    (:mod:`stickslip_jax.drive_path`)."""
    return _rest_rates(actuator, drive).mechanical


def stage_rate(actuator: Actuator, drive: DriveContext | None = None) -> float:
    """Spectral radius of the input stage's own Jacobian block at rest [rad/s] (0
    without stage states)."""
    return _rest_rates(actuator, drive).stage


def time_scale_report(actuator: Actuator) -> str:
    """The model's fast time scales in words, for messages about step sizes."""
    p, s = actuator.piezo, actuator.slider
    k_c = float(actuator.friction.stiffness(DriveContext.make()))
    mp, kp, ms = float(p.Mp), float(p.Kp), float(s.Ms)
    parts = []
    if mp > 0 and kp >= 0:
        parts.append(f"√(Kp/Mp) = {math.sqrt(kp / mp) / (2 * math.pi):.3g} Hz")
    if mp > 0 and k_c >= 0:
        parts.append(f"√(contact stiffness/Mp) = {math.sqrt(k_c / mp) / (2 * math.pi):.3g} Hz")
    if ms > 0 and k_c >= 0:
        parts.append(f"√(contact stiffness/Ms) = {math.sqrt(k_c / ms) / (2 * math.pi):.3g} Hz")
    try:
        rate = fastest_rate(actuator)
        parts.append(f"fastest mode of the linearised model {rate / (2 * math.pi):.3g} Hz")
    except Exception:  # noqa: BLE001 - a report must not fail where the model does
        pass
    return "; ".join(parts)


class StepPlan(eqx.Module):
    """A resolved stepping (all static): what one compiled simulation does.

    Attributes
    ----------
    substeps: coarse sub-steps per sample interval [-].
    refine: sub-step factor on intervals whose estimate exceeds ``tolerance`` (1: never).
    tolerance: bound on an interval's summed local error estimate [m].
    radians_per_step: the coarse step as a phase of the fastest mode [rad]; a velocity
        error [m/s] enters the estimate times ``coarse step/radians_per_step`` (1/ω_max
        for a planned step), so that it counts in metres.
    solver: the Runge-Kutta tableau, with or without event location.
    stage_substeps: RK4 steps of an input stage integrated apart, per gap between the
        sub-steps' stage times (:mod:`stickslip_jax.drive_path`; unused without one).
    stage_apart: integrate an input stage apart from the mechanics (default), or
        inside the mechanical step with everything else (then the sub-steps must
        resolve its poles; kept for comparisons).

    Only integers and user settings: a plan does not change with the parameter values
    unless the sub-step count does, so compiled simulations are reused.
    """

    substeps: int = eqx.field(static=True)
    refine: int = eqx.field(static=True, default=DEFAULT_REFINE)
    tolerance: float = eqx.field(static=True, default=DEFAULT_TOLERANCE_M)
    radians_per_step: float = eqx.field(static=True, default=DEFAULT_RADIANS_PER_STEP)
    solver: ExplicitRK = eqx.field(static=True, default=RK4)
    stage_substeps: int = eqx.field(static=True, default=1)
    stage_apart: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        if self.substeps < 1 or self.refine < 1 or self.stage_substeps < 1:
            raise ValueError(f"substeps, refine and stage_substeps must be ≥ 1, got "
                             f"{self.substeps}, {self.refine}, {self.stage_substeps}")

    @property
    def refines(self) -> bool:
        return self.refine > 1

    def doubled(self) -> StepPlan:
        """Twice the sub-steps, same rules (for step-doubling error estimates); an
        input stage's steps halve with the gaps they span."""
        return StepPlan(2 * self.substeps, self.refine, self.tolerance,
                        self.radians_per_step / 2, self.solver, self.stage_substeps,
                        self.stage_apart)


class Stepping(eqx.Module):
    """How to choose the simulator's internal steps (see the module docstring).

    Attributes
    ----------
    max_step: longest coarse step [s]; ``None`` (default): ``radians_per_step/ω_max``
        from the actuator's own time scales (:func:`fastest_rate`).
    substeps: fixed coarse sub-steps per sample instead (overrides ``max_step``): for
        convergence studies, where the step must follow the sample period.
    refine: sub-step factor on intervals whose error estimate exceeds ``tolerance``
        (1 switches refinement off).
    tolerance: bound on an interval's summed local error estimate [m].
    radians_per_step: the coarse step as a phase of the fastest mode [rad].
    solver: Runge-Kutta tableau (default RK4, with event location).
    stage_apart: integrate an input stage apart from the mechanics, at its own step
        (default, :mod:`stickslip_jax.drive_path`); ``False``: inside the mechanical
        step, whose sub-steps then follow the stage's poles too (comparisons).
    """

    max_step: float | None = eqx.field(static=True, default=None)
    substeps: int | None = eqx.field(static=True, default=None)
    refine: int = eqx.field(static=True, default=DEFAULT_REFINE)
    tolerance: float = eqx.field(static=True, default=DEFAULT_TOLERANCE_M)
    radians_per_step: float = eqx.field(static=True, default=DEFAULT_RADIANS_PER_STEP)
    solver: ExplicitRK = eqx.field(static=True, default=RK4)
    stage_apart: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        if self.max_step is not None and not (math.isfinite(self.max_step)
                                              and self.max_step > 0):
            raise ValueError(f"max_step must be a finite time > 0 [s], got {self.max_step!r}")
        if self.substeps is not None and self.substeps < 1:
            raise ValueError(f"substeps must be ≥ 1, got {self.substeps}")
        if self.refine < 1:
            raise ValueError(f"refine must be ≥ 1, got {self.refine}")
        if not self.tolerance > 0:
            raise ValueError(f"tolerance must be > 0 [m], got {self.tolerance!r}")

    @staticmethod
    def uniform(substeps: int, solver: ExplicitRK = RK4) -> Stepping:
        """Exactly ``substeps`` sub-steps per sample, never refined (studies)."""
        return Stepping(substeps=int(substeps), refine=1, solver=solver)

    def longest_step(self, actuator: Actuator) -> float:
        """The longest coarse step [s] for this actuator (its mechanics: an input
        stage is integrated apart at its own step, :meth:`stage_steps`)."""
        return self._longest_step(actuator, self._rates(actuator))

    def stage_steps(self, actuator: Actuator, gap: float) -> int:
        """RK4 steps of the input stage per ``gap`` [s] between stage times: enough
        that each is at most ``radians_per_step`` of the stage's fastest pole. 1 without
        stage states, for a stage advanced in closed form, or for traced values (then
        ``max_step`` should resolve it)."""
        return self._stage_steps(actuator, gap, self._rates(actuator))

    @staticmethod
    def _rates(actuator: Actuator) -> _RestRates | None:
        return _rest_rates(actuator) if _concrete(actuator) else None

    def _longest_step(self, actuator: Actuator, rates: _RestRates | None) -> float:
        rate = None
        if rates is not None:
            rate = rates.mechanical if self.stage_apart else rates.fastest
            if not (math.isfinite(rate) and rate > 0):
                raise SteppingError(
                    "the model's linearisation at rest is not finite; check the "
                    f"parameters ({time_scale_report(actuator)})")
        if self.max_step is not None:
            step = float(self.max_step)
        elif rate is not None:
            if rate > 2 * math.pi * MAX_PLAUSIBLE_MODE_HZ and self.substeps is None:
                raise SteppingError(
                    f"the model's fastest mode is {rate / (2 * math.pi) / 1e6:.3g} MHz, far "
                    f"above any stick-slip actuator's ({time_scale_report(actuator)}): a "
                    "unit slip? (Kp in N/µm read as N/m, Mp in g read as kg.) If it is "
                    "meant, give the step explicitly (Stepping(max_step=...), --max-step).")
            step = self.radians_per_step / rate
        else:
            step = FALLBACK_MAX_STEP_S
        return step

    def _stage_steps(self, actuator: Actuator, gap: float,
                     rates: _RestRates | None) -> int:
        stage = actuator.input_stage
        if (stage.n_states == 0 or not self.stage_apart or has_closed_form(stage)
                or rates is None):
            return 1
        rate = rates.stage
        if not (math.isfinite(rate) and rate >= 0):
            raise SteppingError("the input stage's linearisation at rest is not finite; "
                                "check its parameters")
        steps = max(1, math.ceil(gap * rate / self.radians_per_step * (1 - 1e-12)))
        if steps > MAX_STAGE_STEPS:
            raise SteppingError(
                f"the input stage's pole is at {rate / (2 * math.pi) / 1e6:.3g} MHz: "
                f"{steps} steps between the simulator's stage times (limit "
                f"{MAX_STAGE_STEPS}), far above any drive amplifier's bandwidth: a unit "
                "slip (a time constant in µs read as s)?")
        return steps

    def _too_much_work(self, actuator: Actuator, rates: _RestRates | None, n: int,
                       samples: int, step: float, dt: float) -> str:
        """Why a call of ``samples`` intervals at ``n`` sub-steps each passes
        :data:`MAX_SUBSTEPS_PER_CALL`: too many sub-steps per sample (a short step: the
        model's time scale, where a unit slip is the usual cause, or a step given too
        short), or too many in all (an ordinary step, a job too large)."""
        total = (f"{samples:,} sample intervals × {n} sub-steps = {n * samples:.3g} "
                 f"sub-steps, above the limit of {MAX_SUBSTEPS_PER_CALL:.3g} per call")
        if self.substeps is not None:
            return (f"too many sub-steps in all: {total} ({n} per sample as given). Fix: "
                    "fewer sub-steps per sample, or fewer samples.")
        if self.max_step is not None:
            return (f"too many sub-steps per sample: the given longest step of "
                    f"{step * 1e9:.3g} ns cuts each {dt * 1e6:.3g} µs sample into {n}; "
                    f"{total}. Fix: a longer max_step (or none: the model's own step), or "
                    "fewer samples.")
        rate = None if rates is None else (rates.mechanical if self.stage_apart
                                           else rates.fastest)
        mode_hz = None if rate is None else rate / (2 * math.pi)
        if mode_hz is not None and mode_hz > TYPICAL_MODE_HZ:
            return (f"too many sub-steps per sample: the model's fastest mode is "
                    f"{mode_hz:.3g} Hz ({time_scale_report(actuator)}), so each "
                    f"{dt * 1e6:.3g} µs sample takes {n} sub-steps of {step * 1e9:.3g} ns; "
                    f"{total}. A mode far above {TYPICAL_MODE_HZ / 1e3:g} kHz usually "
                    "means a unit slip (Kp in N/µm read as N/m, Mp in g read as kg); if "
                    "it is meant, simulate fewer samples.")
        # An ordinary time scale: the job itself is too large. A lower sample rate only
        # helps where each sample takes one sub-step (the samples, not the model's step,
        # then set the count).
        rate_hint = (", or a lower sample rate (one sub-step per sample: the samples set "
                     "the work)" if n == 1 else
                     f" (a lower sample rate would not help: the model's {step * 1e9:.3g} "
                     f"ns step sets the work)")
        where = ("" if mode_hz is None else
                 f"; the model's fastest mode, {mode_hz:.3g} Hz, is ordinary")
        return (f"too many sub-steps in all: the job is too large: {total}{where}. Fix: "
                f"simulate fewer samples: fewer rows or grid points, fewer periods, a "
                f"shorter duration{rate_hint}.")

    def plan(self, actuator: Actuator, dt, *, samples: int | None = None) -> StepPlan:
        """The static :class:`StepPlan` for ``actuator`` sampled every ``dt`` [s] (one
        value, or one per row of a batch: the longest sets the sub-step count).

        ``samples``: the sample intervals of the whole call (all rows), to refuse a
        simulation of more than :data:`MAX_SUBSTEPS_PER_CALL` sub-steps up front.
        """
        if not _concrete(dt):
            raise ValueError("dt is traced (inside jit/grad): plan the steps outside, "
                             "stepping=plan_steps(actuator, dt), and pass that StepPlan")
        dt_max = float(np.max(np.asarray(dt, dtype=float)))
        if not (math.isfinite(dt_max) and dt_max > 0):
            raise ValueError(f"dt must be a finite time > 0 [s], got {dt!r}")
        rates = self._rates(actuator)      # one Jacobian at rest for both steps
        step = self._longest_step(actuator, rates)
        if self.substeps is not None:
            n = int(self.substeps)
        else:
            n = max(1, math.ceil(dt_max / step * (1 - 1e-12)))
        if samples is not None and n * samples > MAX_SUBSTEPS_PER_CALL:
            raise SteppingError(self._too_much_work(actuator, rates, n, samples, step,
                                                    dt_max))
        gap = dt_max / n * float(np.max(np.diff(self.solver.stage_times)))
        return StepPlan(n, self.refine, self.tolerance, self.radians_per_step, self.solver,
                        self._stage_steps(actuator, gap, rates), self.stage_apart)


DEFAULT_STEPPING = Stepping()
"""The stepping ``simulate`` and the tools use unless told otherwise."""

REFERENCE_FACTOR = 16

REFERENCE_STEPPING = Stepping(radians_per_step=DEFAULT_RADIANS_PER_STEP / REFERENCE_FACTOR,
                              tolerance=DEFAULT_TOLERANCE_M / 100)
"""For data that will judge a fit (fixtures, tests, benchmarks): every step 16x shorter
than the default's (coarse 0.28 µs, refined 35 ns on the default profile) and a
tolerance 100x tighter, so the data carry no trace of the fit's own discretisation
(no "inverse crime"). About 16 times the default's cost."""


def _hermite_root(s0, d0, s1, d1, iterations: int = 6):
    """Root in [0, 1] of the cubic Hermite interpolant through ``(0, s0)`` and
    ``(1, s1)`` with slopes ``d0``, ``d1`` (per unit of θ), for ``s0·s1 < 0``.

    Starts at the secant root and takes ``iterations`` Newton steps, each clipped into
    [0, 1]: a fixed count (static shapes), and differentiable, so the located time
    carries its dependence on the parameters into the sensitivities. The divisions are
    guarded so that the branch stays finite where it is evaluated but not taken
    (``vmap`` turns the ``cond`` around it into a select).
    """
    den = s0 - s1
    theta = jnp.clip(s0 / jnp.where(den == 0.0, 1.0, den), 0.0, 1.0)

    def newton(_, theta):
        t2 = theta * theta
        t3 = t2 * theta
        value = ((2 * t3 - 3 * t2 + 1) * s0 + (t3 - 2 * t2 + theta) * d0
                 + (3 * t2 - 2 * t3) * s1 + (t3 - t2) * d1)
        slope = ((6 * t2 - 6 * theta) * (s0 - s1) + (3 * t2 - 4 * theta + 1) * d0
                 + (3 * t2 - 2 * theta) * d1)
        return jnp.clip(theta - value / jnp.where(slope == 0.0, 1.0, slope), 0.0, 1.0)

    # A loop, not unrolled: the unrolled steps and their tangents cost XLA seconds to
    # compile inside the simulator's nested control flow.
    return jax.lax.fori_loop(0, iterations, newton, theta)


@custom_vmap
def _any_row(need):
    """``need`` [bool] as it is; under ``vmap``, whether any row needs it (unbatched).

    A ``cond`` whose predicate is batched becomes a select that computes both branches
    for every row, every time. With this predicate the ``cond`` stays a branch, taken
    when some row of the batch needs it; each row then keeps the branch's result only
    where it needs it itself (``jnp.where``), so every row gets exactly what it would get
    alone, and a batch pays a branch only where one of its rows does.
    """
    return need


@_any_row.def_vmap
def _any_row_batched(axis_size, in_batched, need):
    (batched,) = in_batched
    return (jnp.any(need) if batched else need), False


def _branch(need, branch, otherwise):
    """``branch(None)`` where ``need``, else ``otherwise`` (pytrees of equal structure),
    as a ``cond`` that stays a branch under ``vmap`` (see :func:`_any_row`)."""
    taken = jax.lax.cond(_any_row(need), branch, lambda _: otherwise, None)
    return jax.tree.map(lambda t, o: jnp.where(need, t, o), taken, otherwise)


def _relative_velocity(y):
    return y[1] - y[3]


def _interval_integrator(actuator: Actuator, dt, drive, plan: StepPlan):
    """``(y, memory, u_a, du, τ0, span) ↦ (y, memory, estimate)``: the part
    ``[τ0, τ0 + span]`` (fractions of the sample interval of ``dt`` [s], voltage
    ``u_a + du·τ``) in ``plan.substeps`` sub-steps, switches located (if the solver
    says so), with the summed local error estimate [m] (see the module docstring; 0
    for tableaux other than classic RK4). The whole interval and its refined parts go
    through this one function: one copy of the sub-step in the compiled program.
    """
    solver = plan.solver
    n = plan.substeps
    velocity_time = dt / plan.substeps / plan.radians_per_step   # 1/ω_max when planned
    weights = jnp.stack([1.0, velocity_time, 1.0, velocity_time, 1.0])
    # Distinct stage times of the solver (RK4: 0, 1/2, 1) and each stage's column.
    times = solver.stage_times
    column = tuple(times.index(c) for c in solver.c)
    end_column = times.index(1.0)
    grid = jnp.asarray(stage_grid(times, n))
    fast = actuator.stroke_follows_command
    embedded = len(solver.c) == 4 and solver.order == 4
    # An input stage with states is integrated apart, onto the stage times
    # (:mod:`stickslip_jax.drive_path`); the mechanics then take the piezo voltage.
    separate = plan.stage_apart and separate_stage(actuator)
    mechanics = held_mechanics(actuator) if separate else actuator
    if separate:
        points_np, point_index = grid_points(times, n)
        stage_at = stage_slice(actuator)

    def stroke_rows(memory, u):
        return jax.vmap(actuator.hysteresis.output, (None, 0))(
            memory, u.reshape(-1)).reshape(u.shape)

    def run(y, memory, u_a, du, tau0, span):
        h = dt * span / n
        fractions = tau0 + span * grid            # (n, distinct c) stage times
        if fast:
            # The voltage is linear, hence monotone, over the interval, and along a
            # monotone path every play output is clip(p_start, u − r, u + r): the
            # stroke at every stage time follows from the interval's starting memory,
            # in one vectorised evaluation.
            u_stage = u_a + du * fractions
            strokes = stroke_rows(memory, u_stage)
        if separate:
            points = tau0 + span * jnp.asarray(points_np)
            states, volts, rates = stage_table(actuator.input_stage, y[stage_at], u_a, du,
                                               dt, points, plan.stage_substeps)

            def voltage(tau):
                return table_voltage(tau, points, volts, rates)
        else:
            def voltage(tau):
                return u_a + du * tau

        def field_with(u, yy, memory):
            # The vector field at piezo voltage u, the stroke from the memory.
            return mechanics.vector_field(yy, u, mechanics.free_stroke(yy, memory, u), drive)

        def substep(j, state):
            y, memory, k1, total = state

            def field_at(tau, yy):
                return field_with(voltage(tau), yy, memory)

            if fast:
                u_row = jax.lax.dynamic_index_in_dim(u_stage, j, keepdims=False)
                g_row = jax.lax.dynamic_index_in_dim(strokes, j, keepdims=False)

                def on_grid(col, yy):
                    return mechanics.vector_field(yy, u_row[col], g_row[col], drive)
            elif separate:
                at = jnp.asarray(point_index)[j]

                def on_grid(col, yy):
                    return field_with(volts[at[col]], yy, memory)
            else:
                row = jax.lax.dynamic_index_in_dim(fractions, j, keepdims=False)

                def on_grid(col, yy):
                    return field_at(row[col], yy)

            stages = []

            def field(i, yy):
                stages.append(on_grid(column[i], yy))
                return stages[-1]

            y1 = mechanics.project(solver.step(field, y, h, k1), drive)
            k_end = on_grid(end_column, y1)
            err = jnp.zeros_like(y[0])
            if embedded:
                # Classic RK4 against the third-order solution with weights
                # b + (e5 − e4)/6 on its stages plus f(y1): they differ by h/6·(k4 − f(y1)).
                err = jnp.max(jnp.abs(h / 6.0 * (stages[-1][:N_CORE] - k_end[:N_CORE]))
                              * weights)
            if solver.locate_events:
                y1, k_end = _located(mechanics, drive, solver, field_at, y, y1, k1, k_end,
                                     tau0 + span * j / n, span / n, h)
            if separate:
                # The held stage states: from the table, at the sub-step's end.
                y1 = y1.at[stage_at].set(states[at[end_column]])
            if not fast:
                # Committing at the end voltage leaves the stroke there, so k_end stands.
                u_end = (volts[at[end_column]] if separate
                         else voltage(tau0 + span * (j + 1) / n))
                memory = mechanics.commit_memory(y1, memory, u_end)
            # The estimate only decides (a comparison with the tolerance): no tangent.
            # Left differentiable it starts each loop with a zero tangent and gains one,
            # so JAX's forward-mode fixpoint traced every enclosing loop's body twice
            # (the sub-step's eight times) before the zero tangents were dropped.
            return y1, memory, k_end, total + jax.lax.stop_gradient(err)

        k0 = field_with(voltage(tau0), y, memory)
        # Zeros typed like the state (under shard_map a loop carry must keep the state's
        # varying axes).
        zero = jnp.zeros_like(y[0])
        y, memory, _, total = jax.lax.fori_loop(0, n, substep, (y, memory, k0, zero))
        return y, memory, total

    return run


def _crossed(actuator, drive, y, y1, k1, k_end):
    """Which switching functions (:meth:`Actuator.switches`) changed sign from ``y`` to
    ``y1`` where they change the field's form [bool per switch]."""
    g0, _ = actuator.switches(y, k1, drive)
    g1, _ = actuator.switches(y1, k_end, drive)
    changed = g0 * g1 < 0

    def matters(_):
        return changed & (actuator.switch_active(y, drive) | actuator.switch_active(y1, drive))

    return _branch(jnp.any(changed), matters, jnp.zeros_like(changed))


def _located(actuator, drive, solver, field_at, y, y1, k1, k_end, tau0, dtau, h):
    """The sub-step ``y → y1`` as taken, or redone as two steps meeting at the first
    switch it crossed (a slip reversal where the law bends, a break-away strain while
    slipping). Returns the end state and the field there."""
    crossed = _crossed(actuator, drive, y, y1, k1, k_end)

    def split(_):
        g0, r0 = actuator.switches(y, k1, drive)
        g1, r1 = actuator.switches(y1, k_end, drive)
        # One root per switch, unrolled (a vmap of the unrolled Newton steps took XLA
        # a second to compile, six times the rest of the simulator).
        roots = jnp.stack([_hermite_root(g0[i], h * r0[i], g1[i], h * r1[i])
                           for i in range(g0.shape[0])])
        theta = jnp.min(jnp.where(crossed, roots, 1.0))
        shares = jnp.stack([theta, 1.0 - theta])

        def piece(p, state):
            # One Runge-Kutta step over a share of the sub-step (the two pieces share
            # this code: half the program to compile).
            y_start, k_start, t_start = state
            share = shares[p]
            y_stop = actuator.project(solver.step(
                lambda i, yy: field_at(t_start + solver.c[i] * share * dtau, yy),
                y_start, share * h, k_start), drive)
            t_stop = t_start + share * dtau
            return y_stop, field_at(t_stop, y_stop), t_stop

        t0 = tau0 + jnp.zeros_like(theta)   # typed like θ (varying axes under shard_map)
        y_stop, k_stop, _ = jax.lax.fori_loop(0, 2, piece, (y, k1, t0))
        return y_stop, k_stop

    return _branch(jnp.any(crossed), split, (y1, k_end))


def sample_stepper(actuator: Actuator, dt, drive, plan: StepPlan, *,
                   checkpoint: bool = True):
    """The scan body over one sample interval: ``((y, memory), (u_a, u_b)) ↦
    ((y, memory), q_b)`` with the voltage linear from ``u_a`` to ``u_b`` [V] over
    ``dt`` [s] and ``q_b`` [m] the output at its end (before the output map).

    Pass 0 takes the interval in ``plan.substeps`` sub-steps with error estimates.
    With refinement (``plan.refine = r > 1``), where their sum exceeds
    ``plan.tolerance``, passes 1..r take the interval again as r parts of
    ``plan.substeps`` sub-steps each; otherwise they are skipped (a ``cond``: only those
    intervals pay; under ``vmap`` a batch pays a pass where one of its rows needs it,
    :func:`_branch`). All passes run the same integrator, so it is compiled once.

    ``checkpoint``: the body under ``jax.checkpoint``, so that reverse mode through the
    sample loop keeps one carry per sample and recomputes the interval's inside. A
    caller that never takes reverse mode through it (the forward-mode programs of
    :mod:`~.identify.sensitivities`) passes False: the same arithmetic (identify's
    parameters equal to the bit), without tracing and lowering the remat (cold
    ``stickslip identify`` on the fixtures 31.7 → 28.0 s, medians of three,
    ``benchmarks/experiments/bench_identify_checkouts.py``).
    """
    run = _interval_integrator(actuator, dt, drive, plan)
    r = plan.refine

    def sample_step(carry, u_pair):
        y, memory = carry
        u_a, u_b = u_pair
        du = u_b - u_a
        if r == 1:
            y1, memory1, _ = run(y, memory, u_a, du, 0.0, 1.0)
        else:
            def one_pass(p, state):
                # state: pass 0's result and estimate, and the refined run so far.
                y_c, mem_c, est, y_r, mem_r = state
                first = p == 0

                def go(_):
                    y_in = jnp.where(first, y, y_r)
                    mem_in = jnp.where(first, memory, mem_r)
                    tau0 = jnp.where(first, 0.0, (p - 1) / r)
                    span = jnp.where(first, 1.0, 1.0 / r)
                    y_out, mem_out, e = run(y_in, mem_in, u_a, du, tau0, span)
                    return (jnp.where(first, y_out, y_c), jnp.where(first, mem_out, mem_c),
                            jnp.where(first, e, est), jnp.where(first, y, y_out),
                            jnp.where(first, memory, mem_out))

                return _branch(first | (est > plan.tolerance), go, state)

            zero = jnp.zeros_like(y[0])
            y_c, mem_c, est, y_r, mem_r = jax.lax.fori_loop(
                0, r + 1, one_pass, (y, memory, zero, y, memory))
            refined = est > plan.tolerance
            y1 = jnp.where(refined, y_r, y_c)
            memory1 = jnp.where(refined, mem_r, mem_c)
        if actuator.stroke_follows_command:
            memory1 = actuator.commit_memory(y1, memory, u_b)
        q = actuator.output(y1, u_b, actuator.free_stroke(y1, memory1, u_b), drive)
        return (y1, memory1), q

    return jax.checkpoint(sample_step) if checkpoint else sample_step

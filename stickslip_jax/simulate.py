"""Fixed-step simulation of an :class:`Actuator` driven by a sampled voltage.

One ``lax.scan`` over sample intervals; inside each interval Runge-Kutta sub-steps in
a ``fori_loop`` (not unrolled: unrolling multiplies compile time), with a step size in
seconds, located slip reversals and refined intervals (:mod:`stickslip_jax.stepping`).
The per-sample step is wrapped in ``jax.checkpoint`` so that a reverse-mode gradient
stores one carry per sample and recomputes the sub-steps, keeping memory linear in
the trace length with a small constant.

Works under ``jit``, ``vmap``, ``jacfwd``/``jvp`` and ``grad``. Several recordings
go through one batched scan with :func:`simulate_batch` (pad to a common length).

The sub-step count is static: it is planned (:meth:`Stepping.plan`) from concrete
parameter values at the call. Called with traced parameters (inside a user's ``jit``
or ``grad``), the plan falls back to ``Stepping.max_step`` or
:data:`~stickslip_jax.stepping.FALLBACK_MAX_STEP_S`; pass ``stepping=`` a
:class:`Stepping` with ``max_step`` (or a :class:`StepPlan` made outside) to get the
same steps inside and outside.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .adjoint import DEFAULT_ADJOINT, AbstractAdjoint
from .model.actuator import Actuator
from .model.base import DriveContext
from .program_store import stored_jit
from .solvers import ExplicitRK
from .stepping import (
    DEFAULT_STEPPING,
    Stepping,
    StepPlan,
    mechanical_rate,
    sample_stepper,
    time_scale_report,
)

RK4_STABLE_PHASE = 2.78
"""Largest ``h·|λ|`` [rad] at which classic RK4 stays stable for an undamped mode
(its stability region reaches 2√2 ≈ 2.83 on the imaginary axis)."""

__all__ = [
    "NonFiniteSimulation", "Trajectory", "check_finite", "estimate_error", "plan_steps",
    "simulate", "simulate_batch", "simulate_recording", "simulate_recordings",
    "simulate_states",
]


class NonFiniteSimulation(ValueError):
    """A simulated trace that went non-finite (NaN or ±inf)."""


def plan_steps(actuator: Actuator, dt, *, stepping: Stepping | StepPlan | None = None,
               substeps: int | None = None, solver: ExplicitRK | None = None,
               samples: int | None = None) -> StepPlan:
    """The static :class:`StepPlan` for a call: ``stepping`` (default
    :data:`~stickslip_jax.stepping.DEFAULT_STEPPING`) planned for ``actuator`` at
    sample period(s) ``dt`` [s]. ``substeps``: exactly that many sub-steps per sample,
    never refined (convergence studies; overrides ``stepping``). ``solver`` replaces the
    stepping's tableau. A :class:`StepPlan` is used as given."""
    if isinstance(stepping, StepPlan):
        return stepping
    stepping = DEFAULT_STEPPING if stepping is None else stepping
    if substeps is not None:
        stepping = Stepping.uniform(substeps, stepping.solver)
    if solver is not None:
        stepping = dataclasses.replace(stepping, solver=solver)
    return stepping.plan(actuator, dt, samples=samples)


def check_finite(q, actuator: Actuator, plan: StepPlan, dt, what: str = "the simulated trace"):
    """``q`` unchanged, or :class:`NonFiniteSimulation` saying where it went non-finite
    and what to check. Only for concrete arrays (skipped for tracers)."""
    if isinstance(q, jax.core.Tracer):
        return q
    arr = np.asarray(q)
    if arr.size and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        where = f"sample {int(bad[-1])}" + (f" of row {int(bad[0])}" if arr.ndim > 1 else "")
        h = float(np.max(np.asarray(dt))) / plan.substeps
        cause = ("A natural frequency far above 100 kHz, or a negative mass, stiffness or "
                 "damping, usually means a unit slip.")
        try:
            rate = mechanical_rate(actuator)
        except Exception:  # noqa: BLE001 - the report must not fail where the model did
            rate = None
        if rate is not None and h * rate > RK4_STABLE_PHASE:
            cause = (f"The sub-step is {h * 1e6:.3g} µs, longer than RK4 can follow the "
                     f"model's fastest mode ({rate / (2 * np.pi):.3g} Hz needs at most "
                     f"{RK4_STABLE_PHASE / rate * 1e6:.3g} µs): use the automatic stepping "
                     "(no substeps) or a shorter max_step. " + cause)
        raise NonFiniteSimulation(
            f"{what} went non-finite at {where} (sub-step {h * 1e9:.3g} ns, "
            f"{plan.substeps} per sample). {cause} Parameters: {time_scale_report(actuator)}.")
    return q


def rest_carry(actuator: Actuator, u0, drive):
    """Scan carry ``(y, memory)`` at rest under voltage ``u0`` [V], and its output q [m]."""
    y0, m0 = actuator.initial_state(u0, drive)
    return (y0, m0), actuator.output(y0, u0, actuator.free_stroke(y0, m0, u0), drive)


def _scan(actuator: Actuator, voltage, dt, drive, plan: StepPlan, *, keep_states: bool = False):
    """Unmapped model output q [m] at every sample of ``voltage`` [V] (length T), and
    with ``keep_states`` also the integrated state at every sample, (T, n_states)."""
    carry, q0 = rest_carry(actuator, voltage[0], drive)
    step = sample_stepper(actuator, dt, drive, plan)

    def body(c, u_pair):
        c, q = step(c, u_pair)
        return c, ((c[0], q) if keep_states else q)

    _, out = jax.lax.scan(body, carry, (voltage[:-1], voltage[1:]))
    if not keep_states:
        return jnp.concatenate([q0[None], out])
    ys, qs = out
    return jnp.concatenate([carry[0][None], ys]), jnp.concatenate([q0[None], qs])


def model_output(actuator: Actuator, voltage, dt, drive, plan: StepPlan):
    """Unmapped model output q [m] at every sample of ``voltage`` [V] (length T)."""
    return _scan(actuator, voltage, dt, drive, plan)


def _checked(voltage, drive) -> tuple[jax.Array, DriveContext]:
    """The voltage as a float64 1-D array of ≥ 2 samples, and the drive (default forward)."""
    voltage = jnp.asarray(voltage, dtype=float)
    if voltage.ndim != 1 or voltage.shape[0] < 2:
        raise ValueError(f"voltage must be a 1-D array of at least 2 samples, got {voltage.shape}")
    return voltage, DriveContext.make() if drive is None else drive


@stored_jit
def _simulate(actuator, voltage, dt, drive, plan, adjoint=DEFAULT_ADJOINT):
    # Everything differentiable is one explicit argument of the adjoint's wrapper
    # (no closed-over tracers), so its derivative rule sees which inputs are perturbed.
    dynamic, static = eqx.partition((actuator, dt, drive), eqx.is_inexact_array)

    def run(dynamic, voltage):
        actuator, dt, drive = eqx.combine(dynamic, static)
        q = model_output(actuator, voltage, dt, drive, plan)
        t = dt * jnp.arange(voltage.shape[0])
        return actuator.output_map(t, q)

    return adjoint.wrap(run)(dynamic, voltage)


def simulate(
    actuator: Actuator,
    voltage: Float[Array, " T"],
    *,
    dt: float,
    drive: DriveContext | None = None,
    stepping: Stepping | StepPlan | None = None,
    substeps: int | None = None,
    solver: ExplicitRK | None = None,
    adjoint: AbstractAdjoint = DEFAULT_ADJOINT,
) -> Float[Array, " T"]:
    """Output q [m] of ``actuator`` for a voltage [V] sampled every ``dt`` [s].

    The actuator starts at rest under ``voltage[0]``; between samples the voltage is
    linear (first-order hold). ``q[0]`` is the rest output. ``drive`` selects
    direction-dependent parameters (default: forward). ``stepping`` chooses the
    internal steps (default: from the model's time scales, located slip reversals,
    refined intervals; :mod:`stickslip_jax.stepping`); ``substeps`` fixes the sub-steps
    per sample instead (studies). ``adjoint`` chooses how derivatives go through the
    simulation (:mod:`stickslip_jax.adjoint`): the default ``ForwardSensitivities()``
    gives ``jax.grad`` over up to 128 parameters from forward sensitivities;
    ``CheckpointedScan()`` is plain reverse mode through the scan.

    Raises :class:`NonFiniteSimulation` (when the result is concrete) if the trace
    goes non-finite, and :class:`~stickslip_jax.stepping.SteppingError` when the model's
    time scales would need an unreasonable number of sub-steps.
    """
    voltage, drive = _checked(voltage, drive)
    plan = plan_steps(actuator, dt, stepping=stepping, substeps=substeps, solver=solver,
                      samples=voltage.shape[0] - 1)
    q = _simulate(actuator, voltage, jnp.asarray(dt, dtype=float), drive, plan, adjoint)
    return check_finite(q, actuator, plan, dt)


def estimate_error(
    actuator: Actuator,
    voltage: Float[Array, " T"],
    *,
    dt: float,
    drive: DriveContext | None = None,
    stepping: Stepping | StepPlan | None = None,
) -> float:
    """A-posteriori estimate of how far ``simulate`` at this stepping is from the
    converged trace: RMS over the samples, offset removed [m].

    Step doubling: the trace again with twice the coarse sub-steps (same refinement
    rule); for a fourth-order method the error of the coarser trace is 16/15 of their
    difference. Costs about two more simulations.
    """
    voltage, drive = _checked(voltage, drive)
    plan = plan_steps(actuator, dt, stepping=stepping, samples=voltage.shape[0] - 1)
    dt_arr = jnp.asarray(dt, dtype=float)
    q1 = np.asarray(_simulate(actuator, voltage, dt_arr, drive, plan))
    q2 = np.asarray(_simulate(actuator, voltage, dt_arr, drive, plan.doubled()))
    d = q1 - q2
    d = d - d.mean()
    return float(np.sqrt(np.mean(d * d)) * 16.0 / 15.0)


class Trajectory(eqx.Module):
    """Per-sample states of one simulation (arrays of length T).

    Attributes
    ----------
    t: time [s]; x1, v1: piezo tip position [m] and velocity [m/s]; x2, v2: slider
    position [m] and velocity [m/s]; z: friction bristle strain [m]; friction: the
    contact force Ff [N] on the slider (positive drags it forward); q: the mapped
    output [m]; y: the whole integrated state, (T, n_states).
    """

    t: Float[Array, " T"]
    x1: Float[Array, " T"]
    v1: Float[Array, " T"]
    x2: Float[Array, " T"]
    v2: Float[Array, " T"]
    z: Float[Array, " T"]
    friction: Float[Array, " T"]
    q: Float[Array, " T"]
    y: Float[Array, "T N"]


@stored_jit
def _trajectory(actuator, voltage, dt, drive, plan):
    ys, q = _scan(actuator, voltage, dt, drive, plan, keep_states=True)
    t = dt * jnp.arange(voltage.shape[0])
    xdot = ys[:, 1] - ys[:, 3]
    z = ys[:, 4]
    zdot = jax.vmap(lambda zz, xd: actuator.friction.z_rate(zz, xd, drive))(z, xdot)
    ff = jax.vmap(lambda zz, zd, xd: actuator.friction.force(zz, zd, xd, drive))(z, zdot, xdot)
    return Trajectory(t, ys[:, 0], ys[:, 1], ys[:, 2], ys[:, 3], z, ff,
                      actuator.output_map(t, q), ys)


def simulate_states(
    actuator: Actuator,
    voltage: Float[Array, " T"],
    *,
    dt: float,
    drive: DriveContext | None = None,
    stepping: Stepping | StepPlan | None = None,
    substeps: int | None = None,
    solver: ExplicitRK | None = None,
) -> Trajectory:
    """Like :func:`simulate` but keeps every state at every sample (a :class:`Trajectory`).

    For looking inside the model (the friction state z and force Ff through a
    sawtooth period, the slider and piezo separately); ``simulate`` is leaner.
    """
    voltage, drive = _checked(voltage, drive)
    plan = plan_steps(actuator, dt, stepping=stepping, substeps=substeps, solver=solver,
                      samples=voltage.shape[0] - 1)
    tr = _trajectory(actuator, voltage, jnp.asarray(dt, dtype=float), drive, plan)
    check_finite(tr.q, actuator, plan, dt)
    return tr


def default_batching() -> str:
    """How :func:`simulate_batch` runs its rows by default.

    ``"map"`` (one row after the other, ``jax.lax.map``) on a CPU: each row is one tight
    scalar loop whose refinement and event ``cond``s run only where needed; under
    ``vmap`` they become selects and every interval of every row pays every branch
    (measured on 17 rows of a 0.2 s trace: vmapped 18x the cost of the stepping before
    event location, mapped 0.74x; with XLA's native small loops mapped also wins).
    ``"vmap"`` on an accelerator, where the rows run in parallel.
    """
    if jax.default_backend() == "cpu":
        return "map"
    return "vmap"


def checked_batching(batching: str | None) -> str:
    """``batching`` ("map" or "vmap"), or :func:`default_batching` for None."""
    batching = default_batching() if batching is None else batching
    if batching not in ("map", "vmap"):
        raise ValueError(f"batching must be 'map' or 'vmap', got {batching!r}")
    return batching


def over_rows(fn, rows, batching: str):
    """``fn(*row)`` for every row of the pytree ``rows`` (leading axis), stacked:
    one vmapped call (``"vmap"``) or the rows one after the other (``"map"``)."""
    if batching == "vmap":
        return jax.vmap(fn)(*rows)
    return jax.lax.map(lambda row: fn(*row), rows)


@stored_jit
def _simulate_batch(actuator, voltages, dts, drives, plan, adjoint, batching):
    return over_rows(lambda v, dt, d: _simulate(actuator, v, dt, d, plan, adjoint),
                     (voltages, dts, drives), batching)


def simulate_batch(
    actuator: Actuator,
    voltages: Float[Array, "B T"],
    *,
    dt: Float[Array, " B"] | float,
    drives: DriveContext | None = None,
    stepping: Stepping | StepPlan | None = None,
    substeps: int | None = None,
    solver: ExplicitRK | None = None,
    adjoint: AbstractAdjoint = DEFAULT_ADJOINT,
    batching: str | None = None,
) -> Float[Array, "B T"]:
    """Simulate B voltages of common length T in one compiled call (``adjoint`` as in
    :func:`simulate`).

    ``batching``: ``"vmap"`` (one batched scan) or ``"map"`` (the rows one after the
    other in one program); default :func:`default_batching`. Same numbers either way.

    ``stepping``/``substeps``/``solver`` as in :func:`simulate`; one plan serves all
    rows, its sub-step count set by the longest ``dt``.

    ``dt`` [s] is one value or one per row; ``drives`` is a DriveContext whose fields
    have shape (B,) (see :func:`stack_drives`). Shorter recordings should be padded
    by repeating their last voltage sample; the padded tail of the output is simply
    ignored (the state before it is unaffected: the scan is causal).
    """
    batching = checked_batching(batching)
    voltages = jnp.asarray(voltages, dtype=float)
    if voltages.ndim != 2 or voltages.shape[1] < 2:
        raise ValueError(f"voltages must be a (B, T) array with T ≥ 2, got {voltages.shape}")
    b = voltages.shape[0]
    dts = jnp.broadcast_to(jnp.asarray(dt, dtype=float), (b,))
    if drives is None:
        drives = stack_drives([DriveContext.make()] * b)
    plan = plan_steps(actuator, dts, stepping=stepping, substeps=substeps,
                      solver=solver, samples=b * (voltages.shape[1] - 1))
    q = _simulate_batch(actuator, voltages, dts, drives, plan, adjoint, batching)
    return check_finite(q, actuator, plan, dts)


def stack_drives(drives) -> DriveContext:
    """Stack single :class:`DriveContext` objects into one with (B,) fields."""
    return jax.tree.map(lambda *xs: jnp.stack(xs), *drives)


def pad_voltages(voltages) -> tuple[np.ndarray, np.ndarray]:
    """Pad 1-D voltage arrays to a common length with their last value.

    Returns the (B, T) array and the original lengths.
    """
    lengths = np.array([len(v) for v in voltages])
    t_max = int(lengths.max())
    out = np.empty((len(voltages), t_max))
    for i, v in enumerate(voltages):
        out[i, : len(v)] = v
        out[i, len(v) :] = v[-1]
    return out, lengths


def drive_context(recording) -> DriveContext:
    """The :class:`DriveContext` of a :class:`~stickslip_jax.io.Recording`.

    Direction from its metadata or inferred from its voltage; recordings without a
    direction (step, sine) count as forward (docs/model.md).
    """
    info = recording.drive
    return DriveContext.make(
        backward=info.is_backward,
        amplitude=info.amplitude_V or 0.0,
        frequency=info.frequency_Hz or 0.0,
    )


def simulate_recording(actuator: Actuator, recording, *,
                       stepping: Stepping | StepPlan | None = None,
                       substeps: int | None = None) -> np.ndarray:
    """Model output q [m] for a recording's voltage, on its own time grid."""
    q = simulate(actuator, recording.voltage_V, dt=recording.dt,
                 drive=drive_context(recording), stepping=stepping, substeps=substeps)
    return np.asarray(q)


def simulate_recordings(actuator: Actuator, recordings, *,
                        stepping: Stepping | StepPlan | None = None,
                        substeps: int | None = None) -> list[np.ndarray]:
    """Model outputs q [m] of several recordings, simulated in one batched scan."""
    recordings = list(recordings)
    voltages, lengths = pad_voltages([r.voltage_V for r in recordings])
    q = simulate_batch(
        actuator, voltages, dt=np.array([r.dt for r in recordings]),
        drives=stack_drives([drive_context(r) for r in recordings]),
        stepping=stepping, substeps=substeps,
    )
    q = np.asarray(q)
    return [q[i, :n] for i, n in enumerate(lengths)]

"""Fixed-step simulation of an :class:`Actuator` driven by a sampled voltage.

One ``lax.scan`` over sample intervals; inside each interval ``substeps`` Runge-Kutta
sub-steps in a ``fori_loop`` (not unrolled: unrolling multiplies compile time). The
per-sample step is wrapped in ``jax.checkpoint`` so that a reverse-mode gradient
stores one carry per sample and recomputes the sub-steps, keeping memory linear in
the trace length with a small constant.

Works under ``jit``, ``vmap``, ``jacfwd``/``jvp`` and ``grad``. Several recordings
go through one batched scan with :func:`simulate_batch` (pad to a common length).
"""

from __future__ import annotations

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .adjoint import DEFAULT_ADJOINT, AbstractAdjoint
from .model.actuator import Actuator
from .model.base import DriveContext
from .solvers import RK4, ExplicitRK
from .xla_flags import native_loops_requested

DEFAULT_SUBSTEPS = 16
"""Default RK4 sub-steps per sample period (chosen by tests/test_convergence.py)."""


def rest_carry(actuator: Actuator, u0, drive):
    """Scan carry ``(y, memory)`` at rest under voltage ``u0`` [V], and its output q [m]."""
    y0, m0 = actuator.initial_state(u0, drive)
    return (y0, m0), actuator.output(y0, u0, actuator.free_stroke(y0, m0, u0), drive)


def sample_stepper(actuator: Actuator, dt, drive, substeps: int, solver: ExplicitRK):
    """The scan body over one sample interval: ``((y, memory), (u_a, u_b)) ↦
    ((y, memory), q_b)`` with the voltage linear from ``u_a`` to ``u_b`` [V] over
    ``dt`` [s] and ``q_b`` [m] the output at its end (before the output map)."""
    h = dt / substeps
    # Distinct stage times of the solver (RK4: 0, 1/2, 1) and each stage's column.
    c_unique = tuple(sorted(set(solver.c)))
    column = tuple(c_unique.index(c) for c in solver.c)
    # Stage times as fractions of one sample interval, shape (substeps, distinct c).
    fractions = jnp.asarray(
        (np.arange(substeps)[:, None] + np.asarray(c_unique)[None, :]) / substeps
    )

    def interval_fast(y, memory, u_a, du):
        # The voltage is linear, hence monotone, over the interval, and along a
        # monotone path every play output is clip(p_start, u - r, u + r): the
        # stroke at every stage time comes from one vectorised evaluation and
        # equals what per-sub-step commits would give, at a fraction of the cost.
        u_stage = u_a + du * fractions
        strokes = jax.vmap(actuator.hysteresis.output, (None, 0))(
            memory, u_stage.reshape(-1)
        ).reshape(u_stage.shape)

        def substep(j, y):
            u_row = jax.lax.dynamic_index_in_dim(u_stage, j, keepdims=False)
            g_row = jax.lax.dynamic_index_in_dim(strokes, j, keepdims=False)

            def field(i, yy):
                return actuator.vector_field(yy, u_row[column[i]], g_row[column[i]], drive)

            return actuator.project(solver.step(field, y, h), drive)

        return jax.lax.fori_loop(0, substeps, substep, y)

    def interval_general(y, memory, u_a, du):
        # The piezo voltage depends on input-stage states: evaluate the hysteresis
        # at every stage with the memory of the sub-step start, commit at its end.
        def substep(j, state):
            y, memory = state

            def field(i, yy):
                u = u_a + du * fractions[j, column[i]]
                return actuator.vector_field(yy, u, actuator.free_stroke(yy, memory, u), drive)

            y = solver.step(field, y, h)
            memory = actuator.commit_memory(y, memory, u_a + du * (j + 1) / substeps)
            return actuator.project(y, drive), memory

        return jax.lax.fori_loop(0, substeps, substep, (y, memory))

    @jax.checkpoint
    def sample_step(carry, u_pair):
        y, memory = carry
        u_a, u_b = u_pair
        if actuator.stroke_follows_command:
            y = interval_fast(y, memory, u_a, u_b - u_a)
            memory = actuator.commit_memory(y, memory, u_b)
        else:
            y, memory = interval_general(y, memory, u_a, u_b - u_a)
        q = actuator.output(y, u_b, actuator.free_stroke(y, memory, u_b), drive)
        return (y, memory), q

    return sample_step


def _scan(actuator: Actuator, voltage, dt, drive, substeps: int, solver: ExplicitRK, *,
          keep_states: bool = False):
    """Unmapped model output q [m] at every sample of ``voltage`` [V] (length T), and
    with ``keep_states`` also the integrated state at every sample, (T, n_states)."""
    carry, q0 = rest_carry(actuator, voltage[0], drive)
    step = sample_stepper(actuator, dt, drive, substeps, solver)

    def body(c, u_pair):
        c, q = step(c, u_pair)
        return c, ((c[0], q) if keep_states else q)

    _, out = jax.lax.scan(body, carry, (voltage[:-1], voltage[1:]))
    if not keep_states:
        return jnp.concatenate([q0[None], out])
    ys, qs = out
    return jnp.concatenate([carry[0][None], ys]), jnp.concatenate([q0[None], qs])


def _model_output(actuator: Actuator, voltage, dt, drive, substeps: int, solver: ExplicitRK):
    """Unmapped model output q [m] at every sample of ``voltage`` [V] (length T)."""
    return _scan(actuator, voltage, dt, drive, substeps, solver)


def _checked(voltage, drive) -> tuple[jax.Array, DriveContext]:
    """The voltage as a float64 1-D array of ≥ 2 samples, and the drive (default forward)."""
    voltage = jnp.asarray(voltage, dtype=float)
    if voltage.ndim != 1 or voltage.shape[0] < 2:
        raise ValueError(f"voltage must be a 1-D array of at least 2 samples, got {voltage.shape}")
    return voltage, DriveContext.make() if drive is None else drive


@partial(eqx.filter_jit)
def _simulate(actuator, voltage, dt, drive, substeps, solver, adjoint=DEFAULT_ADJOINT):
    # Everything differentiable is one explicit argument of the adjoint's wrapper
    # (no closed-over tracers), so its derivative rule sees which inputs are perturbed.
    dynamic, static = eqx.partition((actuator, dt, drive), eqx.is_inexact_array)

    def run(dynamic, voltage):
        actuator, dt, drive = eqx.combine(dynamic, static)
        q = _model_output(actuator, voltage, dt, drive, substeps, solver)
        t = dt * jnp.arange(voltage.shape[0])
        return actuator.output_map(t, q)

    return adjoint.wrap(run)(dynamic, voltage)


def simulate(
    actuator: Actuator,
    voltage: Float[Array, " T"],
    *,
    dt: float,
    drive: DriveContext | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    solver: ExplicitRK = RK4,
    adjoint: AbstractAdjoint = DEFAULT_ADJOINT,
) -> Float[Array, " T"]:
    """Output q [m] of ``actuator`` for a voltage [V] sampled every ``dt`` [s].

    The actuator starts at rest under ``voltage[0]``; between samples the voltage is
    linear (first-order hold). ``q[0]`` is the rest output. ``drive`` selects
    direction-dependent parameters (default: forward). ``adjoint`` chooses how
    derivatives go through the simulation (:mod:`stickslip_jax.adjoint`): the default
    ``ForwardSensitivities()`` gives ``jax.grad`` over a few parameters from forward
    sensitivities (about 3x cheaper than reverse mode); ``CheckpointedScan()`` is plain
    reverse mode through the scan.
    """
    voltage, drive = _checked(voltage, drive)
    return _simulate(actuator, voltage, jnp.asarray(dt, dtype=float), drive, substeps, solver,
                     adjoint)


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


@partial(eqx.filter_jit)
def _trajectory(actuator, voltage, dt, drive, substeps, solver):
    ys, q = _scan(actuator, voltage, dt, drive, substeps, solver, keep_states=True)
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
    substeps: int = DEFAULT_SUBSTEPS,
    solver: ExplicitRK = RK4,
) -> Trajectory:
    """Like :func:`simulate` but keeps every state at every sample (a :class:`Trajectory`).

    For looking inside the model (the friction state z and force Ff through a
    sawtooth period, the slider and piezo separately); ``simulate`` is leaner.
    """
    voltage, drive = _checked(voltage, drive)
    return _trajectory(actuator, voltage, jnp.asarray(dt, dtype=float), drive, substeps, solver)


def default_batching() -> str:
    """How :func:`simulate_batch` runs its rows by default.

    ``"map"`` (one row after the other, ``jax.lax.map``) on a CPU whose small loops XLA
    compiles natively (:func:`~stickslip_jax.xla_flags.fast_cpu_loops`): each row is
    then one tight scalar loop, where ``vmap`` would make every operation a short
    vector operation (measured, 17 rows of a 1 s trace: 46 ms per row mapped against
    77 ms vmapped). ``"vmap"`` otherwise: on an accelerator the rows run in parallel,
    and with XLA's default CPU loops a vmapped row costs less than a mapped one
    (94 against 150 ms).
    """
    if jax.default_backend() == "cpu" and native_loops_requested():
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


@partial(eqx.filter_jit)
def _simulate_batch(actuator, voltages, dts, drives, substeps, solver, adjoint, batching):
    return over_rows(lambda v, dt, d: _simulate(actuator, v, dt, d, substeps, solver, adjoint),
                     (voltages, dts, drives), batching)


def simulate_batch(
    actuator: Actuator,
    voltages: Float[Array, "B T"],
    *,
    dt: Float[Array, " B"] | float,
    drives: DriveContext | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    solver: ExplicitRK = RK4,
    adjoint: AbstractAdjoint = DEFAULT_ADJOINT,
    batching: str | None = None,
) -> Float[Array, "B T"]:
    """Simulate B voltages of common length T in one compiled call (``adjoint`` as in
    :func:`simulate`).

    ``batching``: ``"vmap"`` (one batched scan) or ``"map"`` (the rows one after the
    other in one program); default :func:`default_batching`. Same numbers either way.

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
    return _simulate_batch(actuator, voltages, dts, drives, substeps, solver, adjoint,
                           batching)


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
    direction (step, sine) count as forward (MODEL.md).
    """
    info = recording.drive
    return DriveContext.make(
        backward=info.is_backward,
        amplitude=info.amplitude_V or 0.0,
        frequency=info.frequency_Hz or 0.0,
    )


def simulate_recording(actuator: Actuator, recording, *, substeps: int = DEFAULT_SUBSTEPS,
                       solver: ExplicitRK = RK4) -> np.ndarray:
    """Model output q [m] for a recording's voltage, on its own time grid."""
    q = simulate(actuator, recording.voltage_V, dt=recording.dt,
                 drive=drive_context(recording), substeps=substeps, solver=solver)
    return np.asarray(q)


def simulate_recordings(actuator: Actuator, recordings, *, substeps: int = DEFAULT_SUBSTEPS,
                        solver: ExplicitRK = RK4) -> list[np.ndarray]:
    """Model outputs q [m] of several recordings, simulated in one batched scan."""
    recordings = list(recordings)
    voltages, lengths = pad_voltages([r.voltage_V for r in recordings])
    q = simulate_batch(
        actuator, voltages, dt=np.array([r.dt for r in recordings]),
        drives=stack_drives([drive_context(r) for r in recordings]),
        substeps=substeps, solver=solver,
    )
    q = np.asarray(q)
    return [q[i, :n] for i, n in enumerate(lengths)]

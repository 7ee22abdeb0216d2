"""Batched simulation of many sawtooth drives: slots, segments, devices.

Grid points differ in length (10 periods at 50 Hz are 20x longer than at 1000 Hz),
so one padded scan would spend most of its work on padding, and a scan per length
would compile once per frequency. Instead a fixed number of *slots* (``chunk``) run
side by side through one compiled, vmapped scan of ``segment`` samples; the host
carries the state from segment to segment and, when a point has all its samples,
puts the next point of the grid into its slot (state reset to rest). Every call has
the same shapes, so it compiles once; the work is the grid's total sample count
plus at most one segment per point; memory is bounded by ``chunk`` whatever the grid.

The slots are sharded over all JAX devices (``jax.sharding``): the same code uses
every GPU of a machine, or the CPU devices made by
``XLA_FLAGS=--xla_force_host_platform_device_count=N``.

The drive voltage of each slot is made on the host with exactly the formula of
:func:`stickslip_jax.signals.sawtooth`, so a sweep point equals ``simulate`` of that
signal. The sweep output is the model output q = x1 + x2 before any output map
(sensor effects are not actuator behaviour).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ..model.actuator import Actuator
from ..model.base import DriveContext
from ..signals import DEFAULT_SAMPLE_RATE_HZ
from ..simulate import check_finite, default_batching, over_rows, plan_steps, rest_carry
from ..stepping import Stepping, StepPlan, sample_stepper
from .grid import DriveGrid


def sawtooth_samples(amplitude, frequency, backward, k, sample_rate_Hz) -> np.ndarray:
    """Sawtooth voltage [V] at integer sample indices ``k`` (rows: points), the
    formula of :func:`stickslip_jax.signals.sawtooth` broadcast over points."""
    amplitude = np.asarray(amplitude, float)[:, None]
    ramp = amplitude * (np.mod(k * np.asarray(frequency, float)[:, None], sample_rate_Hz)
                        / sample_rate_Hz)
    return np.where(np.asarray(backward)[:, None], amplitude - ramp, ramp)


def samples_needed(frequency_Hz, periods: int, sample_rate_Hz: float) -> np.ndarray:
    """Samples (from t = 0) that cover ``periods`` whole periods [-]."""
    return np.ceil(periods * sample_rate_Hz / np.asarray(frequency_Hz, float) - 1e-9
                   ).astype(int) + 1


def auto_chunk(need, n_devices: int = 1, *, limit: int | None = None,
               cap: int = 256) -> int:
    """Slots for a grid whose points need ``need`` samples each [-].

    With C slots the run lasts at least the longest point, and at least the total
    work over C; C = total / longest balances the two (more slots would idle while
    the longest point finishes). At least one slot per device, at most ``cap`` (or
    ``limit``), a multiple of the device count.
    """
    need = np.asarray(need)
    c = int(np.ceil(need.sum() / need.max()))
    c = max(1, min(c, int(limit) if limit is not None else cap, need.size))
    return -(-c // n_devices) * n_devices


@eqx.filter_jit
def _rest(actuator, u0, drives):
    return jax.vmap(lambda u, d: rest_carry(actuator, u, d))(u0, drives)


@eqx.filter_jit
def _segment(actuator, carry, volts, dt, drives, plan, mesh=None):
    """One segment of every slot. With ``mesh`` (CPU, native loops) each device runs its
    own slots one after the other (``lax.map`` inside ``shard_map``), else one vmapped
    scan over all slots (:func:`~stickslip_jax.simulate.default_batching` says why)."""

    def one(c, v, d):
        step = sample_stepper(actuator, dt, d, plan)
        return jax.lax.scan(step, c, (v[:-1], v[1:]))

    if mesh is None:
        return over_rows(one, (carry, volts, drives), "vmap")
    spec = PartitionSpec("points")
    return jax.shard_map(lambda *rows: over_rows(one, rows, "map"), mesh=mesh,
                         in_specs=(spec, spec, spec), out_specs=(spec, spec))(
        carry, volts, drives)


@eqx.filter_jit
def _replace(mask, new, old):
    def pick(n, o):
        m = mask.reshape(mask.shape + (1,) * (n.ndim - 1))
        return jnp.where(m, n, o)

    return jax.tree.map(pick, new, old)


@dataclass(frozen=True)
class SweepRun:
    """How a grid was run: slots, segment length, devices, work and timing."""

    chunk: int
    segment: int
    devices: int
    segments_run: int
    samples_simulated: int
    samples_needed: int
    wall_s: float


def _drives(amplitude, frequency, backward) -> DriveContext:
    return DriveContext(jnp.asarray(backward, float), jnp.asarray(amplitude, float),
                        jnp.asarray(frequency, float))


def run_grid(actuator: Actuator, grid: DriveGrid, *, periods: int = 10,
             sample_rate_Hz: float = DEFAULT_SAMPLE_RATE_HZ, chunk: int | None = None,
             segment: int = 250, stepping: Stepping | StepPlan | None = None,
             reduce: Callable[[int, np.ndarray], object] | None = None,
             progress: Callable[[int, int], None] | None = None,
             ) -> tuple[list, SweepRun]:
    """Simulate every point of ``grid`` for ``periods`` sawtooth periods from rest.

    ``reduce(i, q)`` turns point ``i``'s output trace q [m] (``samples_needed``
    samples from t = 0) into what is kept (default: the trace itself); it is called
    as soon as the point is done, so only ``chunk`` traces are held at a time.
    ``progress(done, total)`` is called after each segment. Returns the reduced
    values in grid order and a :class:`SweepRun`.

    ``chunk`` (slots side by side) defaults to :func:`auto_chunk`; a given value is an
    upper bound on memory (state and one segment of output per slot). ``stepping``:
    the simulator's internal steps (default :data:`~stickslip_jax.stepping.DEFAULT_STEPPING`).

    Raises :class:`~stickslip_jax.simulate.NonFiniteSimulation` when a point's trace
    goes non-finite: a sweep never returns a NaN as a result.
    """
    if periods < 1:
        raise ValueError("periods must be ≥ 1")
    n_points = len(grid)
    if n_points == 0:
        return [], SweepRun(0, segment, 0, 0, 0, 0, 0.0)
    devices = jax.devices()
    n_dev = len(devices)
    need = samples_needed(grid.frequency_Hz, periods, sample_rate_Hz)
    plan = plan_steps(actuator, 1.0 / sample_rate_Hz, stepping=stepping,
                      samples=int(need.sum()))
    chunk = auto_chunk(need, n_dev, limit=chunk)
    mesh = Mesh(np.array(devices), ("points",))
    sharding = NamedSharding(mesh, PartitionSpec("points"))
    mapped = default_batching() == "map"
    reduce = reduce or (lambda i, q: q)
    order = list(np.argsort(-need, kind="stable"))  # longest first: packs the tail
    dt = jnp.asarray(1.0 / sample_rate_Hz)
    steps = np.arange(segment + 1)

    # Slot state on the host: which point, how many samples it has.
    point = np.full(chunk, -1)
    have = np.zeros(chunk, dtype=int)
    amp = np.ones(chunk)
    freq = np.ones(chunk)
    back = np.zeros(chunk, dtype=bool)
    traces: list[list[np.ndarray]] = [[] for _ in range(chunk)]
    results: list = [None] * n_points
    done = 0
    carry = None
    start = time.perf_counter()
    segments_run = 0

    def fill(slots) -> None:
        nonlocal carry
        for s in slots:
            if order:
                i = int(order.pop(0))
                point[s], have[s] = i, 1
                amp[s], freq[s], back[s] = (grid.amplitude_V[i], grid.frequency_Hz[i],
                                            grid.backward[i])
            else:
                point[s] = -1
            traces[s] = []
        u0 = sawtooth_samples(amp, freq, back, np.zeros(1), sample_rate_Hz)[:, 0]
        new, q0 = _rest(actuator, jax.device_put(jnp.asarray(u0), sharding),
                        jax.device_put(_drives(amp, freq, back), sharding))
        mask = np.zeros(chunk, dtype=bool)
        mask[list(slots)] = True
        carry = new if carry is None else _replace(jnp.asarray(mask), new, carry)
        q0 = np.asarray(q0)
        for s in slots:
            if point[s] >= 0:
                traces[s].append(q0[s:s + 1])

    fill(range(chunk))
    while np.any(point >= 0):
        k = (have - 1)[:, None] + steps[None, :]
        volts = sawtooth_samples(amp, freq, back, k, sample_rate_Hz)
        carry, q = _segment(actuator, carry, jax.device_put(jnp.asarray(volts), sharding), dt,
                            jax.device_put(_drives(amp, freq, back), sharding), plan,
                            mesh if mapped else None)
        segments_run += 1
        q = np.asarray(q)
        live = point >= 0
        if not np.all(np.isfinite(q[live])):
            i = int(point[live][~np.all(np.isfinite(q[live]), axis=1)][0])
            check_finite(q[live], actuator, plan, 1.0 / sample_rate_Hz,
                         what=f"the sweep point {grid.amplitude_V[i]:g} V, "
                              f"{grid.frequency_Hz[i]:g} Hz")
        finished = []
        for s in np.flatnonzero(point >= 0):
            traces[s].append(q[s])
            have[s] += segment
            i = int(point[s])
            if have[s] >= need[i]:
                results[i] = reduce(i, np.concatenate(traces[s])[: need[i]])
                finished.append(int(s))
                done += 1
        if finished:
            fill(finished)
        if progress is not None:
            progress(done, n_points)
    run = SweepRun(chunk, segment, n_dev, segments_run, segments_run * chunk * segment,
                   int(need.sum()), time.perf_counter() - start)
    return results, run

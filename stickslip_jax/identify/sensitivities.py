"""Simulated traces of a dataset's recordings and their forward-mode derivatives, from
programs that every identification step shares.

Each step needs, at every point its solver tries, the model output of some recordings
and its derivatives with respect to the step's free parameters. A residual closed over
the step's recordings and parameter map is a program of its own: XLA compiled the
simulator's forward-mode pass once per step, with one copy of the sample loop per
length bucket, and that was about half of an identification's time on a CPU (issue
#28: 17 s of 40 s on the fixtures).

Here the compiled program simulates *one* recording, padded to the dataset's longest,
and everything that differs between steps is an argument:

- the actuator (the values fitted so far);
- the tangents, given per leaf of the actuator for every quantity that some step fits
  (:func:`perturbed_mask`); a step's columns are the derivatives of those leaves along
  its own coordinates (a leaf the step holds gets zero tangents), in shares of a fixed
  width (:attr:`RecordingPrograms.width`, zero-padded);
- the recording: voltage, number of real samples, sample period, drive.

Only the stepping plan (the sub-step counts, static), the shapes and the tangents per
call key the program, so the steps compile it once per plan (twice: a step with few
columns takes them one per call, :func:`tangents_per_call`), and the final
uncertainty and traces reuse it. A call computes one (recording, share) pair; the
pairs are shared among threads
(:func:`~.solve.jacobian_threads`; the simulator's loop is sequential, so one call
keeps one core busy), longest recordings first, and put back in a fixed order: the
numbers do not depend on the threads.

A value-only program (no tangents) serves traces alone (the step-doubling error
estimate, :func:`~.residuals.numerical_error`).
"""

from __future__ import annotations

import atexit
import threading
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..program_store import stored_jit
from ..simulate import rest_carry
from ..stepping import StepPlan, sample_stepper
from .dataset import Dataset, check_readable
from .parameters import ParameterSpec, parameter_getter
from .solve import jacobian_pool, jacobian_threads

CHUNK = 128
"""Samples per chunk of the per-recording loop [-]. A chunk that starts after the
recording's last real sample is skipped (a ``cond``), so a recording padded to the
dataset's longest pays for at most ``CHUNK − 1`` samples past its end; skipping sample
by sample instead costs each padded sample a copy of the whole tangent state."""


def _row_output(actuator, voltage, n, dt, drive, recording, plan: StepPlan):
    """``(output, q)`` of one recording: the model output [m] and the slider position q
    [m] it reads (the sensor's input), each (T,). ``voltage`` [V] (T,) padded with its
    last value, ``n`` real samples, ``recording`` its index in the dataset (what the
    sensor reads it with); past them q repeats its last real value (as
    :class:`~.dataset.Dataset` pads the measurement). The same arithmetic as
    :func:`~.residuals.simulate_dataset` on the real samples."""
    carry, q0 = rest_carry(actuator, voltage[0], drive)
    # Forward mode only (values and JVPs): no remat to trace (sample_stepper).
    step = sample_stepper(actuator, dt, drive, plan, checkpoint=False)
    t = voltage.shape[0]
    chunks = -(-(t - 1) // CHUNK)
    u = jnp.concatenate([voltage, jnp.full(chunks * CHUNK + 1 - t, voltage[-1])])
    u_a = u[:-1].reshape(chunks, CHUNK)
    u_b = u[1:].reshape(chunks, CHUNK)
    first = 1 + CHUNK * jnp.arange(chunks)  # the sample each chunk's first interval ends at

    def chunk(c, x):
        start, a, b = x
        return jax.lax.cond(start < n, lambda c: jax.lax.scan(step, c, (a, b)),
                            lambda c: (c, jnp.zeros(CHUNK, dtype=q0.dtype)), c)

    _, qs = jax.lax.scan(chunk, carry, (first, u_a, u_b))
    q = jnp.concatenate([q0[None], qs.reshape(-1)[: t - 1]])
    k = jnp.arange(t)
    q = jnp.where(k < n, q, q[n - 1])
    return actuator.output_map.read(dt * k, q, recording), q


@stored_jit
def _row(actuator, voltage, n, dt, drive, recording, plan):
    return _row_output(actuator, voltage, n, dt, drive, recording, plan)


@stored_jit
def _row_with_tangents(perturbed, fixed, tangents, voltage, n, dt, drive, recording, plan):
    """``(output (T,), d output (T, W), q (T,))``: the output, its derivatives along the
    W tangents (leading axis of every leaf of ``tangents``) of the ``perturbed`` leaves,
    and the position the sensor read (:func:`_row_output`)."""

    def output(p):
        return _row_output(eqx.combine(p, fixed), voltage, n, dt, drive, recording, plan)

    width = jax.tree.leaves(tangents)[0].shape[0]
    if width == 1:
        # One direction: a plain JVP (vmapped, every loop operation would be a length-1
        # vector operation).
        value, tangent, q = jax.jvp(output, (perturbed,),
                                    (jax.tree.map(lambda x: x[0], tangents),), has_aux=True)
        return value, tangent[:, None], q
    return jax.vmap(lambda t: jax.jvp(output, (perturbed,), (t,), has_aux=True),
                    out_axes=(None, -1, None))(tangents)


@stored_jit
def _sensor_tangents(perturbed, fixed, tangents, t, q, recordings):
    """``d output (R, T, W)``: the derivatives of the output map's output at times ``t``
    [s] (R, T) and read positions ``q`` [m] (R, T) of the dataset's ``recordings``
    (their indices, (R,)) along the W tangents (leading axis) of its ``perturbed``
    leaves, the positions held. What a column that moves only the sensor's quantities
    needs: nothing of the mechanics depends on them."""

    def output(p, t, q, b):
        return eqx.combine(p, fixed).read(t, q, b)

    def row(t, q, b):
        return jax.vmap(lambda d: jax.jvp(lambda p: output(p, t, q, b), (perturbed,),
                                          (d,))[1], out_axes=-1)(tangents)

    return jax.vmap(row)(t, q, recordings)


def strong_leaves(tree):
    """``tree`` with every weakly typed JAX array leaf made an ordinary (strongly typed)
    numpy array of its dtype. A program is traced and kept per argument type, weak type
    included (:func:`~stickslip_jax.program_store.stored_jit`), and an actuator's
    leaves are weak or not by where they came from (``jnp.asarray(0.0)`` is weak, the
    fitted values in numpy are not): the same program was compiled twice per actuator
    structure (seen in a reduced diagnosis: one of its 30 programs). Under float64
    throughout, a weak and a strong float64 leaf promote alike, so the arithmetic is
    the same."""
    return jax.tree.map(
        lambda x: np.asarray(x) if isinstance(x, jax.Array) and x.weak_type else x, tree)


def sensor_only_columns(tangents) -> np.ndarray:
    """Which of the k columns of ``tangents`` (a pytree of an actuator's leaves with a
    leading axis of k, as :meth:`RecordingPrograms.sensitivities` takes) move only the
    output map's leaves (bool (k,)): every other leaf's tangent exactly 0 there. Such a
    column's derivative is the output map's own at the simulated positions
    (:func:`_sensor_tangents`), exactly what the forward pass through the mechanics
    would carry to it (zero tangents there), without that pass."""
    leaves = jax.tree.leaves(tangents)
    k = leaves[0].shape[0]
    sensor = {id(x) for x in jax.tree.leaves(getattr(tangents, "output_map", None))}
    if not sensor or k == 0:  # no sensor leaves, or no columns (a value-only program)
        return np.zeros(k, dtype=bool)
    moving = np.zeros(k, dtype=bool)
    for x in leaves:
        if id(x) not in sensor:
            moving |= np.any(np.reshape(np.asarray(x) != 0, (k, -1)), axis=1)
    return ~moving


def tangents_per_call(k: int, width: int) -> int:
    """Tangents per call for a step of ``k`` columns: one (a plain JVP, the second
    program) when ``2·k ≤ width``, else ``width``.

    A vmapped pass pays a fixed cost for its vector operations besides each tangent's:
    through one 2500-sample recording, with the native loops of
    :func:`~stickslip_jax.fast_cpu_loops`, 4 ms without tangents, 6 ms with one plain
    tangent, 16 ms with two vmapped and 65 ms with 21 (issue #28). So k single calls
    (6.2·k ms) beat one call of 21 up to k = 10: the friction step's two break-aways
    and the dynamics step's six quantities go singly (on the fixtures a friction
    Jacobian takes 0.14 s instead of 0.62 s), the hysteresis (35) and joint (42) steps
    in shares of the width."""
    return 1 if 2 * k <= width else width


def perturbed_mask(actuator, names: Sequence[str],
                   specs: dict[str, ParameterSpec] | None = None):
    """A pytree of bools shaped like ``actuator``: True at the leaves of ``names`` (built-in
    quantities, or ``specs`` for model extensions), the quantities whose derivatives the
    shared programs carry."""
    specs = specs or {}
    mask = jax.tree.map(lambda _: False, actuator)
    for name in names:
        getter = specs[name].getter if name in specs else parameter_getter(name, actuator)
        node = getter(mask)  # a leaf, or a tuple of them (one vector quantity)
        mask = eqx.tree_at(getter, mask, (True,) * len(node) if isinstance(node, tuple)
                           else True)
    return mask


def mask_size(actuator, mask) -> int:
    """The number of scalars in the leaves of ``actuator`` that ``mask`` (a pytree of
    bools shaped like it, :func:`perturbed_mask`) marks: a step's Jacobian columns."""
    return sum(int(np.size(x)) for x, m in zip(jax.tree.leaves(actuator),
                                                jax.tree.leaves(mask), strict=True) if m)


_BACKGROUND: list = []
"""The threads :func:`in_background` started, with their stop flags."""


def in_background(jobs: Sequence) -> threading.Thread | None:
    """Run ``jobs`` (callables) one after the other in a thread, which it returns; None
    without a program store, where nothing can be made ahead.

    At the interpreter's exit the thread finishes the job it is in and starts no other
    (:func:`_finish_background`): a thread left in XLA's compiler while Python shuts
    down aborts the process ("FATAL: exception not rethrown"). The command line's
    Ctrl-C ends the process at once (``os._exit``), thread and all."""
    from ..program_store import program_store_dir

    if program_store_dir() is None or not jobs:
        return None
    stop = threading.Event()

    def run():
        for job in jobs:
            if stop.is_set():
                return
            job()

    thread = threading.Thread(target=run, name="stickslip-prefetch", daemon=True)
    _BACKGROUND[:] = [(t, s) for t, s in _BACKGROUND if t.is_alive()] + [(thread, stop)]
    thread.start()
    return thread


@atexit.register
def _finish_background() -> None:
    for _, stop in _BACKGROUND:
        stop.set()
    for thread, _ in _BACKGROUND:
        thread.join()


class RecordingPrograms:
    """The recordings of ``data`` one by one through the shared programs (module
    docstring): traces (:meth:`simulate`) and traces with their derivatives along
    tangents of the ``mask`` leaves of ``actuator`` (:meth:`sensitivities`), ``threads``
    calls at once (default :func:`~.solve.jacobian_threads`).

    :attr:`width`, the tangents per call (default: the total size of the mask's leaves
    shared equally among the threads, so that the widest step, every fitted quantity,
    takes one call per thread and recording, and a narrower step one call per
    recording). Without a mask only :meth:`simulate` serves.
    """

    def __init__(self, data: Dataset, actuator=None, mask=None, *,
                 threads: int | None = None, width: int | None = None):
        self.data = data
        self.mask = mask
        self.threads = jacobian_threads() if threads is None else int(threads)
        self.width = width
        if mask is not None and width is None:
            self.width = max(1, -(-mask_size(actuator, mask) // self.threads))
        self._rows = [
            (jnp.asarray(data.voltages[b]),
             jnp.asarray(int(data.mask[b].sum()), dtype=jnp.int32),
             jnp.asarray(data.dt[b]),
             jax.tree.map(lambda x, b=b: jnp.asarray(np.asarray(x)[b]), data.drives),
             jnp.asarray(b, dtype=jnp.int32))
            for b in range(len(data))]
        self._length = np.asarray(data.mask.sum(axis=1), dtype=int)
        self._compiled: set = set()

    def precompile(self, actuator, plan: StepPlan, *, widths: Sequence[int] = (),
                   value_plans: Sequence[StepPlan] = ()) -> None:
        """Make ready, without running them, the programs of actuators of the
        structure of ``actuator``: the one of each of ``widths`` tangents per call at
        ``plan`` and the value-only one at each of ``value_plans``
        (:func:`~stickslip_jax.program_store.stored_jit`'s ``precompile``: a call of one
        of them meanwhile waits for it; nothing is made without a program store). What
        fails here is left to the call, which makes the program as before."""
        rows = self._order(range(len(self._rows)))
        if not rows:
            return
        row = self._rows[rows[0]]  # every row has the same shapes (padded)
        actuator = strong_leaves(actuator)
        jobs = [(_row, (actuator, *row, p)) for p in value_plans]
        if self.mask is not None and widths:
            perturbed, fixed = eqx.partition(actuator, self.mask)
            perturbed = jax.tree.map(lambda x: jnp.asarray(x, dtype=float), perturbed)
            jobs += [(_row_with_tangents, (perturbed, fixed, jax.tree.map(
                lambda x, w=w: np.zeros((w,) + np.shape(x)), perturbed), *row, plan))
                for w in widths]
        for program, args in jobs:
            try:
                program.precompile(*args)
            except Exception:  # noqa: BLE001 - the call makes it then
                return

    def prefetch(self, actuator, plan: StepPlan, *, wide: bool = True
                 ) -> threading.Thread | None:
        """:meth:`precompile`, in a thread of its own, of what an identification's
        later steps are likely to need: the program of :attr:`width` tangents at
        ``plan`` (the wide steps'; left out when ``wide`` is False, no later Jacobian
        having that many columns: :meth:`goes_wide`) and the value-only one at
        ``plan.doubled()`` (the step-doubling error estimate at the end). Started with
        the first step, this compiling takes the core the first step's own compiling
        and serial solver leave idle; the programs, and so the numbers, are those the
        calls would have made. Returns the thread, or None without a mask or a program
        store (the calls then compile as before)."""
        if self.mask is None:
            return None
        widths = (self.width,) if wide else ()
        return in_background([lambda: self.precompile(
            actuator, plan, widths=widths, value_plans=(plan.doubled(),))])

    def goes_wide(self, columns: int) -> bool:
        """Whether a Jacobian of ``columns`` columns (through the mechanics) runs the
        program of :attr:`width` tangents (:func:`tangents_per_call`), not the
        one-tangent one."""
        return self.mask is not None and tangents_per_call(columns, self.width) > 1

    def _order(self, rows: Sequence[int]) -> list[int]:
        # Longest first, so that the last calls are short ones (threads finish together).
        return sorted(rows, key=lambda b: (-self._length[b], b))

    def _run(self, tasks, call, key) -> dict:
        """``{task: call(task)}``; the first task alone when ``key`` (the program) is new
        here, so that the threads do not each compile it, the rest among the threads."""
        out = {}
        tasks = list(tasks)
        if key not in self._compiled and tasks:
            out[tasks[0]] = jax.block_until_ready(call(tasks[0]))
            self._compiled.add(key)
            tasks = tasks[1:]
        if self.threads == 1 or len(tasks) <= 1:
            out.update({t: jax.block_until_ready(call(t)) for t in tasks})
            return out
        pool = jacobian_pool(self.threads)
        futures = {t: pool.submit(lambda t=t: jax.block_until_ready(call(t))) for t in tasks}
        out.update({t: f.result() for t, f in futures.items()})
        return out

    def _all(self, rows):
        return list(range(len(self.data))) if rows is None else [int(b) for b in rows]

    def simulate(self, actuator, plan: StepPlan, rows: Sequence[int] | None = None
                 ) -> np.ndarray:
        """Model output q [m] of the recordings ``rows`` (default all), (R, T), each
        padded to the dataset's length T with its last real value."""
        return self._values(actuator, plan, self._all(rows))[0]

    def _values(self, actuator, plan: StepPlan, rows) -> tuple[np.ndarray, np.ndarray]:
        """``(outputs, positions)`` [m] (R, T) of the recordings ``rows`` through the
        value-only program: the model outputs and the positions the sensor read."""
        check_readable(actuator, self.data)
        actuator = strong_leaves(actuator)
        key = ("value", plan, jax.tree.structure(actuator))
        done = self._run(self._order(rows), lambda b: _row(actuator, *self._rows[b], plan),
                         key)
        return tuple(np.stack([np.asarray(done[b][i]) for b in rows]) for i in (0, 1))

    def sensitivities(self, actuator, tangents, plan: StepPlan,
                      rows: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(q (R, T), dq (R, T, k))``: the outputs [m] of the recordings ``rows``
        (default all) and their derivatives along ``k`` tangents, ``tangents`` being a
        pytree of the mask's leaves (``eqx.filter(…, mask)`` of an actuator-shaped tree)
        with a leading axis of k on every leaf.

        Columns that move only the output map's leaves (:func:`sensor_only_columns`: a
        sensor's delay, drift, periodic error) are the output map's derivatives at the
        simulated positions, apart from the mechanics' pass; the others ride on it. At
        most half :attr:`width` of those go one per call, through the program of a
        single plain JVP (:func:`tangents_per_call`); more, :attr:`width` per call."""
        rows = self._all(rows)
        check_readable(actuator, self.data)
        perturbed, fixed = eqx.partition(strong_leaves(actuator), self.mask)
        perturbed = jax.tree.map(lambda x: jnp.asarray(x, dtype=float), perturbed)
        tangents = jax.tree.map(lambda x: np.asarray(x, dtype=float), tangents)
        k = jax.tree.leaves(tangents)[0].shape[0]
        sensor = sensor_only_columns(tangents)
        moving = np.flatnonzero(~sensor)
        t_len = self.data.voltages.shape[1]
        dq = np.empty((len(rows), t_len, k))
        if moving.size:
            q, dq[:, :, moving], positions = self._through_mechanics(
                perturbed, fixed, jax.tree.map(lambda x: x[moving], tangents), plan, rows)
        else:
            q, positions = self._values(actuator, plan, rows)
        if sensor.any():
            dq[:, :, sensor] = self._through_sensor(perturbed, fixed, tangents, sensor,
                                                    positions, rows)
        return q, dq

    def _through_mechanics(self, perturbed, fixed, tangents, plan: StepPlan, rows):
        """``(q, dq, positions)`` of :meth:`sensitivities` along ``tangents``, through the
        shared programs of the mechanics; ``positions`` the positions the sensor read
        [m] (R, T)."""
        k = jax.tree.leaves(tangents)[0].shape[0]
        w = tangents_per_call(k, self.width)
        shares = max(1, -(-k // w))

        def share(s):
            def cut(x):
                part = x[s * w:(s + 1) * w]
                return np.concatenate([part, np.zeros((w - part.shape[0],) + x.shape[1:])])
            return jax.tree.map(cut, tangents)

        parts = [share(s) for s in range(shares)]
        key = ("tangents", plan, w, jax.tree.structure(perturbed), jax.tree.structure(fixed))
        tasks = [(b, s) for b in self._order(rows) for s in range(shares)]
        done = self._run(tasks, lambda t: _row_with_tangents(
            perturbed, fixed, parts[t[1]], *self._rows[t[0]], plan), key)
        t_len = self.data.voltages.shape[1]
        q = np.empty((len(rows), t_len))
        positions = np.empty((len(rows), t_len))
        dq = np.empty((len(rows), t_len, shares * w))
        for i, b in enumerate(rows):
            q[i] = np.asarray(done[(b, 0)][0])
            positions[i] = np.asarray(done[(b, 0)][2])
            for s in range(shares):
                dq[i, :, s * w:(s + 1) * w] = np.asarray(done[(b, s)][1])
        return q, dq[:, :, :k], positions

    def _through_sensor(self, perturbed, fixed, tangents, columns: np.ndarray,
                        positions: np.ndarray, rows) -> np.ndarray:
        """The derivatives (R, T, c) of the outputs along the ``columns`` (bool (k,)) of
        ``tangents`` that move only the output map (:func:`_sensor_tangents`), at the
        read ``positions`` [m] (R, T). The columns are padded to the output map's share
        of the mask, so that one program serves every fit."""
        cut = jax.tree.map(lambda x: x[columns], tangents.output_map)
        c = int(np.sum(columns))
        width = max(c, sum(int(np.size(x)) for x in jax.tree.leaves(perturbed.output_map)))
        padded = jax.tree.map(
            lambda x: np.concatenate([x, np.zeros((width - c,) + x.shape[1:])]), cut)
        times = np.asarray(self.data.dt)[rows, None] * np.arange(positions.shape[1])
        out = _sensor_tangents(perturbed.output_map, fixed.output_map, padded,
                               jnp.asarray(times), jnp.asarray(positions),
                               jnp.asarray(rows, dtype=jnp.int32))
        return np.asarray(out)[:, :, :c]


class StepJacobian:
    """``θ ↦ (residual, ∂residual/∂θ)`` of one step's residual ``res`` (a
    :class:`~.residuals.TraceResiduals` over the recordings ``rows`` of the programs'
    dataset, around its own parameter map), through the shared programs: the outputs'
    derivatives along the step's coordinates, then the residual's by the chain rule
    (:meth:`~.residuals.TraceResiduals.jacobian_from_outputs`, numpy). For
    :func:`~.solve.solve_least_squares` ``jacobian``.

    The outputs of the last few points are kept (:meth:`outputs_at`): the traces at the
    optimum come with the solve.
    """

    KEEP = 8
    """Points whose outputs are kept [-]: the solver ends at the point it evaluated
    last, or, after rejected steps, at one before it (after more than seven rejected
    steps in a row the traces at the optimum are simulated again)."""

    def __init__(self, res, programs: RecordingPrograms, rows: Sequence[int]):
        self.res = res
        self.programs = programs
        self.rows = [int(b) for b in rows]
        self._outputs: dict[bytes, np.ndarray] = {}

    def __call__(self, theta) -> tuple[np.ndarray, np.ndarray]:
        theta = np.asarray(theta, dtype=float)
        pmap = self.res.pmap
        # The actuator and its leaves' tangents in numpy: nothing compiled per step.
        tangents = pmap.leaf_tangents(theta, self.programs.mask)
        q, dq = self.programs.sensitivities(self.actuator(theta), tangents, self.res.plan,
                                            self.rows)
        t = self.res.data.voltages.shape[1]
        self._outputs[theta.tobytes()] = q
        while len(self._outputs) > self.KEEP:
            self._outputs.pop(next(iter(self._outputs)))
        return self.res.jacobian_from_outputs(q[:, :t], dq[:, :t])

    def value(self, theta) -> np.ndarray:
        """The residual (N,) at ``theta`` alone, through the value-only program (what a
        point the solver may reject needs)."""
        q = self.programs.simulate(self.actuator(theta), self.res.plan, self.rows)
        return np.asarray(self.res.from_output(q[:, :self.res.data.voltages.shape[1]],
                                               xp=np))

    def actuator(self, theta):
        """The step's actuator at ``theta`` (``pmap.actuator`` in numpy)."""
        return self.res.pmap.actuator(np.asarray(theta, dtype=float), xp=np)

    def outputs_at(self, theta) -> np.ndarray | None:
        """The outputs q [m] (R, T) at ``theta`` if it was one of the last points
        evaluated, else None."""
        return self._outputs.get(np.asarray(theta, dtype=float).tobytes())

"""Speed, accuracy, derivative cost and memory of the stickslip_jax simulator.

One run, one trace: 1 s at 25 kHz of a 40 V, 50 Hz forward sawtooth (docs/model.md), the
default profile ``lu2015_slc1720()``. Everything is float64. The simulator is measured
at two steppings (``stickslip_jax/stepping.py``), side by side and interleaved:

- *default*: ``Stepping()``, what ``simulate`` does unless told otherwise: a step in
  seconds from the model's fastest mode (9 coarse RK4 sub-steps per 25 kHz sample on
  this profile), slip reversals located inside sub-steps, and sample intervals whose
  error estimate exceeds the tolerance integrated again with 8x the sub-steps;
- *today's*: ``Stepping.uniform(16, RK4.with_events(False))``, the scheme before event
  location (RK4, 16 sub-steps per sample, nothing located, nothing refined): the
  scheme of earlier runs of this benchmark and of the numba loops.

The default is the *stepping under study*: the one the derivatives, the memory child
and the XLA-default-loops child use. ``--stepping today`` studies today's instead;
``--substeps N`` studies N uniform RK4 sub-steps per sample with located reversals and
no refinement (``Stepping.uniform(N)``, what ``simulate(..., substeps=N)`` does).
Usage (see benchmarks/README.md)::

    .venv/bin/python benchmarks/bench_simulator.py --json out/bench_simulator.json
    .venv/bin/python benchmarks/bench_simulator.py --quick      # smoke run

What is timed
-------------
1. ``simulate`` (one recording) and ``simulate_batch`` with 17 rows (17 copies of the
   trace: the scan does the same work whatever the rows hold), after compilation, at
   the stepping under study and at today's; wall-clock medians and minima. These are
   the public calls as a user makes them, so they include planning the step
   (``plan_steps``: the model's fastest mode from its Jacobian at rest, each call);
   single-recording rows with a ``StepPlan`` made once (``stepping=plan``) show the
   cost without it, and a ``plan_steps`` row times the planning alone. Today's scheme
   at 32 and 64 sub-steps (information: what finer uniform steps cost and buy).
   Compile time two ways: first call minus the steady median (after
   ``jax.clear_caches()``; planning's own first call included), and
   ``jax.jit(...).lower(...)`` / ``.compile()`` timed separately (with a plan made
   outside: inside ``jit`` the actuator is traced; the batch through the private
   ``_simulate_batch``, as ``simulate_batch`` cannot be traced: ``batch_in_jit``). The
   persistent compilation cache is off.
2. numba references, written from docs/model.md, not from the JAX code, all at
   today's scheme with 16 sub-steps per sample (``NUMBA_SUBSTEPS``: a fixed external
   yardstick, whatever stepping the JAX rows use):

   - *plain*: the contract's scheme as a scalar loop. Per RK4 sub-step the voltage
     is the first-order hold at each stage time, the PI output is evaluated with the
     play memory of the sub-step start (once per distinct stage time: stages 2 and
     3 share t + h/2, hence one value), the memory is committed at the sub-step end,
     and |z| is saturated at |z_ss| after each sub-step. The profile values are
     runtime arguments (read from the Actuator), not compile-time constants.
   - *per-interval PI* (labelled): the same loop, but the PI output for all stage
     times of one sample interval is evaluated with the memory of the interval
     start and the memory committed once per interval, as the JAX simulator does
     (exact: the voltage is linear, hence monotone, over an interval).
   - *17 recordings, prange*: the plain loop over the 17 rows with
     ``numba.prange`` (information only: what a numba user gets from all cores).

   Both single-recording loops are checked against the JAX output at today's
   stepping, the same scheme (NRMSE, c = 0).
3. ``scipy.integrate.solve_ivp`` (LSODA, RK45, Radau; rtol 1e-6, atol 1e-12,
   max_step = one sample period), right-hand side in plain Python/NumPy (no numba),
   no analytic Jacobian (LSODA and Radau estimate it by finite differences). Two
   honest formulations of the hysteresis memory and the saturation:

   - *per interval*: one ``solve_ivp`` call per sample interval. Inside the interval
     the voltage is linear, so the PI output at time t is exactly
     ``Σ w_i clip(p_i(t_k), U(t) − r_i, U(t) + r_i)`` with the memory of the interval
     start; the memory is committed and |z| saturated at the interval end. Every
     call restarts the integrator (step-size selection, order 1 for LSODA).
   - *one call*: one ``solve_ivp`` call over the whole trace. With the identity
     input stage the play memory depends on the voltage alone, so the memory at
     every sample is tabulated beforehand and Γ(t) is the exact, state-independent
     function above (continuous in t). No saturation is applied: in continuous time
     |z| ≤ |z_ss| is invariant (α = 1 at |z_ss| makes ż = 0, and beyond it ż points
     back), so the projection is only a discrete-time device. Output at the samples
     comes from the solver's dense output (``t_eval``).

   LSODA runs the whole trace. RK45 and Radau run the whole trace when a one-period
   pilot projects it to fit ``--scipy-budget`` seconds, otherwise a prefix of whole
   drive periods that fits, and their time is scaled linearly to the full trace
   (the drive is periodic; the table says when and from how long a prefix).
4. Accuracy of each method against a tight reference: NRMSE (RMS difference over the
   reference's peak-to-peak, c = 0) and RMS difference in nm with the mean removed
   (as a fit with an offset sees it). The reference is the JAX simulator with uniform
   20 ns steps, switches located, no refinement (``Stepping(max_step=2e-8,
   refine=1)``, 2000 sub-steps per sample), checked against the same at 40 ns. For
   scipy prefixes, over the prefix.
5. Derivatives of q(θ) where θ = (Mp, Dp, Kp, Ms, Ds, rho0, z_ba_forward,
   z_ba_backward, zba_ratio), put into the Actuator with ``eqx.tree_at``, at the
   stepping under study through a ``StepPlan`` made outside the traced functions
   (inside ``jacfwd``/``grad`` the actuator is traced and planning would fall back to
   a fixed step): ``jax.jacfwd`` of the trace (T x 9), again with the 35 PI weights
   added (T x 44), and over Mp alone and Mp, Dp, Kp (T x 1, T x 3: how the cost grows
   with columns), and ``jax.grad`` of sum((q − q_target)²), q_target being the trace
   at θ·1.01, with the default adjoint (``ForwardSensitivities()``, which for nine
   parameters with native CPU loops hands over to reverse mode:
   ``default_max_directions``), with ``ForwardSensitivities(max_directions=64)`` (the
   gradient as Jᵀ·c from forward sensitivities) and with ``adjoint=CheckpointedScan()``
   (plain reverse mode through the checkpointed scan). Beside them the forward θ → q,
   ``jacfwd`` (T x 9) and ``jax.grad`` (default adjoint) at today's stepping, for run
   and compile time, and how far today's Jacobian columns are from the studied one's.
   All jitted, compiled ahead of time (compile timed), timed interleaved with the
   plain forward θ → q at the stepping under study, and reported as multiples of it.
   (z_ba_backward has a zero column on a forward drive; it still costs a tangent.)
6. Memory of the gradient (default adjoint, stepping under study) over a 10 s trace,
   in a fresh subprocess: the compiled executable's ``memory_analysis()`` (temp,
   argument, output sizes) and the process peak RSS increase (``resource.getrusage``)
   from before compiling the gradient to after running it; also the run alone (peak
   reset through ``/proc/self/clear_refs`` where the kernel allows it).
7. Ratios next to the targets of the issues, each marked PASS or MISS; among them
   issue 26's: the forward cost per recording at the default stepping at most 1.5x
   today's (single recording, public call; and batched per recording).
8. XLA's loop compilation: the JAX rows run with ``stickslip_jax.fast_cpu_loops()``
   (small while loops compiled as native loops, as the command line does; see
   ``stickslip_jax/xla_flags.py``) unless ``--xla-default-loops``. A fresh subprocess
   with XLA's default setting times the single and batched simulation (stepping
   under study and today's) and the numba plain loop interleaved, so the table shows
   what the setting changes (ratios to numba within each process). Without native
   loops ``simulate_batch`` vmaps its rows (``default_batching``), which turns the
   refinement's and the event location's ``cond`` into selects: every interval then
   pays for both branches.

The machine may be shared and noisy: the timed variants of a section are run in
interleaved rounds (rotating order) and medians and minima reported; ``cpu/wall``
(process CPU time over wall time) shows whether a variant used more than one core.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib.metadata
import json
import math
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
with contextlib.suppress(Exception):
    jax.config.update("jax_enable_compilation_cache", False)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numba  # noqa: E402
import numpy as np  # noqa: E402
import scipy  # noqa: E402
from numba import njit, prange  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from stickslip_jax import fast_cpu_loops  # noqa: E402
from stickslip_jax.adjoint import (  # noqa: E402
    DEFAULT_ADJOINT,
    CheckpointedScan,
    ForwardSensitivities,
    default_max_directions,
)
from stickslip_jax.model.base import DriveContext  # noqa: E402
from stickslip_jax.model.profiles import lu2015_slc1720  # noqa: E402
from stickslip_jax.signals import sawtooth  # noqa: E402
from stickslip_jax.simulate import (  # noqa: E402
    _simulate_batch,
    default_batching,
    plan_steps,
    simulate,
    simulate_batch,
    stack_drives,
)
from stickslip_jax.solvers import RK4  # noqa: E402
from stickslip_jax.stepping import DEFAULT_STEPPING, Stepping, StepPlan  # noqa: E402

FS = 25_000.0  # sample rate [Hz]
DT = 1.0 / FS  # sample period [s]
AMPLITUDE = 40.0  # [V]
FREQUENCY = 50.0  # [Hz]
N_BATCH = 17  # recordings in the batched scan
NUMBA_SUBSTEPS = 16  # the numba loops' RK4 sub-steps per sample (today's scheme), fixed
TODAY = Stepping.uniform(NUMBA_SUBSTEPS, RK4.with_events(False))
"""The stepping before event location: RK4, 16 sub-steps per sample, nothing located or
refined (what ``simulate`` did and what the numba loops do)."""
STEPPINGS = {"default": DEFAULT_STEPPING, "today": TODAY}
REFERENCE = Stepping(max_step=2e-8, refine=1)  # uniform 20 ns, switches located
REFERENCE_CHECK = Stepping(max_step=4e-8, refine=1)  # the same at 40 ns
PERIOD_SAMPLES = round(FS / FREQUENCY)
SCIPY_TOL = {"rtol": 1e-6, "atol": 1e-12}
PHYSICAL = ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0", "z_ba_forward", "z_ba_backward", "zba_ratio")

TARGETS = {
    "forward_over_today": 1.5,
    "batched_per_recording_over_numba": 2.0,
    "forward_over_numba_equal_accuracy": 0.5,  # issue 64
    "lsoda_over_jax": 50.0,
    "jacfwd_over_forward": 4.0,  # issue 64 (6 before)
    "grad_over_forward": 6.0,
    "compile_s": 5.0,  # issue 64 (15 before)
    "grad_memory_10s_MB": 2000.0,
}

EQUAL_ACCURACY_NM = 0.05
"""The accuracy [nm RMS against the converged reference] at which the default stepping
and the numba loop are compared (issue 64): the numba loop runs at the fewest sub-steps
of :data:`NUMBA_LADDER` that reach it."""

NUMBA_LADDER = (16, 32, 64, 128, 256, 512, 1024, 2048)
"""Sub-steps per sample tried for the numba loop at :data:`EQUAL_ACCURACY_NM` (its
last rung is used, and said, when none reaches it)."""


def numba_substeps_for(u_np, prm, r, w, q_ref, target_nm: float = EQUAL_ACCURACY_NM
                       ) -> tuple[int, float, dict]:
    """``(sub-steps, error [nm], ladder)``: the fewest sub-steps per sample of
    :data:`NUMBA_LADDER` at which :func:`numba_plain` is within ``target_nm`` RMS of
    ``q_ref``, its error, and the error at every rung tried."""
    ladder = {}
    for k in NUMBA_LADDER:
        ladder[k] = rms_nm(numba_plain(u_np, DT, k, prm, r, w), q_ref)
        if ladder[k] <= target_nm:
            break
    return k, ladder[k], ladder

# ---------------------------------------------------------------------------------
# Parameters, read from the Actuator (never baked into the reference loops)
# ---------------------------------------------------------------------------------
def reference_parameters(actuator) -> tuple[tuple[float, ...], np.ndarray, np.ndarray]:
    """Scalars (Mp, Dp, Kp, Kact2·N, Ms, Ds, F_ext, k_load, rho0, rho1, rho2, z_ba,
    zba_ratio) for a forward drive, PI thresholds r [V] and weights w [m/V]."""
    p, s, f, h = actuator.piezo, actuator.slider, actuator.friction, actuator.hysteresis
    scalars = (
        p.Mp, p.Dp, p.Kp, p.Kact2 * p.N, s.Ms, s.Ds, s.F_ext, s.k_load,
        f.rho0, f.rho1, f.rho2, f.z_ba_forward, f.zba_ratio,
    )
    return (
        tuple(float(v) for v in scalars),
        np.asarray(h.thresholds, dtype=np.float64),
        np.asarray(h.weights, dtype=np.float64),
    )


# ---------------------------------------------------------------------------------
# numba references
# ---------------------------------------------------------------------------------
@njit(inline="always")
def _nb_field(x1, v1, x2, v2, z, g, prm):
    """Right-hand side (docs/model.md) for stroke ``g`` [m]; ``prm`` as reference_parameters."""
    mp, dp, kp, f_pre, ms, ds, f_ext, k_load, rho0, rho1, rho2, z_ba, ratio = prm
    zss = z_ba / ratio
    xdot = v1 - v2
    alpha = 0.0
    if xdot * z > 0.0:  # alpha = 0 when sgn(xdot) != sgn(z)
        az = abs(z)
        if az >= zss:
            alpha = 1.0
        elif az > z_ba:
            alpha = 0.5 * math.sin(math.pi * (az - 0.5 * (zss + z_ba)) / (zss - z_ba)) + 0.5
    z_ss = zss if xdot >= 0.0 else -zss  # sign switch; +|z_ss| at xdot = 0
    zdot = xdot * (1.0 - alpha * z / z_ss)
    ff = rho0 * z + rho1 * zdot + rho2 * xdot
    a1 = (kp * (g - x1) - dp * v1 - f_pre - ff) / mp
    a2 = (ff + f_ext - k_load * x2 - ds * v2) / ms
    return v1, a1, v2, a2, zdot


@njit(inline="always")
def _nb_pi(p, u, r, w):
    """Γ = Σ w_i clip(p_i, u − r_i, u + r_i) [m] with memory ``p`` [V]."""
    s = 0.0
    for i in range(p.shape[0]):
        s += w[i] * min(max(p[i], u - r[i]), u + r[i])
    return s


@njit(inline="always")
def _nb_rk4(x1, v1, x2, v2, z, g0, gm, g1, h, prm):
    """One RK4 step with the strokes at the sub-step start, middle and end."""
    hh = 0.5 * h
    k1 = _nb_field(x1, v1, x2, v2, z, g0, prm)
    k2 = _nb_field(x1 + hh * k1[0], v1 + hh * k1[1], x2 + hh * k1[2], v2 + hh * k1[3],
                   z + hh * k1[4], gm, prm)
    k3 = _nb_field(x1 + hh * k2[0], v1 + hh * k2[1], x2 + hh * k2[2], v2 + hh * k2[3],
                   z + hh * k2[4], gm, prm)
    k4 = _nb_field(x1 + h * k3[0], v1 + h * k3[1], x2 + h * k3[2], v2 + h * k3[3],
                   z + h * k3[4], g1, prm)
    h6 = h / 6.0
    x1 += h6 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
    v1 += h6 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
    x2 += h6 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2])
    v2 += h6 * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3])
    z += h6 * (k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4])
    return x1, v1, x2, v2, z


@njit(inline="always")
def _nb_rest(u0, prm, r, w, p):
    """Fill the memory ``p`` at rest under ``u0`` and return the rest state."""
    kp, f_pre, f_ext, rho0 = prm[2], prm[3], prm[6], prm[8]
    for i in range(r.shape[0]):
        p[i] = min(max(0.0, u0 - r[i]), u0 + r[i])
    x1 = _nb_pi(p, u0, r, w) - (f_pre - f_ext) / kp
    return x1, 0.0, 0.0, 0.0, -f_ext / rho0


@njit
def numba_plain(u, dt, substeps, prm, r, w):
    """q [m] at the samples of ``u`` [V]: the contract's plain scheme (module doc)."""
    n = u.shape[0]
    zss = prm[11] / prm[12]
    p = np.empty(r.shape[0])
    x1, v1, x2, v2, z = _nb_rest(u[0], prm, r, w, p)
    q = np.empty(n)
    q[0] = x1 + x2
    h = dt / substeps
    for k in range(n - 1):
        ua = u[k]
        du = u[k + 1] - ua
        for j in range(substeps):
            u0 = ua + du * (j / substeps)
            um = ua + du * ((j + 0.5) / substeps)
            u1 = ua + du * ((j + 1.0) / substeps)
            g0 = _nb_pi(p, u0, r, w)
            gm = _nb_pi(p, um, r, w)
            g1 = _nb_pi(p, u1, r, w)
            x1, v1, x2, v2, z = _nb_rk4(x1, v1, x2, v2, z, g0, gm, g1, h, prm)
            for i in range(p.shape[0]):  # commit the memory at the sub-step end
                p[i] = min(max(p[i], u1 - r[i]), u1 + r[i])
            z = min(max(z, -zss), zss)  # saturate |z| at |z_ss|
        q[k + 1] = x1 + x2
    return q


@njit
def numba_interval(u, dt, substeps, prm, r, w):
    """As :func:`numba_plain`, PI per sample interval with one commit (as the JAX code)."""
    n = u.shape[0]
    zss = prm[11] / prm[12]
    p = np.empty(r.shape[0])
    x1, v1, x2, v2, z = _nb_rest(u[0], prm, r, w, p)
    q = np.empty(n)
    q[0] = x1 + x2
    h = dt / substeps
    g = np.empty(2 * substeps + 1)  # strokes at fractions m / (2·substeps)
    for k in range(n - 1):
        ua = u[k]
        du = u[k + 1] - ua
        for m in range(2 * substeps + 1):
            g[m] = _nb_pi(p, ua + du * (0.5 * m / substeps), r, w)
        for j in range(substeps):
            x1, v1, x2, v2, z = _nb_rk4(x1, v1, x2, v2, z, g[2 * j], g[2 * j + 1], g[2 * j + 2],
                                        h, prm)
            z = min(max(z, -zss), zss)
        ub = u[k + 1]
        for i in range(p.shape[0]):
            p[i] = min(max(p[i], ub - r[i]), ub + r[i])
        q[k + 1] = x1 + x2
    return q


@njit(parallel=True)
def numba_plain_batch(us, dt, substeps, prm, r, w):
    """:func:`numba_plain` over the rows of ``us``, rows spread over threads."""
    out = np.empty_like(us)
    for b in prange(us.shape[0]):
        out[b] = numba_plain(us[b], dt, substeps, prm, r, w)
    return out


# ---------------------------------------------------------------------------------
# scipy references
# ---------------------------------------------------------------------------------
def _py_field(y, g, prm):
    """Same right-hand side as :func:`_nb_field`, plain Python floats."""
    mp, dp, kp, f_pre, ms, ds, f_ext, k_load, rho0, rho1, rho2, z_ba, ratio = prm
    x1, v1, x2, v2, z = y.tolist()
    zss = z_ba / ratio
    xdot = v1 - v2
    alpha = 0.0
    if xdot * z > 0.0:
        az = abs(z)
        if az >= zss:
            alpha = 1.0
        elif az > z_ba:
            alpha = 0.5 * math.sin(math.pi * (az - 0.5 * (zss + z_ba)) / (zss - z_ba)) + 0.5
    z_ss = zss if xdot >= 0.0 else -zss
    zdot = xdot * (1.0 - alpha * z / z_ss)
    ff = rho0 * z + rho1 * zdot + rho2 * xdot
    a1 = (kp * (g - x1) - dp * v1 - f_pre - ff) / mp
    a2 = (ff + f_ext - k_load * x2 - ds * v2) / ms
    return np.array([v1, a1, v2, a2, zdot])


def _py_rest(u0, prm, r, w):
    p = np.clip(0.0, u0 - r, u0 + r)
    x1 = float(w @ p) - (prm[3] - prm[6]) / prm[2]
    return np.array([x1, 0.0, 0.0, 0.0, -prm[6] / prm[8]]), p


def scipy_per_interval(u, dt, prm, r, w, method):
    """One solve_ivp call per sample interval (module doc). Returns (q, nfev)."""
    zss = prm[11] / prm[12]
    y, p = _py_rest(u[0], prm, r, w)
    q = np.empty(len(u))
    q[0] = y[0] + y[2]
    nfev = 0
    for k in range(len(u) - 1):
        ua, du = u[k], u[k + 1] - u[k]

        def rhs(s, yy, ua=ua, du=du, p=p):
            uu = ua + du * (s / dt)
            return _py_field(yy, float(w @ np.minimum(np.maximum(p, uu - r), uu + r)), prm)

        sol = solve_ivp(rhs, (0.0, dt), y, method=method, max_step=dt, **SCIPY_TOL)
        if not sol.success:
            raise RuntimeError(f"{method} failed in interval {k}: {sol.message}")
        nfev += sol.nfev
        y = sol.y[:, -1].copy()
        y[4] = min(max(y[4], -zss), zss)
        p = np.minimum(np.maximum(p, u[k + 1] - r), u[k + 1] + r)
        q[k + 1] = y[0] + y[2]
    return q, nfev


def scipy_one_call(u, dt, prm, r, w, method):
    """One solve_ivp call with a tabulated PI memory (module doc). Returns (q, nfev)."""
    n = len(u)
    y0, p = _py_rest(u[0], prm, r, w)
    memory = np.empty((n, len(r)))
    for k in range(n):
        p = np.minimum(np.maximum(p, u[k] - r), u[k] + r)
        memory[k] = p

    def rhs(t, yy):
        s = t / dt
        k = min(max(int(s), 0), n - 2)
        uu = u[k] + (u[k + 1] - u[k]) * (s - k)
        pk = memory[k]
        return _py_field(yy, float(w @ np.minimum(np.maximum(pk, uu - r), uu + r)), prm)

    t_eval = np.arange(n) * dt
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), y0, method=method, t_eval=t_eval, max_step=dt,
                    **SCIPY_TOL)
    if not sol.success:
        raise RuntimeError(f"{method} failed: {sol.message}")
    return sol.y[0] + sol.y[2], sol.nfev


# ---------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------
def nrmse(q, ref) -> float:
    """RMS of q − ref over the peak-to-peak of ref (docs/model.md "Fit quality", c = 0)."""
    q, ref = np.asarray(q), np.asarray(ref)
    return float(np.sqrt(np.mean((q - ref) ** 2)) / np.ptp(ref))


def rms_nm(q, ref) -> float:
    """RMS of q − ref [nm] with its mean removed (the error a fit with an offset sees)."""
    e = np.asarray(q) - np.asarray(ref)
    e = e - e.mean()
    return float(1e9 * np.sqrt(np.mean(e * e)))


def _timed(fn):
    gc.collect()
    c0, t0 = time.process_time(), time.perf_counter()
    out = jax.block_until_ready(fn())
    wall = time.perf_counter() - t0
    return wall, time.process_time() - c0, out


def _stats(walls, cpus=None) -> dict:
    walls = [float(x) for x in walls]
    out = {"median_s": float(np.median(walls)), "min_s": min(walls), "runs_s": walls}
    if cpus:
        out["cpu_over_wall"] = float(np.sum(cpus) / np.sum(walls))
    return out


def interleaved(variants: dict, repeats: int) -> tuple[dict, dict]:
    """Time each callable ``repeats`` times in rotating interleaved rounds, after a warm-up.

    Returns ({name: stats}, {name: last output}).
    """
    names = list(variants)
    for fn in variants.values():  # one untimed call each (compiles what is not yet)
        jax.block_until_ready(fn())
    walls = {n: [] for n in names}
    cpus = {n: [] for n in names}
    outs = {}
    for rep in range(repeats):
        shift = rep % len(names)
        for name in names[shift:] + names[:shift]:
            w_, c_, outs[name] = _timed(variants[name])
            walls[name].append(w_)
            cpus[name].append(c_)
    return {n: _stats(walls[n], cpus[n]) for n in names}, outs


def aot_compile(fn, *args) -> tuple[object, dict]:
    """``jax.jit(fn).lower(*args).compile()`` from cold caches; times each part."""
    jax.clear_caches()
    t0 = time.perf_counter()
    lowered = jax.jit(fn).lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    return compiled, {"lower_s": t1 - t0, "compile_s": t2 - t1, "total_s": t2 - t0}


def parameter_function(actuator, plan: StepPlan, *, with_pi: bool, adjoint=None,
                       count: int = len(PHYSICAL)):
    """θ → q for the first ``count`` physical parameters (and the PI weights when
    ``with_pi``), stepped by ``plan`` (made outside: the actuator is traced in here);
    ``adjoint`` (default: the simulator's) is passed to ``simulate``."""
    extra = {} if adjoint is None else {"adjoint": adjoint}

    def leaves(a):
        out = (a.piezo.Mp, a.piezo.Dp, a.piezo.Kp, a.slider.Ms, a.slider.Ds, a.friction.rho0,
               a.friction.z_ba_forward, a.friction.z_ba_backward, a.friction.zba_ratio)[:count]
        return out + (a.hysteresis.weights,) if with_pi else out

    theta0 = jnp.concatenate([jnp.ravel(x) for x in leaves(actuator)])

    def q_of(theta, u):
        values = tuple(theta[i] for i in range(count))
        if with_pi:
            values = values + (theta[count:],)
        return simulate(eqx.tree_at(leaves, actuator, values), u, dt=DT, stepping=plan,
                        **extra)

    return q_of, theta0


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def _proc_status_mb(key: str) -> float | None:
    with contextlib.suppress(OSError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return float(line.split()[1]) / 1024.0
    return None


# ---------------------------------------------------------------------------------
# steppings
# ---------------------------------------------------------------------------------
def studied_stepping(args) -> tuple[str, Stepping]:
    """(short name, Stepping) of the stepping under study (module doc)."""
    if args.substeps is not None:
        return f"uniform {args.substeps}", Stepping.uniform(args.substeps)
    return args.stepping, STEPPINGS[args.stepping]


def stepping_argv(args) -> list[str]:
    """The command-line options that choose the stepping under study (for the children)."""
    out = ["--stepping", args.stepping]
    if args.substeps is not None:
        out += ["--substeps", str(args.substeps)]
    return out


def plan_record(plan: StepPlan, dt: float = DT) -> dict:
    """A StepPlan's figures for the JSON and the report."""
    return {"substeps": plan.substeps, "step_ns": 1e9 * dt / plan.substeps,
            "refine": plan.refine, "tolerance_m": plan.tolerance if plan.refines else None,
            "locate_events": plan.solver.locate_events, "solver": plan.solver.name}


def describe(plan: StepPlan, dt: float = DT) -> str:
    """A StepPlan in words."""
    text = (f"{plan.solver.name.upper()}, {plan.substeps} sub-steps/sample "
            f"({1e6 * dt / plan.substeps:.3g} µs)")
    if plan.refines:
        text += f", x{plan.refine} where the estimate > {plan.tolerance:.0e} m"
    return text + (", reversals located" if plan.solver.locate_events else
                   ", nothing located")


# ---------------------------------------------------------------------------------
# 6. memory of the gradient, in a fresh process
# ---------------------------------------------------------------------------------
def memory_child(duration_s: float, stepping: Stepping) -> dict:
    """Compile and run the gradient (default adjoint) over ``duration_s`` [s]; memory figures.

    getrusage's ``ru_maxrss`` is the peak over the process's life (it also inherits
    the spawning process's RSS at ``exec``, which is why the parent starts this child
    before it grows). Phase 1: peak increase from before compiling to after the first
    run. Phase 2: the kernel's peak (VmHWM) is reset and a second run measured alone.
    """
    start = {"ru_maxrss_MB": peak_rss_mb(), "VmRSS_MB": _proc_status_mb("VmRSS")}
    actuator = lu2015_slc1720()
    _, u = sawtooth(AMPLITUDE, FREQUENCY, duration_s=duration_s, sample_rate_Hz=FS)
    u = jnp.asarray(u)
    plan = plan_steps(actuator, DT, stepping=stepping)
    q_of, theta0 = parameter_function(actuator, plan, with_pi=False)
    target = jax.block_until_ready(jax.jit(q_of)(theta0 * 1.01, u))

    def loss(theta, u, target):
        return jnp.sum((q_of(theta, u) - target) ** 2)

    gc.collect()
    rss_before = peak_rss_mb()
    vmrss_before = _proc_status_mb("VmRSS")
    compiled, ctime = aot_compile(jax.grad(loss), theta0, u, target)
    rss_compiled = peak_rss_mb()
    ma = compiled.memory_analysis()
    analysis = {}
    for key in ("temp_size_in_bytes", "argument_size_in_bytes", "output_size_in_bytes",
                "alias_size_in_bytes", "generated_code_size_in_bytes"):
        value = getattr(ma, key, None)
        if value is not None:
            analysis[key.replace("_in_bytes", "_MB")] = value / 1e6
    analysis["temp+argument+output_MB"] = sum(
        analysis.get(k, 0.0) for k in ("temp_size_MB", "argument_size_MB", "output_size_MB")
    )
    t0 = time.perf_counter()
    grad = jax.block_until_ready(compiled(theta0, u, target))
    run_s = time.perf_counter() - t0
    rss_after = peak_rss_mb()
    del grad
    gc.collect()
    run_only = None
    with contextlib.suppress(OSError):  # reset VmHWM to the current RSS (Linux >= 4.0)
        Path("/proc/self/clear_refs").write_text("5")
        rss_now = _proc_status_mb("VmRSS")
        grad = jax.block_until_ready(compiled(theta0, u, target))
        hwm = _proc_status_mb("VmHWM")
        if hwm is not None and rss_now is not None:
            run_only = hwm - rss_now
    return {
        "duration_s": duration_s,
        "samples": int(u.shape[0]),
        "plan": plan_record(plan),
        "compile": ctime,
        "first_run_s": run_s,
        "memory_analysis": analysis,
        "process_start": start,
        "ru_maxrss_before_compile_MB": rss_before,
        "VmRSS_before_compile_MB": vmrss_before,
        "peak_rss_increase_MB": rss_after - rss_before,
        "peak_rss_increase_compile_MB": rss_compiled - rss_before,
        "peak_rss_run_only_MB": run_only,
        "grad_finite": bool(np.all(np.isfinite(np.asarray(grad)))),
    }


def run_memory_child(duration_s: float, argv: list[str]) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--memory-child", str(duration_s),
           *argv]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        return {"error": proc.stderr[-2000:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def benchmark_trace(duration_s: float):
    """The benchmark's actuator, voltage (numpy and JAX), its 17-row batch (numpy and
    JAX) and the numba loops' parameters ``(scalars, thresholds, weights)``."""
    actuator = lu2015_slc1720()
    _, u_np = sawtooth(AMPLITUDE, FREQUENCY, duration_s=duration_s, sample_rate_Hz=FS)
    ubatch_np = np.tile(u_np, (N_BATCH, 1))
    return (actuator, u_np, jnp.asarray(u_np), ubatch_np, jnp.asarray(ubatch_np),
            reference_parameters(actuator))


def default_loops_child(duration_s: float, stepping: Stepping, repeats: int) -> dict:
    """Forward timings with XLA's default loop compilation (run in a fresh process):
    the stepping under study and today's, public calls, and the numba plain loop."""
    actuator, u_np, u, _, ubatch, (prm, r, w) = benchmark_trace(duration_s)
    numba_plain(np.ascontiguousarray(u_np[:100]), DT, NUMBA_SUBSTEPS, prm, r, w)
    variants = {
        "jax_single": lambda: simulate(actuator, u, dt=DT, stepping=stepping),
        "jax_batch17": lambda: simulate_batch(actuator, ubatch, dt=DT, stepping=stepping),
        "jax_single_today": lambda: simulate(actuator, u, dt=DT, stepping=TODAY),
        "jax_batch17_today": lambda: simulate_batch(actuator, ubatch, dt=DT, stepping=TODAY),
        "numba_plain": lambda: numba_plain(u_np, DT, NUMBA_SUBSTEPS, prm, r, w),
    }
    stats, _ = interleaved(variants, repeats)
    for name in ("jax_batch17", "jax_batch17_today"):
        for stat in ("median", "min"):
            stats[name][f"per_recording_{stat}_s"] = stats[name][f"{stat}_s"] / N_BATCH
    stats["XLA_FLAGS"] = os.environ.get("XLA_FLAGS")
    stats["plan"] = plan_record(plan_steps(actuator, DT, stepping=stepping))
    return stats


def run_default_loops_child(duration_s: float, argv: list[str], repeats: int) -> dict:
    env = {**os.environ, "XLA_FLAGS": ""}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--default-loops-child",
           str(duration_s), *argv, "--repeats", str(repeats), "--xla-default-loops"]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    if proc.returncode != 0:
        return {"error": proc.stderr[-2000:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------------------
# main
# ---------------------------------------------------------------------------------
def fmt_s(x: float | None) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    if x >= 100:
        return f"{x:.0f} s"
    if x >= 1:
        return f"{x:.2f} s"
    return f"{1e3 * x:.1f} ms"


def batch_in_jit(actuator, voltages, plan: StepPlan):
    """What ``simulate_batch(actuator, voltages, dt=DT, stepping=plan)`` runs, callable
    under ``jax.jit``: the public function makes its sample periods concrete
    (``np.asarray``) before it looks at the plan, which fails on a tracer."""
    b = voltages.shape[0]
    return _simulate_batch(actuator, voltages, jnp.full((b,), DT),
                           stack_drives([DriveContext.make()] * b), plan, DEFAULT_ADJOINT,
                           default_batching())


def first_minus_steady(fn, steady_runs: int) -> float:
    """Wall of ``fn``'s first call after ``jax.clear_caches()`` minus its steady median."""
    jax.clear_caches()
    w_first, _, _ = _timed(fn)
    steady = [_timed(fn)[0] for _ in range(steady_runs)]
    return w_first - float(np.median(steady))


def run(args) -> dict:
    quick = args.quick
    duration = 0.2 if quick else 1.0
    repeats = args.repeats or (2 if quick else 7)
    scipy_repeats = args.scipy_repeats or (1 if quick else 3)
    name, stepping = studied_stepping(args)
    mem_duration = 1.0 if quick else 10.0
    actuator, u_np, u, ubatch_np, ubatch, (prm, r, w) = benchmark_trace(duration)
    n = len(u_np)
    plan = plan_steps(actuator, DT, stepping=stepping)
    today = plan_steps(actuator, DT, stepping=TODAY)
    ref_plan = plan_steps(actuator, DT, stepping=REFERENCE)
    check_plan = plan_steps(actuator, DT, stepping=REFERENCE_CHECK)
    finer = {f"jax_single_today_{k}x": Stepping.uniform(k * NUMBA_SUBSTEPS,
                                                        RK4.with_events(False))
             for k in (2, 4)}
    res: dict = {
        "config": {
            "trace": f"{AMPLITUDE:g} V {FREQUENCY:g} Hz forward sawtooth, lu2015_slc1720",
            "duration_s": duration, "sample_rate_Hz": FS, "samples": n,
            "stepping": name, "plan": plan_record(plan), "plan_text": describe(plan),
            "today_plan": plan_record(today), "today_text": describe(today),
            "numba_substeps": NUMBA_SUBSTEPS,
            "reference": {"max_step_s": REFERENCE.max_step, **plan_record(ref_plan),
                          "check_max_step_s": REFERENCE_CHECK.max_step},
            "batch_rows": N_BATCH, "repeats": repeats, "scipy_repeats": scipy_repeats,
            "quick": quick, "scipy_budget_s": args.scipy_budget,
        },
        "environment": {
            "python": platform.python_version(), "platform": platform.platform(),
            "jax": jax.__version__, "jaxlib": importlib.metadata.version("jaxlib"),
            "equinox": eqx.__version__, "numba": numba.__version__,
            "numba_threads": numba.get_num_threads(), "scipy": scipy.__version__,
            "numpy": np.__version__, "cpu_count": os.cpu_count(),
            "cpu_affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
            else None, "jax_devices": [str(d) for d in jax.devices()],
            "XLA_FLAGS": os.environ.get("XLA_FLAGS"),
            "fast_cpu_loops": not args.xla_default_loops,
        },
    }
    log = print if args.verbose else (lambda *a, **k: None)

    # --- 6. memory, first: the child inherits this process's RSS as its ru_maxrss floor
    log("gradient memory (subprocess) ...")
    mem = run_memory_child(mem_duration, stepping_argv(args))
    log("XLA default loops (subprocess) ...")
    res["default_xla_loops"] = run_default_loops_child(duration, stepping_argv(args), repeats)

    # --- reference ---------------------------------------------------------------
    log("reference ...")
    t0 = time.perf_counter()
    q_ref = np.asarray(simulate(actuator, u, dt=DT, stepping=ref_plan))
    res["config"]["reference"]["run_s"] = time.perf_counter() - t0
    q_check = np.asarray(simulate(actuator, u, dt=DT, stepping=check_plan))
    res["reference_check"] = {"nrmse": nrmse(q_check, q_ref), "nm": rms_nm(q_check, q_ref)}

    # --- 1. JAX compile ----------------------------------------------------------
    log("JAX compile ...")
    comp = {}
    for tag, st, pl in (("", stepping, plan), ("_today", TODAY, today)):
        comp[f"single{tag}_first_minus_steady_s"] = first_minus_steady(
            lambda st=st: simulate(actuator, u, dt=DT, stepping=st), 3)
        comp[f"batch{tag}_first_minus_steady_s"] = first_minus_steady(
            lambda st=st: simulate_batch(actuator, ubatch, dt=DT, stepping=st), 2)
        _, comp[f"single{tag}_aot"] = aot_compile(
            lambda a, v, pl=pl: simulate(a, v, dt=DT, stepping=pl), actuator, u)
        _, comp[f"batch{tag}_aot"] = aot_compile(
            lambda a, v, pl=pl: batch_in_jit(a, v, pl), actuator, ubatch)

    # --- numba compile -----------------------------------------------------------
    log("numba compile ...")
    uref = np.ascontiguousarray(u_np[: 2 * PERIOD_SAMPLES])
    for key, fn, data in (("plain", numba_plain, uref), ("interval", numba_interval, uref),
                          ("batch_prange", numba_plain_batch, ubatch_np[:, :100].copy())):
        t0 = time.perf_counter()
        fn(data, DT, NUMBA_SUBSTEPS, prm, r, w)
        comp[f"numba_{key}_first_call_s"] = time.perf_counter() - t0
    res["compile"] = comp

    # --- the numba loop at the default stepping's accuracy (issue 64) ------------------
    log("numba at equal accuracy ...")
    k_equal, err_equal, ladder = numba_substeps_for(u_np, prm, r, w, q_ref)
    res["numba_equal_accuracy"] = {"target_nm": EQUAL_ACCURACY_NM, "substeps": k_equal,
                                   "error_nm": err_equal, "reached": err_equal
                                   <= EQUAL_ACCURACY_NM,
                                   "ladder_nm": {str(k): v for k, v in ladder.items()}}

    # --- 1-2. forward timings, interleaved -----------------------------------------
    log("forward timings ...")
    fwd_variants = {
        "jax_single": lambda: simulate(actuator, u, dt=DT, stepping=stepping),
        "jax_single_today": lambda: simulate(actuator, u, dt=DT, stepping=TODAY),
        "jax_single_plan": lambda: simulate(actuator, u, dt=DT, stepping=plan),
        "jax_single_today_plan": lambda: simulate(actuator, u, dt=DT, stepping=today),
        "plan_steps": lambda: plan_steps(actuator, DT, stepping=stepping).substeps,
        **{key: (lambda st=st: simulate(actuator, u, dt=DT, stepping=st))
           for key, st in finer.items()},
        "jax_batch17": lambda: simulate_batch(actuator, ubatch, dt=DT, stepping=stepping),
        "jax_batch17_today": lambda: simulate_batch(actuator, ubatch, dt=DT, stepping=TODAY),
        "numba_plain": lambda: numba_plain(u_np, DT, NUMBA_SUBSTEPS, prm, r, w),
        "numba_plain_equal_accuracy": lambda: numba_plain(u_np, DT, k_equal, prm, r, w),
        "numba_interval": lambda: numba_interval(u_np, DT, NUMBA_SUBSTEPS, prm, r, w),
        "numba_plain_batch17_prange": lambda: numba_plain_batch(ubatch_np, DT, NUMBA_SUBSTEPS,
                                                                prm, r, w),
    }
    fwd, outs = interleaved(fwd_variants, repeats)
    res["planning"] = fwd.pop("plan_steps")
    outs.pop("plan_steps")
    batched = ("jax_batch17", "jax_batch17_today", "numba_plain_batch17_prange")
    for key, entry in fwd.items():
        rows = N_BATCH if key in batched else 1
        entry["per_recording_median_s"] = entry["median_s"] / rows
        entry["per_recording_min_s"] = entry["min_s"] / rows
    accuracy, accuracy_nm = {}, {}
    for key, out in outs.items():
        q = np.asarray(out)
        rows = q if q.ndim > 1 else q[None]
        accuracy[key] = max(nrmse(row, q_ref) for row in rows)
        accuracy_nm[key] = max(rms_nm(row, q_ref) for row in rows)
    q_today = np.asarray(outs["jax_single_today"])
    res["consistency_nrmse"] = {
        "numba_plain_vs_jax_today": nrmse(outs["numba_plain"], q_today),
        "numba_interval_vs_jax_today": nrmse(outs["numba_interval"], q_today),
        "jax_batch_row0_vs_single": nrmse(np.asarray(outs["jax_batch17"])[0],
                                          outs["jax_single"]),
        "jax_single_plan_vs_single": nrmse(outs["jax_single_plan"], outs["jax_single"]),
    }

    # --- 3. scipy --------------------------------------------------------------------
    log("scipy ...")
    scipy_res = {}
    runs = {}
    for method in ("LSODA", "RK45", "Radau"):
        for form, fn in (("one_call", scipy_one_call), ("per_interval", scipy_per_interval)):
            key = f"scipy_{method}_{form}"
            pilot_n = min(n, PERIOD_SAMPLES + 1)
            t0 = time.perf_counter()
            fn(u_np[:pilot_n], DT, prm, r, w, method)
            pilot = time.perf_counter() - t0
            projected = pilot * (n - 1) / (pilot_n - 1)
            if method == "LSODA" or projected <= args.scipy_budget:
                m = n
            else:
                per_period = pilot * PERIOD_SAMPLES / (pilot_n - 1)
                periods = max(1, int(args.scipy_budget / per_period))
                m = min(n, periods * PERIOD_SAMPLES + 1)
            runs[key] = (fn, method, m)
            scipy_res[key] = {"method": method, "formulation": form,
                              "simulated_s": (m - 1) / FS, "samples": m,
                              "pilot_s": pilot, "scale_to_full": (n - 1) / (m - 1)}
    walls = {k: [] for k in runs}
    for rep in range(scipy_repeats):
        names = list(runs)
        shift = rep % len(names)
        for key in names[shift:] + names[:shift]:
            fn, method, m = runs[key]
            wall, _, (q, nfev) = _timed(lambda fn=fn, method=method, m=m:
                                        fn(u_np[:m], DT, prm, r, w, method))
            walls[key].append(wall)
            scipy_res[key]["nfev"] = int(nfev)
            scipy_res[key]["nrmse_vs_ref"] = nrmse(q, q_ref[:m])
            scipy_res[key]["nm_vs_ref"] = rms_nm(q, q_ref[:m])
    for key, entry in scipy_res.items():
        scale = entry["scale_to_full"]
        entry["measured"] = _stats(walls[key])
        entry["median_s"] = entry["measured"]["median_s"] * scale
        entry["min_s"] = entry["measured"]["min_s"] * scale
        entry["per_recording_median_s"] = entry["median_s"]
        entry["per_recording_min_s"] = entry["min_s"]
        accuracy[key] = entry["nrmse_vs_ref"]
        accuracy_nm[key] = entry["nm_vs_ref"]
    res["forward"] = {**fwd, **scipy_res}
    res["accuracy_nrmse_vs_reference"] = accuracy
    res["accuracy_nm_vs_reference"] = accuracy_nm

    # --- 5. derivatives -----------------------------------------------------------------
    log("derivatives ...")
    q_phys, theta_phys = parameter_function(actuator, plan, with_pi=False)
    q_all, theta_all = parameter_function(actuator, plan, with_pi=True)
    # How the Jacobian's cost grows with its columns: Mp alone, then Mp, Dp, Kp.
    q_one, theta_one = parameter_function(actuator, plan, with_pi=False, count=1)
    q_three, theta_three = parameter_function(actuator, plan, with_pi=False, count=3)
    q_today_of, _ = parameter_function(actuator, today, with_pi=False)
    target = jax.block_until_ready(jax.jit(q_phys)(theta_phys * 1.01, u))

    q_rev, _ = parameter_function(actuator, plan, with_pi=False, adjoint=CheckpointedScan())
    q_fs, _ = parameter_function(actuator, plan, with_pi=False,
                                 adjoint=ForwardSensitivities(max_directions=64))

    def loss(theta, u, target):
        return jnp.sum((q_phys(theta, u) - target) ** 2)

    def loss_rev(theta, u, target):
        return jnp.sum((q_rev(theta, u) - target) ** 2)

    def loss_fs(theta, u, target):
        return jnp.sum((q_fs(theta, u) - target) ** 2)

    def loss_today(theta, u, target):
        return jnp.sum((q_today_of(theta, u) - target) ** 2)

    deriv_comp = {}
    c_fwd, deriv_comp["forward"] = aot_compile(q_phys, theta_phys, u)
    c_jphys, deriv_comp["jacfwd_phys"] = aot_compile(jax.jacfwd(q_phys), theta_phys, u)
    c_jall, deriv_comp["jacfwd_phys_pi"] = aot_compile(jax.jacfwd(q_all), theta_all, u)
    c_j1, deriv_comp["jacfwd_1"] = aot_compile(jax.jacfwd(q_one), theta_one, u)
    c_j3, deriv_comp["jacfwd_3"] = aot_compile(jax.jacfwd(q_three), theta_three, u)
    c_grad, deriv_comp["grad_phys"] = aot_compile(jax.grad(loss), theta_phys, u, target)
    c_gfwd, deriv_comp["grad_phys_forward_mode"] = aot_compile(
        jax.jacfwd(loss), theta_phys, u, target)
    c_grev, deriv_comp["grad_phys_checkpointed_scan"] = aot_compile(
        jax.grad(loss_rev), theta_phys, u, target)
    c_gfs, deriv_comp["grad_phys_forward_sensitivities"] = aot_compile(
        jax.grad(loss_fs), theta_phys, u, target)
    c_ftoday, deriv_comp["forward_today"] = aot_compile(q_today_of, theta_phys, u)
    c_jtoday, deriv_comp["jacfwd_phys_today"] = aot_compile(
        jax.jacfwd(q_today_of), theta_phys, u)
    c_gtoday, deriv_comp["grad_phys_today"] = aot_compile(
        jax.grad(loss_today), theta_phys, u, target)
    dvariants = {
        "forward": lambda: c_fwd(theta_phys, u),
        "jacfwd_phys": lambda: c_jphys(theta_phys, u),
        "jacfwd_phys_pi": lambda: c_jall(theta_all, u),
        "jacfwd_1": lambda: c_j1(theta_one, u),
        "jacfwd_3": lambda: c_j3(theta_three, u),
        "grad_phys": lambda: c_grad(theta_phys, u, target),
        "grad_phys_forward_mode": lambda: c_gfwd(theta_phys, u, target),
        "grad_phys_checkpointed_scan": lambda: c_grev(theta_phys, u, target),
        "grad_phys_forward_sensitivities": lambda: c_gfs(theta_phys, u, target),
        "forward_today": lambda: c_ftoday(theta_phys, u),
        "jacfwd_phys_today": lambda: c_jtoday(theta_phys, u),
        "grad_phys_today": lambda: c_gtoday(theta_phys, u, target),
    }
    deriv, douts = interleaved(dvariants, repeats)
    base = deriv["forward"]["median_s"]
    for key, entry in deriv.items():
        entry["over_forward"] = entry["median_s"] / base
        entry["compile"] = deriv_comp[key]
    deriv["jacfwd_phys"]["shape"] = list(np.shape(douts["jacfwd_phys"]))
    deriv["jacfwd_phys_pi"]["shape"] = list(np.shape(douts["jacfwd_phys_pi"]))
    deriv["grad_phys"]["value"] = np.asarray(douts["grad_phys"]).tolist()
    deriv["grad_phys"]["finite"] = bool(np.all(np.isfinite(np.asarray(douts["grad_phys"]))))
    deriv["jacfwd_phys"]["finite"] = bool(np.all(np.isfinite(np.asarray(douts["jacfwd_phys"]))))
    g_default = np.asarray(douts["grad_phys"])
    for other in ("grad_phys_forward_mode", "grad_phys_checkpointed_scan",
                  "grad_phys_forward_sensitivities"):
        g = np.asarray(douts[other])
        deriv[other]["max_rel_diff_vs_grad"] = float(
            np.max(np.abs(g - g_default)) / np.max(np.abs(g_default)))
    # The two steppings' Jacobians, column by column (relative to the column's largest).
    j_s, j_t = np.asarray(douts["jacfwd_phys"]), np.asarray(douts["jacfwd_phys_today"])
    scale = np.max(np.abs(j_s), axis=0)
    deriv["jacfwd_phys_today"]["max_rel_diff_by_column_vs_studied"] = [
        float(np.max(np.abs(j_t[:, i] - j_s[:, i])) / s) if s > 0 else None
        for i, s in enumerate(scale)]
    deriv["parameters"] = list(PHYSICAL)
    deriv["default_adjoint_max_directions"] = default_max_directions()
    res["derivatives"] = deriv

    # --- 6. memory (run above, first) -------------------------------------------------------
    if "error" not in mem:
        scale = 10.0 / mem_duration
        mem["scale_to_10s"] = scale
        mem["xla_total_10s_MB"] = mem["memory_analysis"]["temp+argument+output_MB"] * scale
        if scale == 1.0:
            mem["rss_increase_10s_MB"] = mem["peak_rss_increase_MB"]
        else:  # compile memory does not grow with the trace; the run's share does
            mem["rss_increase_10s_MB"] = (mem["peak_rss_increase_compile_MB"]
                                          + scale * (mem["peak_rss_run_only_MB"] or 0.0))
    res["gradient_memory"] = mem

    # --- 7. ratios and targets ------------------------------------------------------------
    f = res["forward"]
    all_compiles = {
        "simulate (first call - steady)": comp["single_first_minus_steady_s"],
        "simulate_batch (first call - steady)": comp["batch_first_minus_steady_s"],
        "simulate (lower+compile)": comp["single_aot"]["total_s"],
        "simulate_batch (lower+compile)": comp["batch_aot"]["total_s"],
        "simulate, today's (first call - steady)": comp["single_today_first_minus_steady_s"],
        "simulate_batch, today's (first call - steady)":
            comp["batch_today_first_minus_steady_s"],
        "jacfwd phys (lower+compile)": deriv_comp["jacfwd_phys"]["total_s"],
        "jacfwd phys+PI (lower+compile)": deriv_comp["jacfwd_phys_pi"]["total_s"],
        "grad phys (lower+compile)": deriv_comp["grad_phys"]["total_s"],
        "jacfwd phys, today's (lower+compile)": deriv_comp["jacfwd_phys_today"]["total_s"],
        "grad phys, today's (lower+compile)": deriv_comp["grad_phys_today"]["total_s"],
    }
    if "compile" in mem:
        all_compiles[f"grad phys {mem_duration:g} s trace (lower+compile)"] = \
            mem["compile"]["total_s"]
    worst_compile = max(all_compiles.items(), key=lambda kv: kv[1])
    mem_10s = (max(mem["xla_total_10s_MB"], mem["rss_increase_10s_MB"])
               if "error" not in mem else float("nan"))

    def per_rec(key, stat):
        if key.startswith("default_loops:"):
            entry = res["default_xla_loops"][key.split(":", 1)[1]]
            return entry.get(f"per_recording_{stat}_s", entry[f"{stat}_s"])
        if key == "lsoda_best":
            return min(per_rec("scipy_LSODA_one_call", stat),
                       per_rec("scipy_LSODA_per_interval", stat))
        if key in deriv:
            return deriv[key][f"{stat}_s"]
        return f[key][f"per_recording_{stat}_s"]

    def ratio(name_, num, den, target=None, le=True, info=""):
        value = per_rec(num, "median") / per_rec(den, "median")
        out = {"name": name_, "value": value, "value_of_minima": per_rec(num, "min")
               / per_rec(den, "min"), "info": info}
        if target is not None:
            ok = value <= target if le else value >= target
            out.update(target=target, target_op="<=" if le else ">=",
                       status="PASS" if ok else "MISS")
        return out

    def limit(name_, value, target, info):
        return {"name": name_, "value": value, "target": target, "target_op": "<=",
                "status": "PASS" if value <= target else "MISS", "info": info}

    def plain(name_, value, info=""):
        return {"name": name_, "value": value, "info": info}

    ratios = [
        ratio(f"JAX simulate, 1 recording: {name} / today's", "jax_single",
              "jax_single_today", TARGETS["forward_over_today"],
              info="issue 26; public calls, planning included"),
        ratio(f"JAX simulate_batch per recording: {name} / today's", "jax_batch17",
              "jax_batch17_today", TARGETS["forward_over_today"], info="issue 26"),
        ratio(f"JAX simulate, plan made once: {name} / today's", "jax_single_plan",
              "jax_single_today_plan", info="planning excluded"),
        ratio(f"JAX batched per recording ({name}) / numba plain", "jax_batch17",
              "numba_plain", TARGETS["batched_per_recording_over_numba"]),
        ratio("JAX batched per recording (today's) / numba plain", "jax_batch17_today",
              "numba_plain", info="same scheme"),
        ratio(f"JAX single ({name}) / numba plain", "jax_single", "numba_plain"),
        ratio(f"JAX single ({name}) / numba plain at {EQUAL_ACCURACY_NM:g} nm "
              f"({k_equal} sub-steps/sample"
              f"{'' if err_equal <= EQUAL_ACCURACY_NM else ', not reached'})",
              "jax_single", "numba_plain_equal_accuracy",
              TARGETS["forward_over_numba_equal_accuracy"], info="issue 64"),
        ratio("JAX single (today's) / numba plain", "jax_single_today", "numba_plain"),
        ratio(f"JAX batched per rec. ({name}) / numba per-interval PI", "jax_batch17",
              "numba_interval"),
        ratio(f"JAX batched per rec. ({name}) / numba 17 rec. prange per rec.",
              "jax_batch17", "numba_plain_batch17_prange"),
        ratio(f"LSODA (faster formulation) / JAX single ({name})", "lsoda_best",
              "jax_single", TARGETS["lsoda_over_jax"], le=False),
        ratio(f"LSODA (faster formulation) / JAX batched per recording ({name})",
              "lsoda_best", "jax_batch17"),
        ratio("LSODA one call / JAX batched per recording", "scipy_LSODA_one_call",
              "jax_batch17"),
        ratio("LSODA per interval / JAX batched per recording", "scipy_LSODA_per_interval",
              "jax_batch17"),
    ]
    if "error" not in res["default_xla_loops"]:
        ratios += [
            ratio(f"XLA default loops: JAX single ({name}) / numba plain (same process)",
                  "default_loops:jax_single", "default_loops:numba_plain"),
            ratio(f"XLA default loops: JAX batched per rec. ({name}) / numba plain",
                  "default_loops:jax_batch17", "default_loops:numba_plain"),
            ratio(f"XLA default loops: JAX single, {name} / today's",
                  "default_loops:jax_single", "default_loops:jax_single_today"),
            ratio(f"XLA default loops: JAX batched per rec., {name} / today's",
                  "default_loops:jax_batch17", "default_loops:jax_batch17_today",
                  info="rows vmapped"),
            ratio(f"XLA default loops: LSODA (faster) / JAX single ({name})", "lsoda_best",
                  "default_loops:jax_single"),
        ]
    ratios += [
        ratio("jacfwd (9 physical) / forward", "jacfwd_phys", "forward",
              TARGETS["jacfwd_over_forward"]),
        ratio("jacfwd (9 physical + 35 PI weights) / forward", "jacfwd_phys_pi", "forward"),
        ratio("jacfwd (Mp only) / forward", "jacfwd_1", "forward"),
        ratio("jacfwd (Mp, Dp, Kp) / forward", "jacfwd_3", "forward"),
        ratio("grad (9 physical, jax.grad) / forward", "grad_phys", "forward",
              TARGETS["grad_over_forward"]),
        ratio("same gradient by forward mode (jacfwd of loss) / fwd", "grad_phys_forward_mode",
              "forward"),
        ratio("jax.grad with adjoint=CheckpointedScan() (reverse mode) / forward",
              "grad_phys_checkpointed_scan", "forward"),
        ratio("jax.grad, ForwardSensitivities(max_directions=64) / forward",
              "grad_phys_forward_sensitivities", "forward"),
        ratio("today's: jacfwd (9 physical) / today's forward", "jacfwd_phys_today",
              "forward_today", info="the ratio before event location"),
        ratio("today's: grad (9 physical) / today's forward", "grad_phys_today",
              "forward_today", info="the ratio before event location"),
        ratio(f"jacfwd (9 physical): {name} / today's", "jacfwd_phys", "jacfwd_phys_today"),
        ratio(f"grad (9 physical): {name} / today's", "grad_phys", "grad_phys_today"),
        plain(f"jacfwd (9 physical) compile: {name} / today's",
              deriv_comp["jacfwd_phys"]["total_s"] / deriv_comp["jacfwd_phys_today"]["total_s"],
              f"{fmt_s(deriv_comp['jacfwd_phys']['total_s'])} against "
              f"{fmt_s(deriv_comp['jacfwd_phys_today']['total_s'])}"),
        plain(f"grad (9 physical) compile: {name} / today's",
              deriv_comp["grad_phys"]["total_s"] / deriv_comp["grad_phys_today"]["total_s"],
              f"{fmt_s(deriv_comp['grad_phys']['total_s'])} against "
              f"{fmt_s(deriv_comp['grad_phys_today']['total_s'])}"),
        plain(f"simulate compile: {name} / today's",
              comp["single_aot"]["total_s"] / comp["single_today_aot"]["total_s"],
              "lower+compile"),
        limit("worst compile time [s]", worst_compile[1], TARGETS["compile_s"],
              worst_compile[0]),
        limit("gradient memory, 10 s trace [MB]", mem_10s, TARGETS["grad_memory_10s_MB"],
              "max(XLA temp+arg+out, peak RSS increase)"
              + ("" if mem_duration == 10.0 else f"; {mem_duration:g} s trace: XLA and run "
                 f"RSS scaled x{10.0 / mem_duration:g}")),
    ]
    res["compile_all_s"] = all_compiles
    res["ratios"] = ratios
    return res


def print_report(res: dict) -> None:
    c, e, f = res["config"], res["environment"], res["forward"]
    acc, acc_nm = res["accuracy_nrmse_vs_reference"], res["accuracy_nm_vs_reference"]
    name = c["stepping"]
    print(f"stickslip_jax simulator benchmark: {c['duration_s']:g} s at {c['sample_rate_Hz']/1e3:g}"
          f" kHz ({c['samples']} samples), {c['trace']}"
          + ("  [QUICK smoke run: short trace, few repeats]" if c["quick"] else ""))
    print(f"machine: {e['cpu_count']} CPUs ({e['cpu_affinity']} usable), {e['platform']}; "
          f"jax {e['jax']}, numba {e['numba']} ({e['numba_threads']} threads), scipy "
          f"{e['scipy']}; medians of {c['repeats']} interleaved runs (scipy: "
          f"{c['scipy_repeats']})")
    print(f"stepping under study ({name}): {c['plan_text']}")
    print(f"today's stepping: {c['today_text']}; numba loops: RK4, {c['numba_substeps']} "
          "sub-steps/sample, nothing located")
    ref, chk = c["reference"], res["reference_check"]
    print(f"reference: JAX simulator, uniform {ref['max_step_s'] * 1e9:g} ns steps "
          f"({ref['substeps']} per sample), switches located, no refinement "
          f"({fmt_s(ref.get('run_s'))}); at {ref['check_max_step_s'] * 1e9:g} ns it differs "
          f"by NRMSE {chk['nrmse']:.1e}, {chk['nm']:.1e} nm: figures near that are "
          "reference-limited\n")
    hdr = (f"{'forward simulation':56s} {'median':>9s} {'min':>9s} {'per rec.':>9s} "
           f"{'cpu/wall':>8s} {'NRMSE':>8s} {'nm RMS':>8s}  note")
    print(hdr)
    print("-" * len(hdr))
    labels = {
        "jax_single": f"JAX simulate, 1 recording, {name}",
        "jax_single_today": "JAX simulate, 1 recording, today's",
        "jax_single_plan": f"JAX simulate, 1 recording, {name}, plan made once",
        "jax_single_today_plan": "JAX simulate, 1 recording, today's, plan made once",
        "jax_single_today_2x": f"JAX today's scheme, {2 * c['numba_substeps']} sub-steps (info)",
        "jax_single_today_4x": f"JAX today's scheme, {4 * c['numba_substeps']} sub-steps (info)",
        "jax_batch17": f"JAX simulate_batch, {c['batch_rows']} recordings, {name}",
        "jax_batch17_today": f"JAX simulate_batch, {c['batch_rows']} recordings, today's",
        "numba_plain": "numba plain loop (contract scheme)",
        "numba_plain_equal_accuracy": (f"numba plain, {res['numba_equal_accuracy']['substeps']}"
                                       f" sub-steps (≤ {EQUAL_ACCURACY_NM:g} nm?)"),
        "numba_interval": "numba, per-interval PI (as the JAX code)",
        "numba_plain_batch17_prange": f"numba plain, {c['batch_rows']} recordings, prange",
    }
    for key, entry in f.items():
        label = labels.get(key)
        note = ""
        if label is None:
            label = f"scipy {entry['method']} ({entry['formulation'].replace('_', ' ')})"
            note = f"nfev {entry['nfev']}"
            if entry["scale_to_full"] > 1.0 + 1e-9:
                note += (f"; timed on {entry['simulated_s']:g} s prefix, scaled x"
                         f"{entry['scale_to_full']:.3g}, errors on prefix")
        cw = entry.get("cpu_over_wall")
        print(f"{label:56s} {fmt_s(entry['median_s']):>9s} {fmt_s(entry['min_s']):>9s} "
              f"{fmt_s(entry['per_recording_median_s']):>9s} "
              f"{(f'{cw:.2f}' if cw else '-'):>8s} {acc[key]:8.1e} {acc_nm[key]:8.1e}  {note}")
    pl = res["planning"]
    print(f"planning alone (plan_steps, {name}, in every public call): median "
          f"{fmt_s(pl['median_s'])}, min {fmt_s(pl['min_s'])}")
    cons = res["consistency_nrmse"]
    print(f"numba vs JAX today's (same scheme), NRMSE: plain "
          f"{cons['numba_plain_vs_jax_today']:.1e}, per-interval "
          f"{cons['numba_interval_vs_jax_today']:.1e}; JAX batch row 0 vs single "
          f"{cons['jax_batch_row0_vs_single']:.1e}; plan made once vs public call "
          f"{cons['jax_single_plan_vs_single']:.1e}")

    comp = res["compile"]
    print("\ncompile / first call")
    for tag, what in (("", name), ("_today", "today's")):
        for kind in ("single", "batch"):
            fn = "simulate" if kind == "single" else "simulate_batch"
            aot = comp[f"{kind}{tag}_aot"]
            print(f"  {fn + ', ' + what + ':':30s} first call - steady "
                  f"{fmt_s(comp[f'{kind}{tag}_first_minus_steady_s'])}; lower "
                  f"{fmt_s(aot['lower_s'])} + compile {fmt_s(aot['compile_s'])}")
    print(f"  numba first call (compile + 2 periods): plain "
          f"{fmt_s(comp['numba_plain_first_call_s'])}, per-interval "
          f"{fmt_s(comp['numba_interval_first_call_s'])}, prange "
          f"{fmt_s(comp['numba_batch_prange_first_call_s'])}")

    dl = res.get("default_xla_loops", {})
    if "error" in dl:
        print("\nXLA default loops (fresh process): FAILED: "
              + dl["error"].strip().splitlines()[-1])
    else:
        print("\nXLA default loops (fresh process), per recording: "
              + ", ".join(f"{k} {fmt_s(v.get('per_recording_median_s', v['median_s']))}"
                          for k, v in dl.items() if isinstance(v, dict) and "median_s" in v))

    d = res["derivatives"]
    hdr = (f"{'derivatives (θ → q, jitted)':56s} {'median':>9s} {'min':>9s} {'x fwd':>9s} "
           f"{'cpu/wall':>8s} {'compile':>8s}")
    print("\n" + hdr)
    print("-" * len(hdr))
    dlab = {"forward": f"forward q(θ), {name}", "jacfwd_phys": "jacfwd, 9 physical parameters",
            "jacfwd_phys_pi": "jacfwd, 9 physical + 35 PI weights",
            "jacfwd_1": "jacfwd, Mp only (how the cost grows)",
            "jacfwd_3": "jacfwd, Mp, Dp, Kp (how the cost grows)",
            "grad_phys": "grad of sum((q - target)^2), 9 physical (default)",
            "grad_phys_forward_mode": "same gradient by jacfwd(loss) (info, forward mode)",
            "grad_phys_checkpointed_scan": "grad, adjoint=CheckpointedScan() (reverse)",
            "grad_phys_forward_sensitivities": "grad, ForwardSensitivities(max_directions=64)",
            "forward_today": "forward q(θ), today's",
            "jacfwd_phys_today": "jacfwd, 9 physical parameters, today's",
            "grad_phys_today": "grad of sum((q - target)^2), 9 physical, today's"}
    for key, label in dlab.items():
        entry = d[key]
        print(f"{label:56s} {fmt_s(entry['median_s']):>9s} {fmt_s(entry['min_s']):>9s} "
              f"{entry['over_forward']:9.2f} {entry['cpu_over_wall']:8.2f} "
              f"{fmt_s(entry['compile']['total_s']):>8s}")
    cols = d["jacfwd_phys_today"]["max_rel_diff_by_column_vs_studied"]
    print("jacfwd today's vs " + name + ", max |difference| / column max: "
          + ", ".join(f"{p} {'-' if v is None else f'{v:.1e}'}"
                      for p, v in zip(d["parameters"], cols, strict=True)))

    m = res["gradient_memory"]
    print("\ngradient memory (fresh process)")
    if "error" in m:
        print("  FAILED: " + m["error"].strip().splitlines()[-1])
    else:
        ma = m["memory_analysis"]
        run_only = m["peak_rss_run_only_MB"]
        print(f"  {m['duration_s']:g} s trace ({m['samples']} samples): XLA temp "
              f"{ma.get('temp_size_MB', float('nan')):.1f} MB, arguments "
              f"{ma.get('argument_size_MB', float('nan')):.1f} MB, output "
              f"{ma.get('output_size_MB', float('nan')):.3f} MB; peak RSS increase "
              f"{m['peak_rss_increase_MB']:.0f} MB (compile alone "
              f"{m['peak_rss_increase_compile_MB']:.0f} MB"
              + (f", run alone {run_only:.0f} MB" if run_only is not None else "")
              + f"); compile {fmt_s(m['compile']['total_s'])}, run {fmt_s(m['first_run_s'])}")

    hdr = f"{'ratio':70s} {'medians':>9s} {'minima':>9s} {'target':>9s}  status"
    print("\n" + hdr)
    print("-" * len(hdr))
    for r_ in res["ratios"]:
        tgt = f"{r_['target_op']} {r_['target']:g}" if "target" in r_ else ""
        vmin = f"{r_['value_of_minima']:9.2f}" if "value_of_minima" in r_ else f"{'':9s}"
        info = f"  ({r_['info']})" if r_.get("info") else ""
        print(f"{r_['name']:70s} {r_['value']:9.2f} {vmin} {tgt:>9s}  {r_.get('status', '')}"
              f"{info}")
    if c["quick"]:
        print("\n(quick run: figures are indicative only; run without --quick for the real "
              "comparison)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, help="write all results to this JSON file")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 0.2 s trace, 2 repeats, 1 s memory trace")
    ap.add_argument("--stepping", choices=sorted(STEPPINGS), default="default",
                    help="the stepping under study (derivatives, memory, XLA-default-loops "
                    "child), timed beside today's: 'default' (Stepping(), the default) or "
                    "'today' (RK4, 16 sub-steps per sample, nothing located or refined)")
    ap.add_argument("--substeps", type=int, default=None,
                    help="study N uniform RK4 sub-steps per sample with located reversals "
                    "instead (Stepping.uniform(N); overrides --stepping)")
    ap.add_argument("--repeats", type=int, default=None,
                    help="timed repeats per variant (default 7, quick 2)")
    ap.add_argument("--scipy-repeats", type=int, default=None,
                    help="timed repeats per scipy variant (default 3, quick 1)")
    ap.add_argument("--scipy-budget", type=float, default=8.0,
                    help="seconds per RK45/Radau run before a prefix is used (default 8)")
    ap.add_argument("--verbose", action="store_true", help="print progress")
    ap.add_argument("--xla-default-loops", action="store_true",
                    help="keep XLA's default loop compilation (skip fast_cpu_loops)")
    ap.add_argument("--memory-child", type=float, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--default-loops-child", type=float, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.substeps is not None and args.substeps < 1:
        ap.error("--substeps must be at least 1")
    if not args.xla_default_loops:
        fast_cpu_loops()  # before JAX's first computation in this process
    _, stepping = studied_stepping(args)
    if args.default_loops_child is not None:
        print(json.dumps(default_loops_child(args.default_loops_child, stepping,
                                             args.repeats or 7)))
        return 0
    if args.memory_child is not None:
        print(json.dumps(memory_child(args.memory_child, stepping)))
        return 0
    res = run(args)
    if args.json:  # first: a report that fails to print loses no measurement
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=2))
    print_report(res)
    if args.json:
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The stepping rules: located switches, refined intervals, plans, derivatives across slips.

Derivatives: the located switch time depends on the parameters; its derivative goes
into the sensitivities through the differentiable Hermite root. Checked against
central differences on a drive that slips every period (40 V, 500 Hz, backward), with
uniform located sub-steps (no refinement decision can flip between the difference
quotient's two runs) and with the default stepping (where a flip moves the trace by
about the 0.1 pm tolerance, so the difference step is larger).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.model.base import DriveContext
from stickslip_jax.stepping import _hermite_root

DT = 4e-5
NAMES = ("Mp", "Kp", "Ds", "rho0", "z_ba_backward")


def _where(a):
    return (a.piezo.Mp, a.piezo.Kp, a.slider.Ds, a.friction.rho0, a.friction.z_ba_backward)


def test_hermite_root_is_exact_on_a_cubic_and_differentiable():
    # g(θ) = (θ − 0.3)(θ + 1)(θ + 2), Hermite data at 0 and 1 reproduce it exactly.
    def g(t, c):
        return (t - c) * (t + 1) * (t + 2)

    def dg(t, c):
        return jax.grad(g)(t, c)

    def root(c):
        return _hermite_root(g(0.0, c), dg(0.0, c), g(1.0, c), dg(1.0, c))

    assert float(root(0.3)) == pytest.approx(0.3, abs=1e-12)
    # d(root)/dc = 1: the located time moves with the parameter.
    assert float(jax.grad(root)(0.3)) == pytest.approx(1.0, abs=1e-8)


@pytest.fixture(scope="module")
def slipping():
    base = ss.lu2015_slc1720()
    p0 = jnp.stack(_where(base))
    u = jnp.asarray(ss.sawtooth(40.0, 500.0, direction="backward", duration_s=0.012)[1])
    drive = DriveContext.make(True, 40.0, 500.0)

    def q_of(delta, stepping):
        a = eqx.tree_at(_where, base, tuple(p0 * (1.0 + delta)))
        return ss.simulate(a, u, dt=DT, drive=drive, stepping=stepping)

    return base, u, drive, q_of


def _central(fun, i, h):
    e = np.zeros(len(NAMES))
    e[i] = h
    return (np.asarray(fun(jnp.asarray(e))) - np.asarray(fun(jnp.asarray(-e)))) / (2 * h)


def test_trace_slips_and_reverses(slipping):
    # The check below is across events: the drive slips (net motion per period) and
    # the relative velocity reverses in slip (|z| > z_ba with ẋ changing sign).
    base, u, drive, _ = slipping
    tr = ss.simulate_states(base, u, dt=DT, drive=drive)
    assert float(tr.q[-1] - tr.q[0]) < -1e-6
    xd, z = np.asarray(tr.v1 - tr.v2), np.asarray(tr.z)
    z_ba = float(base.friction.z_ba_backward)
    assert np.any((np.abs(z) > z_ba) & (np.sign(xd) != np.sign(z)))


@pytest.mark.parametrize("kind", ["uniform", "default"])
def test_jacfwd_matches_differences_across_slips(slipping, kind):
    base, _, _, q_of = slipping
    if kind == "uniform":
        plan, h, tol = ss.plan_steps(base, DT, substeps=16), 1e-6, 1e-5
    else:
        plan, h, tol = ss.plan_steps(base, DT), 1e-4, 2e-3
    jac = np.asarray(jax.jacfwd(lambda d: q_of(d, plan))(jnp.zeros(len(NAMES))))
    for i, name in enumerate(NAMES):
        fd = _central(lambda d, plan=plan: q_of(d, plan), i, h)
        err = np.linalg.norm(fd - jac[:, i]) / np.linalg.norm(jac[:, i])
        assert err < tol, (kind, name, err)
        assert np.linalg.norm(jac[:, i]) > 1e-8, name   # every column matters


def test_reverse_mode_equals_forward_mode_across_slips(slipping):
    base, u, drive, _ = slipping
    plan = ss.plan_steps(base, DT)
    p0 = jnp.stack(_where(base))
    target = np.asarray(ss.simulate(base, u, dt=DT, drive=drive, stepping=plan)) * 1.001

    def loss(delta, adjoint):
        a = eqx.tree_at(_where, base, tuple(p0 * (1.0 + delta)))
        q = ss.simulate(a, u, dt=DT, drive=drive, stepping=plan, adjoint=adjoint)
        return jnp.sum((q - target) ** 2) / 1e-18

    zero = jnp.zeros(len(NAMES))
    rev = np.asarray(jax.grad(loss)(zero, ss.CheckpointedScan()))
    fwd = np.asarray(jax.grad(loss)(zero, ss.ForwardSensitivities(max_directions=64)))
    np.testing.assert_allclose(rev, fwd, rtol=1e-8, atol=1e-10 * np.abs(rev).max())


def test_vmap_and_map_agree_with_refinement():
    # Under vmap the refinement's cond becomes a select; the numbers must not change.
    act = ss.lu2015_slc1720()
    volts = np.stack([ss.sawtooth(60.0, 500.0, direction=d, duration_s=0.01)[1]
                      for d in ("forward", "backward")])
    drives = ss.stack_drives([DriveContext.make(b, 60.0, 500.0) for b in (False, True)])
    q_map = np.asarray(ss.simulate_batch(act, volts, dt=DT, drives=drives, batching="map"))
    q_vmap = np.asarray(ss.simulate_batch(act, volts, dt=DT, drives=drives, batching="vmap"))
    np.testing.assert_allclose(q_vmap, q_map, rtol=0, atol=1e-18)


def test_plan_follows_the_model_and_stays_put_under_small_changes():
    act = ss.lu2015_slc1720()
    plan = ss.plan_steps(act, DT)
    # The 17.5 kHz stick mode at 0.5 rad per step: 4.6 µs, so 9 sub-steps of 40 µs.
    assert plan.substeps == 9 and plan.refine == ss.DEFAULT_STEPPING.refine
    nudged = eqx.tree_at(lambda a: a.piezo.Kp, act, act.piezo.Kp * 1.01)
    assert ss.plan_steps(nudged, DT) == plan          # same static plan: no recompilation
    stiff = eqx.tree_at(lambda a: a.piezo.Mp, act, act.piezo.Mp / 16)
    assert ss.plan_steps(stiff, DT).substeps >= 4 * plan.substeps - 3
    assert ss.plan_steps(act, DT, stepping=ss.Stepping(max_step=1e-6)).substeps == 40
    assert ss.plan_steps(act, DT, substeps=5) == ss.StepPlan(5, 1)


def test_refinement_takes_only_the_intervals_that_need_it():
    # A 50 Hz stepping drive: the refined intervals are the edge and its ringing, a
    # few in a period of 500 samples.
    from stickslip_jax.simulate import rest_carry
    from stickslip_jax.stepping import _interval_integrator

    act = ss.lu2015_slc1720()
    u = jnp.asarray(ss.sawtooth(40.0, 50.0, duration_s=0.06)[1])
    drive = DriveContext.make(False, 40.0, 50.0)
    plan = ss.plan_steps(act, DT)
    run = _interval_integrator(act, DT, drive, plan)

    def body(c, pair):
        y, m = c
        y1, _, est = run(y, m, pair[0], pair[1] - pair[0], 0.0, 1.0)
        return (y1, act.commit_memory(y1, m, pair[1])), est

    carry, _ = rest_carry(act, u[0], drive)
    _, est = jax.jit(lambda: jax.lax.scan(body, carry, (u[:-1], u[1:])))()
    refined = np.asarray(est) > plan.tolerance
    per_period = refined[500:1000]
    assert 2 <= per_period.sum() <= 20, np.flatnonzero(per_period)
    # They are at the edge (sample 499 → 500 of the period) and just after it.
    assert set(np.flatnonzero(per_period)) <= set(range(0, 20)) | {499}


def test_nonfinite_voltage_is_reported():
    act = ss.lu2015_slc1720()
    u = np.asarray(ss.sawtooth(40.0, 50.0, duration_s=0.01)[1])
    u[100] = np.inf
    with pytest.raises(ss.NonFiniteSimulation, match="non-finite at sample"):
        ss.simulate(act, u, dt=DT)


def test_stepping_settings_are_checked():
    with pytest.raises(ValueError, match="max_step"):
        ss.Stepping(max_step=-1.0)
    with pytest.raises(ValueError, match="tolerance"):
        ss.Stepping(tolerance=0.0)
    with pytest.raises(ValueError, match="refine"):
        ss.Stepping(refine=0)

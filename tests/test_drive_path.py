"""The input stage integrated apart from the mechanics (stickslip_jax/drive_path.py):
the table against closed forms, the interpolation, the plan, the trace and its
derivative against a finely stepped reference."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.drive_path import grid_points, has_closed_form, stage_table, table_voltage
from stickslip_jax.model.base import AbstractInputStage
from stickslip_jax.model.extensions import LowPassInput, SecondOrderInput
from stickslip_jax.synthetic import DriveSpec


class SteppedLowPass(LowPassInput):
    """The low-pass without its closed form: the table takes RK4 steps of its rate."""

    advance = AbstractInputStage.advance


@pytest.mark.parametrize("stage_type, atol", [(LowPassInput, 1e-12), (SteppedLowPass, 2e-6)],
                         ids=["closed_form", "rk4_steps"])
def test_low_pass_table_matches_the_closed_form(stage_type, atol):
    """Under a linear command u_a + du·τ, τ·ṡ = u − s has the exact solution
    s = u − T·u̇ + (s0 − u_a + T·u̇)·e^(−t/T); the table reaches it at every point, in
    closed form to rounding, by RK4 steps to their error."""
    tau, dt = 2e-6, 10e-6
    stage = stage_type(tau, mix=0.75)
    assert has_closed_form(stage) == (stage_type is LowPassInput)
    points = jnp.asarray(grid_points((0.0, 0.5, 1.0), 8)[0])
    s0, u_a, du = jnp.asarray([3.0]), 1.0, 4.0
    states, volts, rates = stage_table(stage, s0, u_a, du, dt, points, steps=6)
    t = np.asarray(points) * dt
    slope = du / dt
    exact = u_a + slope * t - tau * slope + (3.0 - u_a + tau * slope) * np.exp(-t / tau)
    np.testing.assert_allclose(np.asarray(states[:, 0]), exact, rtol=0, atol=atol)
    u = u_a + du * np.asarray(points)
    np.testing.assert_allclose(np.asarray(volts), u + 0.75 * (exact - u), atol=atol)
    # The rate per unit fraction: mix·ṡ·dt + (1 − mix)·du.
    s_dot = (u - exact) / tau
    np.testing.assert_allclose(np.asarray(rates), 0.75 * s_dot * dt + 0.25 * du,
                               atol=10 * atol * dt / tau)


def test_a_vanishing_time_constant_stays_finite_in_value_and_derivative():
    """A fit with no drive effect drives the low-pass's τ towards 0 (the pass-through)
    from a plan made at its start: the closed form stays finite there, the RK4 steps
    planned for the start's τ would not."""
    rec = DriveSpec("sawtooth", 60.0, 500.0, "forward", 0.004).recording()
    u = jnp.asarray(rec.voltage_V)
    base = ss.lu2015_slc1720()
    plan = ss.plan_steps(eqx.tree_at(lambda a: a.input_stage, base, LowPassInput(2e-6)), rec.dt)

    def trace(log_tau):
        act = eqx.tree_at(lambda a: a.input_stage, base, LowPassInput(jnp.exp(log_tau)))
        return ss.simulate(act, u, dt=rec.dt, stepping=plan)

    q, dq = jax.jvp(trace, (jnp.log(3e-8),), (jnp.asarray(1.0),))
    assert np.all(np.isfinite(np.asarray(q))) and np.all(np.isfinite(np.asarray(dq)))
    # Nearly the pass-through: a lag of 30 ns moves the trace by a few per cent of 2 µs.
    q_plain = np.asarray(ss.simulate(base, u, dt=rec.dt, stepping=plan))
    at_start = np.asarray(trace(jnp.log(2e-6)))
    moved = np.max(np.abs(np.asarray(q) - q_plain))
    assert 0 < moved < 0.05 * np.max(np.abs(at_start - q_plain))


def test_hermite_voltage_is_exact_on_a_cubic_and_hits_the_table():
    points = jnp.asarray(grid_points((0.0, 0.5, 1.0), 3)[0])

    def cubic(x):
        return 2.0 - x + 3.0 * x**2 - 5.0 * x**3

    def slope(x):
        return -1.0 + 6.0 * x - 15.0 * x**2

    volts, rates = cubic(points), slope(points)
    for x in (0.0, 0.07, 1 / 6, 0.41, 0.5, 0.93, 1.0):
        np.testing.assert_allclose(float(table_voltage(x, points, volts, rates)), cubic(x),
                                   rtol=0, atol=1e-13)


def test_a_fast_amplifier_leaves_the_mechanical_step_as_it_is():
    """The stage's pole no longer sets the sub-step: a 1 µs low-pass plans the baseline's
    coarse sub-steps, with its own steps between stage times resolving 1/τ."""
    base = ss.lu2015_slc1720()
    dt = 1e-5
    plain = ss.plan_steps(base, dt)
    act = eqx.tree_at(lambda a: a.input_stage, base, LowPassInput(1e-6))
    plan = ss.plan_steps(act, dt)
    assert plan.substeps == plain.substeps
    assert plan.stage_substeps == 1          # advanced in closed form
    stepped = ss.plan_steps(eqx.tree_at(lambda a: a.input_stage, base, SteppedLowPass(1e-6)),
                            dt)
    gap = dt / plan.substeps / 2
    assert stepped.substeps == plain.substeps
    assert stepped.stage_substeps == int(np.ceil(gap / 1e-6 / 0.5)) > 1
    assert ss.fastest_rate(act) == pytest.approx(1e6, rel=1e-9)
    assert ss.mechanical_rate(act) == pytest.approx(ss.fastest_rate(base), rel=1e-9)


@pytest.fixture(scope="module")
def saw():
    rec = DriveSpec("sawtooth", 40.0, 500.0, "forward", 0.006).recording()
    return rec, jnp.asarray(rec.voltage_V)


@pytest.mark.parametrize("stage", [LowPassInput(1e-6), SecondOrderInput(60e3, 0.5),
                                   ss.SlewLimitedInput(0.4e6, 0.2e-6)],
                         ids=["low_pass_1us", "two_pole_60kHz", "slew_0.2us_exact"])
def test_trace_matches_a_finely_stepped_reference(saw, stage):
    """Default stepping against the reference stepping (16x shorter steps, each pole
    resolved): within 0.05 nm RMS on a 500 Hz sawtooth, where the stage itself moves
    the trace by nanometres."""
    rec, u = saw
    base = ss.lu2015_slc1720()
    act = eqx.tree_at(lambda a: a.input_stage, base, stage)
    q = np.asarray(ss.simulate(act, u, dt=rec.dt))
    ref = np.asarray(ss.simulate(act, u, dt=rec.dt, stepping=ss.REFERENCE_STEPPING))
    effect = ref - np.asarray(ss.simulate(base, u, dt=rec.dt, stepping=ss.REFERENCE_STEPPING))
    assert np.sqrt(np.mean(effect**2)) > 1e-9
    assert np.sqrt(np.mean((q - ref) ** 2)) < 5e-11


def test_derivative_in_the_time_constant_matches_finite_differences(saw):
    rec, u = saw
    base = ss.lu2015_slc1720()
    tau = 3e-6
    plan = ss.plan_steps(eqx.tree_at(lambda a: a.input_stage, base, LowPassInput(tau)), rec.dt)

    def trace(t):
        act = eqx.tree_at(lambda a: a.input_stage, base, LowPassInput(t))
        return ss.simulate(act, u, dt=rec.dt, stepping=plan)

    _, tangent = jax.jvp(trace, (jnp.asarray(tau),), (jnp.asarray(1.0),))
    h = 1e-3 * tau
    central = (trace(jnp.asarray(tau + h)) - trace(jnp.asarray(tau - h))) / (2 * h)
    tangent, central = np.asarray(tangent), np.asarray(central)
    assert np.max(np.abs(tangent)) > 1e-4   # metres per second of τ: it matters
    np.testing.assert_allclose(tangent, central, rtol=0, atol=1e-3 * np.max(np.abs(central)))


def test_apart_and_inside_the_mechanical_step_agree(saw):
    """The stage integrated apart gives the trace that integrating it inside the
    mechanical step gives, with an eighth of the sub-steps for a 1 µs amplifier."""
    rec, u = saw
    act = eqx.tree_at(lambda a: a.input_stage, ss.lu2015_slc1720(), LowPassInput(1e-6))
    inside = ss.Stepping(stage_apart=False)
    plan_in, plan_apart = ss.plan_steps(act, rec.dt, stepping=inside), ss.plan_steps(act, rec.dt)
    assert plan_in.substeps >= 8 * plan_apart.substeps
    q_in = np.asarray(ss.simulate(act, u, dt=rec.dt, stepping=plan_in))
    q_apart = np.asarray(ss.simulate(act, u, dt=rec.dt, stepping=plan_apart))
    assert np.sqrt(np.mean((q_in - q_apart) ** 2)) < 2e-11

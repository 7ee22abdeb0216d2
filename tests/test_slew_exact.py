"""The exact step of the tanh slew-limited drive stage (stickslip_jax/model/slew_exact.py)
against a finely stepped RK4 reference, at the limits where RK4 steps would need a
step the stage's pole allows, and in the simulator."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.drive_path import grid_points, has_closed_form, stage_table
from stickslip_jax.model.base import AbstractInputStage
from stickslip_jax.model.extensions import LowPassInput, SlewLimitedInput
from stickslip_jax.model.slew_exact import (
    MAX_ITERATIONS,
    advance_slew_limited,
    lag_and_steps,
    slew_lag_after,
)
from stickslip_jax.synthetic import DriveSpec


class SteppedSlew(SlewLimitedInput):
    """The tanh slew limit without its exact step: the table takes RK4 steps."""

    advance = AbstractInputStage.advance


def rk4_lag(x0, beta, elapsed, steps=20000):
    """dx/d(t/τ) = β − tanh x by classic RK4, every case at once (numpy)."""
    x0, beta, elapsed = np.broadcast_arrays(*(np.asarray(v, float) for v in (x0, beta, elapsed)))
    x, h = x0.copy(), elapsed / steps

    def f(x):
        return beta - np.tanh(x)

    for _ in range(steps):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


# Both regimes, near |β| = 1 on either side, lags on both sides of the equilibrium,
# deep in saturation, and steps from a hundredth to ten time constants.
BETAS = (-3.0, -1.001, -0.9999, -0.5, 0.0, 0.3, 0.999, 1.0001, 2.5)
LAGS = (-20.0, -2.0, -0.1, 0.0, 0.05, 1.5, 30.0)
ELAPSED = (0.01, 0.3, 2.0, 10.0)


def test_the_exact_lag_matches_fine_rk4_in_both_regimes():
    b, x0, t = (np.asarray(v).ravel() for v in np.meshgrid(BETAS, LAGS, ELAPSED, indexing="ij"))
    exact = np.asarray(jax.jit(slew_lag_after)(jnp.asarray(x0), jnp.asarray(b), jnp.asarray(t)))
    # Every element's solve converged by its tolerance, well before the step cap.
    steps = np.asarray(jax.jit(jax.vmap(lambda *v: lag_and_steps(*v)[1]))(
        jnp.asarray(x0), jnp.asarray(b), jnp.asarray(t)))
    assert steps.max() < MAX_ITERATIONS // 2
    ref = rk4_lag(x0, b, t)
    np.testing.assert_allclose(exact, ref, rtol=0, atol=1e-10 * (1 + np.abs(ref)).max())
    # Slower than the slew rate, the lag stays on its side of atanh β; faster, it grows.
    below = np.abs(b) < 1
    eq = np.arctanh(np.clip(b, -0.999999, 0.999999))
    assert np.all(np.sign(exact - eq)[below & (x0 != eq)]
                  == np.sign(x0 - eq)[below & (x0 != eq)])
    above = ~below
    assert np.all(np.sign(b[above]) * (exact[above] - x0[above]) > 0)


def test_at_the_slew_rate_exactly_the_lag_moves_at_the_saturated_rate():
    """|β| = 1 is the removable singularity of both forms (moved 1e-7 off): a lag deep
    on the slow side falls at 2 per τ, on the fast side it holds; both as RK4."""
    x0 = jnp.asarray([-20.0, -2.0, 0.0, 1.5, 30.0])
    for beta in (1.0, -1.0):
        exact = np.asarray(slew_lag_after(beta * x0, jnp.asarray(beta), jnp.asarray(3.0)))
        ref = rk4_lag(beta * np.asarray(x0), beta, 3.0)
        np.testing.assert_allclose(exact, ref, rtol=0, atol=1e-6)


@pytest.mark.parametrize("beta", [-0.5, 0.0, 0.99, 1.5, -4.0])
def test_a_step_of_a_million_time_constants_lands_where_the_stage_must(beta):
    """τ → 0: below the slew rate the lag sits at atanh β (the stage follows the
    command with its equilibrium lag); above it the lag grows by |β| − 1 per τ once
    saturated, and by more before (tanh x < 1)."""
    def lag(elapsed):
        return float(slew_lag_after(jnp.asarray(2.0), jnp.asarray(beta), jnp.asarray(elapsed)))

    x = lag(1e6)
    if abs(beta) < 1:
        assert x == pytest.approx(np.arctanh(beta), abs=1e-12)
    else:
        assert np.sign(beta) * (x - lag(1e6 - 1)) == pytest.approx(abs(beta) - 1, abs=1e-8)
        assert np.sign(beta) * (x - 2.0) > (abs(beta) - 1) * 1e6


@pytest.mark.parametrize("point", [(0.3, 0.5, 2.0), (5.0, 0.5, 2.0), (-1.0, 1.7, 0.7),
                                   (-3.0, -2.2, 4.0), (0.2, -0.9, 0.05)])
def test_derivatives_match_central_differences_in_both_modes(point):
    """The derivative comes from the implicit function theorem at the root (one Newton
    step with the arguments live), not through the iterations."""
    p = jnp.asarray(point)

    def f(v):
        return slew_lag_after(v[0], v[1], v[2])

    eps = 1e-6
    central = np.array([(f(p.at[i].add(eps)) - f(p.at[i].add(-eps))) / (2 * eps)
                        for i in range(3)])
    np.testing.assert_allclose(np.asarray(jax.grad(f)(p)), central, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(np.asarray(jax.jacfwd(f)(p)), central, rtol=1e-6, atol=1e-9)


def test_advance_in_volts_and_the_stage_table_against_rk4_steps():
    """In volts, and through the simulator's stage table: the exact step against RK4
    steps of the same rate, fine enough to resolve a 1 µs stage on 10 µs samples, from
    the middle of an interval as the refined intervals start."""
    slew, tau, dt = 1.2e6, 1e-6, 10e-6
    exact, stepped = SlewLimitedInput(slew, tau, 0.8), SteppedSlew(slew, tau, 0.8)
    assert has_closed_form(exact) and not has_closed_form(stepped)
    assert not has_closed_form(ss.ClippedSlewInput(slew, tau))
    points = 0.25 + 0.5 * jnp.asarray(grid_points((0.0, 0.5, 1.0), 6)[0])
    for u_a, du in ((0.0, 40.0), (10.0, -60.0), (3.0, 2.0)):   # β = 3.3, −5, 0.17
        s0 = jnp.asarray([u_a + 0.7])
        a = stage_table(exact, s0, u_a, du, dt, points, steps=1)
        b = stage_table(stepped, s0, u_a, du, dt, points, steps=400)
        for got, want in zip(a, b, strict=True):
            np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=0,
                                       atol=1e-9 * float(np.max(np.abs(np.asarray(want)))))
    s = advance_slew_limited(jnp.asarray(0.0), 0.0, 60.0, 1e-3, slew, tau)
    assert float(s) == pytest.approx(60.0 - slew * tau * np.arctanh(60.0 / 1e-3 / slew),
                                     rel=1e-12)


def test_parallel_stages_advance_together_when_each_can():
    slew, tau = 1.2e6, 2e-6
    both = ss.ParallelInputs((LowPassInput(5e-6, 1.0), SlewLimitedInput(slew, tau, 1.0)))
    mixed = ss.ParallelInputs((LowPassInput(5e-6, 1.0), SteppedSlew(slew, tau, 1.0)))
    assert has_closed_form(both) and not has_closed_form(mixed)
    assert mixed.advance(jnp.zeros(2), 0.0, 1.0, 1e-6) is None
    s = both.advance(jnp.asarray([1.0, 2.0]), 0.0, 30.0, 4e-6)
    np.testing.assert_allclose(np.asarray(s), [
        float(LowPassInput(5e-6).advance(jnp.asarray(1.0), 0.0, 30.0, 4e-6)),
        float(advance_slew_limited(jnp.asarray(2.0), 0.0, 30.0, 4e-6, slew, tau))], rtol=1e-14)


@pytest.fixture(scope="module")
def saw():
    rec = DriveSpec("sawtooth", 40.0, 500.0, "forward", 0.006).recording()
    return rec, jnp.asarray(rec.voltage_V)


def test_a_fast_slew_limit_plans_no_stage_steps(saw):
    """A 0.2 µs slew-limited amplifier: the default plan takes the baseline's sub-steps
    and no stage steps (its trace against the reference stepping:
    tests/test_drive_path.py::test_trace_matches_a_finely_stepped_reference)."""
    rec, _ = saw
    base = ss.lu2015_slc1720()
    act = eqx.tree_at(lambda a: a.input_stage, base, SlewLimitedInput(0.4e6, 0.2e-6))
    plan = ss.plan_steps(act, rec.dt)
    assert plan.substeps == ss.plan_steps(base, rec.dt).substeps
    assert plan.stage_substeps == 1
    stepped = ss.plan_steps(eqx.tree_at(lambda a: a.input_stage, base,
                                        SteppedSlew(0.4e6, 0.2e-6)), rec.dt)
    assert stepped.stage_substeps > 10


def test_the_trace_stays_finite_with_a_vanishing_time_constant(saw):
    """A fit may drive τ towards 0 from a plan made at its start: value and derivative
    stay finite, and the trace tends to the hard limit's at that slew rate."""
    rec, u = saw
    base = ss.lu2015_slc1720()
    slew = 0.4e6
    plan = ss.plan_steps(eqx.tree_at(lambda a: a.input_stage, base,
                                     SlewLimitedInput(slew, 5e-6)), rec.dt)

    def trace(log_tau):
        act = eqx.tree_at(lambda a: a.input_stage, base,
                          SlewLimitedInput(slew, jnp.exp(log_tau)))
        return ss.simulate(act, u, dt=rec.dt, stepping=plan)

    q, dq = jax.jvp(trace, (jnp.log(1e-9),), (jnp.asarray(1.0),))
    assert np.all(np.isfinite(np.asarray(q))) and np.all(np.isfinite(np.asarray(dq)))
    # The hard limit at 20 ns, by RK4 steps resolving it (its lag S·τ is 8 mV).
    hard = eqx.tree_at(lambda a: a.input_stage, base, ss.ClippedSlewInput(slew, 20e-9))
    q_hard = np.asarray(ss.simulate(hard, u, dt=rec.dt))
    q_plain = np.asarray(ss.simulate(base, u, dt=rec.dt, stepping=plan))
    assert np.sqrt(np.mean((np.asarray(q) - q_hard) ** 2)) < 0.05 * np.sqrt(
        np.mean((q_hard - q_plain) ** 2))

"""The Levenberg-Marquardt solve's Gauss-Newton trial (``LMSettings.gauss_newton_trial``):
after a step the linear model predicted, the full Gauss-Newton point is tried next."""

import numpy as np
import pytest

from stickslip_jax.identify.solve import LevenbergMarquardtSteps, solve_least_squares


def drift_basis(n: int = 2000):
    """A sensor drift's basis over 0.5 s: the linear term and ten settling terms
    ``1 − exp(−t/T)`` on a logarithmic grid from 5 ms to 1.5 s (as the catalogue's
    sensor_drift entry builds it): linear, and ill-conditioned (the slow terms are
    nearly the linear one)."""
    t = np.linspace(0.0, 0.5, n)
    times = np.geomspace(5e-3, 1.5, 10)
    return np.column_stack([t] + [1.0 - np.exp(-t / tau) for tau in times])


def test_an_ill_conditioned_linear_fit_converges_in_a_few_steps():
    basis = drift_basis()
    scaled = basis / np.linalg.norm(basis, axis=0)
    assert np.linalg.cond(scaled) > 1e8  # damping 3.5x lower per step: ~15 steps to reach
    truth = np.zeros(basis.shape[1])
    truth[[0, 3, 7]] = 2.0, 0.3, -0.5
    data = basis @ truth + 0.01 * np.random.default_rng(3).standard_normal(basis.shape[0])
    best = np.linalg.lstsq(basis, data, rcond=None)[0]
    best_cost = float(np.sum((basis @ best - data) ** 2))
    noise_variance = best_cost / (basis.shape[0] - basis.shape[1])

    def residual(theta):
        return basis @ np.asarray(theta) - data

    def run(trial: bool):
        return solve_least_squares(residual, np.zeros(basis.shape[1]), max_steps=15,
                                   gn_tol=0.01, gauss_newton_trial=trial,
                                   jacobian=lambda th: (residual(th), basis))

    damped = run(False)
    assert not damped.converged  # the damped steps creep: several noise variances short
    assert damped.cost_end - best_cost > 2.0 * noise_variance
    tried = run(True)
    assert tried.converged, tried.message
    assert tried.iterations <= 3
    assert tried.cost_end == pytest.approx(best_cost, rel=1e-9)
    np.testing.assert_allclose(basis @ tried.theta, basis @ best, atol=1e-9)


def rosenbrock(y):
    return np.array([10 * (y[1] - y[0] ** 2), 1 - y[0], 0.1 * y[2] * y[0] - 0.2])


def rosenbrock_jacobian(y):
    return np.array([[-20 * y[0], 10.0, 0.0], [-1.0, 0.0, 0.0],
                     [0.1 * y[2], 0.0, 0.1 * y[0]]])


def test_a_rejected_trial_leaves_the_damping_and_a_curved_fit_still_converges():
    lm = LevenbergMarquardtSteps(np.array([-1.2, 1.0, 0.5]), step_size=1.0,
                                 gauss_newton_trial=True)
    lm.step(rosenbrock(lm.y_eval), rosenbrock_jacobian(lm.y_eval))  # the start
    tried = rejected_trials = waited = 0
    for _ in range(60):
        before, was_trial = lm.step_size, lm.trying_gauss_newton
        accepted = lm.step(rosenbrock(lm.y_eval), rosenbrock_jacobian(lm.y_eval))
        tried += was_trial
        if was_trial and not accepted:
            rejected_trials += 1
            assert lm.step_size == before  # λ's own step is tried next, unchanged
            assert not lm.trying_gauss_newton
        elif not accepted:
            assert lm.step_size == pytest.approx(0.25 * before)
        if accepted and lm.gain_ratio >= lm.HIGH_CUTOFF:
            # A well-predicted step: Gauss-Newton next, unless a trial failed at this
            # reach (λ no lower than then).
            assert lm.trying_gauss_newton == (lm.step_size > lm.trial_failed_at)
            waited += lm.trial_failed_at > 0 and not lm.trying_gauss_newton
    assert tried > 0 and rejected_trials > 0
    out = solve_least_squares(rosenbrock, np.array([-1.2, 1.0, 0.5]), max_steps=200,
                              gauss_newton_trial=True, rtol=1e-10, atol=1e-12,
                              jacobian=lambda y: (rosenbrock(y), rosenbrock_jacobian(y)))
    assert out.converged, out.message
    np.testing.assert_allclose(out.theta, [1.0, 1.0, 2.0], atol=1e-5)


def test_a_rejected_trial_costs_a_value_evaluation_not_a_step():
    """From a strongly damped start on a curved residual the first trials overshoot
    (the exponential) and are rejected, each for a value evaluation; the damped point
    is then tried within the same step, and the fit still ends in fewer steps."""

    def residual(y):
        return np.array([np.exp(y[0]) - 5.0, 0.1 * y[0], 0.05 * (y[1] - y[0])])

    def jacobian(y):
        return residual(y), np.array([[np.exp(y[0]), 0.0], [0.1, 0.0], [-0.05, 0.05]])

    def run(trial: bool):
        return solve_least_squares(residual, np.zeros(2), max_steps=60, gn_tol=1e-6,
                                   initial_damping=100.0, gauss_newton_trial=trial,
                                   jacobian=jacobian, value=residual)

    damped, tried = run(False), run(True)
    assert damped.converged and tried.converged
    assert damped.values == damped.jacobians  # every damped point was accepted
    assert tried.values > tried.jacobians  # trials rejected on their value alone
    assert tried.iterations < damped.iterations
    np.testing.assert_allclose(tried.theta, damped.theta, atol=1e-4)

"""Standard errors that mean what they say: the Gauss-Newton stopping test, the
spectral sandwich and the loading curve's errors, on problems whose answers are known."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.identify.loading_curve import loading_curve
from stickslip_jax.identify.solve import gauss_newton_distance, solve_least_squares
from stickslip_jax.identify.uncertainty import parameter_uncertainty, spectral_meat


def _design(n=2000, seed=0):
    """A smooth three-column design over n samples (like sensitivities of a trace)."""
    t = np.linspace(0.0, 1.0, n)
    return np.stack([np.sin(2 * np.pi * 3 * t), np.cos(2 * np.pi * 5 * t), t - t.mean()],
                    axis=1)


def test_gauss_newton_distance_is_the_step_in_standard_errors():
    rng = np.random.default_rng(1)
    x = _design()
    y = x @ np.array([1.0, -2.0, 0.5]) + 0.1 * rng.standard_normal(len(x))
    beta = np.linalg.lstsq(x, y, rcond=None)[0]
    # At the least-squares solution there is no step left.
    assert gauss_newton_distance(x @ beta - y, x) < 1e-20
    # Moved by d, the step back is d, and its length in the metric XᵀX/σ̂² is known.
    d = np.array([0.01, 0.0, -0.02])
    r = x @ (beta + d) - y
    sigma2 = (r @ r) / (len(x) - 3)
    expected = d @ (x.T @ x) @ d / sigma2
    assert gauss_newton_distance(r, x) == pytest.approx(expected, rel=1e-9)


def test_gauss_newton_test_ends_a_fit_at_the_minimiser():
    # An ill-conditioned nonlinear fit (two nearly equal decay rates), where steps
    # creep: the point test stops it only within a tenth of a standard error.
    rng = np.random.default_rng(2)
    t = jnp.linspace(0.0, 5.0, 400)
    truth = jnp.array([1.0, 0.8, 1.3])

    def model(p):
        return p[0] * jnp.exp(-p[1] * t) + p[0] * 0.5 * jnp.exp(-p[2] * t)

    y = model(truth) + 0.01 * rng.standard_normal(t.size)
    fit = solve_least_squares(lambda p: model(p) - y, jnp.array([1.5, 0.5, 2.0]),
                              max_steps=200, gn_tol=0.01)
    assert fit.converged and "Gauss-Newton" in fit.message
    jac = np.asarray(jax.jacfwd(model)(jnp.asarray(fit.theta)))
    assert gauss_newton_distance(fit.residual, jac) <= 0.01


def test_spectral_meat_is_sigma2_jtj_for_white_noise():
    rng = np.random.default_rng(3)
    x = _design(4000)
    e = 0.7 * rng.standard_normal(len(x))
    meat = spectral_meat(x[None], e[None], np.ones((1, len(x))))
    np.testing.assert_allclose(meat, 0.49 * x.T @ x, rtol=0.1, atol=0.05 * np.abs(
        0.49 * x.T @ x).max())


def _ar1(rng, n, rho, sigma):
    e = np.empty(n)
    e[0] = rng.standard_normal() * sigma / np.sqrt(1 - rho**2)
    for i in range(1, n):
        e[i] = rho * e[i - 1] + sigma * rng.standard_normal()
    return e


def test_sandwich_errors_match_the_spread_under_coloured_noise():
    # Least squares under AR(1) noise (ρ = 0.8): the white-noise formula understates
    # the estimator's spread by ~sqrt((1 + ρ)/(1 − ρ)) = 3 for slow regressors; the
    # spectral sandwich states it, as the spread over 300 noise draws shows.
    rng = np.random.default_rng(4)
    x = _design(2000)
    estimates, se_white, se_sandwich = [], [], []
    for _ in range(300):
        e = _ar1(rng, len(x), 0.8, 0.1)
        beta = np.linalg.lstsq(x, e, rcond=None)[0]
        r = e - x @ beta
        estimates.append(beta)
        args = (np.eye(3), beta, ["a", "b", "c"])
        se_white.append(parameter_uncertainty(x, r, *args).std_errors)
        se_sandwich.append(parameter_uncertainty(x, r, *args,
                                                 mask=np.ones((1, len(x)))).std_errors)
    spread = np.std(np.array(estimates), axis=0)
    sandwich = np.median(np.array(se_sandwich), axis=0)
    white = np.median(np.array(se_white), axis=0)
    np.testing.assert_allclose(sandwich, spread, rtol=0.2)
    assert np.all(white < 0.5 * spread)


def test_loading_curve_is_the_hysteresis_on_a_rising_ramp():
    pi = ss.lu2015_slc1720().hysteresis
    thresholds, weights = np.asarray(pi.thresholds), np.asarray(pi.weights)
    ramp = np.linspace(0.0, 60.0, 6001)
    along = np.asarray(pi.along(ramp))
    pick = [37, 512, 2999, 5500]  # samples of the ramp, between and near thresholds
    knots, expected = ramp[pick], along[pick]
    np.testing.assert_allclose(np.asarray(loading_curve(thresholds, weights, knots)),
                               expected, rtol=1e-9, atol=1e-15)

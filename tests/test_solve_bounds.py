"""The Gauss-Newton test within the parameters' domains: a weight whose optimum is its
bound (0) is reached only as θ → −∞, and the unbounded Gauss-Newton step, which would
carry it below 0, promises a fall that does not shrink as the weight does, so a fit
there never passed the test. Within the domains the step is bounded and the fit
converges."""

import jax.numpy as jnp
import numpy as np
import pytest

from stickslip_jax.identify.parameters import FreeParameter
from stickslip_jax.identify.solve import (
    bounded_gauss_newton_step,
    gauss_newton_distance,
    gauss_newton_drop,
    solve_least_squares,
)


@pytest.mark.parametrize("kind, start, floor, theta", [
    ("log", 2.0, 0.0, 0.3), ("log", 2.0, 0.5, -0.2), ("nonneg", 0.0, 0.0, -3.0),
    ("nonneg", 0.0, 0.0, 25.0), ("softplus", 0.7, 0.0, 1.5), ("logit", 0.3, 0.0, 0.4),
])
def test_the_first_order_move_to_a_bound_reaches_it(kind, start, floor, theta):
    p = FreeParameter("w", kind, 1, np.asarray(start), 0.5, floor)
    value = float(p.to_physical(np.array(theta), xp=np))
    slope = float(p.derivative(np.array([theta]))[0, 0])
    lo, hi = p.step_bounds(np.array([theta]))
    least = 1e-300 if kind != "log" else floor
    np.testing.assert_allclose(value + slope * lo[0], least, atol=1e-12 * value)
    if kind == "logit":
        np.testing.assert_allclose(value + slope * hi[0], 1.0, rtol=1e-12)
    else:
        assert hi[0] == np.inf


def test_linear_and_pi_bounds():
    lin = FreeParameter("x", "linear", 2, np.zeros(2), 1.0)
    assert np.all(lin.step_bounds(np.zeros(2))[0] == -np.inf)
    pi = FreeParameter("pi", "pi_cumlog", 3, np.array([1.0, 0.5, 0.2]))
    np.testing.assert_array_equal(pi.step_bounds(np.zeros(3))[0], [-1.0, -1.0, -1.0])


def _problem(rng, n=400):
    """Data with a negative part along a direction only a non-negative weight reaches
    (besides two free coefficients), and white noise of σ = 0.01."""
    basis = rng.standard_normal((n, 3))
    y = basis @ np.array([1.0, -0.5, -0.2]) + 0.01 * rng.standard_normal(n)
    return jnp.asarray(basis), jnp.asarray(y)


def test_the_bounded_drop_is_what_setting_the_weight_to_zero_gives():
    basis, y = _problem(np.random.default_rng(3))
    # At a small weight v: residual r = B·(c, v) − y with c at its optimum given v.
    v = 1e-3
    c = np.linalg.lstsq(np.asarray(basis[:, :2]), np.asarray(y - v * basis[:, 2]),
                        rcond=None)[0]
    r = np.asarray(basis @ jnp.array([c[0], c[1], v]) - y)
    jac = np.asarray(basis) * np.array([1.0, 1.0, v])  # θ = log v for the weight
    free = gauss_newton_drop(r, jac)
    lo = np.array([-np.inf, -np.inf, -1.0])
    bounded = gauss_newton_drop(r, jac, bounds=(lo, np.full(3, np.inf)))
    at_zero = np.linalg.lstsq(np.asarray(basis[:, :2]), np.asarray(y), rcond=None)[1][0]
    assert free > 100 * bounded  # the unbounded step crosses 0 for a fall it cannot have
    np.testing.assert_allclose(float(r @ r) - bounded, at_zero, rtol=1e-9)
    # A step within the bounds is left as it was.
    wide = (np.full(3, -1e9), np.full(3, np.inf))
    assert gauss_newton_drop(r, jac, bounds=wide) == free


def test_a_weight_at_its_bound_converges_within_the_domain():
    basis, y = _problem(np.random.default_rng(4))
    weight = FreeParameter("w", "nonneg", 1, np.asarray(0.0), 1.0)

    def residuals(theta):
        return (basis[:, :2] @ theta[:2] + basis[:, 2] * weight.to_physical(theta[2:])
                - y)

    def bounds(theta):
        lo, hi = weight.step_bounds(theta[2:])
        return np.r_[-np.inf, -np.inf, lo], np.r_[np.inf, np.inf, hi]

    start = jnp.array([0.0, 0.0, 20.0])  # the weight at softplus(0) = 0.69; its optimum is 0
    capped = solve_least_squares(residuals, start, gn_tol=0.01, max_steps=30)
    bounded = solve_least_squares(residuals, start, gn_tol=0.01, max_steps=30,
                                  step_bounds=bounds)
    assert not capped.converged and capped.iterations == 30
    # The damped steps creep towards the bound (the weight's column shrinks with it while
    # the damping does not); the bound trial takes the weight to where its part of the
    # cost is within the test's tolerance, and no deeper than a factor e beyond it.
    assert bounded.converged and bounded.iterations <= 5
    value = float(weight.to_physical(bounded.theta[2:], xp=np))
    assert 1e-8 < value < 1e-5
    # Within a tenth of a noise variance of the bounded optimum (the weight at 0), where
    # the capped fit is not.
    sigma2 = bounded.cost_end / (basis.shape[0] - 3)
    coef, at_zero = np.linalg.lstsq(np.asarray(basis[:, :2]), np.asarray(y), rcond=None)[:2]
    least = float(at_zero[0])
    assert bounded.cost_end - least < 0.01 * sigma2 < capped.cost_end - least
    np.testing.assert_allclose(bounded.theta[:2], coef, atol=5e-4)  # a standard error


def test_a_jacobian_whose_normal_matrix_overflows_is_never_called_converged():
    j = np.array([[1e200, 1.0], [2.0, 1e-3], [0.0, 5.0]])  # finite, JᵀJ is not
    r = np.ones(3)
    assert gauss_newton_drop(r, j) == np.inf
    assert gauss_newton_drop(r, j, bounds=(np.full(2, -1.0), np.full(2, np.inf))) == np.inf
    r_huge = np.array([1e300, 1e300, 1e300])
    assert gauss_newton_drop(r_huge, np.array([[1e10], [1e10], [1e10]])) == np.inf  # Jᵀr
    assert gauss_newton_drop(np.ones(2), np.eye(2)) == pytest.approx(2.0)  # (ordinary)


def test_a_jacobian_that_is_not_finite_is_never_called_converged():
    # A NaN or infinite column (a derivative through a non-smooth point) measures no
    # step: the distance must not read as 0, which the fit would take for converged.
    r = np.array([1.0, -0.5, 0.25, 0.1])
    j = np.array([[1.0, np.nan], [0.0, 1.0], [1.0, 1.0], [2.0, 0.0]])
    assert gauss_newton_drop(r, j) == np.inf
    assert gauss_newton_distance(r, j) == np.inf
    assert gauss_newton_distance(r, np.where(np.isnan(j), np.inf, j)) == np.inf
    assert gauss_newton_distance(np.array([np.nan, 0, 0, 0]), np.ones((4, 2))) == np.inf
    assert gauss_newton_distance(np.zeros(4), np.ones((4, 2))) == 0.0  # an exact fit
    ok = np.column_stack([np.ones(4), np.arange(4.0)])
    # (ordinary) drop / σ̂², σ̂² = rᵀr/(N − p)
    assert gauss_newton_distance(r, ok) == pytest.approx(
        gauss_newton_drop(r, ok) / (r @ r / 2), rel=1e-12)


@pytest.mark.parametrize("shape", [(400, 6), (5, 8)])
def test_every_step_from_the_triangle_is_the_step_from_the_whole_jacobian(shape):
    # The steps are solved in R and c = Qᵀr (one QR per accepted point); each must be
    # the least-squares step of the N-row problem: damped, Gauss-Newton (rank-deficient
    # here: two equal columns) and bounded.
    from scipy.optimize import lsq_linear

    from stickslip_jax.identify.solve import LevenbergMarquardtSteps

    rng = np.random.default_rng(3)
    jac = rng.standard_normal(shape)
    jac[:, 1] = jac[:, 0]
    r = rng.standard_normal(shape[0])
    # Padding rows (0 in both), left out of the factorisation, change no step.
    jac, r = np.vstack([jac, np.zeros((7, shape[1]))]), np.concatenate([r, np.zeros(7)])
    lm = LevenbergMarquardtSteps(np.zeros(shape[1]), step_size=0.7)
    lm.step(r, jac)  # the start: accepted
    k = shape[1]
    damped = np.linalg.lstsq(np.vstack([jac, np.sqrt(1 / 0.7) * np.eye(k)]),
                             np.concatenate([r, np.zeros(k)]), rcond=None)[0]
    np.testing.assert_allclose(lm._damped_step(), damped, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(lm._gauss_newton_step(),
                               np.linalg.lstsq(jac, r, rcond=1e-9)[0], rtol=1e-9, atol=1e-12)
    lo, hi = np.full(k, -0.05), np.full(k, 0.05)
    tri, c = lm.triangle
    for bounds in (None, (lo, hi)):  # the convergence test's drop, from the triangle
        assert gauss_newton_drop(r, jac, bounds=bounds, triangle=lm.triangle) == pytest.approx(
            gauss_newton_drop(r, jac, bounds=bounds), rel=1e-10)
    np.testing.assert_allclose(bounded_gauss_newton_step(tri, c, lo, hi),
                               lsq_linear(jac, -r, bounds=(lo, hi), method="bvls").x,
                               rtol=1e-9, atol=1e-12)


def test_a_column_whose_squares_overflow_is_scaled_and_the_fit_converges():
    # θ₁ enters at 1e160 (a parameter in absurd units): its column's sum of squares
    # overflows though every entry is finite. The column scaling must still be its
    # norm (not inf, which made the scaled column NaN and the final Jacobian inf·0),
    # so the fit finds the optimum.
    x = jnp.linspace(0.0, 1.0, 50)
    y = 1.5 + 0.75 * x

    def residuals(th):
        return 1e150 * th[0] + 1e160 * th[1] * x - y

    out = solve_least_squares(residuals, jnp.array([0.0, 0.0]))
    assert out.converged
    np.testing.assert_allclose(out.theta, [1.5e-150, 0.75e-160], rtol=1e-8)

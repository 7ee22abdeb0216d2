"""Leave one regime out (diagnose/holdout.py) on linear models, where the linearised
leave-out is exact, against refits done by hand."""

import numpy as np

from stickslip_jax.diagnose.holdout import held_out_cost, predicts_as_well

REGIMES = ["step", "scanning", "scanning", "stepping_forward", "stepping_backward", "sine"]
T = 300


def _design(rng):
    """Rows recording-major: B recordings of T samples, a common offset and slope plus
    a per-regime feature."""
    t = np.tile(np.linspace(0, 1, T), len(REGIMES))
    return np.stack([np.ones_like(t), t], axis=1)


def _refit_cost(x, y, rows_held):
    coef = np.linalg.lstsq(x[~rows_held], y[~rows_held], rcond=None)[0]
    e = y[rows_held] - x[rows_held] @ coef
    return float(e @ e)


def test_the_linearised_leave_out_equals_the_refit_for_a_linear_model():
    rng = np.random.default_rng(1)
    x = _design(rng)
    y = x @ np.array([0.3, -1.2]) + 0.1 * rng.standard_normal(x.shape[0])
    coef = np.linalg.lstsq(x, y, rcond=None)[0]
    r = x @ coef - y  # residual = model − data; the Jacobian of the residual is x
    got = held_out_cost(r, x, REGIMES)
    rows = np.repeat(np.array(REGIMES), T)
    for g, cost in got.items():
        assert np.isclose(cost, _refit_cost(x, y, rows == g), rtol=1e-8), g
    assert set(got) == set(REGIMES)


def test_an_extra_term_that_only_fits_noise_does_not_predict_better():
    rng = np.random.default_rng(2)
    x = _design(rng)
    y = x @ np.array([0.3, -1.2]) + 0.1 * rng.standard_normal(x.shape[0])
    rows = np.repeat(np.array(REGIMES), T)
    # An entry whose signature lives in one regime only: fitted in-sample, it cannot
    # be predicted when that regime is left out.
    spike = (rows == "sine").astype(float) * rng.standard_normal(x.shape[0])
    xe = np.column_stack([x, spike])
    base_r = x @ np.linalg.lstsq(x, y, rcond=None)[0] - y
    ext_r = xe @ np.linalg.lstsq(xe, y, rcond=None)[0] - y
    base, ext = held_out_cost(base_r, x, REGIMES), held_out_cost(ext_r, xe, REGIMES)
    # Without the sine regime the term is undetermined: that regime cannot be
    # predicted and is not checked; on the others the term changes next to nothing.
    assert "sine" not in ext and "sine" in base
    common = [g for g in ext if g != "sine"]
    assert np.isclose(sum(ext[g] for g in common), sum(base[g] for g in common), rtol=0.02)
    # A real effect shared by every regime predicts the regimes left out far better.
    effect = np.sin(np.arange(x.shape[0]) / 9.0)
    y2 = y + 0.5 * effect
    xe2 = np.column_stack([x, effect])
    base2 = held_out_cost(x @ np.linalg.lstsq(x, y2, rcond=None)[0] - y2, x, REGIMES)
    ext2 = held_out_cost(xe2 @ np.linalg.lstsq(xe2, y2, rcond=None)[0] - y2, xe2, REGIMES)
    assert predicts_as_well(ext2, base2)
    assert sum(ext2.values()) < 0.2 * sum(base2.values())


def test_one_regime_alone_has_nothing_to_leave_out():
    r = np.ones(2 * T)
    assert held_out_cost(r, np.ones((2 * T, 1)), ["step", "step"]) == {}
    assert predicts_as_well({}, {"step": 1.0})

"""The hysteresis's shape refined in the baseline (stickslip_jax/diagnose/hysteresis_shape.py)."""

import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.hysteresis_shape import refined_thresholds, with_refined_hysteresis
from stickslip_jax.identify.solve import gauss_newton_drop
from stickslip_jax.model.hysteresis import PrandtlIshlinskii
from stickslip_jax.synthetic import DriveSpec


def test_refined_thresholds_keep_the_old_and_add_the_midpoints():
    r = refined_thresholds([0.0, 1.0, 3.0, 7.0])
    np.testing.assert_array_equal(r, [0.0, 0.5, 1.0, 2.0, 3.0, 5.0, 7.0])


def test_the_refined_model_starts_at_the_same_trace_and_can_bend_between_old_kinks():
    base = ss.lu2015_slc1720()
    rec = DriveSpec("sine", 60.0, frequency_Hz=50.0, duration_s=0.04).recording()
    u = jnp.asarray(rec.voltage_V)
    fine = with_refined_hysteresis(base)
    n = base.hysteresis.n_memory
    assert fine.hysteresis.n_memory == 2 * n - 1
    np.testing.assert_array_equal(np.asarray(fine.hysteresis.weights)[1::2], 0.0)
    np.testing.assert_allclose(ss.simulate(fine, u, dt=rec.dt), ss.simulate(base, u, dt=rec.dt),
                               rtol=0, atol=1e-15)
    # A play at a new threshold changes the loop: the refinement adds a shape.
    gamma_new = PrandtlIshlinskii(fine.hysteresis.thresholds[3:4], jnp.ones(1)).along(u)
    coarse = base.hysteresis.thresholds
    plays = np.stack([np.asarray(PrandtlIshlinskii(coarse[i:i + 1], jnp.ones(1)).along(u))
                      for i in range(n)], axis=1)
    fit = np.linalg.lstsq(plays, np.asarray(gamma_new), rcond=None)
    assert np.max(np.abs(plays @ fit[0] - np.asarray(gamma_new))) > 1e-3 * np.ptp(gamma_new)
    with pytest.raises(ValueError, match="Prandtl-Ishlinskii"):
        with_refined_hysteresis(_without_pi(base))


def _without_pi(act):
    import equinox as eqx

    class NotPI(eqx.Module):
        pass

    return eqx.tree_at(lambda a: a.hysteresis, act, NotPI())


def test_gauss_newton_drop_is_what_least_squares_removes():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((200, 4))
    r = rng.standard_normal(200)
    beta = np.linalg.lstsq(x, -r, rcond=None)[0]
    after = r + x @ beta
    assert gauss_newton_drop(r, x) == pytest.approx(r @ r - after @ after, rel=1e-10)
    assert gauss_newton_drop(r, np.full((200, 4), np.nan)) == 0.0

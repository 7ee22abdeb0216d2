"""The hysteresis's shape refined in the baseline (stickslip_jax/diagnose/hysteresis_shape.py)."""

from pathlib import Path
from types import SimpleNamespace

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose import run
from stickslip_jax.diagnose.budget import Budget
from stickslip_jax.diagnose.config import DiagnoseConfig
from stickslip_jax.diagnose.hysteresis_shape import refined_thresholds, with_refined_hysteresis
from stickslip_jax.diagnose.policy import Policy
from stickslip_jax.diagnose.problem import Problem
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.solve import gauss_newton_drop
from stickslip_jax.model.extensions import SensorOutput
from stickslip_jax.model.hysteresis import PrandtlIshlinskii
from stickslip_jax.synthetic import DriveSpec, paper_protocol, simulate_set


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
    assert gauss_newton_drop(r, np.full((200, 4), np.nan)) == np.inf


# ---- the loop's shape after an accepted entry ------------------------------------------
TRUTH = Path(__file__).resolve().parent.parent / "fixtures" / "identification" / "truth.json"
DRIFT = 4e-7
"""The hidden sensor drift [m/s] (40 nm at 0.1 s), taken as already named."""


@pytest.fixture(scope="module")
def drift_on_another_grid():
    """A short set from a truth whose PI operators sit between the default grid's (the
    refined grid, the new operators at half their neighbours' weights) with a sensor
    drift; and the model an accepted drift entry would leave: the truth's dynamics and
    drift, its loop least-squares projected on the default grid."""
    base = ss.load_params(TRUTH)
    fine = with_refined_hysteresis(base)
    w = np.asarray(fine.hysteresis.weights).copy()
    w[1::2] = 0.5 * (w[:-1:2] + w[2::2])
    truth = eqx.tree_at(lambda a: (a.hysteresis.weights, a.output_map), fine,
                        (jnp.asarray(w), SensorOutput(drift=DRIFT)))
    specs = paper_protocol(periods=2, amplitudes=(60.0,), frequencies=(100.0,),
                           step_duration_s=0.02, sine_periods=1)
    recs = simulate_set(truth, specs, noise_m=0.5e-9, seed=5)
    u = np.concatenate([r.voltage_V for r in recs])
    plays = np.stack([np.asarray(PrandtlIshlinskii(base.hysteresis.thresholds[i:i + 1],
                                                   jnp.ones(1)).along(jnp.asarray(u)))
                      for i in range(base.hysteresis.n_memory)], axis=1)
    target = np.asarray(truth.hysteresis.along(jnp.asarray(u)))
    coarse = np.linalg.lstsq(plays, target, rcond=None)[0]
    model = eqx.tree_at(lambda a: (a.hysteresis.weights, a.output_map), base,
                        (jnp.asarray(coarse), SensorOutput(drift=DRIFT)))
    return recs, model


def _drift_problem(recs, total=None):
    return Problem.whitened(Dataset.from_recordings(recs), {"Ms": 0.0247}, lambda s: None,
                            Budget(total))


def test_after_an_accepted_entry_the_refined_loop_takes_up_the_grid_residue(
        drift_on_another_grid):
    recs, model = drift_on_another_grid
    problem = _drift_problem(recs)
    rss, nrmse, q = problem.evaluate(model)
    significance = run._significance(problem, SimpleNamespace(act=model, q=q), Policy())
    # The premise: the coarse loop leaves a residue beyond the tolerance.
    assert not significance.adequate(rss, problem.chi2_per_recording(nrmse)), rss / problem.n_obs
    notes: list[str] = []
    refined = run._refined_after(problem, model, rss, significance, DiagnoseConfig(), notes,
                                 ["sensor_drift"])
    assert refined is not None, notes
    assert refined.act.hysteresis.n_memory == 2 * model.hysteresis.n_memory - 1
    assert significance.adequate(refined.rss, problem.chi2_per_recording(refined.nrmse))
    assert refined.rss < problem.n_obs + significance.tolerance_rss < rss
    # The accepted entry is held: the drift stays what it was.
    assert float(refined.act.output_map.drift) == DRIFT
    assert "after sensor_drift" in notes[-1] and "within the noise tolerance" in notes[-1]


def test_the_refinement_after_an_entry_is_bounded_by_the_budget_and_the_config(
        drift_on_another_grid):
    recs, model = drift_on_another_grid
    problem = _drift_problem(recs, total=1.0)
    notes: list[str] = []
    assert run._refined_after(problem, model, 1e9, None, DiagnoseConfig(), notes,
                              ["sensor_drift"]) is None
    assert "skipped" in notes[-1] and problem.budget.skipped
    assert problem.budget.spent == 0
    off = DiagnoseConfig(refine_hysteresis=False)
    assert run._refined_after(_drift_problem(recs), model, 1e9, None, off, [],
                              ["sensor_drift"]) is None

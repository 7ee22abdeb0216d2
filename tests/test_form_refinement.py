"""A slew limit whose corner the data decide (ShapedSlewInput) and an accepted entry's
form refined within its class (stickslip_jax/diagnose/form_refinement.py)."""

from pathlib import Path
from types import SimpleNamespace

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose import run
from stickslip_jax.diagnose.budget import Budget
from stickslip_jax.diagnose.catalogue import candidate
from stickslip_jax.diagnose.form_refinement import refine_forms
from stickslip_jax.diagnose.policy import Policy
from stickslip_jax.diagnose.problem import Problem
from stickslip_jax.diagnose.records import Acceptance, RefitOutcome
from stickslip_jax.diagnose.results import CandidateResult
from stickslip_jax.drive_path import has_closed_form
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.parameters import ParameterSpec
from stickslip_jax.model.extensions import shaped_saturation
from stickslip_jax.synthetic import DriveSpec, paper_protocol, simulate_set

X = jnp.asarray([-1e3, -3.0, -1.0, -0.4, -1e-6, 0.0, 1e-300, 1e-6, 0.3, 0.99, 1.0, 1.2, 50.0,
                 1e6])


def test_the_shaped_saturation_runs_from_tanh_to_the_hard_clip():
    np.testing.assert_allclose(shaped_saturation(X, 1.0), jnp.tanh(X), rtol=0, atol=1e-15)
    np.testing.assert_allclose(shaped_saturation(X, 1e4), jnp.clip(X, -1, 1), rtol=0,
                               atol=3e-5)
    # Softer than the tanh below p = 1, sharper above; odd; ±1 far out, for every p.
    for p in (0.5, 1.0, 3.0, 30.0):
        v = np.asarray(shaped_saturation(X, p))
        np.testing.assert_allclose(v, -np.asarray(shaped_saturation(-X, p)), atol=0)
        assert abs(v[0] + 1) < 1e-9 and abs(v[-1] - 1) < 1e-9
    corner = [float(shaped_saturation(jnp.asarray(1.0), p)) for p in (0.5, 1.0, 3.0, 30.0)]
    assert corner == sorted(corner) and corner[1] == pytest.approx(np.tanh(1.0), rel=1e-14)


def test_the_shaped_saturation_has_slope_one_at_rest_and_finite_derivatives():
    grad = jax.vmap(jax.grad(shaped_saturation, argnums=(0, 1)), in_axes=(0, None))
    for p in (0.7, 1.0, 5.0, 200.0):
        dx, dp = (np.asarray(g) for g in grad(X, p))
        assert np.all(np.isfinite(dx)) and np.all(np.isfinite(dp))
        np.testing.assert_allclose(dx[5], 1.0, rtol=0, atol=0)  # x = 0
    # The derivative in p against a central difference, off the branch seams.
    x, p, h = 0.8, 2.0, 1e-6
    fd = (shaped_saturation(x, p + h) - shaped_saturation(x, p - h)) / (2 * h)
    assert float(jax.grad(shaped_saturation, argnums=1)(x, p)) == pytest.approx(float(fd),
                                                                             rel=1e-7)


@pytest.fixture(scope="module")
def saw():
    rec = DriveSpec("sawtooth", 60.0, frequency_Hz=500.0, direction="forward",
                    duration_s=0.01).recording()
    return jnp.asarray(rec.voltage_V), rec.dt


def test_the_shaped_stage_is_the_tanh_at_one_and_the_hard_limit_when_sharp(saw):
    u, dt = saw
    base = ss.lu2015_slc1720()
    slew, tau = 1.2e6, 8e-6

    def q(stage):
        return np.asarray(ss.simulate(eqx.tree_at(lambda a: a.input_stage, base, stage), u,
                                      dt=dt))

    shaped = ss.ShapedSlewInput(slew, tau, 1.0)
    assert not has_closed_form(shaped)
    tanh, hard = q(ss.SlewLimitedInput(slew, tau)), q(ss.ClippedSlewInput(slew, tau))
    # The premise: the hard limit and the tanh differ by far more than the steps' error.
    assert np.max(np.abs(hard - tanh)) > 1e-8
    assert np.max(np.abs(q(shaped) - tanh)) < 1e-3 * np.max(np.abs(hard - tanh))
    sharp = q(ss.ShapedSlewInput(slew, tau, 300.0))
    assert np.max(np.abs(sharp - hard)) < 0.02 * np.max(np.abs(hard - tanh))


def test_the_drive_entry_offers_the_freed_corner_of_a_fitted_tanh():
    base = ss.lu2015_slc1720()
    entry = candidate("drive_bandwidth")
    act = eqx.tree_at(lambda a: a.input_stage, base, ss.SlewLimitedInput(1.3e6, 6e-6))
    [(start, specs)] = entry.refined_forms(act, {"sample_interval_s": 40e-6})
    assert isinstance(start.input_stage, ss.ShapedSlewInput)
    assert float(start.input_stage.sharpness) == 1.0
    assert set(specs) == {"drive_slew", "drive_tau", "drive_sharpness"}
    assert specs["drive_tau"].floor == pytest.approx(0.4e-6)
    for other in (ss.ClippedSlewInput(1e6, 5e-6),
                  ss.SlewLimitedInput(1e6, 5e-6, 0.5), ss.LowPassInput(5e-6, 0.5)):
        assert entry.refined_forms(eqx.tree_at(lambda a: a.input_stage, base, other), {}) == []
    said = entry.describe({"drive_slew": 1.2e6, "drive_tau": 8e-6, "drive_sharpness": 40.0})
    assert "1.2 V/µs" in said and "8 µs" in said and "99 %" in said
    assert entry.describe({"drive_tau": 8e-6}) == ""


def test_a_fitted_low_pass_gets_a_second_pole_that_starts_where_it_adds_nothing(saw):
    u, dt = saw
    base = ss.lu2015_slc1720()
    entry = candidate("drive_bandwidth")
    act = eqx.tree_at(lambda a: a.input_stage, base, ss.LowPassInput(2e-6))
    [(start, specs)] = entry.refined_forms(act, {})
    stages = start.input_stage.stages
    assert [float(st.tau) for st in stages] == [2e-6, 0.5e-6]
    assert [float(st.mix) for st in stages] == [1.0, 0.0]
    assert set(specs) == {"drive_tau", "drive_mix", "drive_tau2", "drive_mix2"}
    assert float(specs["drive_tau2"].getter(start)) == 0.5e-6
    assert has_closed_form(start.input_stage)
    q_act = np.asarray(ss.simulate(act, u, dt=dt))
    np.testing.assert_allclose(ss.simulate(start, u, dt=dt), q_act, rtol=0, atol=1e-15)
    # With the second pole mixed in, the trace moves: the form adds a shape.
    moved = eqx.tree_at(lambda a: a.input_stage.stages[1].mix, start, jnp.asarray(0.5))
    assert np.max(np.abs(np.asarray(ss.simulate(moved, u, dt=dt)) - q_act)) > 1e-10
    params = {"drive_tau": 2e-6, "drive_mix": 1.0, "drive_tau2": 0.5e-6, "drive_mix2": 0.0}
    # One pole of 2 µs: half power at 1/(2π·2 µs) = 79.6 kHz (the grid's resolution).
    said = entry.describe(params)
    assert "two real poles" in said and "79.6 kHz" in said
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    assert entry.plot_form(ax, params)
    f, gain = ax.lines[0].get_xdata(), ax.lines[0].get_ydata()
    np.testing.assert_allclose(gain, 1 / np.sqrt(1 + (2 * np.pi * f * 2e-6) ** 2), rtol=1e-12)
    plt.close(fig)
    assert not entry.plot_form(ax, {"drive_tau": 2e-6})


def test_a_fitted_complex_pair_gets_a_real_pole_that_starts_where_it_adds_nothing(saw):
    u, dt = saw
    base = ss.lu2015_slc1720()
    entry = candidate("drive_bandwidth")
    act = eqx.tree_at(lambda a: a.input_stage, base, ss.SecondOrderInput(12e3, 0.4))
    [(start, specs)] = entry.refined_forms(act, {})
    pair, pole = start.input_stage.stages
    assert isinstance(pair, ss.SecondOrderInput) and isinstance(pole, ss.LowPassInput)
    assert float(pole.tau) == pytest.approx(0.25 / (2 * np.pi * 12e3), rel=1e-15)
    assert float(pole.mix) == 0.0
    assert set(specs) == {"drive_frequency", "drive_damping", "drive_tau2", "drive_mix2"}
    assert float(specs["drive_frequency"].getter(start)) == 12e3
    q_act = np.asarray(ss.simulate(act, u, dt=dt))
    # The same filter; the real pole's faster time scale may refine the stage's steps.
    np.testing.assert_allclose(ss.simulate(start, u, dt=dt), q_act, rtol=0, atol=1e-12)
    moved = eqx.tree_at(lambda a: a.input_stage.stages[1].mix, start, jnp.asarray(0.5))
    assert np.max(np.abs(np.asarray(ss.simulate(moved, u, dt=dt)) - q_act)) > 1e-10
    # A refined stage is not refined again: three poles are the class's most.
    assert entry.refined_forms(start, {}) == []
    params = {"drive_frequency": 12e3, "drive_damping": 0.4, "drive_tau2": float(pole.tau),
              "drive_mix2": 0.0}
    said = entry.describe(params)
    assert "three poles" in said and "12 kHz" in said
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots()
    assert entry.plot_form(ax, params)
    f, gain = ax.lines[0].get_xdata(), ax.lines[0].get_ydata()
    r = f / 12e3  # the pair alone: 1/√((1 − r²)² + (2ζr)²)
    np.testing.assert_allclose(gain, 1 / np.sqrt((1 - r**2) ** 2 + (0.8 * r) ** 2),
                               rtol=1e-12)
    plt.close(fig)


# ---- the refinement after an accepted entry -------------------------------------------
TRUTH = Path(__file__).resolve().parent.parent / "fixtures" / "identification" / "truth.json"
SLEW, TAU = 1.2e6, 8e-6
"""The hidden hard-limited amplifier [V/s], [s] (the concealed set's)."""


@pytest.fixture(scope="module")
def hard_limited():
    """A short set from the truth behind a hard-limited amplifier, and the model an
    accepted drive entry in the tanh form would leave: the truth with the tanh stage
    whose slew and lag fit best, the rest held."""
    truth = ss.load_params(TRUTH)
    specs = paper_protocol(periods=2, amplitudes=(60.0,), frequencies=(100.0, 500.0),
                           step_duration_s=0.02, sine_periods=1)
    recs = simulate_set(eqx.tree_at(lambda a: a.input_stage, truth,
                                    ss.ClippedSlewInput(SLEW, TAU)),
                        specs, noise_m=0.5e-9, seed=7)
    problem = _problem(recs)
    tanh = eqx.tree_at(lambda a: a.input_stage, truth, ss.SlewLimitedInput(SLEW, TAU))
    stage = {"drive_slew": ParameterSpec(lambda a: a.input_stage.slew, "log", 1.0, "V/s"),
             "drive_tau": ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0, "s")}
    model, _, _ = problem.fit(tanh, list(stage), stage, label="tanh", max_steps=20)
    return recs, model, stage


def _problem(recs, total=None):
    return Problem.whitened(Dataset.from_recordings(recs), {"Ms": 0.0247}, lambda s: None,
                            Budget(total))


def _accepted(problem, model, rss, stage):
    before = 3.0 * rss  # a round start the entry took down to ``rss``
    outcome = RefitOutcome(actuator=model, rss_before=before, rss_after=rss, added=2,
                           params={n: float(s.getter(model)) for n, s in stage.items()})
    return CandidateResult("drive_bandwidth", refit=outcome,
                           decision=Acceptance(accepted=True))


def test_an_accepted_tanh_slew_gets_the_corner_the_data_ask_for(hard_limited):
    recs, model, stage = hard_limited
    problem = _problem(recs)
    rss, nrmse, q = problem.evaluate(model)
    significance = run._significance(problem, SimpleNamespace(act=model, q=q), Policy())
    problem.significance = significance
    # The premise: the best tanh leaves a residue beyond the tolerance.
    assert not significance.adequate(rss, problem.chi2_per_recording(nrmse)), rss / problem.n_obs
    res = _accepted(problem, model, rss, stage)
    notes: list[str] = []
    act, rss_new = refine_forms(problem, model, rss, [res], {"sample_interval_s": 40e-6},
                                significance=significance, policy=Policy(), max_steps=25,
                                notes=notes)
    assert isinstance(act.input_stage, ss.ShapedSlewInput), notes
    assert "kept" in notes[-1]
    assert rss_new < problem.n_obs + significance.tolerance_rss < rss
    assert res.params["drive_sharpness"] > 4.0
    assert res.params["drive_slew"] == pytest.approx(SLEW, rel=0.05)
    assert res.refit.added == 3 and res.refit.rss_after == rss_new
    assert res.refit.criterion_delta < 0 and "form refined" in res.note


def test_the_form_refinement_is_bounded_by_the_budget(hard_limited):
    recs, model, stage = hard_limited
    problem = _problem(recs, total=1.0)
    res = _accepted(problem, model, 1e9, stage)
    notes: list[str] = []
    act, rss = refine_forms(problem, model, 1e9, [res], {}, significance=None,
                            policy=Policy(), max_steps=25, notes=notes)
    assert act is model and rss == 1e9
    assert "skipped" in notes[-1] and problem.budget.skipped and problem.budget.spent == 0

"""A refit in two stages (the PI weights held, then everything) ends where one fit of
everything ends, for less counted work."""

from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose import problem as problem_module
from stickslip_jax.diagnose.budget import Budget
from stickslip_jax.diagnose.catalogue import candidate
from stickslip_jax.diagnose.problem import Problem, baseline_free, recentred
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.parameters import ParameterMap
from stickslip_jax.synthetic import paper_protocol, simulate_set
from stickslip_jax.testing.concealed import with_effect

ROOT = Path(__file__).resolve().parent.parent
TRUTH = ROOT / "fixtures" / "identification" / "truth.json"


@pytest.fixture(scope="module")
def case():
    """A short set hiding an external load, the paper's model 10 % off in its
    dynamics, and the load entry attached at a tenth of the hidden load."""
    truth = ss.load_params(TRUTH)
    specs = paper_protocol(periods=2, amplitudes=(60.0,), frequencies=(500.0,),
                           step_duration_s=0.02, sine_periods=1)
    recs = simulate_set(with_effect(truth, "external_load"), specs, noise_m=1e-9, seed=3)
    start = eqx.tree_at(lambda a: (a.piezo.Mp, a.piezo.Dp), truth,
                        (1.1 * truth.piezo.Mp, 0.9 * truth.piezo.Dp))
    entry = candidate("external_load")
    probe = entry.probes(start, {})[0]
    attached, entry_specs = entry.attach(start, 0.001, probe)
    return recs, attached, entry_specs


def _problem(recs) -> Problem:
    return Problem.whitened(Dataset.from_recordings(recs), {"Ms": 0.0247}, lambda s: None,
                            Budget(None))


@pytest.mark.parametrize("trial", [False, True], ids=["damped", "gauss_newton_trial"])
def test_two_stages_end_at_the_optimum_of_one_fit(case, trial):
    recs, attached, entry_specs = case
    one, two = _problem(recs), _problem(recs)
    one.gauss_newton_trial = two.gauss_newton_trial = trial
    names = baseline_free(attached, one.data, one.fix) + list(entry_specs)
    assert "pi_weights" in names
    act_one, cost_one, out_one = one.fit(attached, names, entry_specs, label="one",
                                         max_steps=60)
    act_two, cost_two, out_two = two.refit(attached, names, entry_specs, label="two",
                                           max_steps=60)
    assert out_one.converged and out_two.converged
    # Both at the minimiser to a tenth of a standard error: the same cost to well
    # under one unit of χ² (the start is thousands above it).
    assert out_one.cost_start - cost_one > 1e3
    assert abs(cost_two - cost_one) < 0.5, (cost_one, cost_two)
    load_one = float(act_one.slider.F_ext)
    load_two = float(act_two.slider.F_ext)
    assert abs(load_two - load_one) < 0.02 * abs(load_one), (load_one, load_two)
    # The second stage returns the full Jacobian (the leave-one-regime-out check
    # reads it).
    assert out_two.jacobian.shape == out_one.jacobian.shape
    # Work: with damped steps only, the staging is what made the refit cheaper (185k
    # -> 142k sample-evaluations here: the one fit crept 12 steps). With the
    # Gauss-Newton trial (the default) the one fit takes 4 steps, 71k, and the two
    # stages 110k: the staging no longer pays on this case (not yet measured on sets).
    if trial:
        assert out_one.iterations <= 6, out_one.iterations
    else:
        assert two.budget.spent < one.budget.spent, (two.budget.spent, one.budget.spent)


def test_the_estimate_bounds_both_stages(case):
    recs, attached, entry_specs = case
    problem = _problem(recs)
    names = baseline_free(attached, problem.data, problem.fix) + list(entry_specs)
    problem.refit(attached, names, entry_specs, label="two", max_steps=8)
    columns = int(np.size(ParameterMap.make(attached, names, entry_specs).zeros()))
    assert problem.budget.spent <= problem.refit_estimate(attached, columns, 8)
    held = int(np.size(attached.hysteresis.weights))
    assert problem.refit_estimate(attached, columns, 8) == pytest.approx(
        problem.fit_estimate(attached, columns - held, 8)
        + problem.fit_estimate(attached, columns, 8))


def test_fits_run_the_shared_programs_with_the_whole_sets_jacobian(case, monkeypatch):
    """On a CPU a fit's residual and Jacobian come from the per-recording programs that
    every fit on the same actuator structure shares; they are the whole data set's,
    whitened, as forward mode through the batched simulation (an accelerator's
    program) gives them."""
    recs, attached, entry_specs = case
    problem = _problem(recs)
    names = baseline_free(attached, problem.data, problem.fix) + list(entry_specs)
    program = problem.program(attached, names, entry_specs)
    theta = 0.01 * np.random.default_rng(0).standard_normal(program.pmap.size)
    r, jac = program(theta)
    monkeypatch.setattr(problem_module, "default_batching", lambda: "vmap")
    r_ref, jac_ref = problem.program(attached, names, entry_specs)(theta)
    monkeypatch.undo()
    assert r.shape == r_ref.shape and jac.shape == jac_ref.shape
    # The same model at the same plan; the chunked per-recording loop and the
    # bucketed batch differ only by rounding at the located slips.
    assert np.max(np.abs(r - r_ref)) < 1e-4 * np.max(np.abs(r_ref))
    assert np.max(np.abs(jac - jac_ref)) < 1e-4 * np.max(np.abs(jac_ref))
    # A fit of fewer quantities on the same structure runs the same programs; one
    # that frees a quantity they do not cover (Ms, held by the problem) widens them
    # for every later fit.
    shared = problem.recording_programs(attached)
    assert problem.program(attached, list(entry_specs), entry_specs).programs is shared
    wider = problem.program(attached, ["Ms"] + list(entry_specs), entry_specs).programs
    assert wider is not shared
    assert problem.program(attached, names, entry_specs).programs is wider


def test_a_fits_last_jacobian_recentred_is_the_jacobian_around_its_optimum(case):
    """The polish's last Jacobian serves the score test at its optimum: in the
    coordinates around the actuator there it is that actuator's own Jacobian."""
    recs, attached, entry_specs = case
    problem = _problem(recs)
    # rho1 (softplus: its θ unit is its start value) makes the centre matter.
    attached = eqx.tree_at(lambda a: a.friction.rho1, attached, jnp.asarray(300.0))
    names = ["Mp", "Dp", "rho1", "pi_weights"] + list(entry_specs)
    program = problem.program(attached, names, entry_specs)
    pmap = program.pmap
    theta = 0.05 * np.random.default_rng(1).standard_normal(pmap.size)
    theta[pmap.slices()["rho1"]] = 0.7
    r, jac = program(theta)
    moved = recentred(jac, pmap, theta, entry_specs)
    there = pmap.actuator(theta, xp=np)
    r_there, direct = problem.program(there, names, entry_specs)(np.zeros(pmap.size))
    # (The same model to the simulator's rounding at the located slips: a new centre
    # plans its own sub-steps.)
    assert np.max(np.abs(r_there - r)) < 1e-6 * np.max(np.abs(r))
    assert np.max(np.abs(moved - direct)) < 1e-4 * np.max(np.abs(direct))
    # Not the same numbers without the change of coordinates (rho1's transform depends
    # on the centre; the others' derivatives only on the value).
    column = pmap.slices()["rho1"]
    assert np.max(np.abs(jac[:, column] - direct[:, column])) > 0.1 * np.max(
        np.abs(direct[:, column]))
    # A transform flattened to rounding (rho1's softplus far into its tail: no
    # derivative left) has no direction to carry over: None, the caller simulates.
    flat = theta.copy()
    flat[column] = -800.0
    assert recentred(jac, pmap, flat, entry_specs) is None


def test_a_refit_ending_where_the_simulator_cannot_step_is_set_aside_not_a_crash(
        case, monkeypatch):
    """A fit keeps its start's plan, so it can end at a model that plan under-resolves
    and the simulator refuses (here a two-pole drive whose corner ran to 100 GHz): the
    refit says so and is set aside; the diagnosis goes on."""
    from stickslip_jax.diagnose.catalogue import candidate as entry_of
    from stickslip_jax.diagnose.refit import RefitSetup, RoundStart, refit
    from stickslip_jax.diagnose.results import CandidateResult, CandidateStatus
    from stickslip_jax.diagnose.sizing import HeldSizing
    from stickslip_jax.model.extensions import SecondOrderInput

    recs, attached, entry_specs = case
    problem = _problem(recs)
    unsteppable = eqx.tree_at(lambda a: a.input_stage, attached,
                              SecondOrderInput(1e11, 0.5))
    with pytest.raises(ValueError, match="pole"):
        problem.plan_factor(unsteppable)
    fits = []

    def fit_from(program, theta, **kw):  # the first stage ends here, the second there
        fits.append(kw["label"])
        return (attached if "held" in kw["label"] else unsteppable), 1.0, None
    monkeypatch.setattr(problem, "fit_from", fit_from)
    names = baseline_free(attached, problem.data, problem.fix) + list(entry_specs)
    with pytest.raises(ValueError, match="ended at a model the simulator cannot step"):
        problem.refit(attached, names, entry_specs, label="r", max_steps=5)
    assert fits == ["r, PI weights held", "r"]

    setup = RefitSetup(problem, baseline_free(attached, problem.data, problem.fix),
                       n_base=0, max_steps=5, identify_max_steps=5, carry_on_steps=5)
    at = RoundStart(act=attached, rss=1e4, nrmse=0.0, excess=1e4, reserve=0.0)
    held = HeldSizing(attached, entry_specs, None, np.zeros(1), 9e3, True)
    res = CandidateResult("external_load")
    refit(setup, at, res, entry_of("external_load"), held)
    assert res.status is CandidateStatus.REFIT_FAILED and not res.refitted
    assert "cannot step" in res.note


def test_a_budgeted_refit_whose_second_stage_would_pass_the_budget_is_skipped_there(
        case, monkeypatch):
    """The second stage is planned where the first ended; when that plan makes it dearer
    than the budget left, a budgeted refit is skipped there (said to be), an unbudgeted
    one goes on."""
    from stickslip_jax.diagnose.budget import fit_work
    from stickslip_jax.diagnose.catalogue import candidate as entry_of
    from stickslip_jax.diagnose.problem import OverBudget
    from stickslip_jax.diagnose.refit import RefitSetup, RoundStart, refit
    from stickslip_jax.diagnose.results import CandidateResult, CandidateStatus
    from stickslip_jax.diagnose.sizing import HeldSizing

    recs, attached, entry_specs = case
    problem = _problem(recs)
    # The first stage "ends" at a piezo 9x lighter: 3x the sub-steps per sample.
    stiff = eqx.tree_at(lambda a: a.piezo.Mp, attached, attached.piezo.Mp / 9)
    assert problem.plan_factor(stiff) >= 2.5 * problem.plan_factor(attached)
    second = []

    def fit_from(program, theta, **kw):  # the first stage ends at the stiff model
        if "held" not in kw["label"]:
            second.append(program.factor)
        return stiff, 1.0, None
    monkeypatch.setattr(problem, "fit_from", fit_from)
    names = baseline_free(attached, problem.data, problem.fix) + list(entry_specs)
    columns = int(np.size(ParameterMap.make(attached, names, entry_specs).zeros()))
    before = problem.refit_estimate(attached, columns, 5)
    need = fit_work(problem.samples, columns, 5, problem.plan_factor(stiff))
    assert need > 1.01 * before  # the estimate before the refit did not see it
    problem.budget = Budget(1.01 * before)

    # Unbudgeted: the second stage runs, at the stiff model's plan.
    problem.refit(attached, names, entry_specs, label="r", max_steps=5)
    assert second == [problem.plan_factor(stiff)]
    with pytest.raises(OverBudget) as over:
        problem.refit(attached, names, entry_specs, label="r", max_steps=5, reserve=0.0)
    assert over.value.need == pytest.approx(need) and len(second) == 1

    setup = RefitSetup(problem, baseline_free(attached, problem.data, problem.fix),
                       n_base=columns - len(entry_specs), max_steps=5, identify_max_steps=5,
                       carry_on_steps=5)
    at = RoundStart(act=attached, rss=1e4, nrmse=0.0, excess=1e4, reserve=0.0)
    held = HeldSizing(attached, entry_specs, None, np.zeros(1), 9e3, True)
    res = CandidateResult("external_load")
    refit(setup, at, res, entry_of("external_load"), held)
    assert res.status is CandidateStatus.SKIPPED and not res.refitted
    assert "second stage" in problem.budget.skipped[-1] and "would pass" in res.note
    assert len(second) == 1  # it never ran

"""An identification step re-plans its sub-steps when the fit leaves a fast start
(:func:`stickslip_jax.identify.steps._solve_step`)."""

import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.identify import identify
from stickslip_jax.identify import steps as identify_steps
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.residuals import dataset_plan
from stickslip_jax.synthetic import paper_protocol, simulate_set


@pytest.fixture(scope="module")
def bent_start():
    """Recordings of the default profile, and a start whose piezo mass is 1/9 of the
    truth's: a piezo mode 3x as fast, so the plan from the start takes 3x the sub-steps
    the truth needs."""
    truth = ss.lu2015_slc1720()
    specs = paper_protocol(periods=2, step_duration_s=0.02, sine_periods=2,
                           frequencies=(500.0,))
    recordings = simulate_set(truth, specs, noise_m=1e-9, seed=11)
    params = ss.params_from_actuator(truth)
    start = ss.actuator_from_params({**params, "Mp": params["Mp"] / 9})
    data = Dataset.from_recordings(recordings)
    assert dataset_plan(start, data).substeps >= 2.5 * dataset_plan(truth, data).substeps
    return truth, recordings, start, data


def _joint(recordings, start, truth):
    # Six play operators: a Jacobian of 14 columns, not 42 (the test's time).
    return identify(recordings, init=start, fix={"Ms": float(truth.slider.Ms)},
                    steps=("joint",), uncertainty=False, n_pi=6)


def test_a_step_leaving_a_fast_start_re_plans_and_ends_where_a_start_at_the_truth_does(
        bent_start):
    truth, recordings, start, data = bent_start
    replanned = _joint(recordings, start, truth)
    joint = replanned.steps[-1]
    assert joint.converged and "re-planned" in joint.result.message, joint.result.message
    # The evaluations after the re-plan ran at the plan the fitted model needs, not at
    # the start's.
    assert (dataset_plan(replanned.actuator, data).substeps * identify_steps.REPLAN_FACTOR
            <= dataset_plan(start, data).substeps)
    # Counted as one step: its iterations and evaluations summed over the segments.
    assert 2 <= joint.result.iterations <= 60 and joint.result.jacobians >= 3
    # Each stretch records the plan it ran at (what a work budget charges): the start's
    # first, then the fitted model's.
    plans = [seg.plan.substeps for seg in joint.segments]
    assert len(plans) >= 2 and plans[0] == dataset_plan(start, data).substeps
    assert plans[-1] * identify_steps.REPLAN_FACTOR <= plans[0]
    assert sum(seg.jacobians for seg in joint.segments) == joint.result.jacobians
    assert sum(seg.values for seg in joint.segments) == joint.result.values
    assert replanned.plan is not None
    # The same fit started at the truth (its plan from the start is the one the
    # optimum needs; nothing to re-plan) ends at the same optimum.
    direct = _joint(recordings, truth, truth)
    assert direct.steps[-1].converged and "re-planned" not in direct.steps[-1].result.message
    found, reference = (ss.params_from_actuator(r.actuator) for r in (replanned, direct))
    for name in ("Mp", "Dp", "Kp", "rho0"):
        assert found[name] == pytest.approx(reference[name], rel=2e-3), name


def test_a_solve_interrupted_by_stop_when_says_why_and_hands_on_its_damping():
    from stickslip_jax.identify.solve import solve_least_squares

    target = np.array([3.0, -2.0])

    def residuals(theta):
        return np.asarray(theta) - target

    seen = []

    def stop_when(theta):
        seen.append(np.array(theta))
        return "far enough" if np.linalg.norm(theta) > 1.0 else ""

    out = solve_least_squares(residuals, np.zeros(2), max_steps=50, stop_when=stop_when,
                              jacobian=lambda th: (residuals(th), np.eye(2)),
                              initial_damping=1.0)
    assert out.interrupted == "far enough" and not out.converged
    assert out.message == "interrupted: far enough"
    assert np.linalg.norm(out.theta) > 1.0 and np.isfinite(out.damping) and out.damping > 0
    # Asked at accepted points only, never at the start.
    assert len(seen) == out.iterations and not np.allclose(seen[0], 0.0)
    plain = solve_least_squares(residuals, np.zeros(2), max_steps=50,
                                jacobian=lambda th: (residuals(th), np.eye(2)))
    assert plain.converged and plain.interrupted == ""
    np.testing.assert_allclose(plain.theta, target, atol=1e-6)


def test_nielsens_damping_update_follows_the_gain_ratio_and_reaches_the_optimum():
    """Madsen, Nielsen & Tingleff (2004) eq. 3.16: after an accepted step the damping
    is multiplied by max(1/3, 1 − (2ρ − 1)³); the classical (optimistix) update keeps
    it unless ρ ≥ 0.99. Rejections raise it 4x in both."""
    from stickslip_jax.identify.solve import LevenbergMarquardtSteps, solve_least_squares

    def fn(y):  # Rosenbrock as residuals, with a third, weakly coupled one
        return np.array([10 * (y[1] - y[0] ** 2), 1 - y[0], 0.1 * y[2] * y[0] - 0.2])

    def jac(y):
        return np.array([[-20 * y[0], 10.0, 0.0], [-1.0, 0.0, 0.0],
                         [0.1 * y[2], 0.0, 0.1 * y[0]]])

    y0 = np.array([-1.2, 1.0, 0.5])
    for rule in ("classical", "nielsen"):
        lm = LevenbergMarquardtSteps(y0, step_size=1.0, damping_update=rule)
        lm.step(fn(lm.y_eval), jac(lm.y_eval))  # the start: always accepted
        checked = 0
        for _ in range(40):
            before = lm.step_size
            accepted = lm.step(fn(lm.y_eval), jac(lm.y_eval))
            rho = lm.gain_ratio
            if not accepted:
                assert lm.step_size == pytest.approx(before * 0.25)
            elif rule == "classical":
                assert lm.step_size == pytest.approx(before * (3.5 if rho >= 0.99 else 1.0))
            elif not np.isfinite(rho):  # the model promised no fall (at the optimum)
                assert lm.step_size == before
            else:
                factor = max(1 / 3, 1 - (2 * rho - 1) ** 3)
                assert lm.step_size == pytest.approx(before / factor)
                checked += 0.0 < rho < 0.99  # a ratio where the two rules differ
        if rule == "nielsen":
            assert checked > 0
    with pytest.raises(ValueError, match="damping_update"):
        LevenbergMarquardtSteps(y0, damping_update="fast")
    for rule in ("classical", "nielsen"):
        out = solve_least_squares(fn, y0, max_steps=200, damping_update=rule,
                                  jacobian=lambda y: (fn(y), jac(y)), rtol=1e-10, atol=1e-12)
        assert out.converged, (rule, out.message)
        np.testing.assert_allclose(out.theta, [1.0, 1.0, 2.0], atol=1e-5)

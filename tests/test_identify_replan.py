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
    """Recordings of the default profile, and a start whose piezo mass is 1/16 of the
    truth's: a piezo mode 4x as fast, so the plan from the start takes several times
    the sub-steps the truth needs."""
    truth = ss.lu2015_slc1720()
    specs = paper_protocol(periods=2, step_duration_s=0.02, sine_periods=2,
                           frequencies=(500.0,))
    recordings = simulate_set(truth, specs, noise_m=1e-9, seed=11)
    params = ss.params_from_actuator(truth)
    start = ss.actuator_from_params({**params, "Mp": params["Mp"] / 16})
    data = Dataset.from_recordings(recordings)
    assert dataset_plan(start, data).substeps >= 3 * dataset_plan(truth, data).substeps
    return truth, recordings, start, data


def _joint(recordings, start, truth):
    return identify(recordings, init=start, fix={"Ms": float(truth.slider.Ms)},
                    steps=("joint",), uncertainty=False)


def test_a_step_leaving_a_fast_start_re_plans_and_ends_where_it_would_without(
        bent_start, monkeypatch):
    truth, recordings, start, data = bent_start
    replanned = _joint(recordings, start, truth)
    joint = replanned.steps[-1]
    assert joint.converged and "re-planned" in joint.result.message, joint.result.message
    # The evaluations after the re-plan ran at the plan the fitted model needs, not at
    # the start's.
    end_plan = dataset_plan(replanned.actuator, data)
    assert end_plan.substeps * identify_steps.REPLAN_FACTOR <= dataset_plan(start, data).substeps
    # The same fit without re-planning (every evaluation at the start's plan) ends at
    # the same optimum: the sub-steps change the simulator's error, not the fit.
    monkeypatch.setattr(identify_steps, "REPLAN_FACTOR", np.inf)
    kept = _joint(recordings, start, truth)
    assert kept.steps[-1].converged and "re-planned" not in kept.steps[-1].result.message
    found, reference = (ss.params_from_actuator(r.actuator) for r in (replanned, kept))
    for name in ("Mp", "Dp", "Kp", "rho0"):
        assert found[name] == pytest.approx(reference[name], rel=2e-3), name
    assert found["Mp"] == pytest.approx(ss.params_from_actuator(truth)["Mp"], rel=0.05)
    # Counted as one step: its iterations and evaluations summed over the segments.
    assert joint.result.iterations <= 60 and joint.result.jacobians >= 2


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

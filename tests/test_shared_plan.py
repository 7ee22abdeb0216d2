"""A diagnosis's fits share stepping plans (``Problem.plan_for``): a model needing fewer
sub-steps than a plan already run, but more than half of them, runs at that plan (one
set of compiled programs, never a coarser simulation); one needing half or fewer gets
its own; an estimate does not add a plan."""

import equinox as eqx
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.problem import Problem
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.parameters import ParameterMap
from stickslip_jax.identify.residuals import dataset_plan
from stickslip_jax.synthetic import paper_protocol, simulate_set


@pytest.fixture(scope="module")
def problem_and_needs():
    act = ss.lu2015_slc1720()
    specs = paper_protocol(periods=2, amplitudes=(60.0,), frequencies=(500.0,),
                           step_duration_s=0.01, sine_periods=1)[:2]
    data = Dataset.from_recordings(simulate_set(act, specs, noise_m=1e-9, seed=1))

    def with_mass(f):  # the piezo's mass scaled: its mode, hence the sub-steps, moves
        return eqx.tree_at(lambda a: a.piezo.Mp, act, act.piezo.Mp * f)

    actuators = [with_mass(f) for f in (1.0, 1.3, 1.6, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0)]
    needs = [dataset_plan(a, data).substeps for a in actuators]
    return data, actuators, needs


def test_a_model_needing_more_than_half_a_plan_runs_at_it(problem_and_needs):
    data, actuators, needs = problem_and_needs
    problem = Problem(data, np.full(len(data), 1e-9), {}, None)
    first = problem.plan_for(actuators[0])
    assert first == dataset_plan(actuators[0], data)
    n0 = first.substeps
    near = [a for a, n in zip(actuators, needs, strict=True) if n0 / 2 < n < n0]
    far = [a for a, n in zip(actuators, needs, strict=True) if n <= n0 / 2]
    assert near and far, (n0, needs)  # the masses span both cases
    # Fewer sub-steps needed, more than half the plan's: the plan run before.
    assert problem.plan_for(near[0]) == first
    res = problem.residuals(ParameterMap.make(near[0], []))
    assert res.inner.plan == first
    # Half or fewer: its own plan; an estimate (keep=False) does not remember it.
    own = dataset_plan(far[0], data)
    assert problem.plan_for(far[-1], keep=False) == dataset_plan(far[-1], data)
    assert problem.plan_for(far[0]) == own and own.substeps <= n0 / 2
    # ...but a fit does: a model needing a little less than that plan now shares it.
    between = [a for a, n in zip(actuators, needs, strict=True) if own.substeps / 2 < n
               < own.substeps]
    for a in between:
        assert problem.plan_for(a) == own
    # A model needing more than every plan run gets its own, never a coarser one.
    stiff = eqx.tree_at(lambda a: a.piezo.Mp, actuators[0], actuators[0].piezo.Mp * 0.5)
    assert problem.plan_for(stiff).substeps == dataset_plan(stiff, data).substeps > n0

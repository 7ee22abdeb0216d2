"""The sensor's columns of a Jacobian, derived apart from the mechanics' pass
(:func:`stickslip_jax.identify.sensitivities.sensor_only_columns`), equal those the
forward pass through the mechanics carries."""

from pathlib import Path

import equinox as eqx
import jax
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.identify import sensitivities
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.residuals import dataset_plan
from stickslip_jax.model.extensions import SensorOutput, delayed
from stickslip_jax.synthetic import paper_protocol, simulate_set

TRUTH = Path(__file__).resolve().parent.parent / "fixtures" / "identification" / "truth.json"


@pytest.fixture(scope="module")
def case():
    base = ss.load_params(TRUTH)
    # Every kind of sensor quantity: a delay, a drift with a settling term, two
    # harmonics of a periodic error.
    act = eqx.tree_at(lambda a: a.output_map, base,
                      SensorOutput(delay=3e-6, drift=2e-6, settling=(3e-9,),
                                   settle_times=(0.01,), periodic=(1e-9, 0.5e-9, 0.2e-9, 0.0)))
    specs = paper_protocol(periods=1, amplitudes=(60.0,), frequencies=(500.0,),
                           step_duration_s=0.005, sine_periods=1)
    data = Dataset.from_recordings(simulate_set(base, specs[:3], noise_m=1e-9, seed=2))
    mask = jax.tree.map(lambda _: False, act)
    for where in (lambda a: a.piezo.Mp, lambda a: a.piezo.Kp, lambda a: a.output_map.delay,
                  lambda a: a.output_map.drift, lambda a: a.output_map.settling,
                  lambda a: a.output_map.periodic):
        node = where(mask)
        mask = eqx.tree_at(where, mask, (True,) * len(node) if isinstance(node, tuple)
                           else True)
    return act, data, dataset_plan(act, data), mask


def _columns(act, mask, setters):
    """Tangents of the mask's leaves, one column per entry of ``setters`` (each a list
    of (where, value) pairs)."""
    zeros = jax.tree.map(lambda x: np.zeros((len(setters),) + np.shape(x)),
                         eqx.filter(act, mask))
    for k, pairs in enumerate(setters):
        for where, value in pairs:
            node = where(zeros)
            if isinstance(node, tuple):
                for i, v in enumerate(value):
                    node[i][k] = v
            else:
                node[k] = value
    return zeros


def test_sensor_columns_equal_the_mechanics_pass(case):
    act, data, plan, mask = case
    p = lambda a: a.output_map.periodic  # noqa: E731
    tangents = _columns(act, mask, [
        [(lambda a: a.piezo.Mp, 1e-6)],                                      # mechanics
        [(lambda a: a.output_map.drift, 1.0)],                         # sensor
        [(p, (0.0, 0.0, 1.0, 0.0))],                                   # sensor
        [(lambda a: a.piezo.Kp, 1e5), (lambda a: a.output_map.drift, 1.0)],  # both
        [(lambda a: a.output_map.delay, 1e-6)],                        # sensor
        [(lambda a: a.output_map.settling, (1.0,)), (p, (1.0, 0.5, 0.0, 0.0))],  # sensor
    ])
    np.testing.assert_array_equal(sensitivities.sensor_only_columns(tangents),
                                  [False, True, True, False, True, True])
    programs = sensitivities.RecordingPrograms(data, act, mask, threads=1)
    q, dq = programs.sensitivities(act, tangents, plan)
    perturbed, fixed = eqx.partition(act, mask)
    perturbed = jax.tree.map(lambda x: np.asarray(x, dtype=float), perturbed)
    q_all, dq_all, positions = programs._through_mechanics(perturbed, fixed, tangents,
                                                           plan, [0, 1, 2])
    # (Another number of tangents per pass moves the last bits of the value.)
    np.testing.assert_allclose(q, q_all, rtol=1e-13, atol=0)
    scale = np.max(np.abs(dq_all), axis=(0, 1))
    assert np.all(scale > 0)  # every column moves the output
    np.testing.assert_allclose(dq / scale, dq_all / scale, rtol=0, atol=1e-13)
    # The drift's column is the time itself, the settling's 1 − exp(−t/T) plus the
    # periodic error's cosine and half its sine at the delayed position.
    n = int(data.mask[1].sum())
    t = data.dt[1] * np.arange(n)
    np.testing.assert_allclose(dq[1, :n, 1], t, rtol=1e-15, atol=0)
    read = np.asarray(delayed(t, positions[1, :n], act.output_map.delay))
    phase = 2 * np.pi * read / act.output_map.period
    np.testing.assert_allclose(dq[1, :n, 5], (1 - np.exp(-t / 0.01)) + np.cos(phase)
                               + 0.5 * np.sin(phase), rtol=0, atol=1e-12)


def test_only_sensor_columns_run_the_value_program(case):
    act, data, plan, mask = case
    tangents = _columns(act, mask, [[(lambda a: a.output_map.drift, 1.0)],
                                    [(lambda a: a.output_map.delay, 1e-6)]])
    programs = sensitivities.RecordingPrograms(data, act, mask, threads=1)
    q, dq = programs.sensitivities(act, tangents, plan, rows=[2, 0])
    np.testing.assert_array_equal(q, programs.simulate(act, plan, rows=[2, 0]))
    perturbed, fixed = eqx.partition(act, mask)
    _, dq_all, _ = programs._through_mechanics(perturbed, fixed, tangents, plan, [2, 0])
    np.testing.assert_allclose(dq, dq_all, rtol=0,
                               atol=1e-13 * float(np.max(np.abs(dq_all))))


def test_a_fit_is_charged_the_columns_that_ride_on_the_mechanics(case):
    """The work budget counts a sensor's quantities as no tangent of the simulation
    (they are derived apart), the mechanics' ones as one each."""
    from stickslip_jax.diagnose.problem import Problem
    from stickslip_jax.identify.parameters import ParameterSpec

    act, data, _, _ = case
    specs = {"sensor_drift": ParameterSpec(lambda a: a.output_map.drift, "linear", 1e-6, "m/s"),
             "periodic": ParameterSpec(lambda a: a.output_map.periodic, "linear", 1e-9, "m")}
    problem = Problem(data, np.full(len(data), 1e-9), {}, None)
    program = problem.program(act, ["Mp", "Kp", "sensor_drift", "periodic"], specs)
    assert program.pmap.size == 2 + 1 + 4
    assert program.simulated_columns == 2
    sensor_alone = problem.program(act, ["periodic"], specs)
    assert sensor_alone.simulated_columns == 0
    r, jac = sensor_alone(np.zeros(4))
    assert np.all(np.isfinite(jac)) and np.all(np.any(jac != 0, axis=0))

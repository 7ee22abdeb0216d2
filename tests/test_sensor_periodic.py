"""The interferometer's periodic error as a class (issue #63): the sensor's periodic
error of the fringe and its harmonics, the catalogue entry that fits it, and the score
test's vector probe."""

import equinox as eqx
import jax.numpy as jnp
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.catalogue import candidate
from stickslip_jax.diagnose.catalogue.sensor_periodic import (
    HARMONICS,
    MAX_HARMONICS,
    coefficient_name,
    with_periodic,
)
from stickslip_jax.diagnose.scores import install_probes, probe_batches
from stickslip_jax.model.extensions import HENE_FRINGE_M, PeriodicSensorError, SensorOutput

matplotlib.use("Agg")
T = jnp.linspace(0.0, 0.02, 2001)
Q = jnp.linspace(0.0, 3e-6, 2001)  # ten fringes


def test_the_error_is_periodic_in_the_position_read_with_its_harmonics():
    # One sine coefficient of the first harmonic is the generators' one-sine form.
    out = SensorOutput(periodic=(0.0, 2.5e-9))(T, Q)
    np.testing.assert_allclose(out, PeriodicSensorError(2.5e-9)(T, Q), rtol=0, atol=1e-21)
    # A second harmonic's cosine: period half the fringe, and read after the delay.
    out = SensorOutput(delay=1e-5, periodic=(0.0, 0.0, 1e-9, 0.0))(T, Q)
    p = np.interp(np.asarray(T) - 1e-5, np.asarray(T), np.asarray(Q))
    want = p + 1e-9 * np.cos(4 * np.pi * p / HENE_FRINGE_M)
    np.testing.assert_allclose(out, want, rtol=0, atol=1e-20)
    # Without harmonics the sum of before, to the last bit.
    plain = SensorOutput(delay=1e-5, drift=2e-7)
    assert np.array_equal(plain(T, Q), SensorOutput(1e-5, 2e-7, periodic=())(T, Q))
    with pytest.raises(ValueError, match="a cosine and a sine coefficient per harmonic"):
        SensorOutput(periodic=(1e-9,))


def test_the_probes_are_one_vector_quantity_whose_columns_are_the_harmonics():
    entry = candidate("sensor_periodic")
    act = ss.lu2015_slc1720()
    probes = entry.probes(act, {})
    assert len(probes) == 2 * HARMONICS and len({id(p.spec) for p in probes}) == 1
    probe_act, installed = install_probes(act, [entry], {})
    assert {i.name for i in installed} == {"probe0"}
    assert [i.index for i in installed] == list(range(2 * HARMONICS))
    assert len(probe_act.output_map.periodic) == 2 * HARMONICS
    # The vector counts as one quantity when the score test sizes its programs.
    others = [candidate("sensor_delay"), candidate("sensor_drift")]
    assert probe_batches(act, [*others, entry], {"recording_durations_s": (0.02, 0.1)},
                         most=3) == [[*others, entry]]
    # The column of element k is the derivative of the reading by coefficient k.
    spec = installed[0].spec
    for k in range(2 * HARMONICS):
        tangent = np.zeros(2 * HARMONICS)
        tangent[k] = 1.0
        col = jax_column(probe_act, spec, tangent)
        phase = 2 * np.pi * (k // 2 + 1) * np.asarray(Q) / HENE_FRINGE_M
        np.testing.assert_allclose(col, np.sin(phase) if k % 2 else np.cos(phase),
                                   atol=1e-12)


def jax_column(act, spec, tangent):
    import jax

    def reading(c):
        return eqx.tree_at(spec.getter, act, c).output_map(T, Q)

    return np.asarray(jax.jvp(reading, (jnp.zeros(tangent.size),),
                              (jnp.asarray(tangent),))[1])


def test_the_entry_frees_every_coefficient_and_keeps_the_sensor_quantities():
    entry = candidate("sensor_periodic")
    act = eqx.tree_at(lambda a: a.output_map, ss.lu2015_slc1720(),
                      SensorOutput(delay=3e-6, drift=1e-7))
    probe = entry.probes(act, {})[3]  # the second harmonic's sine
    new, specs = entry.attach(act, 0.8e-9, probe)
    assert list(specs) == [coefficient_name(i) for i in range(2 * HARMONICS)]
    assert [float(specs[n].getter(new)) for n in specs] == [0.0, 0.0, 0.0, 0.8e-9]
    assert float(new.output_map.delay) == 3e-6 and float(new.output_map.drift) == 1e-7
    carried = entry.carry(ss.lu2015_slc1720(), new).output_map
    np.testing.assert_array_equal(carried(T, Q), new.output_map(T, Q))
    # The sensor drift entry keeps a fitted periodic error when it attaches beside it.
    drift = candidate("sensor_drift")
    hints = {"recording_durations_s": (0.02, 0.1)}
    both, _ = drift.attach(new, 1e-7, drift.probes(new, hints)[0])
    assert tuple(float(c) for c in both.output_map.periodic) == (0.0, 0.0, 0.0, 0.8e-9)


def test_the_refined_form_adds_a_harmonic_at_zero_up_to_the_most():
    entry = candidate("sensor_periodic")
    act, _ = entry.attach(ss.lu2015_slc1720(), 1e-9, entry.probes(ss.lu2015_slc1720(), {})[0])
    [(start, specs)] = entry.refined_forms(act, {})
    assert len(start.output_map.periodic) == 2 * (HARMONICS + 1) and len(specs) == len(
        start.output_map.periodic)
    np.testing.assert_array_equal(start.output_map(T, Q), act.output_map(T, Q))
    full = with_periodic(act, MAX_HARMONICS)
    assert entry.refined_forms(full, {}) == []
    assert entry.refined_forms(ss.lu2015_slc1720(), {}) == []


def test_an_error_whose_slope_reaches_the_positions_is_implausible():
    entry = candidate("sensor_periodic")
    # A sine of amplitude A over the fringe P has the slope 2πA/P: 1 at A = 50.4 nm.
    assert entry.implausible({"periodic_cos_1": 45e-9, "periodic_sin_1": 0.0}) == ""
    assert "run backwards" in entry.implausible({"periodic_cos_1": 0.0,
                                                 "periodic_sin_1": 55e-9})
    said = entry.describe({"periodic_cos_1": 3e-9, "periodic_sin_1": 4e-9,
                           "periodic_cos_2": 0.0, "periodic_sin_2": 1e-9})
    assert "5 nm at 316.4 nm" in said and "1 nm at 158.2 nm" in said
    fig, ax = plt.subplots()
    assert entry.plot_form(ax, {"periodic_cos_1": 3e-9, "periodic_sin_1": 4e-9})
    plt.close(fig)


def test_it_cannot_show_in_recordings_that_move_less_than_a_fringe():
    entry = candidate("sensor_periodic")
    t = np.linspace(0.0, 0.01, 101)

    def rec(span_m):
        return ss.Recording(t, np.zeros_like(t), position=np.linspace(0.0, span_m, t.size)
                            * 1e6, position_unit="um")

    assert "no recording moves one fringe" in entry.needs([rec(0.2e-6), rec(0.1e-6)])
    assert entry.needs([rec(0.2e-6), rec(2e-6)]) is None


def test_a_tuple_of_scalars_is_one_vector_quantity_that_keeps_the_models_structure():
    import jax

    from stickslip_jax.identify.parameters import ParameterMap
    from stickslip_jax.identify.sensitivities import perturbed_mask

    entry = candidate("sensor_periodic")
    act = with_periodic(ss.lu2015_slc1720())
    spec = entry.probes(act, {})[0].spec
    pmap = ParameterMap.make(act, ["Kp", "probe"], {"probe": spec})
    theta = np.array([0.0, 1.0, -2.0, 0.5, 3.0])
    moved = pmap.actuator(jnp.asarray(theta))
    assert jax.tree.structure(moved) == jax.tree.structure(act)
    np.testing.assert_allclose([float(c) for c in moved.output_map.periodic],
                               np.array([1.0, -2.0, 0.5, 3.0]) * 1e-9, rtol=1e-14)
    mask = perturbed_mask(act, ["Kp", "probe"], {"probe": spec})
    assert jax.tree.structure(mask) == jax.tree.structure(act)
    assert sum(jax.tree.leaves(mask)) == 1 + 2 * HARMONICS
    tangents = pmap.leaf_tangents(theta, mask)
    rows = np.stack([np.asarray(c) for c in tangents.output_map.periodic], axis=1)
    np.testing.assert_allclose(rows[1:], np.eye(2 * HARMONICS) * 1e-9, rtol=1e-14)
    assert not rows[0].any()


def test_a_periodic_error_of_another_shape_is_named_and_its_third_harmonic_found():
    """End to end on the tests' reduced protocol (8 recordings, 1 nm noise): an error
    of 3 nm at the fringe plus 1.2 nm at a third of it applied to the reading (the
    generator's form, not the entry's) is named, and the form refined by a third
    harmonic recovers both amplitudes. The same-slot rival (the sensor delay) beside
    it; the full catalogue on the 17 recordings is `bench_diagnose.py --variants`."""
    from pathlib import Path

    from stickslip_jax.diagnose import Verdict, diagnose
    from stickslip_jax.synthetic import paper_protocol, simulate_set
    from stickslip_jax.testing.concealed import with_variant

    base = ss.load_params(Path(__file__).resolve().parent.parent / "fixtures"
                          / "identification" / "truth.json")
    specs = paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(100.0, 500.0),
                           step_duration_s=0.03, sine_periods=2)
    recs = simulate_set(with_variant(base, "interferometer_skewed"), specs, noise_m=1e-9,
                        seed=7)
    d = diagnose(recs, init=base, fix={"Ms": 0.0247}, identify_steps=(),
                 candidates=["sensor_periodic", "sensor_delay"], max_rounds=1, top=2,
                 max_steps=15, size_at_most=2, fallback=False)
    assert [c.name for c in d.accepted] == ["sensor_periodic"]
    assert d.verdict is Verdict.AUGMENTED, d.verdict
    p = d.accepted[0].params
    assert len(p) == 2 * (HARMONICS + 1)  # the refined form's
    assert np.hypot(p["periodic_cos_1"], p["periodic_sin_1"]) == pytest.approx(3e-9, rel=0.05)
    assert np.hypot(p["periodic_cos_3"], p["periodic_sin_3"]) == pytest.approx(1.2e-9,
                                                                             rel=0.05)
    assert abs(p["periodic_sin_2"]) < 0.2e-9


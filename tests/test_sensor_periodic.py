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
    fringe_reference,
    fringe_start,
    offset_name,
    with_periodic,
)
from stickslip_jax.diagnose.scores import install_probes, probe_batches
from stickslip_jax.identify.parameters import ParameterSpec
from stickslip_jax.model.extensions import (
    HENE_FRINGE_M,
    ChainedOutput,
    PeriodicSensorError,
    SensorOutput,
)
from stickslip_jax.model.stages import IdentityOutput

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
    assert len(ax.lines) == 2  # the error and its first harmonic: no offsets fitted
    plt.close(fig)
    # The fitted offsets drawn where each recording starts on the fringe (mod P).
    fig, ax = plt.subplots()
    assert entry.plot_form(ax, {"periodic_cos_1": 3e-9, "periodic_sin_1": 4e-9,
                                "fringe_offset_1": 100e-9, "fringe_offset_2": 400e-9})
    starts = ax.lines[-1]
    np.testing.assert_allclose(starts.get_xdata(), [100.0, 400.0 - 316.4],
                               atol=1e-2)  # nm
    # e(p) = 3 cos(2πp/P) + 4 sin(2πp/P) nm at the starts.
    phase = 2 * np.pi * np.array([100.0, 400.0 - 316.4]) / 316.4
    np.testing.assert_allclose(starts.get_ydata(), 3 * np.cos(phase) + 4 * np.sin(phase),
                               atol=1e-3)
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


def test_each_recording_is_read_at_its_own_fringe_offset():
    sensor = SensorOutput(delay=1e-5, periodic=(0.0, 2.5e-9), fringe_offsets=(0.0, 100e-9))
    assert sensor.recordings() == 2 and SensorOutput().recordings() == 0
    p = np.interp(np.asarray(T) - 1e-5, np.asarray(T), np.asarray(Q))
    want = p + 2.5e-9 * np.sin(2 * np.pi * (p + 100e-9) / HENE_FRINGE_M)
    np.testing.assert_allclose(sensor.read(T, Q, 1), want, rtol=0, atol=1e-20)
    np.testing.assert_allclose(sensor.read(T, Q, jnp.int32(1)), want, rtol=0, atol=1e-20)
    # A trace of no dataset reads at offset 0, as the map itself does.
    assert np.array_equal(sensor.read(T, Q), sensor(T, Q))
    np.testing.assert_allclose(sensor(T, Q), SensorOutput(1e-5, periodic=(0.0, 2.5e-9))(T, Q),
                               rtol=0, atol=0)
    # The generators' form at the same offset.
    np.testing.assert_allclose(
        SensorOutput(periodic=(0.0, 2.5e-9), fringe_offsets=(0.0, 100e-9)).read(T, Q, 1),
        PeriodicSensorError(2.5e-9, offset=100e-9)(T, Q), rtol=0, atol=1e-21)
    chained = ChainedOutput((IdentityOutput(), sensor))
    assert chained.recordings() == 2
    np.testing.assert_array_equal(chained.read(T, Q, 1), sensor.read(T, Q, 1))


def _two_recordings():
    t = np.arange(400) / 25_000.0
    volts = [60.0 * (t * 100.0 % 1.0), 60.0 * (t * 250.0 % 1.0)]
    return [ss.Recording(t, v, position=np.zeros_like(t), position_unit="um") for v in volts]


def test_the_dataset_programs_read_each_recording_at_its_offset_and_differentiate_it():
    from stickslip_jax.identify.dataset import Dataset
    from stickslip_jax.identify.parameters import ParameterMap
    from stickslip_jax.identify.residuals import dataset_plan, simulate_dataset
    from stickslip_jax.identify.sensitivities import RecordingPrograms, perturbed_mask

    recs = _two_recordings()
    data = Dataset.from_recordings(recs)
    plain = ss.lu2015_slc1720()
    offsets = (30e-9, 140e-9)
    act = eqx.tree_at(lambda a: a.output_map, plain,
                      SensorOutput(periodic=(1e-9, 2e-9), fringe_offsets=offsets))
    plan = dataset_plan(act, data)
    q = np.asarray(simulate_dataset(plain, data, plan=plan))
    theta = [2 * np.pi * (q[i] + offsets[i]) / HENE_FRINGE_M for i in range(2)]
    want = np.stack([q[i] + 1e-9 * np.cos(theta[i]) + 2e-9 * np.sin(theta[i])
                     for i in range(2)])
    np.testing.assert_allclose(simulate_dataset(act, data, plan=plan), want, rtol=0,
                               atol=1e-18)
    np.testing.assert_allclose(RecordingPrograms(data).simulate(act, plan), want, rtol=0,
                               atol=1e-18)
    # The offsets' columns (sensor-only: the mechanics' pass skipped), analytically.
    specs = {"o1": ParameterSpec(lambda a: a.output_map.fringe_offsets[1], "linear", 1e-9,
                                 "m")}
    pmap = ParameterMap.make(act, ["Kp", "o1"], specs)
    mask = perturbed_mask(act, ["Kp", "o1"], specs)
    programs = RecordingPrograms(data, act, mask)
    _, dq = programs.sensitivities(act, pmap.leaf_tangents(np.zeros(2), mask), plan)
    rate = 2 * np.pi / HENE_FRINGE_M * 1e-9  # d theta per θ unit of o1
    np.testing.assert_allclose(dq[1, :, 1], rate * (-1e-9 * np.sin(theta[1])
                                                    + 2e-9 * np.cos(theta[1])),
                               rtol=1e-9, atol=1e-24)
    assert not dq[0, :, 1].any()
    # A sensor fitted on another set's recordings is refused, not read with another's.
    with pytest.raises(ValueError, match="a quantity per recording for 2 recordings"):
        simulate_dataset(act, Dataset.from_recordings(recs[:1]))


def _ramps(offsets, amplitudes, *, seed=0, n=3000, span=2e-6):
    """Hints of recordings moving along ramps of ``span`` [m] whose residual is a
    periodic error of first-harmonic ``amplitudes`` [m] at the fringe ``offsets`` [m],
    plus 1 nm noise."""
    rng = np.random.default_rng(seed)
    outputs = tuple(np.linspace(0.0, span * (1 + 0.3 * i), n) for i in range(len(offsets)))
    residuals = tuple(a * np.sin(2 * np.pi * (q + o) / HENE_FRINGE_M)
                      + 1e-9 * rng.standard_normal(n)
                      for q, o, a in zip(outputs, offsets, amplitudes, strict=True))
    return {"outputs_m": outputs, "residuals_m": residuals,
            "noise_m": (1e-9,) * len(offsets)}


def test_the_fringe_start_finds_each_recordings_offset_and_only_when_asked():
    rng = np.random.default_rng(3)
    offsets = rng.uniform(0.0, HENE_FRINGE_M, 6)
    hints = _ramps(offsets, [2e-9] * 6)
    start = fringe_start(hints)
    # The reference: the most samples per noise variance (here a tie: the first).
    assert start is not None and start.reference == fringe_reference(hints) == 0
    assert start.free == (1, 2, 3, 4, 5)
    louder = hints | {"noise_m": (2e-9,) + (1e-9,) * 5}
    assert fringe_reference(louder) == 1
    # The same differences as the drawn offsets (each about 0.65 nm standard error:
    # 1 nm noise, 2 nm error, 3000 samples), and one amplitude.
    diff = np.angle(np.exp(2j * np.pi * (np.asarray(start.offsets) - offsets)
                           / HENE_FRINGE_M))
    assert np.ptp(np.unwrap(diff)) * HENE_FRINGE_M / (2 * np.pi) < 4e-9
    assert np.hypot(*start.coefficients[:2]) == pytest.approx(2e-9, rel=0.02)
    np.testing.assert_allclose(start.coefficients[2:], 0.0, atol=0.05e-9)
    # One phase for all (the simulated protocols): nothing to offer.
    same = _ramps([40e-9] * 6, [2e-9] * 6)
    assert fringe_start(same) is None
    # Another physics' misfit, periodic in time rather than in the position read
    # (3 nm at 20-400 Hz, one 0.1 s ramp each), projects on the fringe's columns with
    # amplitudes that differ by recording: not taken for offsets.
    t = np.linspace(0.0, 0.1, 3000)
    other = hints | {"residuals_m": tuple(
        3e-9 * np.sin(2 * np.pi * f * t + ph) + 1e-9 * rng.standard_normal(t.size)
        for f, ph in zip(rng.uniform(20.0, 400.0, 6), rng.uniform(0, 2 * np.pi, 6),
                         strict=True))}
    assert fringe_start(other) is None
    # Noise alone, or fewer than two recordings that move a fringe.
    assert fringe_start(_ramps(offsets, [0.0] * 6)) is None
    short = _ramps(offsets[:2], [2e-9] * 2, span=0.2e-6)
    assert fringe_start(short) is None and fringe_reference(short) is None


def test_the_entry_offers_the_offsets_as_a_second_start_and_keeps_them_refined():
    entry = candidate("sensor_periodic")
    act = ss.lu2015_slc1720()
    hints = _ramps(np.linspace(0.0, 250e-9, 4), [2e-9] * 4)
    probe = entry.probes(act, hints)[1]
    # The probes read each recording at its offset (at zero strength: unchanged).
    probe_act, _ = install_probes(act, [entry], hints)
    assert probe_act.output_map.recordings() == 4
    np.testing.assert_array_equal(probe_act.output_map.read(T, Q, 3), Q)
    [(shared, shared_specs), (each, specs)] = entry.attach_options(act, 1e-9, probe)
    assert shared.output_map.recordings() == 0 and len(shared_specs) == 2 * HARMONICS
    assert each.output_map.recordings() == 4
    reference = fringe_reference(hints)
    assert sorted(k for k in specs if k.startswith("fringe_offset_")) == [
        offset_name(r) for r in range(4) if r != reference]
    # The refined form frees the offsets too, and starts where the fit ended.
    [(start, refined)] = entry.refined_forms(each, hints)
    assert offset_name(reference) not in refined and len(refined) == 2 * (HARMONICS + 1) + 3
    np.testing.assert_array_equal(start.output_map.read(T, Q, 2), each.output_map.read(T, Q, 2))
    # Without hints (or where one phase does), the shared start alone.
    assert len(entry.attach_options(act, 1e-9, entry.probes(act, {})[1])) == 1


def test_a_periodic_error_of_another_shape_read_from_other_fringe_starts_is_named():
    """End to end on the tests' reduced protocol (8 recordings, 1 nm noise), as a real
    set is read: each recording starts at another point of the fringe (offsets drawn
    at random), and the error is 3 nm at the fringe plus 1.2 nm at a third of it
    applied to the reading (the generator's form, not the entry's). One phase for the
    set explains little of it (before the offsets: nothing named, unexplained
    residual); with an offset per recording it is named, and the form refined by a
    third harmonic recovers both amplitudes and the offsets' differences. The same-slot
    rival (the sensor delay) beside it; the full catalogue on the 17 recordings is
    `bench_diagnose.py --variants`."""
    from pathlib import Path

    from stickslip_jax.diagnose import Verdict, diagnose
    from stickslip_jax.model.extensions import ChainedOutput
    from stickslip_jax.synthetic import paper_protocol, simulate_set
    from stickslip_jax.testing.concealed import read_from_fringe_starts

    base = ss.load_params(Path(__file__).resolve().parent.parent / "fixtures"
                          / "identification" / "truth.json")
    specs = paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(100.0, 500.0),
                           step_duration_s=0.03, sine_periods=2)
    clean = simulate_set(base, specs, noise_m=0.0)
    recs, offsets = read_from_fringe_starts(
        clean, lambda o: ChainedOutput((PeriodicSensorError(3e-9, offset=o),
                                        PeriodicSensorError(1.2e-9, HENE_FRINGE_M / 3, o))),
        noise_m=1e-9, seed=7)
    d = diagnose(recs, init=base, fix={"Ms": 0.0247}, identify_steps=(),
                 candidates=["sensor_periodic", "sensor_delay"], max_rounds=1, top=2,
                 max_steps=15, size_at_most=2, fallback=False)
    assert [c.name for c in d.accepted] == ["sensor_periodic"]
    assert d.verdict is Verdict.AUGMENTED, d.verdict
    p = d.accepted[0].params
    assert sum(k.startswith("periodic_") for k in p) == 2 * (HARMONICS + 1)  # refined
    assert np.hypot(p["periodic_cos_1"], p["periodic_sin_1"]) == pytest.approx(3e-9, rel=0.05)
    assert np.hypot(p["periodic_cos_3"], p["periodic_sin_3"]) == pytest.approx(1.2e-9,
                                                                             rel=0.05)
    assert abs(p["periodic_sin_2"]) < 0.2e-9
    # The fitted offsets differ as the drawn ones do (the held one's value is the
    # fit's origin), to a few nm along the 316 nm fringe (about 0.5 nm standard error
    # each here: 1 nm noise on a 3 nm error over 1500-5000 samples).
    fitted = d.final.output_map.fringe_offsets
    shift = np.angle(np.exp(2j * np.pi * (np.asarray(fitted, dtype=float) - offsets)
                            / HENE_FRINGE_M))
    assert np.ptp(np.unwrap(shift)) * HENE_FRINGE_M / (2 * np.pi) < 5e-9
    assert "(7 offsets)" in candidate("sensor_periodic").describe(p)  # one held

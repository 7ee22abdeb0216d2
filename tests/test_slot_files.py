"""Parameter files hold the actuator's slots (drive stage, extensions, sensor): every
part the model has is written and read back leaf for leaf, simulates the same trace,
and a part that is unknown, misplaced or not a number is refused with the file's
name and the fix."""

import json

import jax
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.model.extensions import (
    ChainedOutput,
    ClippedSlewInput,
    Creep,
    CreepSpectrum,
    ExponentialDrift,
    LearnedForce,
    LowPassInput,
    ParallelInputs,
    PeriodicSensorError,
    PositionRipple,
    RateDependentStroke,
    RateLagForm,
    SaturatingViscosity,
    SecondOrderInput,
    SensorOutput,
    ShapedSlewInput,
    SlewLimitedInput,
    StructuralMode,
)
from stickslip_jax.model.slot_files import PARTS, part_to_json
from stickslip_jax.params import (
    ParameterError,
    actuator_from_params,
    load_params,
    params_from_actuator,
    save_params,
)


def _every_part():
    """An actuator of the profile holding every part of :data:`PARTS` (but the
    identities, the defaults) in its slots, with values away from their defaults."""
    base = ss.lu2015_slc1720()
    stage = ParallelInputs((LowPassInput(2e-6, 0.7), SecondOrderInput(9e3, 0.5),
                            SlewLimitedInput(2e6, 1e-6, 0.4), ClippedSlewInput(1.5e6, 0.6e-6),
                            ShapedSlewInput(1e6, 0.8e-6, 2.0, 0.9)))
    extensions = (Creep(0.01, 5e-3), Creep([0.01, 0.02], [3e-3, 30e-3]),
                  CreepSpectrum((1e-10, 2e-10), (1e-3, 1e-2)),
                  RateDependentStroke(2e-10, 1e-4),
                  RateLagForm(1e-10, 2e-4, (3e-11, 0.0), (0.3, 1.0)),
                  StructuralMode(3300.0, 0.03, 1.2e-7, 1e-8), PositionRipple(1e-4, 1e-6),
                  SaturatingViscosity((0.1, 0.2), (1e-3, 3e-3)),
                  LearnedForce([1e-4, 0.0, 2e-4, 0.0, 0.0, 3e-4],
                               (1e-6, 1e-3, 1e-3, 1e-4, 10.0, 1e-8), [1, 0, 1, 0, 0, 1]))
    sensor = ChainedOutput((SensorOutput(delay=15e-6, drift=2e-7, settling=(1e-9,),
                                         settle_times=(0.02,), periodic=(1e-9, -2e-9),
                                         fringe_offsets=(0.0, 1e-7)),
                            ExponentialDrift(3e-9, 0.05), PeriodicSensorError(1e-9)))
    act = base
    for e in extensions:
        act = act.with_extension(e)
    return ss.Actuator(act.piezo, act.hysteresis, act.slider, act.friction,
                       input_stage=stage, extensions=act.extensions, output_map=sensor)


def test_every_part_is_written_and_read_back_leaf_for_leaf(tmp_path):
    act = _every_part()
    written = {type(p).__name__ for p in (act.input_stage, *act.input_stage.stages,
                                          *act.extensions, act.output_map,
                                          *act.output_map.maps)}
    assert written == set(PARTS) - {"IdentityInput", "IdentityOutput"}
    path = save_params(act, tmp_path / "params.json")
    text = json.loads(path.read_text())
    assert text["extensions"][5] == {"type": "StructuralMode", "frequency": 3300.0,
                                     "damping": 0.03, "compliance": 1.2e-7,
                                     "stack_compliance": 1e-8}
    back = load_params(path)
    assert jax.tree.structure(back) == jax.tree.structure(act)
    for a, b in zip(jax.tree.leaves(act), jax.tree.leaves(back), strict=True):
        np.testing.assert_array_equal(np.asarray(b), np.asarray(a))
    # Written again, the same file: nothing lost or added on the way.
    assert params_from_actuator(back) == params_from_actuator(act)


def test_a_model_read_back_simulates_the_same_trace():
    base = ss.lu2015_slc1720()
    act = ss.Actuator(base.piezo, base.hysteresis, base.slider, base.friction,
                      input_stage=LowPassInput(3e-6),
                      extensions=(StructuralMode(3300.0, 0.03, 1.2e-7),),
                      output_map=SensorOutput(delay=10e-6, periodic=(2e-9, 1e-9)))
    back = actuator_from_params(json.loads(json.dumps(params_from_actuator(act))))
    dt = 1e-5
    t = np.arange(600) * dt
    u = 60.0 * (t * 500.0 % 1.0)  # a 500 Hz sawtooth of 60 V
    q0 = np.asarray(ss.simulate(act, u, dt=dt))
    q1 = np.asarray(ss.simulate(back, u, dt=dt))
    np.testing.assert_array_equal(q1, q0)
    assert np.ptp(q0) > 1e-7  # it moved: the comparison is of a real trace


def _file(**slots):
    return {**params_from_actuator(ss.lu2015_slc1720()), **slots}


@pytest.mark.parametrize(("slots", "said"), [
    ({"extensions": [{"type": "os.system", "command": "rm"}]}, "unknown part type 'os.system'"),
    ({"drive_stage": {"type": "StructuralMode", "frequency": 1e3, "damping": 0.1,
                      "compliance": 1e-8}}, "StructuralMode is not a drive stage"),
    ({"sensor": {"type": "SensorOutput", "delay": float("nan")}}, "sensor.delay must be a finite"),
    ({"extensions": [{"type": "Creep", "gain": 0.01, "tau": 5e-3, "taus": 1.0}]},
     "unknown name(s) 'taus'"),
    ({"extensions": {"type": "Creep", "gain": 0.01, "tau": 5e-3}}, "extensions must be a list"),
    ({"sensor": {"type": "SensorOutput", "periodic": [1e-9]}}, "a cosine and a sine"),
])
def test_a_part_that_is_not_the_models_is_refused_with_the_fix(slots, said):
    with pytest.raises(ParameterError) as err:
        actuator_from_params(_file(**slots), source="p.json")
    assert said in str(err.value) and "p.json" in str(err.value)


def test_a_plain_actuator_writes_no_slot():
    assert not {"drive_stage", "extensions", "sensor"} & set(
        params_from_actuator(ss.lu2015_slc1720()))
    with pytest.raises(ValueError, match="not one of the model's parts"):
        part_to_json(ss.lu2015_slc1720().piezo)


def test_the_final_model_of_a_partial_or_unexplained_diagnosis_is_marked():
    from types import SimpleNamespace

    from stickslip_jax.diagnose import Verdict
    from stickslip_jax.diagnose.report import final_fit_status

    plain = ss.lu2015_slc1720()
    learned = plain.with_extension(LearnedForce(np.zeros(6), (1.0,) * 6))
    left = {"chi2_per_sample": 1.4, "tolerance_chi2": 0.08, "beyond_tolerance_nm": 0.5}

    def status(verdict, final=plain):
        return final_fit_status(SimpleNamespace(verdict=verdict, left=left, final=final))

    assert status(Verdict.AUGMENTED) is None and status(Verdict.BASELINE_ADEQUATE) is None
    assert status(Verdict.PARTLY_EXPLAINED).startswith("misspecified: partly explained")
    assert "1.400" in status(Verdict.PARTLY_EXPLAINED)
    assert "learned force" not in status(Verdict.UNEXPLAINED)
    assert "learned force" in status(Verdict.UNEXPLAINED, learned)


def test_a_rival_the_data_cannot_tell_apart_is_written_as_refitted():
    from types import SimpleNamespace

    from stickslip_jax.diagnose.report import rival_models

    plain = ss.lu2015_slc1720()
    mode = plain.with_extension(StructuralMode(3300.0, 0.03, 1.2e-7))
    creep = plain.with_extension(Creep(0.01, 5e-3))

    def result(name, act, accepted=False, rivals=()):
        return SimpleNamespace(name=name, accepted=accepted, refit=SimpleNamespace(actuator=act),
                               indistinguishable_from=list(rivals))

    rounds = [[result("structural_mode", mode, True, ["creep"]), result("creep", creep),
               result("sensor_delay", plain)]]
    rivals = rival_models(SimpleNamespace(rounds=rounds))
    assert list(rivals) == ["creep"] and rivals["creep"][0] is creep
    assert rivals["creep"][1].startswith("rival: indistinguishable from structural_mode")
    assert rival_models(SimpleNamespace(rounds=[[result("creep", creep, True)]])) == {}


def test_every_model_the_diagnosis_can_name_is_written_and_read_back():
    """Each catalogue entry attached (each probe), seeded and refined within its class:
    the models a diagnosis may end with, every one a parameter file."""
    from stickslip_jax.diagnose.catalogue import CATALOGUE, candidate

    base = ss.lu2015_slc1720()
    hints = {"peaks_Hz": [3300.0], "sample_interval_s": 4e-5}
    models = []
    for cand in CATALOGUE:
        attached = [cand.attach(base, 1e-3 * p.strength_scale(1.0), p)[0]
                    for p in cand.probes(base, hints)]
        attached += [act for act, _ in cand.seeds(base)]
        models += attached + [act for a in attached
                              for act, _ in cand.refined_forms(a, hints)]
    # A fitted slew limit (the drive probes' slew at mix 1) refines to a shaped one.
    slew = ss.Actuator(base.piezo, base.hysteresis, base.slider, base.friction,
                       input_stage=SlewLimitedInput(1.5e6, 1e-6))
    models += [act for act, _ in candidate("drive_bandwidth").refined_forms(slew, hints)]
    kinds = {type(m.input_stage).__name__ for m in models} | {
        type(e).__name__ for m in models for e in m.extensions} | {
        type(m.output_map).__name__ for m in models}
    assert {"ParallelInputs", "SecondOrderInput", "ShapedSlewInput", "StructuralMode",
            "CreepSpectrum", "RateLagForm", "SaturatingViscosity", "SensorOutput"} <= kinds
    for act in models:
        back = actuator_from_params(json.loads(json.dumps(params_from_actuator(act))))
        assert jax.tree.structure(back) == jax.tree.structure(act)
        for a, b in zip(jax.tree.leaves(act), jax.tree.leaves(back), strict=True):
            np.testing.assert_array_equal(np.asarray(b), np.asarray(a))

"""``design_experiment`` and ``stickslip design-experiment`` (issue #68) on a reduced
recording set, with a diagnosis folder written by the test: the candidate grid and its
limits, the parts a rival may move, the detection limit the plan starts from against
the score test's, the plan's files, and bad input."""

import json
from pathlib import Path

import equinox as eqx
import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
from stickslip_jax.design import DriveLimits, candidate_drives, part_specs, unit_duration
from stickslip_jax.diagnose.catalogue import candidate
from stickslip_jax.diagnose.config import DiagnoseConfig
from stickslip_jax.diagnose.problem import Problem, baseline_free
from stickslip_jax.diagnose.run import locate_phase
from stickslip_jax.diagnose.scores import score_candidates
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.model.extensions import LearnedForce, SensorOutput, StructuralMode
from stickslip_jax.noise import noise_sigma, noise_sigma_relative_se
from stickslip_jax.significance import Significance
from stickslip_jax.synthetic import DriveSpec, paper_protocol, simulate_set

ROOT = Path(__file__).resolve().parent.parent
TRUTH = ROOT / "fixtures" / "identification" / "truth.json"
FIX = {"Ms": 0.0247}


def test_the_candidates_stay_within_the_amplifier_and_the_recorder():
    limits = DriveLimits(60.0, 50.0, 1000.0, 25_000.0, 0.1)
    drives = candidate_drives(limits)
    saws = [d for d in drives if d.waveform == "sawtooth"]
    assert len(saws) == 3 * 5 * 2 and len(drives) == 30 + 5 + 3
    assert {d.amplitude_V for d in saws} == {20.0, 40.0, 60.0}
    assert min(d.frequency_Hz for d in saws) == 50.0
    assert max(d.frequency_Hz for d in saws) == 1000.0
    assert all(d.duration_s <= 0.1 + 1e-12 for d in drives)
    # Five periods, at least 20 ms in whole periods, at most the longest unit.
    assert unit_duration(100.0, limits) == pytest.approx(0.05)
    assert unit_duration(1000.0, limits) == pytest.approx(0.02)
    assert unit_duration(20.0, limits) == pytest.approx(0.1)  # two periods fit
    with pytest.raises(ValueError, match="samples per period"):
        DriveLimits(60.0, 50.0, 2000.0, 25_000.0, 0.1)
    with pytest.raises(ValueError, match="is above"):
        DriveLimits(60.0, 500.0, 100.0, 25_000.0, 0.1)
    with pytest.raises(ValueError, match="positive"):
        DriveLimits(-1.0, 50.0, 100.0, 25_000.0, 0.1)


def test_limits_from_the_recordings_stay_where_they_went(fixtures_dir):
    recs = ss.load_recordings(fixtures_dir / "identification")
    limits = DriveLimits.from_recordings(recs)
    assert limits.max_voltage_V == pytest.approx(60.0)
    assert limits.min_frequency_Hz == 50.0
    assert limits.max_frequency_Hz == 1000.0  # 4 x 500 Hz, capped at 25 samples a period
    assert limits.sample_rate_Hz == 25_000.0
    assert limits.longest_unit_s == pytest.approx(0.1, rel=1e-3)
    assert DriveLimits.from_recordings(recs, max_voltage_V=80.0).max_voltage_V == 80.0


def test_a_rival_moves_every_quantity_of_its_parts_but_zeros_and_learned_forces():
    base = ss.load_params(TRUTH)
    act = base.with_extension(StructuralMode(3300.0, 0.03, 1.2e-7, 0.0))
    act = act.with_extension(LearnedForce(np.full(6, 1e-3), scales=(1.0,) * 6))
    act = eqx.tree_at(lambda a: a.output_map, act, SensorOutput(delay=2e-6))
    specs = part_specs(act)
    assert set(specs) == {"extensions[0].frequency", "extensions[0].damping",
                          "extensions[0].compliance", "sensor.delay"}
    # Zeros stay held (the mode is not excited at the stack; the sensor has no drift),
    # and so does the learned force.
    spec = specs["extensions[0].frequency"]
    assert float(spec.getter(act)) == 3300.0 and spec.scale == 3300.0
    assert spec.kind == "linear"


@pytest.fixture(scope="module")
def reduced(tmp_path_factory):
    """A reduced set of the truth (1 nm noise) and a diagnosis folder for it: the truth
    as the final model, creep's detection limit from the score test on these
    recordings, and a tie between a named sensor delay and a rival rate lag."""
    base = ss.load_params(TRUTH)
    specs = paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(100.0, 500.0),
                           step_duration_s=0.03, sine_periods=2)
    recs = simulate_set(base, specs, noise_m=1e-9, seed=5)
    data = Dataset.from_recordings(recs)
    sigmas = np.array([noise_sigma(r) for r in recs])
    problem = Problem(data, sigmas, FIX, None)
    problem.significance = Significance(
        np.asarray(data.mask.sum(axis=1)), sigmas,
        np.array([noise_sigma_relative_se(r) for r in recs]), np.zeros(len(recs)), 3.0)
    hints = locate_phase(problem, problem.evaluate(base)[2], DiagnoseConfig())[2]
    _, limits, _ = score_candidates(problem, base, baseline_free(base, data, FIX),
                                    [candidate("creep")], hints)
    folder = tmp_path_factory.mktemp("diag")
    delay, lag = candidate("sensor_delay"), candidate("rate_dependent_hysteresis")
    named = delay.attach(base, 2e-6, delay.probes(base, hints)[0])[0]
    rival = lag.attach(base, 2e-11, lag.probes(base, hints)[0])[0]
    ss.save_params(named, folder / "params.json")
    ss.save_params(base, folder / "baseline_params.json")
    (folder / "rivals").mkdir()
    ss.save_params(rival, folder / "rivals" / "rate_dependent_hysteresis.json")
    content = {
        "missing_physics": [{"name": "sensor_delay", "evidence": {
            "indistinguishable_from": ["rate_dependent_hysteresis"]}}],
        "detection_limits": {"creep": limits["creep"]},
        "significance": {"z": 3.0}, "config": {}, "residual_peaks_Hz": [],
        "indistinguishable_here": {"preload_dependence": "one preload in every recording"},
    }
    (folder / "diagnosis.json").write_text(json.dumps(content))
    rec_dir = tmp_path_factory.mktemp("recs")
    for r in recs:
        ss.save_recording(r, rec_dir / f"{r.name}.csv")
    return recs, folder, rec_dir, limits["creep"]


CANDIDATES = [DriveSpec("sawtooth", 60.0, 1000.0, "forward", 0.02),
              DriveSpec("sawtooth", 30.0, 100.0, "backward", 0.05),
              DriveSpec("step", 60.0, duration_s=0.03)]


@pytest.fixture(scope="module")
def plan(reduced):
    recs, folder, _, _ = reduced
    return ss.design_experiment(recs, folder, fix=FIX, candidates=CANDIDATES,
                                total_time_s=0.2, entries=["creep", "sensor_delay"])


def test_a_tie_is_asked_alone_unless_entries_are_named(reduced):
    from stickslip_jax.design.plan import ask_questions

    _, folder, _, _ = reduced
    content = json.loads((folder / "diagnosis.json").read_text())
    final = ss.load_params(folder / "params.json")
    rivals = {"rate_dependent_hysteresis": ss.load_params(
        folder / "rivals" / "rate_dependent_hysteresis.json")}
    asked, notes = ask_questions(content, final, final, rivals, {})
    assert [(q.kind, q.entry) for q in asked] == [("tie", "rate_dependent_hysteresis")]
    assert any("asked with --entries" in n for n in notes)
    assert any(n.startswith("preload_dependence: not asked") for n in notes)
    asked, _ = ask_questions(content, final, final, rivals, {}, entries=["creep"])
    assert [(q.kind, q.entry) for q in asked] == [("limit", "creep")]


def test_the_plan_starts_from_the_score_tests_detection_limit(reduced, plan):
    *_, limit = reduced
    creep = next(q for q in plan.questions if q.entry == "creep")
    # Creep is linear in its strength: the whole effect at the score test's limit
    # reaches the tolerance, computed here through the design's own summaries.
    assert creep.ratio_now == pytest.approx(1.0, abs=0.02)
    assert creep.label == f"creep below {limit['strength']:.3g} m/V"
    assert creep.limit_now == pytest.approx(limit["strength"], rel=0.01)
    # More recording time lowers the limit; the protocol again by √(time) at most.
    assert creep.limit_default < creep.limit_now
    assert creep.limit_designed < creep.limit_now


def test_the_plan_fits_its_time_and_says_what_each_recording_answers(plan):
    assert 0 < plan.planned_time_s <= 0.2 + 1e-9
    for r in plan.recordings:
        spec = next(c for c in CANDIDATES if c.waveform == r.drive.waveform
                    and c.frequency_Hz == r.drive.frequency_Hz)
        assert r.drive.duration_s == pytest.approx(r.units * spec.duration_s)
        assert r.serves in {q.label for q in plan.questions}
    tie = next(q for q in plan.questions if q.kind == "tie")
    assert tie.label == "sensor_delay or rate_dependent_hysteresis"
    assert tie.ratio_designed > tie.ratio_now
    assert all(np.isfinite([q.ratio_now, q.ratio_default, q.ratio_designed]).all()
               for q in plan.questions)



def test_the_cli_writes_the_plan_and_drive_files_that_load_back(reduced, tmp_path):
    from stickslip_jax.cli.main import app

    _, folder, rec_dir, _ = reduced
    out = tmp_path / "plan"
    result = CliRunner().invoke(app, ["design-experiment", str(rec_dir), "--diagnosis",
                                      str(folder), "--out", str(out), "--total-time",
                                      "0.1", "--max-frequency", "500", "--fix",
                                      "Ms=0.0247", "--entries", "creep", "--no-figures"])
    assert result.exit_code == 0, result.output
    content = json.loads((out / "plan.json").read_text())
    assert [q["entry"] for q in content["questions"]] == ["creep"]
    assert content["planned_time_s"] <= 0.1 + 1e-9
    assert content["limits"]["max_frequency_Hz"] == 500.0
    for r in content["recordings"]:
        rec = ss.load_recording(out / r["file"], require_output=False)
        assert rec.n * rec.dt == pytest.approx(r["duration_s"], rel=0.01)
        assert rec.drive.waveform == r["waveform"]
        assert r["frequency_Hz"] is None or r["frequency_Hz"] <= 500.0
    assert "creep below" in (out / "plan.md").read_text()
    # Not overwritten without --force.
    again = CliRunner().invoke(app, ["design-experiment", str(rec_dir), "--diagnosis",
                                     str(folder), "--out", str(out)])
    assert again.exit_code == 2


def test_bad_input_is_refused_before_any_computation(reduced, tmp_path):
    from stickslip_jax.cli.main import app

    _, folder, rec_dir, _ = reduced
    runner = CliRunner()
    missing = runner.invoke(app, ["design-experiment", str(rec_dir), "--diagnosis",
                                  str(tmp_path), "--out", str(tmp_path / "p")])
    assert missing.exit_code == 2 and "diagnosis.json" in missing.output
    unknown = runner.invoke(app, ["design-experiment", str(rec_dir), "--diagnosis",
                                  str(folder), "--out", str(tmp_path / "p"),
                                  "--entries", "gremlins"])
    assert unknown.exit_code == 2 and "gremlins" in unknown.output
    fast = runner.invoke(app, ["design-experiment", str(rec_dir), "--diagnosis",
                               str(folder), "--out", str(tmp_path / "p"),
                               "--max-frequency", "5000"])
    assert fast.exit_code == 2 and "samples per period" in fast.output
    assert not (tmp_path / "p").exists()


def test_no_columns_are_no_sensor_only_columns():
    """A value-only program (no columns) of a model holding a sensor part: nothing to
    sort (reshaping zero columns failed, on dev2 set_40's final model with a probe)."""
    import jax

    from stickslip_jax.identify.sensitivities import sensor_only_columns

    act = eqx.tree_at(lambda a: a.output_map, ss.load_params(TRUTH),
                      SensorOutput(delay=3e-6))
    none = jax.tree.map(lambda x: np.zeros((0, *np.shape(x))), act)
    assert sensor_only_columns(none).shape == (0,)
    two = jax.tree.map(lambda x: np.zeros((2, *np.shape(x))), act)
    two = eqx.tree_at(lambda a: a.output_map.delay, two, np.array([1.0, 0.0]))
    two = eqx.tree_at(lambda a: a.piezo.Mp, two, np.array([0.0, 1.0]))
    np.testing.assert_array_equal(sensor_only_columns(two), [True, False])

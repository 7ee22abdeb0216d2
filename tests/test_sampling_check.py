"""A recording that cannot resolve anything (issue #65): sampled below the model's
slowest mode, or under a drive at or above its Nyquist frequency, it is refused before
any fitting, one error per file, naming the likely unit slip of the time column only
when that explains the file (:mod:`stickslip_jax.identify.sampling`).

No simulation: the check takes milliseconds, and so does every test but the command's.
"""

import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
from stickslip_jax.cli.main import app
from stickslip_jax.identify import steps as steps_module
from stickslip_jax.identify.informative import first_mode
from stickslip_jax.identify.sampling import (
    ACQUISITION_RATES_HZ,
    check_sample_rates,
    has_edge,
    sampling_problem,
    slowest_mode_Hz,
    unit_slip,
)
from stickslip_jax.io import RecordingError, RecordingErrors, load_recording, load_recordings
from stickslip_jax.params import load_params

runner = CliRunner()
START = ss.lu2015_slc1720()


def time_scaled_copy(src: Path, dst: Path, factor: float, *, keep=()) -> Path:
    """``src`` with every time cell multiplied by ``factor`` (1000: the time in ms under a
    ``time_s`` header, as a careless export writes it) and only the metadata keys in
    ``keep`` left (``sample_rate_Hz`` would be refused by the loader as disagreeing)."""
    lines = src.read_text().splitlines()
    meta = [line for line in lines if line.startswith("#")
            and line[1:].partition(":")[0].strip() in keep]
    body = [line for line in lines if not line.startswith("#")]
    rows = []
    for row in body[1:]:
        time_cell, sep, rest = row.partition(",")
        rows.append(f"{float(time_cell) * factor!r}{sep}{rest}")
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_text("\n".join([*meta, body[0], *rows]) + "\n")
    return dst


@pytest.fixture()
def ident(fixtures_dir) -> Path:
    return fixtures_dir / "identification"


def _message(recordings, actuator=START) -> str:
    with pytest.raises((RecordingError, RecordingErrors)) as info:
        check_sample_rates(recordings, actuator)
    return str(info.value)


# -------------------------------------------------------------- the model's time scale


def test_the_time_scale_is_the_first_stick_mode_the_data_rules_use():
    assert slowest_mode_Hz(START) == pytest.approx(first_mode(START), rel=1e-12)
    assert slowest_mode_Hz(START) == pytest.approx(523.3, abs=0.1)  # docs/model.md


# ----------------------------------------------------------- legitimate recordings pass


@pytest.mark.parametrize("folder", ["identification", "reference", "aye2018",
                                    *(f"concealed/set_{i:02d}" for i in range(1, 13))])
def test_every_bundled_recording_passes(fixtures_dir, folder):
    recs = load_recordings(fixtures_dir / folder)
    # The starting profile, and the actuators the recordings were made from.
    actuators = [START, load_params(fixtures_dir / "identification" / "truth.json"),
                 load_params(fixtures_dir / "reference" / "params.json")]
    for actuator in actuators:
        check_sample_rates(recs, actuator)


def test_a_slow_quasi_static_sine_passes(fixtures_dir):
    # Aye 2018: a capacitive sensor at 200 Hz under a 1 Hz drive, far below the 523 Hz
    # mode. It has no edge whose response needs the modes, and it resolves its drive.
    rec = load_recording(fixtures_dir / "aye2018" / "model_vi_do.csv")
    assert rec.sample_rate_Hz == pytest.approx(200.0) and rec.drive.waveform == "sine"
    assert not has_edge(rec)
    assert sampling_problem(rec, START) is None


def test_the_check_takes_milliseconds(ident):
    recs = load_recordings(ident)
    assert len(recs) == 17
    check_sample_rates(recs, START)  # the contact stiffness compiles once per process
    t0 = time.perf_counter()
    check_sample_rates(recs, START)
    assert time.perf_counter() - t0 < 0.5


# ----------------------------------------------------------------- what is refused


def test_a_step_in_milliseconds_labelled_seconds_is_refused_naming_the_slip(ident, tmp_path):
    path = time_scaled_copy(ident / "step_40V.csv", tmp_path / "step_40V.csv", 1e3)
    rec = load_recording(path)
    assert rec.sample_rate_Hz == pytest.approx(25.0)  # what the file says
    t0 = time.perf_counter()
    err = _message([rec])
    assert time.perf_counter() - t0 < 1.0
    print(err)
    assert err.startswith(f"{path}: sampled at 25 Hz by its time column")
    assert "\n" not in err  # one line
    assert "no sample_rate_Hz in its metadata" in err
    assert "the model's slowest mode rings at 523 Hz" in err
    assert "cannot resolve any of the actuator's dynamics" in err
    assert "A time column in milliseconds labelled time_s? ×1000 gives 25 kHz" in err
    assert "Fix: write the time column in seconds (divide it by 1000)" in err
    assert "'# sample_rate_Hz: 25000'" in err


def test_microseconds_are_named_when_milliseconds_do_not_explain_the_file(ident, tmp_path):
    path = time_scaled_copy(ident / "step_40V.csv", tmp_path / "step_40V.csv", 1e6)
    err = _message([load_recording(path)])
    assert "sampled at 0.025 Hz" in err and "microseconds" in err and "×1000000" in err
    assert "milliseconds" not in err  # ×1000 gives 25 Hz: it would not resolve the modes


def test_drive_metadata_that_show_the_factor_are_quoted(ident, tmp_path):
    path = time_scaled_copy(ident / "saw_40V_50Hz_fwd.csv", tmp_path / "saw.csv", 1e3,
                            keep=("waveform", "amplitude_V", "frequency_Hz", "direction"))
    err = _message([load_recording(path)])
    print(err)
    assert "sawtooth's flyback, one sample long, lasts 0.04 s here" in err
    assert "its sawtooth drive at 50 Hz (in its metadata) is at or above the Nyquist " \
           "frequency 12.5 Hz" in err
    assert "its metadata's frequency_Hz: 50 is ×1000 the 0.05 Hz its voltage repeats at" in err


def test_every_file_of_one_careless_export_is_named_on_its_own_line(ident, tmp_path):
    names = ["saw_40V_50Hz_fwd.csv", "sine_40V_50Hz.csv", "step_40V.csv"]
    recs = [load_recording(time_scaled_copy(ident / n, tmp_path / n, 1e3)) for n in names]
    recs.append(load_recording(ident / "saw_40V_100Hz_fwd.csv"))  # a good one beside them
    with pytest.raises(RecordingErrors) as info:
        check_sample_rates(recs, START)
    lines = str(info.value).splitlines()
    assert [e.path for e in info.value.errors] == [str(tmp_path / n) for n in names]
    assert len(lines) == 3 and all("milliseconds" in line for line in lines)
    # The sine alone would pass (a slow sine is quasi-static); beside the refused files
    # at the same rate it is named as part of the same export.
    sine = lines[1]
    assert "like saw_40V_50Hz_fwd, step_40V, whose dynamics that rate cannot resolve" in sine
    assert sampling_problem(recs[1], START) is None


def test_a_stated_coarse_rate_is_refused_without_guessing_a_slip(ident, tmp_path):
    rec = load_recording(time_scaled_copy(ident / "step_40V.csv", tmp_path / "s.csv", 1e3))
    stated = ss.Recording(rec.time_s, rec.voltage_V, rec.position, rec.position_unit,
                          meta={"sample_rate_Hz": "25"}, name="stated")
    err = _message([stated])
    assert "sampled at 25 Hz (sample_rate_Hz: 25 in its metadata" in err
    assert "milliseconds" not in err and unit_slip(stated, 523.3) is None
    assert "Fix: record again at ≥ 4.19 kHz (8 samples per period" in err


def test_a_rate_inside_the_acquisition_range_explains_itself(ident):
    # A 1 kHz step: it cannot show the 523 Hz mode (Nyquist 500 Hz), but 1 kHz is a
    # rate recordings are made at, so no slip is guessed.
    full = load_recording(ident / "step_40V.csv")
    coarse = ss.Recording(full.time_s[::25], full.voltage_V[::25], full.position[::25],
                          full.position_unit, name="coarse")
    assert coarse.sample_rate_Hz == pytest.approx(ACQUISITION_RATES_HZ[0])
    err = _message([coarse])
    assert "sampled at 1 kHz" in err and "nothing faster than 500 Hz" in err
    assert "milliseconds" not in err
    # Twice as fast it resolves the mode: left to the identification's finer rules.
    finer = ss.Recording(full.time_s[::12], full.voltage_V[::12], full.position[::12],
                         full.position_unit, name="finer")
    assert sampling_problem(finer, START) is None


def test_a_drive_frequency_beyond_nyquist_is_refused_pointing_at_the_metadata(ident):
    rec = load_recording(ident / "saw_40V_500Hz_fwd.csv")
    wrong = ss.Recording(rec.time_s, rec.voltage_V, rec.position, rec.position_unit,
                         meta={**rec.meta, "frequency_Hz": "50000"}, source=rec.source,
                         name=rec.name)
    err = _message([wrong])
    assert "sawtooth drive at 50 kHz (in its metadata) is at or above the Nyquist " \
           "frequency 12.5 kHz" in err
    assert "check frequency_Hz: its voltage repeats at 500 Hz" in err
    assert "milliseconds" not in err and "record again" not in err


# --------------------------------------------------------------------- the command


@pytest.mark.parametrize("command", ["identify", "diagnose"])
def test_the_command_refuses_before_fitting(ident, tmp_path, monkeypatch, command):
    data = tmp_path / "data"
    bad = time_scaled_copy(ident / "step_40V.csv", data / "step_40V.csv", 1e3)
    before = bad.read_bytes()

    def fit_reached(*args, **kwargs):
        raise RuntimeError("the fit started")  # exit 1, quickly, where the check is missing

    # The first thing identify() does after its argument checks (diagnose calls it too):
    # without the sample-rate check, diagnose fits this file for minutes.
    monkeypatch.setattr(steps_module, "assess", fit_reached)
    out = tmp_path / "out"
    res = runner.invoke(app, [command, str(data), "--out", str(out)])
    err = res.stderr
    print(err)
    assert res.exit_code == 2, res.output
    assert isinstance(res.exception, SystemExit), res.exception  # nothing escaped
    assert "Traceback" not in res.output
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, err
    assert str(bad) in errors[0] and "milliseconds" in errors[0]
    assert not out.exists()
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == [
        Path("data"), Path("data/step_40V.csv")]
    assert bad.read_bytes() == before

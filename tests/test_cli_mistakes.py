"""The command line's answer to user mistakes: refused before any computation, with one
``error:`` line per problem on stderr, exit code 2 (3 when the computation ran and
failed, 1 for an unexpected error), no traceback, and no output file written.

Every case stops before the simulator runs (or replaces the slow step with a stub), so
the module takes a few seconds.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax.sweep as sweep_pkg
import stickslip_jax.sweep.zba_surface as zba_module
from stickslip_jax.cli import simulate as simulate_cli
from stickslip_jax.cli.common import MAX_SAMPLES
from stickslip_jax.cli.main import app
from stickslip_jax.files import OutputPathError, atomic_write_text
from stickslip_jax.sweep.zba_surface import NEGATIVE_R2, ZbaPoints, fit_zba_surface

runner = CliRunner()

AMPLITUDE_RULE = "an amplitude must be a positive number of volts"


def files_under(folder: Path) -> list[Path]:
    return sorted(p.relative_to(folder) for p in folder.rglob("*"))


def refused(folder: Path, *args, code: int = 2, lines: int = 1):
    """Run ``stickslip args`` and check the refusal: exit code, ``lines`` lines on
    stderr each starting ``error:``, no traceback, nothing new under ``folder``.
    Returns the stderr text."""
    before = files_under(folder)
    res = runner.invoke(app, [str(a) for a in args])
    err = res.stderr
    assert res.exit_code == code, res.output
    assert isinstance(res.exception, SystemExit), res.exception  # nothing escaped
    assert "Traceback" not in res.output
    got = err.strip().splitlines()
    assert len(got) == lines and all(line.startswith("error: ") for line in got), err
    assert files_under(folder) == before
    return err


@pytest.fixture()
def saw(fixtures_dir):
    return fixtures_dir / "identification" / "saw_40V_500Hz_fwd.csv"


# ------------------------------------------------- outputs, checked before the work


def test_unknown_recording_extension_is_refused(tmp_path):
    err = refused(tmp_path, "simulate", "--duration", 0.05, "--out", tmp_path / "x.txt")
    assert "'.txt'" in err and ".csv" in err and ".npz" in err


def test_unknown_image_extension_is_refused_before_the_recording_is_written(tmp_path):
    err = refused(tmp_path, "simulate", "--duration", 0.05, "--out", tmp_path / "y.csv",
                  "--plot", tmp_path / "y.xyz")
    assert "'.xyz'" in err and ".png" in err
    assert not (tmp_path / "y.csv").exists()
    err = refused(tmp_path, "simulate", "--duration", 0.05, "--out", tmp_path / "y.csv",
                  "--plot", tmp_path / "y")
    assert "no extension" in err


def test_one_file_for_two_outputs_is_refused(tmp_path):
    err = refused(tmp_path, "simulate", "--duration", 0.05, "--out", tmp_path / "y.npz",
                  "--plot", tmp_path / "y.npz")
    assert "'.npz'" in err


def test_read_only_output_folder_is_refused_naming_the_output(tmp_path, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    if os.geteuid() == 0:  # root writes anywhere: make the folder read-only to os.access
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, mode, *a, **k: (
            Path(p) != ro and real(p, mode, *a, **k)))
    try:
        err = refused(tmp_path, "simulate", "--duration", 0.05, "--out", ro / "a.csv")
        assert "not writable" in err and "a.csv" in err and ".tmp" not in err
        err = refused(tmp_path, "sweep", "--out", ro / "new" / "sweep")
        assert "not writable" in err
    finally:
        ro.chmod(0o755)


def test_a_write_refused_by_the_system_names_the_output_not_the_temporary_file(
        tmp_path, monkeypatch):
    real = os.open

    def no_temp_files(path, *args, **kwargs):
        if str(path).endswith(".tmp"):
            raise PermissionError(13, "Permission denied", str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", no_temp_files)
    err = refused(tmp_path, "params", "--out", tmp_path / "P.json")
    assert err.strip() == (f"error: {tmp_path / 'P.json'}: Permission denied. "
                           "Fix: check the path and its permissions.")


def test_output_under_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("")
    err = refused(tmp_path, "simulate", "--duration", 0.05, "--out", tmp_path / "f" / "a.csv")
    assert "this is a file, but it must be a folder" in err


def test_identify_into_an_existing_file_is_refused_before_the_fit(fixtures_dir, tmp_path):
    (tmp_path / "existing.csv").write_text("keep")
    err = refused(tmp_path, "identify", fixtures_dir / "identification", "--out",
                  tmp_path / "existing.csv", "--fix", "Ms=0.0247")
    assert "existing.csv: this is a file" in err and "params.json" in err
    assert (tmp_path / "existing.csv").read_text() == "keep"


def test_identify_refuses_existing_outputs_before_the_fit(saw, tmp_path):
    (tmp_path / "id").mkdir()
    (tmp_path / "id" / "fit.json").write_text("{}")
    err = refused(tmp_path, "identify", saw, "--out", tmp_path / "id", "--steps", "friction")
    assert "fit.json" in err and "--force" in err


def test_existing_output_needs_force(tmp_path):
    out = tmp_path / "t.csv"
    out.write_text("old")
    err = refused(tmp_path, "simulate", "--duration", 0.01, "--out", out)
    assert "--force" in err and out.read_text() == "old"


def test_output_that_is_an_input_is_refused_even_with_force(saw, tmp_path):
    src = tmp_path / "rec.csv"
    src.write_bytes(saw.read_bytes())
    err = refused(tmp_path, "simulate", "--voltage-from", src, "--out", src, "--force")
    assert "also an input" in err and src.read_bytes() == saw.read_bytes()


def test_output_that_is_a_folder_is_refused(tmp_path):
    (tmp_path / "d.csv").mkdir()
    err = refused(tmp_path, "simulate", "--duration", 0.01, "--out", tmp_path / "d.csv")
    assert "is a folder" in err


def test_other_commands_check_their_output_formats(tmp_path):
    err = refused(tmp_path, "params", "--out", tmp_path / "P.txt")
    assert "(formats: .json)" in err
    err = refused(tmp_path, "drive", "--velocity", "50um/s", "--out", tmp_path / "c.csv")
    assert "(formats: .json)" in err


# ------------------------------------------------------------ inputs accepted wrongly


def test_negative_velocity_means_backward(monkeypatch, tmp_path):
    asked = []

    def fake_drive_for_velocity(actuator, velocity, **kwargs):
        asked.append(velocity)
        return [], []

    monkeypatch.setattr(sweep_pkg, "drive_for_velocity", fake_drive_for_velocity)
    res = runner.invoke(app, ["drive", "--velocity", "-50um/s"])
    assert asked == [pytest.approx(-50e-6)] and "backward at 50 µm/s" in res.output
    res = runner.invoke(app, ["drive", "--velocity", "-50um/s", "--direction", "backward"])
    assert asked[-1] == pytest.approx(-50e-6)
    res = runner.invoke(app, ["drive", "--velocity", "50um/s", "--direction", "backward"])
    assert asked[-1] == pytest.approx(-50e-6)
    res = runner.invoke(app, ["drive", "--velocity", "50um/s"])
    assert asked[-1] == pytest.approx(50e-6) and "forward at 50 µm/s" in res.output


def test_negative_velocity_with_direction_forward_is_refused(tmp_path):
    err = refused(tmp_path, "drive", "--velocity", "-50um/s", "--direction", "forward")
    assert "backward (negative)" in err and "50um/s" in err


def test_huge_duration_is_refused_with_the_samples_and_memory_it_needs(tmp_path):
    err = refused(tmp_path, "simulate", "--duration", 1e9, "--out", tmp_path / "z.csv")
    assert "2.5e+13 samples" in err and "PB of memory" in err
    assert f"{MAX_SAMPLES:,} samples" in err
    refused(tmp_path, "simulate", "--duration", "inf", "--out", tmp_path / "z.csv")


@pytest.mark.parametrize("args", [
    ("simulate", "--amplitude", -40, "--duration", 0.01, "--out", "z.csv"),
    ("simulate", "--amplitude", 0, "--duration", 0.01, "--out", "z.csv"),
    ("sweep", "--amplitudes", "-10,20", "--out", "s"),
    ("drive", "--velocity", "50um/s", "--amplitudes", "-5:100:20"),
    ("contacts", "--amplitudes", "-5:80:16", "--out", "c"),
])
def test_amplitude_must_be_positive_in_every_command(tmp_path, args):
    args = [tmp_path / a if a in ("z.csv", "s", "c") else a for a in args]
    assert AMPLITUDE_RULE in refused(tmp_path, *args)


def _bad_recording(path: Path, cell: str) -> None:
    rows = "\n".join(f"{i * 4e-5:.8f},{i * 0.1:.3f},0.0" for i in range(20))
    path.write_text("time_s,voltage_V,position_um\n" + rows.replace("0.0\n", f"{cell}\n", 1)
                    + "\n")


@pytest.mark.parametrize("command", ["identify", "diagnose", "zba-surface"])
def test_every_bad_recording_of_a_folder_is_reported(saw, tmp_path, command):
    data = tmp_path / "data"
    data.mkdir()
    (data / "good.csv").write_bytes(saw.read_bytes())
    for name, cell in (("a.csv", "x"), ("b.csv", "nan"), ("c.csv", "1e")):
        _bad_recording(data / name, cell)
    err = refused(tmp_path, command, data, "--out", tmp_path / "out", lines=3)
    for name in ("a.csv, line 2", "b.csv, line 2", "c.csv, line 2"):
        assert name in err
    assert "good.csv" not in err


def test_one_bad_recording_is_one_line_with_file_line_and_fix(tmp_path):
    _bad_recording(tmp_path / "bad.csv", "x")
    err = refused(tmp_path, "simulate", "--voltage-from", tmp_path / "bad.csv", "--out",
                  tmp_path / "o.csv")
    assert "bad.csv, line 2" in err and "Fix:" in err


def test_empty_folder_is_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    err = refused(tmp_path, "identify", tmp_path / "empty", "--out", tmp_path / "o")
    assert "holds no recordings" in err


# ------------------------------------------------------ options the tool already checks


def _params_with(tmp_path, fixtures_dir, **changes) -> Path:
    p = json.loads((fixtures_dir / "reference" / "params.json").read_text())
    p.update(changes)
    path = tmp_path / "p.json"
    path.write_text(json.dumps(p))
    return path


@pytest.mark.parametrize("args, needle", [
    (("simulate", "--substeps", -1, "--out", "o.csv"), "--substeps"),
    (("simulate", "--frequency", 0, "--out", "o.csv"), "--frequency"),
    (("simulate", "--params", "missing.json", "--out", "o.csv"), "file not found"),
    (("sweep", "--amplitudes", "10:80", "--out", "s"), "start:stop:count"),
    (("sweep", "--frequencies", "0,100", "--out", "s"), "a frequency must be a positive"),
    (("sweep", "--periods", 1, "--out", "s"), "periods ≥ 2"),
    (("sweep", "--zba-surface", "missing.json", "--out", "s"), "No such file"),
    (("drive", "--velocity", "fast"), "cannot read velocity"),
    (("drive", "--velocity", "50um/s", "--direction", "up"), "choose forward or backward"),
    (("drive", "--velocity", "50um/s", "--settle", 10), "settle < periods"),
    (("contacts", "--spread", "x=1,-1", "--out", "c"), "--spread"),
    (("contacts", "--preloads", "0,1", "--out", "c"), "--preloads"),
    (("params", "--profile", "nope", "--out", "P.json"), "unknown profile"),
])
def test_bad_options_are_refused(tmp_path, args, needle):
    names = ("o.csv", "s", "c", "P.json", "missing.json")
    args = [tmp_path / a if a in names else a for a in args]
    assert needle in refused(tmp_path, *args)


def test_bad_parameter_file_is_refused(tmp_path, fixtures_dir):
    bad = _params_with(tmp_path, fixtures_dir, Ms=-0.03)
    err = refused(tmp_path, "simulate", "--params", bad, "--duration", 0.01, "--out",
                  tmp_path / "o.csv")
    assert "'Ms' must be positive" in err


@pytest.mark.parametrize("args, needle", [
    (("--fix", "mass=3"), "'mass' is not a fixable parameter"),
    (("--fix", "Ms"), "expected NAME=VALUE"),
    (("--steps", "dynamics,magic"), "magic"),
    (("--n-pi", 0), "play operator"),
])
def test_identify_option_mistakes(saw, tmp_path, args, needle):
    assert needle in refused(tmp_path, "identify", saw, "--out", tmp_path / "o", *args)


@pytest.mark.parametrize("args, needle", [
    (("--skip-identify",), "--skip-identify needs --params"),
    (("--candidates", "magic"), "magic"),
    (("--max-rounds", 0), "at least 1"),
])
def test_diagnose_option_mistakes(saw, tmp_path, args, needle):
    assert needle in refused(tmp_path, "diagnose", saw, "--out", tmp_path / "o", *args)


# ----------------------------------------------------------------------- z_ba surface


def test_zba_surface_without_enough_recordings_is_refused_before_the_fit(
        fixtures_dir, tmp_path):
    folder = fixtures_dir / "identification"
    err = refused(tmp_path, "zba-surface", folder / "saw_40V_50Hz_fwd.csv",
                  folder / "saw_40V_50Hz_bwd.csv", "--out", tmp_path / "z")
    assert "forward 1 at 1 drive(s), backward 1 at 1 drive(s)" in err
    assert "at least 3" in err and "7 at 3 amplitudes x 3 frequencies" in err


def _points(amps, z_um, se_um, determined=True) -> ZbaPoints:
    n = len(amps)
    return ZbaPoints([f"p{i}" for i in range(n)], np.array(amps, float), np.full(n, 100.0),
                     np.zeros(n, bool), np.array(z_um) * 1e-6, np.array(se_um) * 1e-6,
                     np.zeros(n), np.ones(n, bool), np.full(n, determined))


def test_a_surface_needs_three_points_at_two_drives():
    one = fit_zba_surface(_points([40], [0.4], [1e-3])).stats["forward"]
    assert not one["supported"] and "1 determined point(s)" in one["note"]
    same = fit_zba_surface(_points([40] * 4, [0.4, 0.41, 0.42, 0.4], [1e-3] * 4))
    assert "all 4 determined points are at one drive" in same.stats["forward"]["note"]
    line = fit_zba_surface(_points([40, 50, 60], [0.40, 0.42, 0.45], [1e-3] * 3))
    st = line.stats["forward"]
    assert st["supported"] and st["terms"] == 2  # one residual degree of freedom


def test_a_negative_r2_is_explained():
    # Two precise points fix the line; the imprecise third lies far off it.
    fit = fit_zba_surface(_points([40, 50, 60], [0.40, 0.30, 0.40], [1e-5, 1e-5, 0.1]))
    st = fit.stats["forward"]
    assert st["r2"] < 0 and st["r2_note"] == NEGATIVE_R2
    ok = fit_zba_surface(_points([40, 50, 60, 70], [0.40, 0.42, 0.44, 0.47], [1e-3] * 4))
    assert ok.stats["forward"]["r2"] > 0.9 and "r2_note" not in ok.stats["forward"]


def test_zba_surface_prints_the_r2_explanation(fixtures_dir, tmp_path, monkeypatch):
    points = _points([40, 50, 60], [0.40, 0.30, 0.40], [1e-5, 1e-5, 0.1])
    monkeypatch.setattr(zba_module, "fit_zba_points", lambda actuator, recordings: points)
    res = runner.invoke(app, ["zba-surface", str(fixtures_dir / "identification"), "--out",
                              str(tmp_path / "z")])
    assert res.exit_code == 0, res.output
    assert "note: R² < 0: the surface predicts these points worse than their mean" \
        in res.stdout
    assert (tmp_path / "z" / "zba_surface.json").exists()


def test_zba_surface_with_no_determined_points_writes_no_surface(fixtures_dir, tmp_path,
                                                                 monkeypatch):
    points = _points([40, 50, 60], [0.40, 0.42, 0.45], [1.0] * 3, determined=False)
    monkeypatch.setattr(zba_module, "fit_zba_points", lambda actuator, recordings: points)
    res = runner.invoke(app, ["zba-surface", str(fixtures_dir / "identification"), "--out",
                              str(tmp_path / "z")])
    assert res.exit_code == 3 and "Traceback" not in res.output
    last = res.stderr.strip().splitlines()[-1]  # after the progress line
    assert last.startswith("error: no direction has enough determined z_ba points")
    assert not (tmp_path / "z" / "zba_surface.json").exists()
    assert (tmp_path / "z" / "zba_points.csv").exists()


# ---------------------------------------------------------- top level, --debug, help


def test_unexpected_error_is_one_line_with_exit_1(tmp_path, monkeypatch):
    def broken(*args):
        raise RuntimeError("boom\nsecond line")

    monkeypatch.setattr(simulate_cli, "_generated", broken)
    err = refused(tmp_path, "simulate", "--duration", 0.01, "--out", tmp_path / "o.csv",
                  code=1)
    assert "unexpected RuntimeError: boom second line" in err and "--debug" in err


@pytest.mark.parametrize("where", ["before", "after", "environment"])
def test_debug_shows_the_exception(tmp_path, monkeypatch, where):
    args = ["simulate", "--out", str(tmp_path / "x.txt")]
    if where == "environment":
        monkeypatch.setenv("STICKSLIP_DEBUG", "1")
    else:
        args = ["--debug", *args] if where == "before" else [*args, "--debug"]
    res = runner.invoke(app, args)
    assert isinstance(res.exception, OutputPathError)  # raised, traceback and all
    monkeypatch.delenv("STICKSLIP_DEBUG", raising=False)
    plain = runner.invoke(app, ["simulate", "--out", str(tmp_path / "x.txt")])
    assert isinstance(plain.exception, SystemExit) and plain.exit_code == 2  # not sticky


def test_help_keeps_brackets_and_colons_for_every_command():
    for command in ("simulate", "params", "identify", "sweep", "drive", "zba-surface",
                    "diagnose", "contacts"):
        text = runner.invoke(app, [command, "--help"], terminal_width=100).output
        assert "\U0001f171" not in text  # rich's :b: emoji
        if command in ("drive", "contacts"):
            assert "a:b:n" in text
    text = runner.invoke(app, ["simulate", "--help"], terminal_width=100).output
    assert "[s]" in text and "drive ." not in text and "[Hz]" in text and "[V]" in text
    text = runner.invoke(app, ["--help"], terminal_width=100).output
    assert "--debug" in text and "Exit codes" in text


def test_params_file_holds_float64_values(tmp_path):
    """In a fresh interpreter (JAX not yet in float64), as a user runs it."""
    out = tmp_path / "P.json"
    res = subprocess.run([sys.executable, "-c", "from stickslip_jax.cli.main import app; "
                          "app()", "params", "--out", str(out)],
                         capture_output=True, text=True, timeout=120,
                         env={**os.environ, "JAX_ENABLE_X64": "0"})
    assert res.returncode == 0, res.stderr
    p = json.loads(out.read_text())
    assert p["Ms"] == 0.0247 and p["Mp"] == 0.000247 and p["Dp"] == 15.6125
    # and the console script's own top level prints no traceback either
    res = subprocess.run([sys.executable, "-c", "from stickslip_jax.cli.main import app; "
                          "app()", "params", "--out", str(out)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.startswith("error: ") and res.stderr.count("\n") == 1


def test_atomic_write_into_a_missing_folder_names_the_destination(tmp_path):
    with pytest.raises(FileNotFoundError) as info:
        atomic_write_text(tmp_path / "no" / "x.json", "{}")
    assert info.value.filename == str(tmp_path / "no" / "x.json")

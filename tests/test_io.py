"""Recordings (file contract), safe output writing and drive signals.

Only files under the repository's ``fixtures/`` and pytest's ``tmp_path`` are read.
"""

from __future__ import annotations

import json
import math
import os
import pickle
import string
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from stickslip_jax import signals
from stickslip_jax.drive_inference import WAVEFORMS, DriveInfo, infer_drive
from stickslip_jax.files import (
    InputOverwriteError,
    OutputExistsError,
    atomic_write_bytes,
    atomic_write_text,
    atomic_writer,
    check_output_path,
)
from stickslip_jax.io import (
    MIN_ROWS,
    Recording,
    RecordingError,
    load_recording,
    load_recordings,
    save_recording,
)

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "reference"
FS = 25_000.0

# ----------------------------------------------------------------------- helpers

META = ["# waveform: sawtooth", "# amplitude_V: 40", "# frequency_Hz: 50"]
HEADER = "time_s,voltage_V,position_um"


def _rows(n: int = 20, fs: float = FS) -> list[str]:
    return [f"{k / fs!r},{0.5 * k!r},{0.001 * k!r}" for k in range(n)]


def _csv(tmp_path: Path, lines: list[str], name: str = "trace.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _good_lines(n: int = 20) -> list[str]:
    return [*META, HEADER, *_rows(n)]


def _row_line(i: int) -> int:
    """Line number of data row ``i`` (0-based) in a file built from _good_lines."""
    return len(META) + 2 + i


def _expect_error(path: Path, line: int | None) -> RecordingError:
    with pytest.raises(RecordingError) as info:
        load_recording(path)
    err = info.value
    message = str(err)
    assert path.name in message
    assert err.path == str(path)
    assert err.line == line, message
    if line is not None:
        assert f", line {line}:" in message
    else:
        assert ", line" not in message
    assert "Fix: " in message and err.fix and err.fix in message
    return err


def _saw_recording(n: int = 40, name: str = "saw") -> Recording:
    t, u = signals.sawtooth(40.0, 1000.0, duration_s=n / FS)
    rec = signals.make_recording(t, u, waveform="sawtooth", amplitude_V=40.0,
                                 frequency_Hz=1000.0, direction="forward", name=name)
    return rec.with_position_m(np.linspace(0.0, 1e-6, rec.n))


# ------------------------------------------------------------- the error message


def test_recording_error_reads_like_the_contract():
    err = RecordingError("trace.csv", 42, "time is not increasing (0.0012 after 0.0013)",
                         "sort the rows by time or remove duplicated rows")
    assert str(err) == ("trace.csv, line 42: time is not increasing (0.0012 after 0.0013). "
                        "Fix: sort the rows by time or remove duplicated rows.")
    assert isinstance(err, ValueError)
    again = pickle.loads(pickle.dumps(err))
    assert (again.path, again.line, again.fix, str(again)) == (err.path, err.line, err.fix,
                                                               str(err))
    assert str(RecordingError("a.npz", None, "x", "y")) == "a.npz: x. Fix: y."


# ------------------------------------------------------------------ bad CSV files


def test_missing_file(tmp_path):
    err = _expect_error(tmp_path / "trace.csv", None)
    assert "not found" in err.problem


@pytest.mark.parametrize("content", ["", "\n\n  \n"])
def test_empty_file(tmp_path, content):
    path = tmp_path / "trace.csv"
    path.write_text(content)
    err = _expect_error(path, None)
    assert "empty" in err.problem


def test_no_header_numbers_first(tmp_path):
    path = _csv(tmp_path, [*META, *_rows()])
    err = _expect_error(path, len(META) + 1)
    assert "header" in err.problem and HEADER in err.fix


def test_no_header_only_metadata(tmp_path):
    err = _expect_error(_csv(tmp_path, META), None)
    assert "no header" in err.problem


@pytest.mark.parametrize(
    ("header", "missing"),
    [
        ("voltage_V,position_um", "time_s"),
        ("time_s,position_um", "voltage_V"),
        ("time_s,voltage_V", "output"),
    ],
)
def test_missing_required_column(tmp_path, header, missing):
    n_cols = header.count(",") + 1
    rows = [",".join(["0.5"] * n_cols)] * 20
    err = _expect_error(_csv(tmp_path, [*META, header, *rows]), len(META) + 1)
    assert missing in err.problem


@pytest.mark.parametrize(
    ("header", "bad", "accepted"),
    [
        ("time_s,voltage_V,position_mm", "position_mm", "position_um"),
        ("time_s,voltage_mV,position_um", "voltage_mV", "voltage_V"),
        ("time_ms,voltage_V,position_um", "time_ms", "time_s"),
        ("time_s,voltage_V,sensor_mV", "sensor_mV", "sensor_V"),
        ("time_s,voltage_V,position", "position", "position_nm"),
    ],
)
def test_unknown_unit(tmp_path, header, bad, accepted):
    err = _expect_error(_csv(tmp_path, [*META, header, *_rows()]), len(META) + 1)
    assert repr(bad) in err.problem and accepted in err.problem and accepted in err.fix


def test_unknown_column_and_duplicate_column(tmp_path):
    path = _csv(tmp_path, [*META, HEADER + ",temperature_C", *[r + ",20" for r in _rows()]])
    assert "temperature_C" in _expect_error(path, len(META) + 1).problem
    path = _csv(tmp_path, [*META, HEADER + ",voltage_V", *[r + ",1" for r in _rows()]])
    assert "twice" in _expect_error(path, len(META) + 1).problem
    path = _csv(tmp_path, [*META, HEADER + ",position_nm", *[r + ",1" for r in _rows()]])
    assert "several position" in _expect_error(path, len(META) + 1).problem


@pytest.mark.parametrize(("cell", "words"), [("abc", "'abc' is not a number"),
                                             ("", "empty cell"),
                                             ("1,5", "cells"),
                                             ('"0.5"', "not a number"),
                                             ("1_000", "not a number")])
def test_non_numeric_cell(tmp_path, cell, words):
    lines = _good_lines()
    i = 6
    t, _, q = lines[_row_line(i) - 1].split(",")
    lines[_row_line(i) - 1] = f"{t},{cell},{q}"
    err = _expect_error(_csv(tmp_path, lines), _row_line(i))
    assert words in err.problem
    if cell != "1,5":
        assert "voltage_V" in err.problem


@pytest.mark.parametrize("cell", ["nan", "NaN", "inf", "-inf"])
def test_nan_or_inf(tmp_path, cell):
    lines = _good_lines()
    i = 11
    t, u, _ = lines[_row_line(i) - 1].split(",")
    lines[_row_line(i) - 1] = f"{t},{u},{cell}"
    err = _expect_error(_csv(tmp_path, lines), _row_line(i))
    assert "position_um" in err.problem
    assert ("NaN" if "n" in cell.lower() and "inf" not in cell else "infinite") in err.problem


@pytest.mark.parametrize("row", ["0.1,0.2", "0.1,0.2,0.3,0.4"])
def test_ragged_row(tmp_path, row):
    lines = _good_lines()
    lines[_row_line(9) - 1] = row
    err = _expect_error(_csv(tmp_path, lines), _row_line(9))
    assert "cells" in err.problem and "3 columns" in err.problem


def test_every_row_with_a_trailing_comma(tmp_path):
    # Consistently 4 cells under a 3-column header: numpy alone would not notice.
    lines = [*META, HEADER, *[r + "," for r in _rows()]]
    err = _expect_error(_csv(tmp_path, lines), _row_line(0))
    assert "4 cells" in err.problem


@pytest.mark.parametrize("kind", ["duplicate", "decreasing"])
def test_time_not_increasing(tmp_path, kind):
    lines = _good_lines()
    i = 12
    earlier = lines[_row_line(i - (1 if kind == "duplicate" else 2)) - 1].split(",")[0]
    rest = lines[_row_line(i) - 1].split(",", 1)[1]
    lines[_row_line(i) - 1] = f"{earlier},{rest}"
    err = _expect_error(_csv(tmp_path, lines), _row_line(i))
    assert "not increasing" in err.problem
    assert f"({float(earlier)!r} after {(i - 1) / FS!r})" in err.problem
    assert "sort the rows" in err.fix


def test_non_uniform_time(tmp_path):
    # A missing sample: rows 0..7, then 9..
    lines = [*META, HEADER, *[r for k, r in enumerate(_rows(22)) if k != 8]]
    err = _expect_error(_csv(tmp_path, lines), _row_line(8))
    assert "uniform" in err.problem and "resample" in err.fix


def test_slightly_non_uniform_time_is_refused(tmp_path):
    lines = _good_lines()
    t, rest = lines[_row_line(5) - 1].split(",", 1)
    lines[_row_line(5) - 1] = f"{float(t) * (1 + 1e-5)!r},{rest}"
    _expect_error(_csv(tmp_path, lines), _row_line(5))


@pytest.mark.parametrize("n", [MIN_ROWS - 1, 1])
def test_too_few_rows(tmp_path, n):
    err = _expect_error(_csv(tmp_path, _good_lines(n)), _row_line(n - 1))
    assert f"only {n} data rows" in err.problem and str(MIN_ROWS) in err.fix


def test_no_rows_at_all(tmp_path):
    err = _expect_error(_csv(tmp_path, [*META, HEADER]), len(META) + 1)
    assert "only 0 data rows" in err.problem


def test_exactly_min_rows_loads(tmp_path):
    assert load_recording(_csv(tmp_path, _good_lines(MIN_ROWS))).n == MIN_ROWS


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("direction", "sideways", "forward or backward"),
        ("amplitude_V", "abc", "plain number"),
        ("amplitude_V", "nan", "plain number"),
        ("waveform", "triangle", "sawtooth, sine, step, other"),
        ("frequency_Hz", "-5", "positive"),
        ("frequency_Hz", "", "plain number"),
        ("sample_rate_Hz", "0", "positive"),
        ("preload_N", "-1", "preload"),
    ],
)
def test_invalid_metadata(tmp_path, key, value, words):
    meta = [m for m in META if not m.startswith(f"# {key}:")]
    lines = [*meta, f"# {key}: {value}", "# note: anything goes here", HEADER, *_rows()]
    err = _expect_error(_csv(tmp_path, lines), len(meta) + 1)
    assert key in err.problem and words in err.fix


def test_duplicate_metadata_key(tmp_path):
    lines = [*META, "# amplitude_V: 41", HEADER, *_rows()]
    err = _expect_error(_csv(tmp_path, lines), len(META) + 1)
    assert "twice" in err.problem and "line 2" in err.problem


def test_sample_rate_disagrees_with_time(tmp_path):
    lines = ["# sample_rate_Hz: 25000.1", *META, HEADER, *_rows()]
    err = _expect_error(_csv(tmp_path, lines), 1)
    assert "sample_rate_Hz" in err.problem and "25000" in err.problem


def test_sample_rate_that_agrees_is_accepted(tmp_path):
    lines = [*META, "# sample_rate_Hz: 25000.00001", HEADER, *_rows()]
    assert load_recording(_csv(tmp_path, lines)).meta["sample_rate_Hz"] == "25000.00001"


def test_comment_line_after_header(tmp_path):
    lines = _good_lines()
    lines.insert(_row_line(4) - 1, "# direction: forward")
    err = _expect_error(_csv(tmp_path, lines), _row_line(4))
    assert "after the header" in err.problem


def test_not_utf8(tmp_path):
    path = tmp_path / "trace.csv"
    path.write_bytes(("\n".join([*META, "# operator: J"]) + "\xe9\n").encode("latin-1"))
    err = _expect_error(path, len(META) + 1)
    assert "UTF-8" in err.fix


def test_line_numbers_count_blank_and_comment_lines(tmp_path):
    lines = ["", "# free comment without a colon", *META, "", HEADER, *_rows(10), "",
             *_rows(20)[10:]]
    # Row 14 is on: 2 + 3 meta + blank + header = line 7 for the header, rows from 8,
    # and one blank line after row 9.
    target = 7 + 14 + 1 + 1
    lines[target - 1] = lines[target - 1].rsplit(",", 1)[0] + ",nan"
    err = _expect_error(_csv(tmp_path, lines), target)
    assert "NaN" in err.problem


# ------------------------------------------------------------------- good CSV files


def test_good_csv_loads(tmp_path):
    lines = [*META, "# direction: backward", "# operator: A: B", HEADER, *_rows(30)]
    rec = load_recording(_csv(tmp_path, lines))
    assert rec.n == 30 and rec.name == "trace" and rec.source == str(tmp_path / "trace.csv")
    assert rec.meta == {"waveform": "sawtooth", "amplitude_V": "40", "frequency_Hz": "50",
                        "direction": "backward", "operator": "A: B"}
    assert rec.position_unit == "um" and rec.sensor_V is None
    np.testing.assert_array_equal(rec.time_s, np.arange(30) / FS)
    np.testing.assert_allclose(rec.position_m, 1e-9 * np.arange(30), rtol=1e-15)
    assert rec.dt == pytest.approx(1 / FS, rel=1e-12)
    assert rec.sample_rate_Hz == pytest.approx(FS, rel=1e-12)
    assert rec.drive == DriveInfo("sawtooth", 40.0, 50.0, "backward", inferred=False)
    assert rec.drive.is_backward and rec.regime == "sawtooth_backward"
    with pytest.raises(ValueError):
        rec.time_s[0] = 1.0  # read-only


def test_crlf_bom_spaces_and_column_order(tmp_path):
    body = "\r\n".join([*META, " position_nm , time_s,voltage_V ",
                        *[f" {0.1 * k} , {k / FS!r},{k}" for k in range(20)]]) + "\r\n"
    path = tmp_path / "trace.csv"
    path.write_bytes(b"\xef\xbb\xbf" + body.encode())
    rec = load_recording(path)
    assert rec.position_unit == "nm" and rec.meta["waveform"] == "sawtooth"
    np.testing.assert_array_equal(rec.voltage_V, np.arange(20.0))
    np.testing.assert_allclose(rec.position_m, 1e-10 * np.arange(20), rtol=1e-12)


def test_sensor_column_and_drive_only_file(tmp_path):
    lines = [HEADER.replace("position_um", "sensor_V"), *_rows()]
    rec = load_recording(_csv(tmp_path, lines))
    assert rec.position is None and rec.position_m is None and rec.sensor_V is not None
    drive_only = _csv(tmp_path, ["time_s,voltage_V", *[r.rsplit(",", 1)[0] for r in _rows()]],
                      name="drive.csv")
    _expect_error(drive_only, 1)
    assert load_recording(drive_only, require_output=False).position is None


# ------------------------------------------------------------------ bad NPZ files


def _npz(tmp_path: Path, name: str = "trace.npz", **arrays) -> Path:
    path = tmp_path / name
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def _good_arrays(n: int = 20) -> dict[str, np.ndarray]:
    k = np.arange(n, dtype=float)
    return {"time_s": k / FS, "voltage_V": 0.5 * k, "position_nm": k}


def test_npz_loads(tmp_path):
    path = _npz(tmp_path, **_good_arrays(),
                meta_json=np.array(json.dumps({"waveform": "step", "x": "y"})))
    rec = load_recording(path)
    assert rec.position_unit == "nm" and rec.meta == {"waveform": "step", "x": "y"}


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"time_s": None}, "time_s"),
        ({"position_nm": None}, "output"),
        ({"position_mm": np.zeros(20)}, "position_mm"),
        ({"voltage_V": np.r_[np.zeros(19), np.nan]}, "sample 19"),
        ({"voltage_V": np.zeros(21)}, "length"),
        ({"time_s": np.arange(20.0)[::-1]}, "not increasing"),
        ({"time_s": np.zeros((20, 1))}, "1-D"),
        ({"meta_json": np.array("{not json")}, "JSON"),
        ({"meta_json": np.array(json.dumps({"direction": "up"}))}, "direction"),
        ({"meta_json": np.array(json.dumps({"sample_rate_Hz": "1000"}))}, "sample_rate"),
    ],
)
def test_bad_npz(tmp_path, change, words):
    arrays = _good_arrays()
    for key, value in change.items():
        if value is None:
            arrays.pop(key)
        else:
            arrays[key] = value
    err = _expect_error(_npz(tmp_path, **arrays), None)
    assert words in str(err)


def test_npz_that_is_not_an_archive(tmp_path):
    path = tmp_path / "trace.npz"
    path.write_text("time_s,voltage_V\n")
    assert "npz" in _expect_error(path, None).problem
    np.save(tmp_path / "plain.npy", np.zeros(3))
    os.replace(tmp_path / "plain.npy", path)
    _expect_error(path, None)
    _expect_error(tmp_path / "missing.npz", None)


# ----------------------------------------------------------------- sets of files


def test_load_folder_sorted_and_filtered(tmp_path):
    folder = tmp_path / "set"
    folder.mkdir()
    _csv(folder, _good_lines(), name="b.csv")
    _npz(folder, name="a.npz", **_good_arrays())
    _csv(folder, ["not", "a recording"], name="notes.txt")
    _csv(folder, ["junk"], name=".b.csv.1234.tmp")
    _csv(folder, ["junk"], name=".hidden.csv")
    (folder / "sub").mkdir()
    _csv(folder / "sub", _good_lines(), name="c.csv")
    recs = load_recordings([folder])
    assert [r.name for r in recs] == ["a", "b"]
    assert [r.name for r in load_recordings(folder)] == ["a", "b"]
    # Files and folders mixed; a file named twice is read once.
    mixed = load_recordings([folder / "sub" / "c.csv", folder, folder / "b.csv"])
    assert [r.name for r in mixed] == ["c", "a", "b"]


def test_load_empty_folder_is_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    _csv(tmp_path / "empty", ["x"], name="readme.txt")
    with pytest.raises(RecordingError) as info:
        load_recordings([tmp_path / "empty"])
    assert "empty" in str(info.value) and "no recordings" in info.value.problem
    with pytest.raises(ValueError):
        load_recordings([])


def test_load_folder_names_the_bad_file(tmp_path):
    _csv(tmp_path, _good_lines(), name="a.csv")
    _csv(tmp_path, _good_lines(5), name="b.csv")
    with pytest.raises(RecordingError) as info:
        load_recordings([tmp_path])
    assert info.value.path == str(tmp_path / "b.csv")
    with pytest.raises(RecordingError, match="not found"):
        load_recordings([tmp_path / "a.csv", tmp_path / "nope.csv"])


def test_load_recording_on_a_folder(tmp_path):
    err = _expect_error(tmp_path, None)
    assert "folder" in err.problem and "load_recordings" in err.fix


# ------------------------------------------------------------------- safe writing


def test_check_output_path(tmp_path):
    out = tmp_path / "deep" / "er" / "out.csv"
    assert check_output_path(out, force=False) == out
    assert out.parent.is_dir()
    out.write_text("old")
    with pytest.raises(OutputExistsError) as info:
        check_output_path(out, force=False)
    assert isinstance(info.value, FileExistsError)
    assert "--force" in str(info.value) and str(out) in str(info.value)
    assert check_output_path(out, force=True) == out
    with pytest.raises(IsADirectoryError):
        check_output_path(tmp_path, force=True)


def test_check_output_path_refuses_inputs_even_with_force(tmp_path, monkeypatch):
    inp = tmp_path / "in.csv"
    inp.write_text("data")
    link = tmp_path / "link.csv"
    link.symlink_to(inp)
    monkeypatch.chdir(tmp_path)
    for spelling in (inp, "in.csv", tmp_path / "x" / ".." / "in.csv", link):
        with pytest.raises(InputOverwriteError) as info:
            check_output_path(spelling, force=True, inputs=[inp])
        assert "another output path" in str(info.value) and "--force" in str(info.value)
    # An input that does not exist yet is still protected by name.
    with pytest.raises(InputOverwriteError):
        check_output_path(tmp_path / "new.csv", force=True, inputs=["new.csv"])
    assert inp.read_text() == "data"


def test_atomic_write_failure_leaves_old_file_and_no_temp(tmp_path):
    path = tmp_path / "out.csv"
    path.write_text("old")
    with pytest.raises(RuntimeError), atomic_writer(path) as fh:
        fh.write("half of the new")
        raise RuntimeError("disk on fire")
    assert path.read_text() == "old"
    assert sorted(os.listdir(tmp_path)) == ["out.csv"]
    new = tmp_path / "new.bin"
    with pytest.raises(KeyboardInterrupt), atomic_writer(new, "wb") as fh:
        fh.write(b"x")
        raise KeyboardInterrupt
    assert sorted(os.listdir(tmp_path)) == ["out.csv"]


def test_atomic_write_text_and_bytes(tmp_path):
    atomic_write_text(tmp_path / "a.txt", "é\nline\n")
    assert (tmp_path / "a.txt").read_bytes() == "é\nline\n".encode()
    atomic_write_bytes(tmp_path / "a.txt", b"\x00\x01")
    assert (tmp_path / "a.txt").read_bytes() == b"\x00\x01"
    assert sorted(os.listdir(tmp_path)) == ["a.txt"]
    umask = os.umask(0o022)
    os.umask(umask)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o666 & ~umask
    with pytest.raises(ValueError):
        with atomic_writer(tmp_path / "b.txt", "a"):
            pass


def test_save_recording_refuses_overwrite_and_inputs(tmp_path):
    rec = _saw_recording()
    out = tmp_path / "sim.csv"
    assert save_recording(rec, out) == out
    first = out.read_bytes()
    with pytest.raises(OutputExistsError):
        save_recording(rec, out)
    save_recording(rec.with_position_m(np.zeros(rec.n)), out, force=True)
    assert out.read_bytes() != first
    loaded = load_recording(out)
    # The loaded recording's own file is an input: never written over, even with force.
    with pytest.raises(InputOverwriteError):
        save_recording(loaded.with_position_m(np.ones(rec.n)), out, force=True)
    other = tmp_path / "other.csv"
    with pytest.raises(InputOverwriteError):
        save_recording(rec, other, force=True, inputs=[other])
    assert not other.exists()
    assert sorted(os.listdir(tmp_path)) == ["sim.csv"]


def test_save_recording_refuses_what_would_not_load(tmp_path):
    rec = _saw_recording(n=10)
    with pytest.raises(ValueError, match="16"):
        save_recording(rec, tmp_path / "short.csv")
    with pytest.raises(ValueError, match="csv or .npz"):
        save_recording(_saw_recording(), tmp_path / "x.txt")
    bad_meta = Recording(time_s=np.arange(20.0), voltage_V=np.zeros(20), meta={"a\nb": "c"})
    with pytest.raises(ValueError, match="metadata key"):
        save_recording(bad_meta, tmp_path / "meta.csv")
    assert os.listdir(tmp_path) == []


def test_with_position_m_checks_and_units():
    rec = _saw_recording()
    q = np.linspace(-1e-6, 2e-6, rec.n)
    for unit, scale in [("m", 1.0), ("um", 1e6), ("nm", 1e9)]:
        out = rec.with_position_m(q, unit=unit)
        np.testing.assert_array_equal(out.position, q * scale)
        np.testing.assert_allclose(out.position_m, q, rtol=1e-15, atol=0)
        assert out.meta == rec.meta and out.time_s is not None and out.sensor_V is None
    with pytest.raises(ValueError):
        rec.with_position_m(q[:-1])
    with pytest.raises(ValueError):
        rec.with_position_m(np.full(rec.n, np.nan))
    with pytest.raises(ValueError):
        rec.with_position_m(q, unit="mm")
    with pytest.raises(ValueError):
        Recording(time_s=np.arange(3.0), voltage_V=np.zeros(3), meta={"direction": "up"})


# -------------------------------------------------------------------- signals


def test_sawtooth_matches_the_definition():
    a, f = 50.0, 100.0
    t, u = signals.sawtooth(a, f, duration_s=0.1)
    assert t.size == 2500 and t[0] == 0.0
    np.testing.assert_array_equal(t, np.arange(2500) / FS)
    period = int(FS / f)
    assert u[0] == 0.0 and u[period] == 0.0 and u[2 * period] == 0.0
    assert u[period - 1] == pytest.approx(a * (1 - f / FS), rel=1e-15)
    assert u.max() == pytest.approx(a * (1 - f / FS), rel=1e-15)
    _, back = signals.sawtooth(a, f, direction="backward", duration_s=0.1)
    assert back[0] == a and back[period] == a
    np.testing.assert_allclose(back, a - u, rtol=0, atol=1e-12)
    with pytest.raises(ValueError):
        signals.sawtooth(a, f, direction="up", duration_s=0.1)
    with pytest.raises(ValueError):
        signals.sawtooth(a, -f, duration_s=0.1)


def test_sine_and_step_match_the_definition():
    t, u = signals.sine(40.0, 100.0, duration_s=0.02, sample_rate_Hz=10_000.0)
    assert t.size == 200 and u[0] == 0.0
    assert u[50] == pytest.approx(40.0, rel=1e-15)  # half a period: the peak
    np.testing.assert_allclose(u, 20.0 * (1 - np.cos(2 * np.pi * 100.0 * t)), atol=1e-12)
    t, u = signals.step(40.0, duration_s=0.01)
    assert np.flatnonzero(u)[0] == 50 and np.all(u[50:] == 40.0)  # t0 = 2 ms at 25 kHz
    t, u = signals.step(-3.0, t0_s=0.0, duration_s=0.001)
    assert np.all(u == -3.0)


def test_make_recording_metadata_and_drive_only_round_trip(tmp_path):
    t, u = signals.sawtooth(60.0, 50.0, direction="backward", duration_s=0.1)
    rec = signals.make_recording(t, u, waveform="sawtooth", amplitude_V=60.0,
                                 frequency_Hz=50.0, direction="backward", name="drive")
    assert rec.meta == {"waveform": "sawtooth", "amplitude_V": "60", "frequency_Hz": "50",
                        "direction": "backward", "sample_rate_Hz": "25000"}
    assert rec.position is None and rec.name == "drive" and rec.regime == "sawtooth_backward"
    path = save_recording(rec, tmp_path / "drive.csv")
    back = load_recording(path, require_output=False)
    assert np.array_equal(back.voltage_V, u) and back.meta == rec.meta
    with pytest.raises(RecordingError, match="output"):
        load_recording(path)
    with pytest.raises(ValueError):
        signals.make_recording(t, u, waveform="square", amplitude_V=1.0, name="x")


# --------------------------------------------------------------- drive inference

SAW_CASES = [
    # amplitude [V], frequency [Hz], periods, sample rate [Hz]
    (50.0, 100.0, 10.0, FS),
    (70.0, 300.0, 1.5, FS),  # 83.3 samples per period, 1.5 periods
    (20.0, 200.0, 1.5, FS),
    (1.5, 37.7, 1.5, FS),
    (150.0, 1000.0, 3.0, FS),  # 25 samples per period
    (0.01, 333.3, 2.2, FS),
    (40.0, 50.0, 4.7, 10_000.0),
    (85.0, 5.0, 1.6, 100_000.0),
]


@pytest.mark.parametrize("direction", ["forward", "backward"])
@pytest.mark.parametrize(("a", "f", "periods", "fs"), SAW_CASES)
def test_infer_sawtooth(direction, a, f, periods, fs):
    t, u = signals.sawtooth(a, f, direction=direction, duration_s=periods / f,
                            sample_rate_Hz=fs)
    info = infer_drive(t, u)
    assert (info.waveform, info.direction, info.inferred) == ("sawtooth", direction, True)
    assert info.amplitude_V == pytest.approx(a, rel=1e-6)
    assert info.frequency_Hz == pytest.approx(f, rel=1e-3)
    assert info.is_backward == (direction == "backward")


@pytest.mark.parametrize(("a", "f", "periods", "fs"), SAW_CASES)
def test_infer_sine(a, f, periods, fs):
    t, u = signals.sine(a, f, duration_s=periods / f, sample_rate_Hz=fs)
    info = infer_drive(t, u)
    assert (info.waveform, info.direction, info.is_backward) == ("sine", None, False)
    assert info.amplitude_V == pytest.approx(a, rel=1e-6)
    assert info.frequency_Hz == pytest.approx(f, rel=1e-3)


@pytest.mark.parametrize(("a", "t0"), [(50.0, 2e-3), (40.0, 0.01), (-12.5, 1e-4), (0.3, 0.0)])
def test_infer_step(a, t0):
    t, u = signals.step(a, t0_s=t0, duration_s=0.05)
    info = infer_drive(t, u)
    assert (info.waveform, info.frequency_Hz, info.is_backward) == ("step", None, False)
    assert info.amplitude_V == pytest.approx(a, rel=1e-6)


def test_infer_other():
    t = np.arange(2000) / FS
    rng = np.random.default_rng(0)
    triangle = 40 * np.abs(((t * 100) % 1.0) - 0.5)
    square = 40.0 * (((t * 100) % 1.0) < 0.5)
    for u in (rng.normal(size=t.size), triangle, square, np.zeros(t.size),
              signals.sawtooth(40, 10, duration_s=0.08)[1]):  # under one period: no edge
        assert infer_drive(t, u).waveform == "other"
    # A sawtooth with noise above the tolerance is not recognised; below it is.
    _, saw = signals.sawtooth(40.0, 100.0, duration_s=0.08)
    assert infer_drive(t, saw + rng.normal(scale=5e-2, size=t.size)).waveform == "other"
    noisy = infer_drive(t, saw + rng.normal(scale=1e-4, size=t.size))
    assert noisy.waveform == "sawtooth" and noisy.amplitude_V == pytest.approx(40, rel=1e-4)


@pytest.mark.parametrize("kind", ["forward", "backward", "sine", "step"])
def test_infer_drive_tolerates_a_little_noise(kind):
    rng = np.random.default_rng(1)
    if kind == "sine":
        t, u = signals.sine(50.0, 100.0, duration_s=0.015)
    elif kind == "step":
        t, u = signals.step(50.0, duration_s=0.015)
    else:
        t, u = signals.sawtooth(50.0, 100.0, direction=kind, duration_s=0.015)
    info = infer_drive(t, u + rng.normal(scale=0.02, size=t.size))  # 0.04 % of 50 V
    assert info.waveform == ("sawtooth" if kind in ("forward", "backward") else kind)
    assert info.amplitude_V == pytest.approx(50.0, rel=1e-3)
    if kind != "step":
        assert info.frequency_Hz == pytest.approx(100.0, rel=1e-3)


@settings(max_examples=60, deadline=None)
@given(
    a=st.floats(0.01, 500.0),
    samples_per_period=st.floats(8.0, 500.0),
    periods=st.floats(1.5, 12.0),
    fs=st.sampled_from([10_000.0, 25_000.0, 50_000.0]),
    kind=st.sampled_from(["forward", "backward", "sine"]),
)
def test_infer_drive_property(a, samples_per_period, periods, fs, kind):
    f = fs / samples_per_period
    if kind == "sine":
        t, u = signals.sine(a, f, duration_s=periods / f, sample_rate_Hz=fs)
    else:
        t, u = signals.sawtooth(a, f, direction=kind, duration_s=periods / f, sample_rate_Hz=fs)
    info = infer_drive(t, u)
    assert info.waveform == ("sine" if kind == "sine" else "sawtooth")
    assert info.direction == (None if kind == "sine" else kind)
    assert info.amplitude_V == pytest.approx(a, rel=1e-6)
    assert info.frequency_Hz == pytest.approx(f, rel=1e-3)


def test_drive_fills_missing_metadata_from_the_voltage():
    t, u = signals.sawtooth(30.0, 150.0, direction="backward", duration_s=0.02)

    def rec(**meta):
        return Recording(time_s=t, voltage_V=u, meta=meta)

    full = rec(waveform="sawtooth", amplitude_V="31", frequency_Hz="150", direction="backward")
    assert full.drive == DriveInfo("sawtooth", 31.0, 150.0, "backward", inferred=False)
    partial = rec(waveform="Sawtooth", amplitude_V="31").drive
    assert (partial.waveform, partial.amplitude_V, partial.direction, partial.inferred) == (
        "sawtooth", 31.0, "backward", True)
    assert partial.frequency_Hz == pytest.approx(150.0, rel=1e-9)
    bare = rec().drive
    assert bare.inferred and bare.amplitude_V == pytest.approx(30.0, rel=1e-9)
    assert rec().regime == "sawtooth_backward"
    # Metadata that contradicts the voltage's waveform is kept, not "corrected".
    wrong = rec(waveform="sine").drive
    assert (wrong.waveform, wrong.amplitude_V, wrong.inferred) == ("sine", None, False)
    # Sine and step are never backward, whatever the metadata says.
    assert not DriveInfo("sine", 1.0, 1.0, "backward").is_backward
    assert not DriveInfo("step", 1.0, None, None).is_backward
    assert rec(waveform="step", amplitude_V="1", direction="backward").regime == "step"
    with pytest.raises(ValueError):
        DriveInfo("square")


# --------------------------------------------------------------- reference files


REFERENCE_FILES = sorted(FIXTURES.glob("*.csv"))


def test_reference_files_exist():
    assert len(REFERENCE_FILES) >= 5


@pytest.mark.parametrize("path", REFERENCE_FILES, ids=lambda p: p.name)
def test_reference_files_load_and_infer(path):
    rec = load_recording(path)
    truth = rec.drive
    assert not truth.inferred and truth.waveform in WAVEFORMS
    assert rec.position_unit == "um" and rec.n >= MIN_ROWS
    assert rec.sample_rate_Hz == pytest.approx(FS, rel=1e-9)
    guess = infer_drive(rec.time_s, rec.voltage_V)
    assert guess.waveform == truth.waveform
    assert guess.amplitude_V == pytest.approx(truth.amplitude_V, rel=1e-6)
    if truth.frequency_Hz is not None:
        assert guess.frequency_Hz == pytest.approx(truth.frequency_Hz, rel=1e-3)
    if truth.waveform == "sawtooth":
        assert guess.direction == truth.direction
        assert rec.regime == f"sawtooth_{truth.direction}"
    # With only the waveform in the metadata the rest is inferred to the same values.
    sparse = Recording(time_s=rec.time_s, voltage_V=rec.voltage_V,
                       meta={"waveform": rec.meta["waveform"]})
    assert sparse.drive.amplitude_V == pytest.approx(truth.amplitude_V, rel=1e-6)
    assert sparse.regime == rec.regime


@pytest.mark.parametrize("path", REFERENCE_FILES[:2], ids=lambda p: p.name)
def test_reference_file_round_trip(tmp_path, path):
    rec = load_recording(path)
    for ext in ("csv", "npz"):
        back = load_recording(save_recording(rec, tmp_path / f"copy.{ext}"))
        for name in ("time_s", "voltage_V", "position"):
            assert np.array_equal(getattr(rec, name), getattr(back, name))
        assert back.meta == rec.meta


# ------------------------------------------------------- property-based round trip

KNOWN_KEYS = ("waveform", "amplitude_V", "frequency_Hz", "direction", "preload_N",
              "sample_rate_Hz")
finite = st.floats(allow_nan=False, allow_infinity=False)
meta_keys = (
    st.text(alphabet=string.ascii_letters + string.digits + "_-. #", min_size=1, max_size=12)
    .map(str.strip)
    .filter(lambda k: k and k not in KNOWN_KEYS)
)
meta_values = st.text(max_size=30).filter(
    lambda v: v == v.strip() and "\n" not in v and "\r" not in v
)


@st.composite
def recordings(draw) -> Recording:
    n = draw(st.integers(MIN_ROWS, 500))
    rate = draw(st.floats(1e-3, 1e9))
    k0 = draw(st.integers(-10_000, 10_000))
    t = (np.arange(n) + k0) / rate
    column = hnp.arrays(np.float64, n, elements=finite)
    output = draw(st.sampled_from(["m", "um", "nm", "sensor", "both"]))
    unit = None if output == "sensor" else ("um" if output == "both" else output)
    known = {
        "waveform": st.sampled_from([*WAVEFORMS, "Sine"]),
        "amplitude_V": finite.map(repr),
        "frequency_Hz": st.floats(1e-300, 1e300).map(repr),
        "direction": st.sampled_from(["forward", "backward", "BACKWARD"]),
        "preload_N": st.floats(0.0, 1e6).map(repr),
        "sample_rate_Hz": st.just(repr(1.0 / float(np.median(np.diff(t))))),
    }
    chosen = draw(st.lists(st.sampled_from(KNOWN_KEYS), unique=True))
    items = [(k, draw(known[k])) for k in chosen]
    items += list(draw(st.dictionaries(meta_keys, meta_values, max_size=5)).items())
    meta = dict(draw(st.permutations(items)))
    return Recording(
        time_s=t,
        voltage_V=draw(column),
        position=None if unit is None else draw(column),
        position_unit=unit,
        sensor_V=draw(column) if output in ("sensor", "both") else None,
        meta=meta,
        name="random",
    )


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rec=recordings(), ext=st.sampled_from(["csv", "npz"]))
def test_round_trip_is_bit_exact(rec, ext):
    with tempfile.TemporaryDirectory() as folder:
        path = save_recording(rec, Path(folder) / f"rec.{ext}")
        back = load_recording(path)
        assert os.listdir(folder) == [f"rec.{ext}"]
    for name in ("time_s", "voltage_V", "position", "sensor_V"):
        a, b = getattr(rec, name), getattr(back, name)
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a, b) and b.dtype == np.float64
            # array_equal treats -0.0 == 0.0; the sign bit must survive too.
            assert np.array_equal(np.signbit(a), np.signbit(b))
    assert back.position_unit == rec.position_unit
    assert back.meta == rec.meta and list(back.meta) == list(rec.meta)
    assert back.name == "rec"


def test_metadata_number_formatting():
    from stickslip_jax.io import format_meta_number

    assert format_meta_number(50.0) == "50"
    assert format_meta_number(0.1) == "0.1"
    assert float(format_meta_number(1 / 3)) == 1 / 3
    assert math.isclose(float(format_meta_number(1e20)), 1e20)

"""Recordings: read, check and write experiment files (docs/model.md, "Recording files").

A recording is one experiment: the drive voltage and the measured output sampled on
a uniform time grid. On disk it is a CSV file::

    # waveform: sawtooth
    # amplitude_V: 40
    # frequency_Hz: 50
    # direction: forward
    time_s,voltage_V,position_um
    0.0,0.0,0.0
    4e-05,0.032,0.000412

(``#`` lines before the header are ``key: value`` metadata; units are part of the
column names) or an ``.npz`` archive holding arrays of the same names plus an
optional ``meta_json`` string. :func:`load_recording` refuses a file that breaks the
contract with a :class:`RecordingError` naming the file, the line and the fix.
:func:`save_recording` writes floats with their shortest round-trip ``repr``, so a
saved recording loads back bit for bit.

This module is pure numpy: reading data does not start JAX.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import zipfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

# DriveInfo (what ``Recording.drive`` returns) and the metadata vocabularies are
# re-exported: they belong to the recording contract as much as to the inference.
from stickslip_jax.drive_inference import DIRECTIONS, WAVEFORMS, DriveInfo, infer_drive
from stickslip_jax.files import atomic_writer, check_output_path

__all__ = [
    "DIRECTIONS",
    "MIN_ROWS",
    "POSITION_UNITS",
    "WAVEFORMS",
    "DriveInfo",
    "Recording",
    "RecordingError",
    "format_meta_number",
    "load_recording",
    "load_recordings",
    "save_recording",
]

PathLike = str | os.PathLike[str]

#: Accepted position units, as units per metre: metres = value / POSITION_UNITS[unit].
POSITION_UNITS: dict[str, float] = {"m": 1.0, "um": 1e6, "nm": 1e9}
#: Fewest samples a recording may hold (docs/model.md "Recording files").
MIN_ROWS = 16
#: Every sample interval must be within this of the median interval, relatively.
UNIFORM_RTOL = 1e-6
#: Metadata ``sample_rate_Hz`` must agree with the time column within this, relatively.
SAMPLE_RATE_RTOL = 1e-6

_TIME, _VOLTAGE, _SENSOR = "time_s", "voltage_V", "sensor_V"
_POSITION_COLUMNS = tuple(f"position_{u}" for u in POSITION_UNITS)
_ALL_COLUMNS = (_TIME, _VOLTAGE, *_POSITION_COLUMNS, _SENSOR)
#: Accepted column names per quantity, to explain a wrong unit ("position_mm").
_ACCEPTED_BY_QUANTITY = {
    "time": (_TIME,),
    "voltage": (_VOLTAGE,),
    "position": _POSITION_COLUMNS,
    "sensor": (_SENSOR,),
}
_META_JSON = "meta_json"
_HEADER_EXAMPLE = "time_s,voltage_V,position_um"


# --------------------------------------------------------------------------- errors


class RecordingError(ValueError):
    """A recording file breaks the file contract.

    Attributes
    ----------
    path:
        The file (as given), or None.
    line:
        1-based line number in the file where the problem is, or None (whole file,
        or an ``.npz`` archive, which has no lines).
    problem:
        What is wrong.
    fix:
        How to repair the file.
    """

    def __init__(self, path: PathLike | None, line: int | None, problem: str, fix: str):
        self.path = None if path is None else str(path)
        self.line = line
        self.problem = problem.rstrip(".")
        self.fix = fix if fix.endswith(".") else fix + "."
        super().__init__(self._message())

    def _message(self) -> str:
        where = self.path if self.path is not None else "<recording>"
        if self.line is not None:
            where += f", line {self.line}"
        return f"{where}: {self.problem}. Fix: {self.fix}"

    def __str__(self) -> str:
        return self._message()

    def __reduce__(self):
        # The default pickling would call RecordingError(message) (used by multiprocessing).
        return (type(self), (self.path, self.line, self.problem, self.fix))


class RecordingErrors(ValueError):
    """Several recordings break the file contract; ``errors``: one
    :class:`RecordingError` per file, each on its own line."""

    def __init__(self, errors):
        self.errors = list(errors)
        super().__init__("\n".join(str(e) for e in self.errors))


# ------------------------------------------------------------------------ metadata


def format_meta_number(x: float) -> str:
    """Format a number for a metadata line: ``50`` rather than ``50.0``, else exact ``repr``."""
    x = float(x)
    if x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


def _parse_number(text: str) -> float | None:
    """``float(text)`` for a plain finite decimal number, else None."""
    # float() also takes "1_000", "nan" and "inf"; none of them belongs in a recording.
    if "_" in text:
        return None
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _meta_problem(key: str, value: str) -> tuple[str, str] | None:
    """Check one known metadata value; return ``(problem, fix)`` or None when valid."""
    low = value.strip().lower()
    if key == "waveform" and low not in WAVEFORMS:
        return (f"waveform {value!r} is not known", f"use one of {', '.join(WAVEFORMS)}")
    if key == "direction" and low not in DIRECTIONS:
        return (f"direction {value!r} is not known", "use forward or backward")
    if key in ("amplitude_V", "frequency_Hz", "preload_N", "sample_rate_Hz"):
        number = _parse_number(value)
        unit = key.rsplit("_", 1)[1]
        example = f"'# {key}: 40'"
        if number is None:
            return (
                f"{key} {value!r} is not a finite number",
                f"write the value in {unit} as a plain number, e.g. {example}",
            )
        if key in ("frequency_Hz", "sample_rate_Hz") and number <= 0:
            return (f"{key} must be > 0, got {value!r}", f"write a positive value in {unit}")
        if key == "preload_N" and number < 0:
            return (f"preload_N must be >= 0, got {value!r}", "write the preload force in N")
    return None


def _meta_write_problem(key: str, value: str) -> str | None:
    """Why ``# key: value`` would not read back as the same pair, or None."""
    if not isinstance(key, str) or not isinstance(value, str):
        return f"metadata key and value must be strings, got {key!r}: {value!r}"
    if not key or key != key.strip() or ":" in key or "\n" in key or "\r" in key:
        return f"metadata key {key!r} must be non-empty, without ':', newlines or edge spaces"
    if value != value.strip() or "\n" in value or "\r" in value:
        return f"metadata value {value!r} for {key!r} must have no newlines or edge spaces"
    return None


def _drive_from_meta(
    meta: Mapping[str, str], time_s: np.ndarray, voltage_V: np.ndarray
) -> DriveInfo:
    """DriveInfo from metadata, with the missing fields inferred from the voltage."""
    waveform = meta["waveform"].strip().lower() if "waveform" in meta else None
    amplitude = float(meta["amplitude_V"]) if "amplitude_V" in meta else None
    frequency = float(meta["frequency_Hz"]) if "frequency_Hz" in meta else None
    direction = meta["direction"].strip().lower() if "direction" in meta else None

    needed = {
        "sawtooth": ("amplitude", "frequency", "direction"),
        "sine": ("amplitude", "frequency"),
        "step": ("amplitude",),
        "other": (),
    }
    have = {"amplitude": amplitude, "frequency": frequency, "direction": direction}
    if waveform is not None and all(have[k] is not None for k in needed[waveform]):
        return DriveInfo(waveform, amplitude, frequency, direction, inferred=False)

    guess = infer_drive(time_s, voltage_V)
    inferred = waveform is None
    if waveform is None:
        waveform = guess.waveform
    # Fill the gaps only from a guess of the same waveform: the amplitude of a
    # "sine" fit means nothing for a file whose metadata says "sawtooth".
    if guess.waveform == waveform:
        fields = {"amplitude": guess.amplitude_V, "frequency": guess.frequency_Hz,
                  "direction": guess.direction}
        for k in needed[waveform]:
            if have[k] is None and fields[k] is not None:
                have[k] = fields[k]
                inferred = True
    return DriveInfo(waveform, have["amplitude"], have["frequency"], have["direction"],
                     inferred=inferred)


# ------------------------------------------------------------------------ recording


def _as_column(name: str, values) -> np.ndarray:
    """A read-only float64 1-D copy (a frozen Recording must not change under us)."""
    arr = np.array(values, dtype=np.float64, copy=True)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Recording:
    """One experiment: drive voltage and measured output on a uniform time grid.

    Attributes
    ----------
    time_s:
        Sample times [s], strictly increasing and uniform (checked on load and save).
    voltage_V:
        Drive voltage ``U`` [V].
    position:
        Measured output ``q`` as read, in ``position_unit`` (None if absent).
    position_unit:
        ``"m"``, ``"um"`` or ``"nm"`` (None without a position column).
    sensor_V:
        Uncalibrated sensor output [V] (unknown gain, offset and sign), or None.
    meta:
        All ``key: value`` metadata, in file order, unknown keys included.
    source:
        The file it was read from, or None.
    name:
        Short name (the file name without extension for a loaded file).

    Notes
    -----
    Arrays are stored as read-only float64 copies. Known metadata values are checked
    on construction (ValueError); the data-level contract (≥ 16 samples, uniform time,
    finite values) is checked by :func:`load_recording` and :func:`save_recording`.
    """

    time_s: np.ndarray
    voltage_V: np.ndarray
    position: np.ndarray | None = None
    position_unit: str | None = None
    sensor_V: np.ndarray | None = None
    meta: dict[str, str] = field(default_factory=dict)
    source: str | None = None
    name: str = "recording"

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: normalise the fields through the back door
        set_(self, "time_s", _as_column("time_s", self.time_s))
        set_(self, "voltage_V", _as_column("voltage_V", self.voltage_V))
        n = self.time_s.shape[0]
        for col in ("voltage_V", "position", "sensor_V"):
            value = getattr(self, col)
            if value is None:
                continue
            value = _as_column(col, value)
            if value.shape[0] != n:
                raise ValueError(f"{col} has {value.shape[0]} samples, time_s has {n}")
            set_(self, col, value)
        if (self.position is None) != (self.position_unit is None):
            raise ValueError("position and position_unit must be given together")
        if self.position_unit is not None and self.position_unit not in POSITION_UNITS:
            raise ValueError(
                f"position_unit must be one of {tuple(POSITION_UNITS)}, "
                f"got {self.position_unit!r}"
            )
        meta = dict(self.meta)
        for key, value in meta.items():
            if not isinstance(key, str) or not isinstance(value, str):
                raise ValueError(f"metadata must map str to str, got {key!r}: {value!r}")
            problem = _meta_problem(key, value)
            if problem is not None:
                raise ValueError(f"{problem[0]}; {problem[1]}")
        set_(self, "meta", meta)
        if self.source is not None:
            set_(self, "source", str(self.source))

    # -- sizes and sampling

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.time_s.shape[0])

    @property
    def dt(self) -> float:
        """Median sample period [s]."""
        if self.n < 2:
            raise ValueError(f"{self.name}: the sample period needs at least 2 samples")
        return float(np.median(np.diff(self.time_s)))

    @property
    def sample_rate_Hz(self) -> float:
        """Sample rate ``1/dt`` [Hz]."""
        return 1.0 / self.dt

    # -- output

    @property
    def position_m(self) -> np.ndarray | None:
        """Measured position in metres (float64), or None without a position column."""
        if self.position is None or self.position_unit is None:
            return None
        scale = POSITION_UNITS[self.position_unit]
        # Division by the exact 1e6 / 1e9 rounds once; multiplying by 1e-6 (inexact)
        # would round twice.
        return self.position if scale == 1.0 else self.position / scale

    def with_position_m(self, q_m: np.ndarray, unit: str = "um") -> Recording:
        """A copy whose output is ``q_m`` (e.g. a simulated trace).

        Parameters
        ----------
        q_m:
            Output ``q`` [m], one value per sample, finite.
        unit:
            Unit of the stored position column: ``"m"``, ``"um"`` or ``"nm"``.

        Returns
        -------
        Recording
            Same time, voltage, metadata and name; ``position`` replaced; ``sensor_V``
            dropped (it belongs to the measurement, not to the new output). ``source``
            is kept so that :func:`save_recording` refuses to write over that file.
        """
        if unit not in POSITION_UNITS:
            raise ValueError(f"unit must be one of {tuple(POSITION_UNITS)}, got {unit!r}")
        q = np.asarray(q_m, dtype=np.float64)
        if q.shape != (self.n,):
            raise ValueError(f"q_m must have shape ({self.n},), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError("q_m holds NaN or inf; a recording must be finite")
        return dataclasses.replace(
            self, position=q * POSITION_UNITS[unit], position_unit=unit, sensor_V=None
        )

    # -- drive

    @cached_property
    def drive(self) -> DriveInfo:
        """The drive, from the metadata; missing fields inferred from the voltage
        (:func:`~stickslip_jax.drive_inference.infer_drive`)."""
        return _drive_from_meta(self.meta, self.time_s, self.voltage_V)

    @property
    def regime(self) -> str:
        """Drive regime: ``"sawtooth_forward"``, ``"sawtooth_backward"``, ``"sine"``,
        ``"step"`` or ``"other"``.

        Scanning versus stepping depends on the actuator, not on the voltage, so it is
        not part of the regime.
        """
        drive = self.drive
        if drive.waveform == "sawtooth" and drive.direction is not None:
            return f"sawtooth_{drive.direction}"
        return drive.waveform

    def __repr__(self) -> str:
        out = (f"position_{self.position_unit}" if self.position_unit else
               (_SENSOR if self.sensor_V is not None else "no output"))
        rate = f"{self.sample_rate_Hz:.6g} Hz" if self.n >= 2 else "? Hz"
        return f"Recording({self.name!r}, n={self.n}, {rate}, {out}, meta={self.meta!r})"


# ---------------------------------------------------------------- column checking


def _column_problem(name: str) -> tuple[str, str] | None:
    """Why a column name is not accepted, as ``(problem, fix)``, or None."""
    if name in _ALL_COLUMNS:
        return None
    if not name:
        return ("a column has an empty name (a trailing comma?)",
                f"name every column, e.g. {_HEADER_EXAMPLE}")
    quantity, sep, unit = name.rpartition("_")
    if not sep:
        quantity, unit = name, ""
    accepted = _ACCEPTED_BY_QUANTITY.get(quantity.lower())
    if accepted is not None:
        what = f"has the unit {unit!r}" if unit else "has no unit"
        return (
            f"column {name!r} {what}; accepted: {', '.join(accepted)}",
            f"convert the values and rename the column to one of {', '.join(accepted)}",
        )
    return (
        f"column {name!r} is not known; accepted columns: {', '.join(_ALL_COLUMNS)}",
        "remove the column or rename it to one of the accepted names (units in the name)",
    )


def _check_columns(
    names: Sequence[str], path: PathLike, line: int | None, *, require_output: bool
) -> None:
    """Check a header's column names (or an archive's array names)."""
    seen: set[str] = set()
    for name in names:
        problem = _column_problem(name)
        if problem is not None:
            raise RecordingError(path, line, *problem)
        if name in seen:
            raise RecordingError(path, line, f"column {name!r} appears twice",
                                 "keep one column of each name")
        seen.add(name)
    for required in (_TIME, _VOLTAGE):
        if required not in seen:
            raise RecordingError(
                path, line, f"required column {required!r} is missing",
                f"add it (the header must name {_TIME}, {_VOLTAGE} and the output, "
                f"e.g. {_HEADER_EXAMPLE})",
            )
    positions = [c for c in _POSITION_COLUMNS if c in seen]
    if len(positions) > 1:
        raise RecordingError(path, line, f"several position columns ({', '.join(positions)})",
                             "keep one position column")
    if require_output and not positions and _SENSOR not in seen:
        raise RecordingError(
            path, line,
            f"no measured output column (one of {', '.join(_POSITION_COLUMNS)} or {_SENSOR})",
            "add the measured position with its unit in the column name, e.g. position_um, "
            f"or {_SENSOR} for a raw sensor voltage",
        )


def _check_data(
    names: Sequence[str],
    data: np.ndarray,
    path: PathLike,
    row_line: Callable[[int], int | None],
    meta: Mapping[str, str],
    meta_line: Mapping[str, int | None],
) -> None:
    """Check numbers, length, time grid and ``sample_rate_Hz`` (rows × columns ``data``).

    ``row_line(i)`` gives the line number (or None) of row ``i``; for an archive it is
    None and the messages give the sample index instead.
    """

    def where(i: int) -> str:
        return "" if row_line(i) is not None else f" at sample {i}"

    bad = ~np.isfinite(data)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        what = "NaN" if np.isnan(data[i, j]) else f"an infinite value ({float(data[i, j])!r})"
        raise RecordingError(
            path, row_line(i), f"{what} in column {names[j]}{where(i)}",
            "remove the row or fill the gap (e.g. by interpolation); every value must be a "
            "finite number",
        )
    n = data.shape[0]
    if n < MIN_ROWS:
        last = row_line(n - 1) if n else None
        raise RecordingError(
            path, last, f"only {n} data rows; a recording needs at least {MIN_ROWS}",
            f"record at least {MIN_ROWS} samples",
        )
    t = data[:, names.index(_TIME)]
    steps = np.diff(t)
    back = np.flatnonzero(steps <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise RecordingError(
            path, row_line(i),
            f"time is not increasing ({float(t[i])!r} after {float(t[i - 1])!r}){where(i)}",
            "sort the rows by time or remove duplicated rows",
        )
    period = float(np.median(steps))
    off = np.flatnonzero(np.abs(steps - period) > UNIFORM_RTOL * period)
    if off.size:
        i = int(off[0]) + 1
        raise RecordingError(
            path, row_line(i),
            f"time is not uniformly sampled: the step to {float(t[i])!r} s is "
            f"{steps[i - 1]:.9g} s, "
            f"the median sample period {period:.9g} s (allowed: {UNIFORM_RTOL:g} relative)"
            f"{where(i)}",
            "resample the recording onto a uniform time grid, or split it where samples "
            "are missing or repeated",
        )
    if "sample_rate_Hz" in meta:
        stated = float(meta["sample_rate_Hz"])
        actual = 1.0 / period
        if abs(stated - actual) > SAMPLE_RATE_RTOL * actual:
            raise RecordingError(
                path, meta_line.get("sample_rate_Hz"),
                f"sample_rate_Hz {meta['sample_rate_Hz']} disagrees with the time column "
                f"({actual:.9g} Hz from the median sample period)",
                "correct the sample_rate_Hz line or remove it",
            )


# --------------------------------------------------------------------- CSV reading


def _read_text(path: Path) -> str:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise RecordingError(path, None, "file not found",
                             "check the path and the file name") from None
    except IsADirectoryError:
        raise RecordingError(path, None, "this is a folder, not a file",
                             "use load_recordings to read every recording in a folder") from None
    except OSError as exc:
        raise RecordingError(path, None, f"cannot read the file ({exc.strerror})",
                             "check the file's permissions") from None
    try:
        text = raw.decode("utf-8-sig")  # "-sig": a byte-order mark is not part of line 1
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise RecordingError(path, line, "the file is not UTF-8 text",
                             "save the file as UTF-8 (plain CSV)") from None
    # Old Mac line ends count as line ends, as in any editor.
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _parse_metadata(
    lines: list[str], path: Path
) -> tuple[dict[str, str], dict[str, int], int | None]:
    """Read the ``#`` lines before the header.

    Returns
    -------
    meta, meta_line, header_index:
        Metadata in file order, the line number of each key, and the 0-based index of
        the header line (None when there is none).
    """
    meta: dict[str, str] = {}
    meta_line: dict[str, int] = {}
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            continue
        if not stripped.startswith("#"):
            return meta, meta_line, i
        key, sep, value = stripped[1:].partition(":")
        key, value = key.strip(), value.strip()
        if not sep or not key:
            continue  # a free comment, not metadata
        if key in meta:
            raise RecordingError(path, i + 1,
                                 f"metadata key {key!r} appears twice (first on line "
                                 f"{meta_line[key]})", "keep one line per key")
        problem = _meta_problem(key, value)
        if problem is not None:
            raise RecordingError(path, i + 1, *problem)
        meta[key] = value
        meta_line[key] = i + 1
    return meta, meta_line, None


def _is_number_cell(cell: str) -> bool:
    return "_" not in cell and _is_float(cell)


def _is_float(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _find_bad_row(
    rows: list[str], line_numbers: np.ndarray, names: Sequence[str], path: Path
) -> RecordingError | None:
    """Slow scan for the first row numpy could not read (only run after it failed)."""
    for row, line in zip(rows, line_numbers.tolist(), strict=True):
        if row.lstrip().startswith("#"):
            return RecordingError(
                path, line, "a '#' line after the header",
                "move metadata lines above the header line, or delete the line",
            )
        cells = row.split(",")
        if len(cells) != len(names):
            return RecordingError(
                path, line,
                f"the row has {len(cells)} cells but the header names {len(names)} columns",
                f"give every row one value per column ({', '.join(names)}), with no "
                "trailing comma",
            )
        for cell, name in zip(cells, names, strict=True):
            text = cell.strip()
            if not _is_number_cell(text):
                what = "an empty cell" if not text else f"{text!r} is not a number"
                return RecordingError(
                    path, line, f"{what} in column {name}",
                    "write plain numbers (a dot as decimal separator, no units or quotes)",
                )
    return None


def _parse_rows(rows: list[str], line_numbers: np.ndarray, names: list[str],
                path: Path) -> np.ndarray:
    """Parse the data rows into a (rows × columns) float64 array."""
    try:
        # numpy's C parser: ~0.3 s for 250k rows; floats are correctly rounded, so the
        # shortest repr written by save_recording reads back bit for bit.
        data = np.loadtxt(rows, delimiter=",", dtype=np.float64, ndmin=2,
                          comments=None, quotechar=None)
    except ValueError as exc:
        error = _find_bad_row(rows, line_numbers, names, path)
        if error is not None:
            raise error from None
        raise RecordingError(path, None, f"cannot read the numbers ({exc})",
                             "write plain decimal numbers, one row per sample") from None
    if data.shape[1] != len(names):
        # Every row has the same, wrong, number of cells: numpy does not notice.
        raise _find_bad_row(rows[:1], line_numbers[:1], names, path) or RecordingError(
            path, int(line_numbers[0]), f"rows have {data.shape[1]} cells, the header names "
            f"{len(names)} columns", "give every row one value per column")
    return data


def _load_csv(path: Path, *, require_output: bool) -> Recording:
    text = _read_text(path)
    if not text.strip():
        raise RecordingError(
            path, None, "the file is empty",
            f"write the recording: optional '# key: value' lines, a header such as "
            f"{_HEADER_EXAMPLE}, then one row per sample",
        )
    lines = text.split("\n")
    meta, meta_line, h = _parse_metadata(lines, path)
    if h is None:
        raise RecordingError(
            path, None, "no header line after the metadata",
            f"add a header naming the columns, e.g. {_HEADER_EXAMPLE}, then the data rows",
        )
    header_line = h + 1
    names = [c.strip() for c in lines[h].split(",")]
    if all(_is_number_cell(c) for c in names):
        raise RecordingError(
            path, header_line, "expected the header line but found numbers",
            f"insert a header naming the columns, e.g. {_HEADER_EXAMPLE}, above the data",
        )
    _check_columns(names, path, header_line, require_output=require_output)

    rows = lines[h + 1:]
    line_numbers = np.arange(h + 2, h + 2 + len(rows))
    # Blank lines (a trailing newline, a gap) are skipped but keep the line numbers right.
    blanks = [i for i, row in enumerate(rows) if not row.strip()]
    if blanks:
        blank = np.zeros(len(rows), dtype=bool)
        blank[blanks] = True
        rows = [row for row, b in zip(rows, blank.tolist(), strict=True) if not b]
        line_numbers = line_numbers[~blank]
    if not rows:
        raise RecordingError(
            path, header_line, f"only 0 data rows; a recording needs at least {MIN_ROWS}",
            f"record at least {MIN_ROWS} samples, one row per sample below the header",
        )
    data = _parse_rows(rows, line_numbers, names, path)

    def row_line(i: int) -> int:
        return int(line_numbers[i])

    _check_data(names, data, path, row_line, meta, meta_line)
    return _make(names, list(data.T), meta, path)


# --------------------------------------------------------------------- NPZ reading


def _load_npz(path: Path, *, require_output: bool) -> Recording:
    if not path.exists():
        raise RecordingError(path, None, "file not found", "check the path and the file name")
    bad_archive = RecordingError(
        path, None, "not a readable .npz archive",
        f"save it with numpy.savez(file, {_TIME}=..., {_VOLTAGE}=..., position_um=...), "
        "or use a CSV file",
    )
    try:
        archive = np.load(path, allow_pickle=False)
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise bad_archive  # a plain .npy array under an .npz name
        with archive:
            arrays = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        raise bad_archive from None

    meta = _npz_meta(arrays.pop(_META_JSON, None), path)
    names = list(arrays)
    _check_columns(names, path, None, require_output=require_output)
    columns = []
    for name in names:
        arr = arrays[name]
        if arr.ndim != 1 or arr.dtype.kind not in "fiu":
            raise RecordingError(
                path, None, f"array {name!r} must be 1-D numbers, got {arr.dtype} {arr.shape}",
                "store each column as a 1-D float array",
            )
        columns.append(arr.astype(np.float64))
    lengths = {c.shape[0] for c in columns}
    if len(lengths) > 1:
        sizes = ", ".join(f"{n}: {c.shape[0]}" for n, c in zip(names, columns, strict=True))
        raise RecordingError(path, None, f"arrays differ in length ({sizes})",
                             "store one value per sample in every array")
    data = np.column_stack(columns)
    _check_data(names, data, path, lambda i: None, meta, {})
    return _make(names, columns, meta, path)


def _npz_meta(raw: np.ndarray | None, path: Path) -> dict[str, str]:
    """Decode the optional ``meta_json`` array (a JSON object of strings)."""
    if raw is None:
        return {}
    fix = f"store the metadata as {_META_JSON}=numpy.array(json.dumps({{'key': 'value'}}))"
    if raw.size != 1 or raw.dtype.kind not in "US":
        raise RecordingError(path, None, f"{_META_JSON} must be one string", fix)
    try:
        decoded = json.loads(str(raw.reshape(()).item()))
    except json.JSONDecodeError as exc:
        raise RecordingError(path, None, f"{_META_JSON} is not valid JSON ({exc})", fix) from None
    if not isinstance(decoded, dict):
        raise RecordingError(path, None, f"{_META_JSON} must hold a JSON object", fix)
    meta: dict[str, str] = {}
    for key, value in decoded.items():
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            raise RecordingError(path, None,
                                 f"metadata {key!r} must be a string or a number", fix)
        value = value if isinstance(value, str) else format_meta_number(value)
        problem = _meta_problem(key, value)
        if problem is not None:
            raise RecordingError(path, None, *problem)
        meta[key] = value
    return meta


def _make(names: Sequence[str], columns: Sequence[np.ndarray], meta: dict[str, str],
          path: Path) -> Recording:
    by_name = dict(zip(names, columns, strict=True))
    unit = next((c.split("_", 1)[1] for c in _POSITION_COLUMNS if c in by_name), None)
    return Recording(
        time_s=by_name[_TIME],
        voltage_V=by_name[_VOLTAGE],
        position=None if unit is None else by_name[f"position_{unit}"],
        position_unit=unit,
        sensor_V=by_name.get(_SENSOR),
        meta=meta,
        source=str(path),
        name=path.stem,
    )


# ------------------------------------------------------------------- public loaders


def load_recording(path: PathLike, *, require_output: bool = True) -> Recording:
    """Read one recording (CSV, or ``.npz`` by extension) and check the file contract.

    Parameters
    ----------
    path:
        The file.
    require_output:
        Require a measured output column (``position_*`` or ``sensor_V``). Pass False
        to read a drive-only file (time and voltage), e.g. the input of a simulation.

    Returns
    -------
    Recording

    Raises
    ------
    RecordingError
        The file is missing, unreadable or breaks the contract; the message names the
        file, the line (CSV) and the fix.
    """
    path = Path(path)
    if path.suffix.lower() == ".npz":
        return _load_npz(path, require_output=require_output)
    return _load_csv(path, require_output=require_output)


def recording_files(folder: Path) -> list[Path]:
    """The recording files (``.csv``, ``.npz``) directly in ``folder``, by name."""
    # Hidden files are skipped: they include the temporary files of an unfinished
    # atomic write (".name.xxxx.tmp") and editors' lock files.
    return sorted(
        p for p in folder.iterdir()
        if p.is_file() and p.suffix.lower() in (".csv", ".npz") and not p.name.startswith(".")
    )


def load_recordings(
    paths: PathLike | Sequence[PathLike], *, require_output: bool = True
) -> list[Recording]:
    """Read a set of recordings: files and/or folders (docs/model.md "Recording files").

    Parameters
    ----------
    paths:
        Files and folders (or a single one). A folder contributes all its ``*.csv`` and
        ``*.npz`` files (not recursive), sorted by name. A file named twice (directly or
        through a folder) is read once.
    require_output:
        See :func:`load_recording`.

    Returns
    -------
    list of Recording
        In the order given.

    Raises
    ------
    RecordingError
        A file breaks the contract, a path does not exist, or a folder holds no
        recordings.
    """
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    if not paths:
        raise ValueError("no recordings given: pass at least one file or folder")
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = recording_files(p)
            if not found:
                raise RecordingError(
                    p, None, "the folder holds no recordings (*.csv or *.npz files)",
                    "put the recordings in it, or pass the files themselves",
                )
            files.extend(found)
        else:
            files.append(p)
    unique: dict[Path, Path] = {}
    for f in files:
        unique.setdefault(f.resolve(), f)
    return [load_recording(f, require_output=require_output) for f in unique.values()]


# ------------------------------------------------------------------------- writing


def _columns_of(rec: Recording) -> dict[str, np.ndarray]:
    columns = {_TIME: rec.time_s, _VOLTAGE: rec.voltage_V}
    if rec.position is not None:
        columns[f"position_{rec.position_unit}"] = rec.position
    if rec.sensor_V is not None:
        columns[_SENSOR] = rec.sensor_V
    return columns


def _check_savable(rec: Recording, out: Path) -> None:
    """Refuse to write a file that :func:`load_recording` would refuse."""
    for key, value in rec.meta.items():
        problem = _meta_write_problem(key, value)
        if problem is not None:
            raise ValueError(f"cannot save {rec.name!r} to {out}: {problem}")
    columns = _columns_of(rec)
    names = list(columns)
    try:
        _check_data(names, np.column_stack(list(columns.values())), out,
                    lambda i: None, rec.meta, {})
    except RecordingError as exc:
        raise ValueError(f"cannot save {rec.name!r} to {out}: {exc.problem}") from None


def _csv_text(rec: Recording) -> str:
    columns = _columns_of(rec)
    parts = [f"# {key}: {value}\n" for key, value in rec.meta.items()]
    parts.append(",".join(columns) + "\n")
    # repr() is the shortest string that reads back as the same double.
    cells = [map(repr, c.tolist()) for c in columns.values()]
    parts.append("\n".join(map(",".join, zip(*cells, strict=True))))
    parts.append("\n")
    return "".join(parts)


def save_recording(
    rec: Recording,
    path: PathLike,
    *,
    force: bool = False,
    inputs: Iterable[PathLike] = (),
) -> Path:
    """Write a recording as CSV or ``.npz`` (by extension), atomically.

    Parameters
    ----------
    rec:
        The recording. Its metadata is written first (CSV: ``# key: value`` lines),
        then the columns ``time_s, voltage_V, position_<unit>, sensor_V`` present.
    path:
        Output file, ending in ``.csv`` or ``.npz``.
    force:
        Overwrite an existing file.
    inputs:
        Files the output is computed from; never overwritten, even with ``force``.
        ``rec.source`` is always counted as an input.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ValueError
        Unknown extension, or the recording would not load back (fewer than 16
        samples, non-uniform time, NaN, unwritable metadata).
    OutputExistsError, InputOverwriteError
        See :func:`stickslip_jax.files.check_output_path`.
    """
    out = Path(path)
    kind = out.suffix.lower()
    if kind not in (".csv", ".npz"):
        raise ValueError(f"{out}: a recording is saved as .csv or .npz, not {kind or 'no'!r}")
    _check_savable(rec, out)
    all_inputs = [*inputs] + ([rec.source] if rec.source is not None else [])
    out = check_output_path(out, force=force, inputs=all_inputs)
    if kind == ".csv":
        with atomic_writer(out, "w") as fh:
            fh.write(_csv_text(rec))
    else:
        arrays = dict(_columns_of(rec))
        arrays[_META_JSON] = np.array(json.dumps(rec.meta))
        with atomic_writer(out, "wb") as fh:
            np.savez(fh, **arrays)
    return out

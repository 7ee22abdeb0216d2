"""Can a recording's sampling resolve the actuator at all? Decided before any fitting.

A recording is a set of samples ``1/fs`` apart [s]; nothing faster than the Nyquist
frequency ``fs/2`` [Hz] shows in it. The actuator's dynamics are its stick chain's
modes (:func:`~stickslip_jax.linear.stick_modes`): the ringing after a step edge, the
inertial slip at a sawtooth's one-sample flyback. A recording whose Nyquist frequency
is below the slowest of them resolves none of them, so a recording that is *for* the
dynamics (one with an abrupt voltage edge: a step, a sawtooth) cannot serve its
purpose, and a periodic drive at or above the Nyquist frequency is not resolved
either. Either way no fit can use the recording, and the simulator, which must follow
the model's fastest mode within every sample interval, spends thousands of sub-steps
per sample on it (the paper's actuator, 17 kHz, at 25 Hz: about 9000; one such step
file kept ``stickslip diagnose`` fitting for minutes: its baseline polish alone took
18 Levenberg-Marquardt steps, 109 s, with nothing to fit). :func:`check_sample_rates`
refuses such recordings before anything is fitted, one
:class:`~stickslip_jax.io.RecordingError` per file.

The usual cause is a unit slip in the time column: milliseconds (or microseconds)
written under ``time_s``, which turns a 25 kHz recording into a 25 Hz one and its
50 Hz sawtooth into a 0.05 Hz one. Only the absolute time scale changes, so the
drive alone cannot betray it; the model's time scales can. The slip is named only
when it explains the file (:func:`unit_slip`): the corrected rate resolves the model
and lies within what acquisition hardware records, and either the metadata's drive
frequency shows the same factor against the voltage, or the recorded rate is below
that range and the file does not state it in its metadata.

A recording without an abrupt edge (a sine, a slow arbitrary drive) sampled below the
slowest mode is a legitimate quasi-static recording: the Prandtl-Ishlinskii loop is
rate-independent, and its drive is resolved (``fixtures/aye2018``, a capacitive
sensor at 200 Hz under a 1 Hz drive). It is refused only beside recordings refused for
a unit slip at the same sample rate: the same export, hence the same slip.

Finer judgements (8 samples per period of the first mode, enough periods, enough
signal) belong to :mod:`.informative`, which says what a usable set cannot determine;
this module only refuses what no fit can use. Pure numpy apart from the stick chain's
contact stiffness (one small compiled program, shared with :mod:`.informative`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..drive_inference import infer_drive
from ..io import UNIFORM_RTOL, Recording, RecordingError, RecordingErrors
from ..linear import stick_modes
from ..model.actuator import Actuator
from ..model.base import DriveContext
from .informative import SAMPLES_PER_MODE_PERIOD, min_sample_rate

__all__ = [
    "ACQUISITION_RATES_HZ",
    "TIME_UNIT_SLIPS",
    "UnitSlip",
    "check_sample_rates",
    "has_edge",
    "sampling_problem",
    "slowest_mode_Hz",
    "unit_slip",
]

TIME_UNIT_SLIPS = ((1e3, "milliseconds"), (1e6, "microseconds"))
"""Factors [-] by which a time column written in a smaller unit than seconds shrinks
the sample rate, with the unit's name; tried smallest first (the smallest correction
that explains the file is the likeliest)."""

ACQUISITION_RATES_HZ = (1e3, 100e6)
"""Sample rates [Hz] at which position recordings of a stick-slip actuator's dynamics
are made. Its first mode lies at hundreds of Hz (the paper's: 523 Hz), so a rate that
shows it is above 1 kHz (Lu 2015 records at 25 kHz); interferometers and laser-Doppler
vibrometers record at up to a few tens of MHz, and no recording of such an actuator
needs more than 100 MHz. A recorded rate inside this range explains itself (a slip is
not named), one below it is a quasi-static recording (``fixtures/aye2018``: 200 Hz)
or a slip, and a corrected rate must land inside it."""

FREQUENCY_MATCH_RTOL = 0.01
"""Relative tolerance [-] within which the metadata's ``frequency_Hz`` is taken as
``factor`` times the frequency the voltage repeats at by the time column. A metadata
frequency is a nominal setting written to two or three significant digits; 1 % still
tells 1000 from 1024."""

EDGE_FRACTION = 0.5
"""A voltage jump between two samples of at least this fraction of the voltage's
range [-] is an abrupt edge, whose response is the actuator's dynamics (the same
test :func:`~.informative.step_problem` uses for a step's edge)."""


@dataclass(frozen=True)
class UnitSlip:
    """A time column in a smaller unit than seconds, as the likely cause.

    ``factor`` [-] multiplies the recorded sample rate to the true one (1000 for
    milliseconds); ``unit`` names the unit; ``rate_Hz`` the corrected sample rate
    [Hz]; ``evidence`` a clause on the drive metadata agreeing with the factor, or
    None.
    """

    factor: float
    unit: str
    rate_Hz: float
    evidence: str | None = None

    def sentence(self) -> str:
        """The hypothesis in one sentence (no final period)."""
        why = f"; {self.evidence}" if self.evidence else ""
        return (f"A time column in {self.unit} labelled time_s? ×{self.factor:.0f} gives "
                f"{_hz(self.rate_Hz)}, which resolves the model's modes{why}")

    def fix(self, rec: Recording, f1_Hz: float) -> str:
        """How to repair the file, and what to do if the rate was right after all."""
        return (f"write the time column in seconds (divide it by {self.factor:.0f}) and add "
                f"'# sample_rate_Hz: {self.rate_Hz:.7g}' above the header, so that the "
                f"loader checks the time column against it; if it really was sampled at "
                f"{_hz(rec.sample_rate_Hz)}, {_record_again(f1_Hz)}")


# ------------------------------------------------------------ the model's time scale


def slowest_mode_Hz(actuator: Actuator, drive: DriveContext | None = None) -> float:
    """Frequency [Hz] of the slowest mode of ``actuator``'s stick chain under ``drive``
    (default: forward): the damped frequency, which is what a step response rings at
    and what the samples must resolve, or the natural frequency of an overdamped
    pair. For the default drive it is :func:`~.informative.first_mode`, the time
    scale of the identification's other data rules."""
    modes = stick_modes(actuator, drive)
    f = float(modes.damped_Hz[0])
    return f if f > 0 else float(modes.natural_Hz[0])


def _drive_context(rec: Recording) -> DriveContext:
    from ..simulate import drive_context  # the simulator's: the same contact the fit sees

    return drive_context(rec)


def _mode_for(rec: Recording, actuator: Actuator, cache: dict) -> float:
    """:func:`slowest_mode_Hz` under ``rec``'s drive, computed once per distinct drive."""
    drive = _drive_context(rec)
    key = tuple(float(x) for x in (drive.backward, drive.amplitude, drive.frequency))
    if key not in cache:
        cache[key] = slowest_mode_Hz(actuator, drive)
    return cache[key]


# ------------------------------------------------------------------ the recording


def has_edge(rec: Recording) -> bool:
    """True when ``rec``'s drive has an abrupt edge, whose response is the actuator's
    dynamics: a step, a sawtooth (its one-sample flyback), or any other drive with a
    one-sample jump of at least :data:`EDGE_FRACTION` of its range. A sine has none."""
    waveform = rec.drive.waveform
    if waveform in ("step", "sawtooth"):
        return True
    if waveform == "sine":
        return False
    u = np.asarray(rec.voltage_V, dtype=float)
    span = float(np.ptp(u))
    return span > 0 and float(np.max(np.abs(np.diff(u)))) >= EDGE_FRACTION * span


def _nyquist(rate_Hz: float) -> float:
    return 0.5 * rate_Hz


def _resolves_modes(rate_Hz: float, f1_Hz: float) -> bool:
    """The samples show the slowest mode ``f1_Hz`` [Hz] without aliasing."""
    return _nyquist(rate_Hz) > f1_Hz


def _drive_resolved(rate_Hz: float, drive_Hz: float | None) -> bool:
    """The samples show the periodic drive ``drive_Hz`` [Hz] (None: not periodic)."""
    return drive_Hz is None or not drive_Hz > 0 or drive_Hz < _nyquist(rate_Hz)


def _voltage_frequency(rec: Recording) -> float | None:
    """The frequency [Hz] the voltage repeats at by the time column, or None."""
    info = infer_drive(rec.time_s, rec.voltage_V)
    return info.frequency_Hz if info.waveform == rec.drive.waveform else None


def _meta_frequency(rec: Recording) -> float | None:
    return float(rec.meta["frequency_Hz"]) if "frequency_Hz" in rec.meta else None


def _factor_seen_in_drive(rec: Recording, factor: float) -> str | None:
    """A clause when the metadata's frequency is ``factor`` times the voltage's."""
    stated = _meta_frequency(rec)
    if stated is None:
        return None
    seen = _voltage_frequency(rec)
    if not seen or abs(stated / (factor * seen) - 1.0) > FREQUENCY_MATCH_RTOL:
        return None
    return (f"its metadata's frequency_Hz: {rec.meta['frequency_Hz']} is ×{factor:.0f} the "
            f"{_hz(seen)} its voltage repeats at by the time column")


def unit_slip(rec: Recording, f1_Hz: float) -> UnitSlip | None:
    """The time-unit slip that explains why ``rec`` does not resolve the model's
    slowest mode ``f1_Hz`` [Hz], or None when none does.

    A factor of :data:`TIME_UNIT_SLIPS` fits when, with the sample rate multiplied by
    it, the samples resolve the slowest mode and any metadata drive frequency (a time
    column's slip leaves the metadata as they were) at a rate within
    :data:`ACQUISITION_RATES_HZ`. It is named when the metadata's drive frequency is
    that factor times the voltage's (direct evidence), or else, for the smallest
    factor that fits, when the recorded rate is below the acquisition range (a rate
    inside it explains itself) and the metadata do not state the sample rate (the
    file would then say it twice: the loader checked that both agree).
    """
    fitting = [(factor, unit, factor * rec.sample_rate_Hz) for factor, unit in TIME_UNIT_SLIPS
               if _slip_fits(rec, factor * rec.sample_rate_Hz, f1_Hz)]
    for factor, unit, rate in fitting:
        evidence = _factor_seen_in_drive(rec, factor)
        if evidence is not None:
            return UnitSlip(factor, unit, rate, evidence)
    low, _ = ACQUISITION_RATES_HZ
    inside = rec.sample_rate_Hz >= low * (1.0 - UNIFORM_RTOL)  # 1/0.001 s is 1 kHz
    if not fitting or inside or "sample_rate_Hz" in rec.meta:
        return None
    return UnitSlip(*fitting[0])


def _slip_fits(rec: Recording, rate_Hz: float, f1_Hz: float) -> bool:
    """At the corrected rate ``rate_Hz`` [Hz] the recording is a usual one that
    resolves the model and its drive."""
    low, high = ACQUISITION_RATES_HZ
    return (low <= rate_Hz <= high and _resolves_modes(rate_Hz, f1_Hz)
            and _drive_resolved(rate_Hz, _meta_frequency(rec)))


# ------------------------------------------------------------------------ messages


def _hz(f_Hz: float) -> str:
    """A frequency [Hz] to three significant digits in Hz, kHz or MHz."""
    f = float(f"{f_Hz:.3g}")  # rounded first: 999.99 Hz is "1 kHz", not "1e+03 Hz"
    for scale, unit in ((1e6, "MHz"), (1e3, "kHz")):
        if abs(f) >= scale:
            return f"{f / scale:.3g} {unit}"
    return f"{f:.3g} Hz"


def _record_again(f1_Hz: float) -> str:
    return (f"record again at ≥ {_hz(min_sample_rate(f1_Hz))} "
            f"({SAMPLES_PER_MODE_PERIOD:g} samples per period of the slowest mode)")


def _said(rec: Recording) -> str:
    """What the file says its sample rate is, and where that comes from."""
    rate = _hz(rec.sample_rate_Hz)
    if "sample_rate_Hz" in rec.meta:
        return (f"sampled at {rate} (sample_rate_Hz: {rec.meta['sample_rate_Hz']} in its "
                f"metadata, as its time column says)")
    return (f"sampled at {rate} by its time column (a step of {rec.dt:.3g} s; no "
            f"sample_rate_Hz in its metadata)")


def _edge_clause(rec: Recording, f1_Hz: float) -> str:
    """Why an edge's response needs the modes resolved, for this drive."""
    waveform = rec.drive.waveform
    if waveform == "step":
        return "and a step response is those dynamics (the ringing after its edge)"
    if waveform == "sawtooth":
        return (f"and a sawtooth's flyback, one sample long, lasts {rec.dt:.3g} s here, "
                f"{rec.dt * f1_Hz:.3g} periods of that mode: no abrupt edge for it")
    return "and the response to its voltage edges is those dynamics"


def _mode_clause(rec: Recording, f1_Hz: float) -> str:
    return (f"nothing faster than {_hz(_nyquist(rec.sample_rate_Hz))} shows in it, but "
            f"the model's slowest mode rings at {_hz(f1_Hz)}: the samples cannot resolve "
            f"any of the actuator's dynamics, {_edge_clause(rec, f1_Hz)}")


def _drive_clause(rec: Recording) -> str:
    drive = rec.drive
    where = "inferred from its voltage" if _meta_frequency(rec) is None else "in its metadata"
    return (f"its {drive.waveform} drive at {_hz(drive.frequency_Hz)} ({where}) is at or "
            f"above the Nyquist frequency {_hz(_nyquist(rec.sample_rate_Hz))}: the samples "
            f"cannot resolve the drive itself")


def _where(rec: Recording) -> str:
    return rec.source if rec.source is not None else rec.name


def sampling_problem(rec: Recording, actuator: Actuator, *,
                     f1_Hz: float | None = None) -> RecordingError | None:
    """Why ``rec``'s samples cannot resolve ``actuator``, or None.

    Refused: a recording with an abrupt edge (:func:`has_edge`) whose Nyquist frequency
    is not above the slowest mode ``f1_Hz`` [Hz] (default: :func:`slowest_mode_Hz`
    under the recording's drive), and any recording whose periodic drive is at or above
    its Nyquist frequency. The message says the rate the file gave, the model's time
    scale, the likely unit slip (:func:`unit_slip`) when one explains it, and the fix.
    """
    f1 = slowest_mode_Hz(actuator, _drive_context(rec)) if f1_Hz is None else f1_Hz
    return _judge(rec, f1)[0]


def _judge(rec: Recording, f1_Hz: float) -> tuple[RecordingError | None, UnitSlip | None]:
    """:func:`sampling_problem`'s error and the unit slip it names (or None each)."""
    if not (math.isfinite(f1_Hz) and f1_Hz > 0):
        return None, None  # no ringing time scale to judge against
    rate = rec.sample_rate_Hz
    modes_lost = has_edge(rec) and not _resolves_modes(rate, f1_Hz)
    drive_lost = not _drive_resolved(rate, rec.drive.frequency_Hz)
    if not (modes_lost or drive_lost):
        return None, None
    clauses = [_mode_clause(rec, f1_Hz)] if modes_lost else []
    clauses += [_drive_clause(rec)] if drive_lost else []
    problem = f"{_said(rec)}: " + "; ".join(clauses)
    slip = unit_slip(rec, f1_Hz)
    if slip is None:
        fix = _plain_fix(rec, f1_Hz, modes_lost=modes_lost)
        return RecordingError(_where(rec), None, problem, fix), None
    return RecordingError(_where(rec), None, f"{problem}. {slip.sentence()}",
                          slip.fix(rec, f1_Hz)), slip


def _plain_fix(rec: Recording, f1_Hz: float, *, modes_lost: bool) -> str:
    """The fix when no unit slip explains the file: a faster recording, or metadata
    that agree with the voltage."""
    fixes = []
    stated = _meta_frequency(rec)
    if stated is not None and not _drive_resolved(rec.sample_rate_Hz, stated):
        seen = _voltage_frequency(rec)
        if seen:  # the voltage, by the time column, repeats at another frequency
            fixes.append(f"check frequency_Hz: its voltage repeats at {_hz(seen)} by the "
                         f"time column")
    if modes_lost:
        fixes.append(_record_again(f1_Hz))
    elif not fixes:
        fixes.append(f"record at more than twice the drive frequency "
                     f"({_hz(2 * rec.drive.frequency_Hz)})")
    fixes.append("convert the time column to seconds if it is in another unit")
    return "; ".join(fixes)


def _companion(rec: Recording, refused: Sequence[tuple[Recording, UnitSlip]],
               f1_Hz: float) -> RecordingError | None:
    """``rec`` (not refused on its own) refused beside recordings refused for a unit
    slip at the same sample rate: the same export, so likely the same slip."""
    if _resolves_modes(rec.sample_rate_Hz, f1_Hz) or "sample_rate_Hz" in rec.meta:
        return None
    same = [(r, s) for r, s in refused
            if abs(r.sample_rate_Hz - rec.sample_rate_Hz) <= UNIFORM_RTOL * r.sample_rate_Hz]
    if not same:
        return None
    names = ", ".join(r.name for r, _ in same)
    slip = UnitSlip(same[0][1].factor, same[0][1].unit, same[0][1].factor * rec.sample_rate_Hz)
    problem = (f"{_said(rec)}, like {names}, whose dynamics that rate cannot resolve: its "
               f"{rec.drive.waveform} drive is slow enough to show at this rate, but it "
               f"comes from the same export, so its time column is likely in {slip.unit} "
               f"too. {slip.sentence()}")
    return RecordingError(_where(rec), None, problem, slip.fix(rec, f1_Hz))


def sampling_problems(recordings: Sequence[Recording],
                      actuator: Actuator) -> list[RecordingError]:
    """Every recording of ``recordings`` whose sampling cannot resolve ``actuator``
    (:func:`sampling_problem`, and the recordings beside them at the same rate that
    :func:`_companion` names), in the order given."""
    cache: dict = {}
    errors: dict[int, RecordingError] = {}
    slipped: list[tuple[Recording, UnitSlip]] = []
    for i, rec in enumerate(recordings):
        error, slip = _judge(rec, _mode_for(rec, actuator, cache))
        if error is not None:
            errors[i] = error
        if slip is not None:
            slipped.append((rec, slip))
    for i, rec in enumerate(recordings):
        if i not in errors and slipped:
            error = _companion(rec, slipped, _mode_for(rec, actuator, cache))
            if error is not None:
                errors[i] = error
    return [errors[i] for i in sorted(errors)]


def check_sample_rates(recordings: Sequence[Recording], actuator: Actuator) -> None:
    """Refuse, before any fitting, recordings whose samples cannot resolve ``actuator``.

    ``recordings`` the loaded recordings; ``actuator`` the model they will be fitted
    to (its stick chain's slowest mode is the time scale). Raises one
    :class:`~stickslip_jax.io.RecordingError` for one bad file, and the command line's
    ``RecordingErrors`` (one line per file) for several; returns None when every
    recording can be used. Takes milliseconds: no simulation, one small compiled
    program (the contact stiffness) shared with :mod:`.informative`.
    """
    errors = sampling_problems(list(recordings), actuator)
    if len(errors) == 1:
        raise errors[0]
    if errors:
        # Lazily: the aggregate lives with the command line (one error line per file).

        raise RecordingErrors(errors)

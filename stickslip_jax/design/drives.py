"""The drives a plan chooses from: what the amplifier can play and the recorder keep.

A candidate is a :class:`~stickslip_jax.synthetic.DriveSpec` of one *unit* duration (a
few periods, as the paper's protocol records); a plan takes a candidate a whole number
of times, one recording that many units long. The grid spans the amplitudes and
frequencies the user's amplifier allows (:class:`DriveLimits`), both sawtooth
directions, a sine per frequency and a step per amplitude: the waveforms the recording
format names.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..synthetic import DriveSpec

UNIT_PERIODS = 5
"""Periods per unit of a periodic candidate, as the paper's protocol records."""
SHORTEST_UNIT_S = 0.02
"""The shortest unit [s] (the protocol's 500 Hz recordings: ten periods)."""
SAMPLES_PER_PERIOD = 25
"""The fewest samples per period of a candidate: the highest frequency is at most the
sample rate over this (a sawtooth's ramp then has 24 samples)."""


@dataclass(frozen=True)
class DriveLimits:
    """What the amplifier and recorder allow: amplitudes up to ``max_voltage_V`` [V],
    frequencies from ``min_frequency_Hz`` to ``max_frequency_Hz`` [Hz], recordings at
    ``sample_rate_Hz`` [Hz], each unit at most ``longest_unit_s`` [s]."""

    max_voltage_V: float
    min_frequency_Hz: float
    max_frequency_Hz: float
    sample_rate_Hz: float
    longest_unit_s: float

    def __post_init__(self):
        for name in ("max_voltage_V", "min_frequency_Hz", "max_frequency_Hz",
                     "sample_rate_Hz", "longest_unit_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if self.min_frequency_Hz > self.max_frequency_Hz:
            raise ValueError(f"min_frequency_Hz {self.min_frequency_Hz:g} is above "
                             f"max_frequency_Hz {self.max_frequency_Hz:g}")
        if self.max_frequency_Hz > self.sample_rate_Hz / SAMPLES_PER_PERIOD:
            raise ValueError(
                f"max_frequency_Hz {self.max_frequency_Hz:g} leaves fewer than "
                f"{SAMPLES_PER_PERIOD} samples per period at {self.sample_rate_Hz:g} Hz: "
                f"at most {self.sample_rate_Hz / SAMPLES_PER_PERIOD:g} Hz")

    @classmethod
    def from_recordings(cls, recordings: Sequence, *, max_voltage_V: float | None = None,
                        min_frequency_Hz: float | None = None,
                        max_frequency_Hz: float | None = None) -> DriveLimits:
        """Limits that stay where the user's recordings went unless told otherwise:
        the largest voltage they drove, their lowest frequency, four times their
        highest (within :data:`SAMPLES_PER_PERIOD` of their sample rate), units no
        longer than their longest recording."""
        # To 9 digits: a rate read from a time column carries rounding (24999.9999998).
        rate = float(f"{min(r.sample_rate_Hz for r in recordings):.9g}")
        freqs = [r.drive.frequency_Hz for r in recordings
                 if r.drive.frequency_Hz is not None and r.drive.frequency_Hz > 0]
        longest = max(r.n * r.dt for r in recordings)
        top = rate / SAMPLES_PER_PERIOD
        if max_voltage_V is None:
            max_voltage_V = max(float(np.max(np.abs(r.voltage_V))) for r in recordings)
        if min_frequency_Hz is None:
            min_frequency_Hz = max(min(freqs, default=50.0), 2.0 / longest)
        if max_frequency_Hz is None:
            max_frequency_Hz = min(4.0 * max(freqs, default=500.0), top)
        return cls(float(max_voltage_V), float(min_frequency_Hz), float(max_frequency_Hz),
                   float(rate), float(longest))


def unit_duration(frequency_Hz: float | None, limits: DriveLimits) -> float:
    """One unit of a candidate [s]: :data:`UNIT_PERIODS` periods, at least
    :data:`SHORTEST_UNIT_S`, at most the limits' longest unit (whole periods); a step's
    is the shortest unit times 2.5 (the protocol's 50 ms)."""
    if frequency_Hz is None:
        return min(2.5 * SHORTEST_UNIT_S, limits.longest_unit_s)
    periods = max(UNIT_PERIODS, math.ceil(SHORTEST_UNIT_S * frequency_Hz))
    periods = max(1, min(periods, math.floor(limits.longest_unit_s * frequency_Hz)))
    return round(periods / frequency_Hz, 12)


def _rounded(x: float) -> float:
    """Three significant digits: the grid's values as a person would set them."""
    return float(f"{x:.3g}")


def candidate_drives(limits: DriveLimits, *, amplitudes: int = 3, frequencies: int = 5,
                     sines: bool = True, steps: bool = True) -> list[DriveSpec]:
    """The grid (module docstring): ``amplitudes`` evenly up to the largest voltage,
    ``frequencies`` log-spaced over the allowed band, sawtooth both ways at each, a sine
    at the middle amplitude per frequency and a step per amplitude; one unit each."""
    volts = [_rounded(limits.max_voltage_V * (k + 1) / amplitudes)
             for k in range(amplitudes)]
    if frequencies == 1 or limits.min_frequency_Hz == limits.max_frequency_Hz:
        freqs = [_rounded(limits.min_frequency_Hz)]
    else:
        freqs = sorted({_rounded(f) for f in np.geomspace(
            limits.min_frequency_Hz, limits.max_frequency_Hz, frequencies)})
    freqs = [min(max(f, limits.min_frequency_Hz), limits.max_frequency_Hz) for f in freqs]
    out = [DriveSpec("sawtooth", a, f, d, unit_duration(f, limits))
           for a in volts for f in freqs for d in ("forward", "backward")]
    if sines:
        mid = volts[len(volts) // 2]
        out += [DriveSpec("sine", mid, f, None, unit_duration(f, limits)) for f in freqs]
    if steps:
        out += [DriveSpec("step", a, None, None, unit_duration(None, limits)) for a in volts]
    return out

"""Sensor noise level estimated from a recording itself, without a model.

Two robust estimators, both based on the median absolute deviation (MAD), which
ignores the sparse large values that slip edges and step fronts produce:

- period repeatability (periodic drives): in steady state a sine or sawtooth response
  repeats every period up to a constant advance (the step per period), so
  ``Δ(x[k+P] − x[k])`` is noise alone, a combination of four samples: std = 2σ.
  The first third of the trace (start-up periods) is left out.
- third differences (any trace): smooth motion sampled finely has tiny third
  differences, white noise has std √20·σ. Ringing near Nyquist/4 and above leaks
  in, so this is an upper bound on stepping traces at high drive frequency.

Position-spectrum levels are not used: a stick-slip trace is not smooth, and its
slip edges fill the upper band of the spectrum with signal.
"""

from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826
"""σ / MAD for a Gaussian."""


def _robust_std(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    return float(MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


def sigma_from_differences(x) -> float:
    """Noise std [units of x] from the MAD of third differences."""
    x = np.asarray(x, dtype=float)
    if x.size < 8:
        raise ValueError("at least 8 samples are needed to estimate the noise")
    return _robust_std(np.diff(x, 3)) / np.sqrt(20.0)


def sigma_from_periods(x, samples_per_period: float, *, min_periods: float = 2.0,
                       skip_fraction: float = 1 / 3) -> float | None:
    """Noise std [units of x] from period-to-period repeatability, or None when the
    period is not a whole number of samples (to 1 %) or too few periods remain."""
    x = np.asarray(x, dtype=float)
    p = int(round(samples_per_period))
    if p < 4 or abs(samples_per_period - p) > 0.01:
        return None
    tail = x[int(len(x) * skip_fraction):]
    if len(tail) < min_periods * p + 2:
        return None
    return _robust_std(np.diff(tail[p:] - tail[:-p])) / 2.0


def noise_sigma(recording) -> float:
    """Sensor noise std [m] of a recording's position: period repeatability where
    the drive is periodic and whole periods fit, else third differences."""
    q = np.asarray(recording.position_m, dtype=float)
    drive = recording.drive
    if drive.waveform in ("sine", "sawtooth") and drive.frequency_Hz > 0:
        s = sigma_from_periods(q, recording.sample_rate_Hz / drive.frequency_Hz)
        if s is not None:
            return s
    return sigma_from_differences(q)

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

How well σ is known (:func:`noise_sigma_relative_se`) matters as much as σ: a residual
whose mean ``(e/σ)²`` exceeds 1 by less than that uncertainty allows is at the noise
level as far as the data can tell.
"""

from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826
"""σ / MAD for a Gaussian."""


def _robust_std(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    return float(MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


MAD_RELATIVE_VARIANCE = 1.3605
"""``n·var(σ̂)/σ²`` of the MAD estimate of a Gaussian's σ from ``n`` independent
samples (asymptotic; its efficiency is 37 % of the standard deviation's)."""

SE_BLOCKS = 8
"""Contiguous blocks whose spread gives the noise estimate's standard error."""


def _third_differences(x: np.ndarray) -> tuple[np.ndarray, float]:
    """Third differences of ``x`` and their noise std per unit σ (√20)."""
    return np.diff(x, 3), np.sqrt(20.0)


def sigma_from_differences(x) -> float:
    """Noise std [units of x] from the MAD of third differences."""
    x = np.asarray(x, dtype=float)
    if x.size < 8:
        raise ValueError("at least 8 samples are needed to estimate the noise")
    d, gain = _third_differences(x)
    return _robust_std(d) / gain


def sigma_from_periods(x, samples_per_period: float, *, min_periods: float = 2.0,
                       skip_fraction: float = 1 / 3) -> float | None:
    """Noise std [units of x] from period-to-period repeatability, or None when the
    period is not a whole number of samples (to 1 %) or too few periods remain."""
    x = np.asarray(x, dtype=float)
    p = int(round(samples_per_period))
    if p < 4 or abs(samples_per_period - p) > 0.01:
        return None
    d = _period_differences(x, p, min_periods, skip_fraction)
    return None if d is None else _robust_std(d) / 2.0


def _period_differences(x: np.ndarray, p: int, min_periods: float,
                        skip_fraction: float) -> np.ndarray | None:
    """``Δ(x[k+p] − x[k])`` over the trace less its first ``skip_fraction`` (noise
    alone in steady state, std 2σ), or None when fewer than ``min_periods`` periods
    remain."""
    tail = x[int(len(x) * skip_fraction):]
    if len(tail) < min_periods * p + 2:
        return None
    return np.diff(tail[p:] - tail[:-p])


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


def _noise_samples(recording) -> np.ndarray:
    """The combination of samples :func:`noise_sigma` takes the MAD of (period
    differences where they apply, else third differences)."""
    q = np.asarray(recording.position_m, dtype=float)
    drive = recording.drive
    if drive.waveform in ("sine", "sawtooth") and drive.frequency_Hz > 0:
        period = recording.sample_rate_Hz / drive.frequency_Hz
        p = int(round(period))
        if p >= 4 and abs(period - p) <= 0.01:
            d = _period_differences(q, p, 2.0, 1 / 3)
            if d is not None:
                return d
    return _third_differences(q)[0]


def noise_sigma_relative_se(recording) -> float:
    """Standard error of :func:`noise_sigma`, relative to it [-].

    The larger of two estimates: the spread of the estimate over
    :data:`SE_BLOCKS` contiguous blocks of the trace, divided by √blocks (this sees
    what the Gaussian formula does not: signal leaking into the differences in some
    stretches, the correlation between overlapping differences), and the asymptotic
    MAD formula for independent Gaussian samples, ``√(1.36/n)``.
    """
    d = _noise_samples(recording)
    n = d.size
    formula = np.sqrt(MAD_RELATIVE_VARIANCE / max(n, 1))
    if n < 16 * SE_BLOCKS:
        return float(formula)
    blocks = np.array([_robust_std(b) for b in np.array_split(d, SE_BLOCKS)])
    centre = float(np.mean(blocks))
    if centre <= 0:
        return float(formula)
    spread = float(np.std(blocks, ddof=1)) / centre / np.sqrt(SE_BLOCKS)
    return float(max(spread, formula))

"""Steady-state velocity of a sawtooth-driven slider, measured phase-locked.

A straight-line fit over a non-whole number of periods is biased by where in the
period it starts and stops, so the position is read at the same phase of every
period: just before each flyback edge, at t_j = j/f − 1/fs (the last sample of
period j when fs/f is whole; linear interpolation between samples otherwise). The
first ``settle`` periods (start-up from rest) are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..regime import drive_steps


@dataclass(frozen=True)
class PointVelocity:
    """``velocity_m_s`` [m/s], ``step_m`` [m] per period, ``swing_m`` [m] peak-to-peak
    within the last period, ``regime`` ``"stepping"`` or ``"scanning"``, and
    ``period_end_q_m`` [m] the position at each period end (j = 1..periods)."""

    velocity_m_s: float
    step_m: float
    swing_m: float
    regime: str
    period_end_q_m: np.ndarray


def period_end_positions(q, frequency_Hz: float, sample_rate_Hz: float,
                         periods: int) -> np.ndarray:
    """q [m] at t_j = j/f − 1/fs, j = 1..periods (linear interpolation) [m]."""
    x = np.arange(1, periods + 1) * sample_rate_Hz / frequency_Hz - 1.0
    return np.interp(x, np.arange(len(q)), np.asarray(q))


def steady_velocity(q, frequency_Hz: float, sample_rate_Hz: float, periods: int,
                    settle: int = 2) -> PointVelocity:
    """Phase-locked steady-state velocity of one trace q [m] sampled from t = 0."""
    if not 0 <= settle < periods:
        raise ValueError(f"settle must be in [0, periods), got {settle} with {periods}")
    ends = period_end_positions(q, frequency_Hz, sample_rate_Hz, periods)
    start = ends[settle - 1] if settle > 0 else float(np.asarray(q)[0])
    n = periods - settle
    step = (ends[-1] - start) / n
    per = sample_rate_Hz / frequency_Hz
    last = np.asarray(q)[int(np.floor((periods - 1) * per)): int(np.ceil(periods * per))]
    swing = float(np.ptp(last)) if last.size else 0.0
    # Stepping or scanning by the one definition every command uses (stickslip_jax.regime).
    regime = "stepping" if drive_steps(step, swing) else "scanning"
    return PointVelocity(float(step * frequency_Hz), float(step), swing, regime, ends)

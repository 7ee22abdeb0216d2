"""Step length against amplitude and the 0-amplitude threshold (Nguyen 2012, Fig. 5).

Below a threshold amplitude the contact never leaves its elastic region: the slider
follows the piezo back and forth and makes no net step. The threshold is read from a
step-vs-amplitude curve as the smallest amplitude at which the phase-locked step per
period reaches ``min_step`` (linear interpolation between grid amplitudes).
"""

from __future__ import annotations

import numpy as np

from ..model.actuator import Actuator
from .grid import DriveGrid
from .map import velocity_map


def step_vs_amplitude(actuator: Actuator, amplitudes, frequency_Hz: float, *,
                      direction: str = "forward", periods: int = 6, settle: int = 2
                      ) -> np.ndarray:
    """Steady step per period [m] at each amplitude [V] (one batched sweep)."""
    grid = DriveGrid.make(np.asarray(amplitudes, float), [frequency_Hz], direction)
    return velocity_map(actuator, grid, periods=periods, settle=settle).step_m


def zero_amplitude_threshold(amplitudes, steps, *, min_step: float = 1e-9) -> float:
    """Smallest amplitude [V] where |step| reaches ``min_step`` [m]; NaN if never
    reached, the first amplitude if already reached there."""
    a = np.asarray(amplitudes, float)
    s = np.abs(np.asarray(steps, float))
    order = np.argsort(a)
    a, s = a[order], s[order]
    above = np.flatnonzero(s >= min_step)
    if above.size == 0:
        return float("nan")
    k = int(above[0])
    if k == 0:
        return float(a[0])
    return float(a[k - 1] + (min_step - s[k - 1]) * (a[k] - a[k - 1]) / (s[k] - s[k - 1]))

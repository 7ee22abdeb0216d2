"""Drive grids for sweeps: amplitude × frequency × direction of a sawtooth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DIRECTION_CHOICES = ("forward", "backward", "both")

MAX_VALUES = 1_000_000
"""The most values one ``start:stop:count`` may ask for: far beyond any sweep the
simulator can run (a grid's work is refused well before), and refused before the values
are made (a count of 10⁹ would take 8 GB)."""


def parse_values(text: str, *, name: str) -> np.ndarray:
    """``"start:stop:count"`` (inclusive, evenly spaced) or ``"a,b,c"`` → floats.

    Raises ValueError naming ``name`` and the expected forms.
    """
    text = text.strip()
    try:
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise ValueError
            start, stop, count = float(parts[0]), float(parts[1]), int(parts[2])
            if count < 1:
                raise ValueError
            if count > MAX_VALUES:
                raise OverflowError
            values = np.linspace(start, stop, count)
        else:
            values = np.array([float(v) for v in text.split(",") if v.strip()])
    except OverflowError:
        raise ValueError(f"{name}: {text!r} asks for more than {MAX_VALUES:,} values; give "
                         f"a smaller count") from None
    except ValueError:
        raise ValueError(f"{name}: cannot read {text!r}; give start:stop:count (inclusive, "
                         f"e.g. 10:80:15) or a comma-separated list (e.g. 50,100,200)") from None
    if values.size == 0 or not np.all(np.isfinite(values)):
        raise ValueError(f"{name}: no finite values in {text!r}; give start:stop:count or a "
                         f"comma-separated list")
    return values


def direction_flags(directions: str) -> list[bool]:
    """The ``backward`` flags that ``directions`` ('forward', 'backward' or 'both')
    stands for; ValueError for anything else. (Its length counts a grid's points
    before the grid is made.)"""
    if directions not in DIRECTION_CHOICES:
        raise ValueError(f"directions must be one of {DIRECTION_CHOICES}, got "
                         f"{directions!r}")
    return {"forward": [False], "backward": [True], "both": [False, True]}[directions]


@dataclass(frozen=True)
class DriveGrid:
    """Flat list of sawtooth drives: ``amplitude_V`` [V], ``frequency_Hz`` [Hz] and
    ``backward`` (bool), one entry per grid point, amplitude varying fastest."""

    amplitude_V: np.ndarray
    frequency_Hz: np.ndarray
    backward: np.ndarray

    def __len__(self) -> int:
        return int(self.amplitude_V.size)

    @staticmethod
    def make(amplitudes, frequencies, directions: str = "both") -> DriveGrid:
        """Cartesian product (direction slowest, amplitude fastest)."""
        a = np.asarray(amplitudes, dtype=float).ravel()
        f = np.asarray(frequencies, dtype=float).ravel()
        dirs = direction_flags(directions)
        if np.any(a <= 0):
            raise ValueError("amplitudes must be > 0 V")
        if np.any(f <= 0):
            raise ValueError("frequencies must be > 0 Hz")
        d_grid, f_grid, a_grid = np.meshgrid(np.array(dirs), f, a, indexing="ij")
        return DriveGrid(a_grid.ravel(), f_grid.ravel(), d_grid.ravel())

    def direction_names(self) -> list[str]:
        return ["backward" if b else "forward" for b in self.backward]

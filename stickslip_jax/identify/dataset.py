"""A set of recordings packed for one batched simulation, with what fitting needs.

Recordings are padded to a common length (voltage repeated, residuals masked), so
the whole set goes through one vmapped scan. For each recording the dataset keeps
its regime, the measured output [m], its peak-to-peak range (the NRMSE scale) and,
for sawtooth drives, the sample indices of the period ends, where the phase-locked
step length is measured (period end to period end: a straight-line fit over a
non-whole number of periods would be biased by the sawtooth's own shape).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io import Recording
from ..model.base import DriveContext
from ..regime import drive_steps
from ..simulate import drive_context, pad_voltages, stack_drives


def period_ends(recording: Recording, *, skip_first: int = 1) -> np.ndarray:
    """Indices of the last sample of each whole sawtooth period [-].

    The first ``skip_first`` periods (start-up from rest) are left out of the
    returned list's differences by starting at the end of period ``skip_first``.
    Empty for non-sawtooth drives or when fewer than two ends remain.
    """
    info = recording.drive
    if info.waveform != "sawtooth" or not info.frequency_Hz:
        return np.zeros(0, dtype=int)
    per = recording.sample_rate_Hz / info.frequency_Hz
    n_periods = int(np.floor(recording.n / per + 1e-9))
    ends = np.round(np.arange(1, n_periods + 1) * per).astype(int) - 1
    ends = ends[ends < recording.n][skip_first - 1 if skip_first > 0 else 0:]
    return ends if len(ends) >= 2 else np.zeros(0, dtype=int)


def step_lengths(q: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Phase-locked displacement per period [m] (``q`` at successive period ends)."""
    return np.diff(np.asarray(q)[ends]) if len(ends) >= 2 else np.zeros(0)


def length_buckets(lengths, *, max_waste: float = 0.25):
    """Group recordings of similar length: ``((indices, padded length), ...)``.

    A batched scan costs (recordings × longest length), so a set mixing 0.02 s and
    0.1 s recordings wastes most of its work on padding. Sorted by length, a new group
    starts when a recording is shorter than ``1 − max_waste`` of its group's longest.
    """
    order = np.argsort(-np.asarray(lengths), kind="stable")
    groups: list[list[int]] = []
    for i in order:
        if groups and lengths[i] >= (1.0 - max_waste) * lengths[groups[-1][0]]:
            groups[-1].append(int(i))
        else:
            groups.append([int(i)])
    return tuple((tuple(sorted(g)), int(lengths[g[0]])) for g in groups)


def mean_step_length(rec, q) -> float:
    """Mean phase-locked step per sawtooth period [m] (period end to period end, the
    start-up period left out); NaN when the recording has fewer than two whole
    periods."""
    steps = step_lengths(q, period_ends(rec))
    return float(np.mean(steps)) if steps.size else float("nan")


def classify_regime(rec, q=None) -> str:
    """``step``, ``sine``, ``scanning``, ``stepping_forward``/``stepping_backward``.

    A sawtooth drive steps or scans by :func:`stickslip_jax.regime.drive_steps`: its
    phase-locked mean step per period against the median peak-to-peak output within a
    period.
    """
    drive = rec.drive
    if drive.waveform != "sawtooth":
        return drive.waveform
    q = rec.position_m if q is None else q
    step = abs(mean_step_length(rec, q))
    per = max(int(round(rec.sample_rate_Hz / drive.frequency_Hz)), 2)
    swing = float(np.median([np.ptp(q[i:i + per]) for i in range(0, len(q) - per + 1, per)]))
    if not np.isfinite(step) or not drive_steps(step, swing):
        return "scanning"
    return "stepping_backward" if drive.is_backward else "stepping_forward"


@dataclass(frozen=True, eq=False)  # identity equality: it is static data under jit
class Dataset:
    """Recordings packed for fitting.

    Attributes: ``recordings``; ``voltages`` (B, T) [V] padded; ``measured`` (B, T) [m]
    padded with the last value; ``mask`` (B, T) 1 on real samples; ``dt`` (B,) [s];
    ``drives`` (a DriveContext of (B,) fields); ``scale`` (B,) peak-to-peak of each
    measured trace [m]; ``ends`` the period-end indices per recording; ``buckets``
    groups of recordings of similar length, simulated as separate batches.
    """

    recordings: tuple[Recording, ...]
    voltages: np.ndarray
    measured: np.ndarray
    mask: np.ndarray
    dt: np.ndarray
    drives: DriveContext
    scale: np.ndarray
    ends: tuple[np.ndarray, ...]
    buckets: tuple[tuple[tuple[int, ...], int], ...] = ()

    @staticmethod
    def from_recordings(recordings) -> Dataset:
        recordings = tuple(recordings)
        if not recordings:
            raise ValueError("no recordings to fit")
        missing = [r.name for r in recordings if r.position is None]
        if missing:
            raise ValueError(f"recordings without a position column cannot be fitted: "
                             f"{', '.join(missing)}")
        voltages, lengths = pad_voltages([r.voltage_V for r in recordings])
        measured, _ = pad_voltages([r.position_m for r in recordings])
        mask = (np.arange(voltages.shape[1])[None, :] < lengths[:, None]).astype(float)
        scale = np.array([np.ptp(r.position_m) for r in recordings])
        scale = np.where(scale > 0, scale, 1e-9)
        return Dataset(
            recordings=recordings, voltages=voltages, measured=measured, mask=mask,
            dt=np.array([r.dt for r in recordings]),
            drives=stack_drives([drive_context(r) for r in recordings]),
            scale=scale, ends=tuple(period_ends(r) for r in recordings),
            buckets=length_buckets(lengths),
        )

    @property
    def names(self) -> list[str]:
        return [r.name for r in self.recordings]

    @property
    def regimes(self) -> list[str]:
        return [r.regime for r in self.recordings]

    def __len__(self) -> int:
        return len(self.recordings)

    def subset(self, keep) -> Dataset:
        """The dataset of the recordings for which ``keep(recording)`` is true."""
        return Dataset.from_recordings([r for r in self.recordings if keep(r)])


def check_readable(actuator, data: Dataset) -> None:
    """Raise ValueError when ``actuator``'s sensor holds quantities per recording
    (:meth:`~stickslip_jax.model.base.AbstractOutputMap.recordings`) for another
    number of recordings than ``data``'s: its recording r would read another's."""
    count = actuator.output_map.recordings()
    if count and count != len(data):
        raise ValueError(f"the model's sensor holds a quantity per recording for {count} "
                         f"recordings, the dataset has {len(data)}: fit it on this set")

"""A wall-clock budget for the optional work of a diagnosis.

The diagnosis's core (baseline, score, sizing, the first refits of round one, the
learned correction when nothing explains the residual) always runs. What only might
change the answer (fallback refits, second looks, re-identifications, later rounds)
is skipped, and said to be, when its estimated duration would carry the run past the
budget: a user asked for a diagnosis in minutes, not one that silently takes an hour.
"""

from __future__ import annotations

import time

DEFAULT_TIME_BUDGET_S = 540.0
"""Default budget of a diagnosis [s]: nine minutes, so that a 17-recording set with its
report and figures ends within ten on a 2-core CPU."""
REFIT_GUESS_S = 60.0
"""Duration assumed for a refit before any has been timed [s] (17 recordings of the
paper's protocol, 25 steps, 2-core CPU: 20-45 s without a drive stage)."""
DRIVE_STAGE_FACTOR = 2.5
"""How much longer a refit takes when the model has a drive (input) stage: the
hysteresis is then evaluated at every RK4 stage instead of once per sample interval.
Measured, same run: 102 s against 30-45 s (set_10), 92 against 22-38 s (a two-pole
amplifier), 108 against 20-31 s (another)."""


class Budget:
    """Elapsed time against ``total_s`` [s] (``None`` or ≤ 0: no limit) from ``start``
    (``time.perf_counter()``), with the refit durations seen so far."""

    def __init__(self, total_s: float | None, start: float | None = None):
        self.total_s = float(total_s) if total_s and total_s > 0 else None
        self.start = time.perf_counter() if start is None else start
        self.refit_walls: dict[bool, list[float]] = {False: [], True: []}
        self.skipped: list[str] = []

    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    def record_refit(self, wall_s: float, drive_stage: bool) -> None:
        """A refit took ``wall_s`` [s]; ``drive_stage``: its model had an input stage."""
        self.refit_walls[bool(drive_stage)].append(float(wall_s))

    def refit_estimate(self, drive_stage: bool = False) -> float:
        """A refit's expected duration [s]: the longest seen so far of its kind (with or
        without a drive stage), else the other kind's scaled by
        :data:`DRIVE_STAGE_FACTOR`, else :data:`REFIT_GUESS_S` (scaled alike)."""
        factor = {False: 1.0, True: DRIVE_STAGE_FACTOR}
        if self.refit_walls[drive_stage]:
            return max(self.refit_walls[drive_stage])
        other = self.refit_walls[not drive_stage]
        plain = max(other) / factor[not drive_stage] if other else REFIT_GUESS_S
        return plain * factor[drive_stage]

    def learned_estimate(self) -> float:
        """The learned correction's expected duration [s]: two fits of the baseline and
        the correction, each about as long as the quickest refit seen."""
        walls = self.refit_walls[False] + self.refit_walls[True]
        return 2.0 * min(walls, default=REFIT_GUESS_S)

    def allows(self, estimate_s: float, reserve_s: float = 0.0) -> bool:
        """Work of ``estimate_s`` [s] ends, with ``reserve_s`` [s] kept for what must
        follow, within the budget."""
        if self.total_s is None:
            return True
        return self.elapsed() + estimate_s + reserve_s <= self.total_s

    def skip(self, what: str) -> str:
        """Record ``what`` as skipped; the note to attach to it."""
        self.skipped.append(what)
        return (f"skipped: it would end past the time budget of {self.total_s:g} s "
                f"({self.elapsed():.0f} s spent)")

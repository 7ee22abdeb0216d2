"""What a refit pass is and what it reads: :class:`RefitPass` and :class:`RefitRound`.

A round of the diagnosis sizes the entries its scores point to and then runs its
refit passes in order (:data:`~.DEFAULT_PASSES`); each pass decides which sized entries
still waiting get a refit (every baseline parameter freed with the entry's own), from
the round's :class:`RefitRound`, and runs them through :meth:`RefitRound.refit`, which
records the pass's name on the entry (:attr:`~..results.CandidateResult.refit_pass`).
A pass is one small class: a new one is a new module and one line in
:data:`~.DEFAULT_PASSES` (or :data:`~.OPT_IN_PASSES`, run when asked for); a
configuration without it (``DiagnoseConfig(passes=...)``) is its ablation.
"""

from __future__ import annotations

import abc
import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

from ...model.actuator import Actuator
from ..catalogue import Candidate
from ..policy import Policy
from ..refit import RefitSetup, RoundStart, refit
from ..results import CandidateResult
from ..sizing import FreeSizing, HeldSizing


@dataclass(frozen=True)
class Reidentification:
    """What a re-identification with an entry attached starts from (round one of an
    identified baseline only)."""

    rss_identified: float
    """Whitened RSS of the identified baseline before its polish."""
    init: Actuator
    """The identification's start."""
    fix: dict
    """Quantities held (SI)."""
    staged: tuple[str, ...]
    """The identification steps before the joint one, which the re-identification
    repeats with the entry free (the refit that follows is the joint step)."""


@dataclass
class RefitRound:
    """One round's refits: where it starts, its sized entries best first, and what a
    pass needs to refit one."""

    setup: RefitSetup
    at: RoundStart
    ranked: list[CandidateResult]
    """The sized entries, best rank value first (:func:`~..rules.rank_value`)."""
    pool: Sequence[Candidate]
    """The catalogue entries tested this round."""
    held_sizings: dict[str, HeldSizing]
    """Per sized entry, its sizing with the baseline held (:mod:`..sizing`)."""
    free_sizings: dict[str, FreeSizing]
    """Per sized entry, its sizing with the baseline free to first order, where
    computed; a pass that carries one on replaces it here."""
    seeded: set[str]
    """Entries with seeds (a rugged cost in a nonlinear parameter)."""
    top: int
    """Entries refitted first at most (:attr:`~..config.DiagnoseConfig.top`)."""
    first_budgeted: bool
    """The first refits are skipped past the work budget (every round but the first)."""
    reidentification: Reidentification | None = None
    timings: dict[str, float] = field(default_factory=dict)
    """Wall time per phase [s], for display."""

    @property
    def policy(self) -> Policy:
        return self.setup.policy

    @property
    def say(self) -> Callable[[str], None]:
        return self.setup.problem.say

    @property
    def excess_or_none(self) -> float | None:
        """The round's excess over the noise, None when below
        :attr:`~..policy.Policy.excess_min` of ``N`` (no shares of it are taken)."""
        n_obs = self.setup.problem.n_obs
        return self.at.excess if self.at.excess > self.policy.excess_min * n_obs else None

    def entry(self, res: CandidateResult) -> tuple[Candidate, HeldSizing, FreeSizing | None]:
        """``(catalogue entry, held sizing, free sizing or None)`` of the sized
        ``res``."""
        return (next(c for c in self.pool if c.name == res.name),
                self.held_sizings[res.name], self.free_sizings.get(res.name))

    def refit(self, res: CandidateResult, by: RefitPass, *, budgeted: bool = True) -> None:
        """Refit ``res`` from the round's start (:func:`~..refit.refit`), as pass
        ``by``."""
        with self.attributed(res, by):
            refit(self.setup, self.at, res, *self.entry(res), budgeted=budgeted)

    @contextlib.contextmanager
    def attributed(self, res: CandidateResult, by: RefitPass):
        """Name pass ``by`` on ``res`` (:attr:`~..results.CandidateResult.refit_pass`)
        when the work inside changes its model."""
        before = res.actuator
        yield
        if res.actuator is not before:
            res.refit_pass = by.name

    def refit_all(self, entries: Sequence[CandidateResult], by: RefitPass) -> None:
        """:meth:`refit` each of ``entries`` in order."""
        for res in entries:
            self.refit(res, by)


class RefitPass(abc.ABC):
    """One pass over a round's sized entries: which still-waiting entries get a refit,
    and when. Its docstring says what it is for and on what evidence."""

    name: ClassVar[str]
    """Its name in reports, ``diagnosis.json`` and ablations."""
    reads: ClassVar[tuple[str, ...]] = ()
    """The :class:`~..policy.Policy` thresholds it decides by (the ablation moves
    each)."""

    @abc.abstractmethod
    def run(self, rnd: RefitRound) -> None:
        """Refit the entries this pass takes (through :meth:`RefitRound.refit`); set
        aside, with a note, those it rules out."""

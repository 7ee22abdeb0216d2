"""What a diagnosis returns: the :class:`Verdict`, each entry's :class:`CandidateResult`
with its :class:`CandidateStatus`, and the :class:`Diagnosis`."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..identify.dataset import Dataset
from ..model.actuator import Actuator
from .locate import RecordingResidual
from .policy import DEFAULT_POLICY, Policy
from .problem import FIRST_ORDER_REACH
from .records import NOT_JUDGED, NOT_SIZED, Acceptance, RefitOutcome, SizingOutcome

if TYPE_CHECKING:  # config -> passes -> refit -> results
    from .config import DiagnoseConfig


class Verdict(enum.StrEnum):
    """The diagnosis's conclusion (its value is what ``diagnosis.json`` and the command
    line print)."""

    AUGMENTED = "augmented"
    """Catalogue entries were accepted and what they leave is within the noise
    tolerance."""
    BASELINE_ADEQUATE = "baseline adequate"
    """The baseline's residual is at the noise level, or nothing structured is left."""
    UNEXPLAINED = "unexplained residual"
    """A structured residual remains and no entry was accepted."""
    PARTLY_EXPLAINED = "partly explained"
    """Entries were accepted, and what is left beside them is beyond the noise
    tolerance (:attr:`Diagnosis.left` says how far and where)."""


class CandidateStatus(enum.StrEnum):
    """Where an entry's round ended. An entry set aside (:data:`SET_ASIDE`) gets no
    further refit in that round; its note says why."""

    SCORED = "scored"
    """Scored only: below the score threshold, or not among those sized."""
    NOT_SIZED = "not sized"
    """After an acceptance, its ``|S|`` was below the share of the excess left."""
    SIZED = "sized"
    """Sized, waiting for a refit."""
    REFITTED = "refitted"
    """Refitted (from the baseline, or after a re-identification)."""
    SKIPPED = "skipped"
    """Its refit or re-identification would have passed the work budget."""
    REFIT_FAILED = "refit not possible"
    """No valid start for its refit."""
    NO_PROMISE = "no promise"
    """Wrong first-order sign, and its sizing raised the cost: no refit is spent on it."""
    NOT_REFITTED = "not refitted"
    """Sized but not refitted: a higher-ranked refit explained the residual."""
    OUT_OF_REACH = "out of reach"
    """Sized but not refitted: its sizings bound what its refit could remove below what
    any acceptance needs (:func:`~.rules.refit_reach`)."""
    CANNOT_RIVAL = "cannot rival"
    """Sized but not refitted: a refit would be accepted, and this entry's sizings bound
    what its refit could remove below what it would need to be preferred to it or named
    indistinguishable from it (:func:`~.rules.cannot_rival`)."""


SET_ASIDE = frozenset({CandidateStatus.NOT_SIZED, CandidateStatus.SKIPPED,
                       CandidateStatus.REFIT_FAILED, CandidateStatus.NO_PROMISE,
                       CandidateStatus.NOT_REFITTED, CandidateStatus.OUT_OF_REACH,
                       CandidateStatus.CANNOT_RIVAL})
"""The statuses of an entry given no further refit in its round."""


_NOT_REFITTED = RefitOutcome()
"""What :class:`CandidateResult`'s refit properties read when it was not refitted."""


def _from_record(record: str, name: str, absent=None) -> property:
    """A read-only property giving ``name`` of the entry's record ``record``
    (``sizing`` or ``refit``); ``absent``'s when that record is None."""
    def get(self):
        return getattr(getattr(self, record) or absent, name)
    kind = {"sizing": "SizingOutcome", "refit": "RefitOutcome",
            "decision": "Acceptance"}[record]
    return property(get, doc=f"Its {record}'s ``{name}`` (:class:`~.records.{kind}`).")


def _from_sizing(name: str) -> property:
    """:func:`_from_record` of the sizings."""
    return _from_record("sizing", name)


def _from_refit(name: str) -> property:
    """:func:`_from_record` of the refit (:data:`_NOT_REFITTED`'s when not refitted)."""
    return _from_record("refit", name, _NOT_REFITTED)


@dataclass
class CandidateResult:
    """One catalogue entry's score and, if refitted, its refit."""

    name: str
    probe: str = ""
    score: float = 0.0
    strength: float = 0.0
    sizing: SizingOutcome = NOT_SIZED
    """What its sizings removed (:mod:`.sizing`); the ``size_*`` properties read it."""
    refit: RefitOutcome | None = None
    """Its refit's record (:func:`~.refit.record_refit`); None when not refitted. The
    properties below (:attr:`rss_after`, :attr:`explained`, ...) read it."""
    refit_pass: str = ""
    """The refit pass whose refit it holds (:mod:`.passes`: ``first``, ``fallback``,
    ``rivals``, ``second_look``, ``reidentify``); empty when not refitted."""
    carried_on: bool = False
    """Its refit, stopped at its step cap, was carried on
    (:class:`~.passes.CarryOnDeciding`)."""
    refit_start: str = ""
    """Where its refit started: ``"held sizing"`` or ``"free sizing's point"``
    (:func:`~.refit.refit_start`); empty when not refitted."""
    refit_start_cost: float = np.nan
    """The whitened cost there."""
    implausible: str = ""
    """Why the refitted values are not the physics the entry names, in words; empty
    when they are (:meth:`~.catalogue.base.CatalogueEntry.implausible`). An implausible
    refit explains nothing and is never accepted (:mod:`.rules`)."""
    decision: Acceptance = NOT_JUDGED
    """The acceptance's decision on it (:class:`~.records.Acceptance`); the
    :attr:`accepted`, :attr:`partial` and :attr:`indistinguishable_from` properties
    read it."""
    note: str = ""
    """What happened to the entry, in words, for the reports (never read by a
    decision: :attr:`status` is)."""
    wall_s: float = 0.0
    status: CandidateStatus = CandidateStatus.SCORED
    """Where its round ended (:class:`CandidateStatus`)."""

    @property
    def refitted(self) -> bool:
        """It holds a refit (:attr:`refit`)."""
        return self.refit is not None

    size_drop = _from_sizing("drop")
    size_converged = _from_sizing("converged")
    size_drop_free = _from_sizing("drop_free")
    size_free_converged = _from_sizing("free_converged")
    size_free_reach = _from_sizing("free_reach")
    refit_converged = _from_refit("converged")
    actuator = _from_refit("actuator")
    params = _from_refit("params")
    rss_before = _from_refit("rss_before")
    rss_after = _from_refit("rss_after")
    nrmse_before = _from_refit("nrmse_before")
    nrmse_after = _from_refit("nrmse_after")
    criterion_delta = _from_refit("criterion_delta")
    added = _from_refit("added")
    explained = _from_refit("explained")
    chi2_after = _from_refit("chi2_after")
    adequate = _from_refit("adequate")
    material = _from_refit("material")
    removed_nm = _from_refit("removed_nm")
    removed_noise_share = _from_refit("removed_noise_share")
    held_out = _from_refit("held_out")
    predicts = _from_refit("predicts")
    param_draws = _from_refit("param_draws")
    accepted = _from_record("decision", "accepted")
    partial = _from_record("decision", "partial")
    indistinguishable_from = _from_record("decision", "indistinguishable_from")

    @property
    def size_free_extrapolated(self) -> bool:
        """That sizing ended where the baseline's first-order move passes
        :data:`~.problem.FIRST_ORDER_REACH`: its drop is not counted (:mod:`.sizing`)."""
        return bool(self.size_free_reach > FIRST_ORDER_REACH)

    @property
    def waiting(self) -> bool:
        """Not refitted, and not set aside (:data:`SET_ASIDE`): a later refit pass of
        the round may still take it."""
        return not self.refitted and self.status not in SET_ASIDE

    def set_aside(self, status: CandidateStatus, note: str) -> None:
        """Give the entry no further refit this round, with ``note`` saying why."""
        self.status, self.note = status, note

    def add_note(self, note: str, *, first: bool = False) -> None:
        """Join ``note`` to the entry's note (``; ``), after it or, ``first``, before."""
        parts = [note, self.note] if first else [self.note, note]
        self.note = "; ".join(filter(None, parts))


@dataclass
class Diagnosis:
    """Result of :func:`~stickslip_jax.diagnose.run.diagnose` (see its module
    docstring)."""

    data: Dataset
    sigmas: np.ndarray
    baseline: Actuator
    final: Actuator
    nrmse_baseline: np.ndarray
    nrmse_final: np.ndarray
    """Per recording NRMSE before and after, fractions [-] (``diagnosis.json``:
    ``nrmse_percent``)."""
    chi2_baseline: float
    chi2_final: float
    analyses_baseline: list[RecordingResidual]
    analyses_final: list[RecordingResidual]
    mismatch: list[dict]
    accepted: list[CandidateResult]
    rounds: list[list[CandidateResult]]
    not_testable: dict[str, str]
    unexplained: dict | None
    verdict: Verdict
    q_baseline: np.ndarray
    q_final: np.ndarray
    terms: list[str]
    timings: dict[str, float]
    notes: list[str] = field(default_factory=list)
    peaks_Hz: list[float] = field(default_factory=list)
    """Peaks of the baseline's residual spectrum shared by several recordings [Hz]:
    candidates for an unmodelled resonance (:func:`~.locate.residual_peaks`)."""
    numerical_error_m: np.ndarray | None = None
    """Per recording: the simulator's error at the final model, RMS, offset removed [m]
    (step doubling, :func:`~stickslip_jax.identify.residuals.numerical_error`)."""
    work: dict = field(default_factory=dict)
    """The work budget: its unit, ``total`` (None: no limit), the work ``spent`` and
    what was ``skipped`` (:meth:`.budget.Budget.record`)."""
    policy: Policy = DEFAULT_POLICY
    """The thresholds the diagnosis decided by (:class:`~.policy.Policy`)."""
    significance: dict = field(default_factory=dict)
    """The tolerance of practical significance and what it is made of
    (:meth:`.significance.Significance.record`)."""
    detection_limits: dict = field(default_factory=dict)
    """Per catalogue entry, the smallest strength a refit could name on these
    recordings (:mod:`.scores`): ``strength`` in ``unit``, ``effect_nm``, ``probe``."""
    config: DiagnoseConfig | None = None
    """How it ran (:class:`~.config.DiagnoseConfig`: the policy, rounds, step caps, the
    work budget)."""
    left: dict | None = None
    """When entries were accepted and the final residual is beyond the noise tolerance
    (verdict partly explained): its mean ``(e/σ)²`` against ``1 + tolerance``, the RMS
    beyond the tolerance [nm], the recordings beyond their own tolerance, and where
    (:func:`~.locate.mismatch_entries` of the final residual)."""

"""Frozen records of what a phase of the diagnosis made, read by the phases after it.

A record is made once, by the one function of its phase, and never changed: a later
pass that improves on it (a refit carried on, a re-identification) makes a new one.
:class:`SizingOutcome` is the sizing phase's (what an entry's sizings removed; the fits
themselves, to go on from, are :class:`~.sizing.HeldSizing` and
:class:`~.sizing.FreeSizing`), :class:`RefitOutcome` the refit phase's
(:func:`~.refit.record_refit`), :class:`Acceptance` the acceptance's
(:func:`~.run._accept`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..model.actuator import Actuator


@dataclass(frozen=True)
class SizingOutcome:
    """What an entry's sizings removed from the round's whitened cost (:mod:`.sizing`):
    with the baseline held (made by :func:`~.sizing.size_entries`) and with the baseline
    free to first order (added by :func:`~.sizing.record_free_sizing`, again when that
    sizing is carried on). The defaults are "not sized"."""

    drop: float = 0.0
    """What the sizing removed, the baseline held."""
    converged: bool = False
    """That sizing ended by its Gauss-Newton test (at an optimum of the entry's own
    parameters), not at its step cap."""
    drop_free: float = -np.inf
    """What the sizing removes with the baseline free to first order (never below
    :attr:`drop`; ``-inf`` when not computed)."""
    free_converged: bool = False
    """That sizing ended by its Gauss-Newton test (at its optimum)."""
    free_reach: float = np.nan
    """The largest move [θ] of a baseline coordinate that sizing's cost takes for
    granted (:meth:`~.problem.BaselineSpan.reach`; NaN when not computed)."""


NOT_SIZED = SizingOutcome()
"""The sizing record of an entry not sized."""


@dataclass(frozen=True)
class RefitOutcome:
    """What one refit of a catalogue entry gave (every baseline parameter free with the
    entry's own), against the round's start. Costs are whitened RSS ((e/σ)² summed over
    the samples). The defaults are "not measured" (NaN), for records built by hand
    (tests, replays of recorded runs)."""

    actuator: Actuator | None = None
    """The refitted model."""
    params: dict = field(default_factory=dict)
    """The entry's own parameters there (SI)."""
    converged: bool = False
    """It ended by the Gauss-Newton test, not at its step cap."""
    rss_before: float = np.nan
    """The round's start cost."""
    rss_after: float = np.nan
    nrmse_before: float = np.nan
    """Mean NRMSE over the recordings [-] at the round's start."""
    nrmse_after: float = np.nan
    criterion_delta: float = np.nan
    """ΔBIC: ``rss_after − rss_before + added·ln N``."""
    added: int = 0
    """The parameters the refit added to the model (the ``k`` of its ΔBIC)."""
    explained: float = np.nan
    """Share of the round's excess over the noise removed [-]; NaN where the round's
    residual is at the noise level."""
    chi2_after: float = np.nan
    """Mean (e/σ)² per sample after it."""
    adequate: bool = False
    """It leaves a residual within the tolerance of the noise
    (:meth:`~stickslip_jax.significance.Significance.adequate`)."""
    material: bool = False
    """What it removed exceeds the tolerance
    (:meth:`~stickslip_jax.significance.Significance.material`)."""
    removed_nm: float = np.nan
    """What it removed, as an RMS over the samples [nm]."""
    removed_noise_share: float = np.nan
    """What it removed, as a share of the noise variance [-]."""
    held_out: dict = field(default_factory=dict)
    """Per regime, the whitened RSS of its recordings predicted by the refit fitted to
    the other regimes (:mod:`.holdout`)."""
    predicts: bool = True
    """It predicts the regimes left out at least as well as the model it extends
    (:func:`~.holdout.predicts_as_well`); True when not checked."""
    param_draws: dict = field(default_factory=dict)
    """Draws of the entry's own parameters from the refit's first-order covariance
    (:func:`~.form_band.parameter_draws`: name → values); empty when not drawn."""


@dataclass(frozen=True)
class Acceptance:
    """The acceptance's decision on an entry of the round's refits (made by
    :func:`~.run._accept` for the one it judged; a later form refinement that makes a
    partial answer whole amends :attr:`partial`). The defaults are "not judged"."""

    accepted: bool = False
    """Named: accepted whole or as a partial answer."""
    partial: bool = False
    """Accepted as a partial answer: it removes a share of the excess between
    :attr:`~.Policy.partial_min` and :attr:`~.Policy.explained_min`
    (:func:`~.rules.acceptable_partly`)."""
    indistinguishable_from: tuple[str, ...] = ()
    """The refitted entries the data cannot tell from it
    (:func:`~.rules.indistinguishable`), whether or not it was accepted."""


NOT_JUDGED = Acceptance()


def amended(record, **fields):
    """A new record: ``record`` (a :class:`SizingOutcome`, :class:`RefitOutcome` or
    :class:`Acceptance`; None: a refit not measured) with ``fields`` changed; ``record``
    itself is left as it was."""
    return dataclasses.replace(RefitOutcome() if record is None else record, **fields)

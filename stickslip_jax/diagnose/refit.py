"""Refits: an entry's parameters and every baseline parameter freed together, from the
round's optimum, and the re-identification of an entry when the baseline was bent.

These were closures of the round loop; each now takes what it reads: the
:class:`RefitSetup` (the problem and what every refit of the diagnosis shares) and the
:class:`RoundStart` (where the round starts).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..identify.steps import identify
from ..model.actuator import Actuator
from ..model.extensions import LEARNED_FEATURES
from ..significance import per_recording_chi2
from .budget import REIDENTIFY_EVALUATIONS
from .catalogue import Candidate
from .form_band import parameter_draws
from .holdout import held_out_cost, predicts_as_well
from .policy import DEFAULT_POLICY, Policy
from .problem import OverBudget, Problem
from .records import RefitOutcome
from .results import CandidateResult, CandidateStatus
from .sizing import FreeSizing, HeldSizing

if TYPE_CHECKING:  # config imports the passes, which import this module
    from .config import DiagnoseConfig


@dataclass(frozen=True)
class RefitSetup:
    """What every refit of a diagnosis shares."""

    problem: Problem
    base_names: list[str]
    """The baseline's fitted quantities (:func:`~.problem.baseline_free`)."""
    n_base: int
    """Their θ columns."""
    max_steps: int
    """Levenberg-Marquardt steps per refit at most."""
    identify_max_steps: int
    """Steps per identification step of a re-identification at most."""
    carry_on_steps: int
    """Steps at most by which a free sizing is carried on (:mod:`.sizing`)."""
    policy: Policy = DEFAULT_POLICY
    regimes: tuple[str, ...] = ()
    """The regime of each recording, for the leave-one-regime-out check (:mod:`.holdout`)."""

    @classmethod
    def from_config(cls, problem: Problem, base_names: list[str], n_base: int,
                    config: DiagnoseConfig, regimes: tuple[str, ...]) -> RefitSetup:
        """The setup of a diagnosis run as ``config``."""
        return cls(problem, base_names, n_base, config.max_steps,
                   config.identify_max_steps, config.carry_on_steps, config.policy, regimes)

    def columns(self, start: Actuator, specs: dict) -> int:
        """A refit's θ columns: the baseline's and the entry's own quantities, freed
        together."""
        return self.n_base + sum(np.size(np.asarray(s.getter(start)))
                                 for s in specs.values())

    def learned_reserve(self, act: Actuator) -> float:
        """Work kept for the learned correction, which follows when nothing explains,
        from ``act`` [sample-evaluations]: its refit of every feature with the baseline
        free (both stages, the PI weights held first: :meth:`~.problem.Problem.
        refit_estimate`) and the fit of the kept features from there (at most as many
        columns), each at ``max_steps`` (:func:`~.learned.fit_learned`)."""
        columns = self.n_base + len(LEARNED_FEATURES)
        return (self.problem.refit_estimate(act, columns, self.max_steps)
                + self.problem.fit_estimate(act, columns, self.max_steps))


@dataclass(frozen=True)
class RoundStart:
    """Where a round starts: its optimum and what its refits are measured against."""

    act: Actuator
    rss: float
    """Whitened RSS of ``act``."""
    nrmse: float
    """Mean NRMSE of ``act`` [-]."""
    excess: float
    """``rss`` over the noise's ``N``, floored at 1e-9."""
    reserve: float
    """Work kept for what must follow the round's refits [sample-evaluations]."""
    held_out: dict | None = None
    """``act``'s held-out cost per regime (:func:`~.holdout.held_out_cost`), None when
    unknown."""


AT_BOUND_SHARE = 1e-3
"""A ``nonneg`` weight below this share of its θ unit (the entry's first-order strength)
sits on its bound, 0: a tenth of where a spectrum's weights start
(:data:`~.catalogue.creep.START_SHARE`), so that only a weight the fit drove down,
not one it left alone, counts as on it."""


def counted_parameters(specs: dict, fitted: Actuator) -> int:
    """The parameters a refit of ``specs`` spent, for the criterion's penalty: every
    value, except ``nonneg`` weights on their bound (:data:`AT_BOUND_SHARE`): under a
    non-negativity constraint the degrees of freedom of a least-squares fit are the
    weights it leaves positive (a projection on a convex cone), so a spectrum pays
    for the weights it uses, not for its grid."""
    k = 0
    for s in specs.values():
        value = np.asarray(s.getter(fitted))
        if s.kind == "nonneg":
            k += int(np.sum(value > AT_BOUND_SHARE * s.scale))
        else:
            k += int(np.size(value))
    return k


def record_refit(setup: RefitSetup, at: RoundStart, res: CandidateResult,
                 fitted: Actuator, out, specs: dict, t0: float) -> None:
    """Store the refit ``out`` (``fitted``, the entry's ``specs``) of ``res``, started at
    ``t0`` (for display), against the round's start ``at``."""
    problem = setup.problem
    n_obs = problem.n_obs
    rss_new = float(out.cost_end)
    k = counted_parameters(specs, fitted)
    sig = problem.significance
    held_out, predicts = res.held_out, res.predicts  # an earlier refit's, if unchecked
    if out.jacobian is not None and out.residual is not None and setup.regimes:
        held_out = held_out_cost(out.residual, out.jacobian, setup.regimes)
        predicts = at.held_out is None or predicts_as_well(held_out, at.held_out)
    res.refit = RefitOutcome(
        actuator=fitted,
        params={n: float(np.asarray(s.getter(fitted))) for n, s in specs.items()},
        converged=bool(out.converged),
        rss_before=at.rss, rss_after=rss_new, nrmse_before=at.nrmse,
        nrmse_after=float(problem.nrmse_from_whitened(out.residual).mean()),
        criterion_delta=rss_new - at.rss + k * np.log(n_obs), added=k,
        # Share of the excess over the noise; undefined when the residual is already
        # at the noise level (then only the criterion and (e/σ)² speak).
        explained=((at.rss - rss_new) / at.excess
                   if at.excess > setup.policy.excess_min * n_obs else np.nan),
        chi2_after=rss_new / n_obs,
        adequate=sig.adequate(rss_new, per_recording_chi2(out.residual, problem.counts)),
        material=sig.material(at.rss, rss_new),
        removed_nm=sig.nm(at.rss - rss_new),
        removed_noise_share=(at.rss - rss_new) / n_obs,
        held_out=held_out, predicts=predicts,
        param_draws=_draws(out, specs, rss_new))
    res.status = CandidateStatus.REFITTED
    res.wall_s += time.perf_counter() - t0
    # Not converged: its ΔBIC is an upper bound (more steps could only lower it).
    res.note = "" if out.converged else f"refit {out.message}"


def _draws(out, specs: dict, rss: float) -> dict:
    """Draws of the entry's parameters (``specs``) from the refit ``out``'s covariance
    (:func:`~.form_band.parameter_draws`), for the report's bands only; none where the
    fit kept no coordinates or Jacobian."""
    pmap = getattr(out, "pmap", None)
    if pmap is None or out.jacobian is None:
        return {}
    return parameter_draws(pmap, out.theta, out.jacobian, list(specs), rss=rss)


def judge_plausibility(res: CandidateResult, cand: Candidate, say) -> None:
    """Set ``res.implausible`` from its refitted values (entry ``cand``), and say it."""
    res.implausible = cand.implausible(res.params)
    if res.implausible:
        res.add_note(f"implausible: {res.implausible}")
        say(f"[refit {cand.name}] implausible: {res.implausible}")


def refit_start(setup: RefitSetup, at: RoundStart, res: CandidateResult,
                held: HeldSizing, free: FreeSizing | None) -> Actuator:
    """Where ``res``'s refit starts: its held sizing ``held``, unless that costs more
    than the round's start ``at`` and its sizing with the baseline free to first order
    (``free``, within the first order) points to a cheaper model: the entry at its
    free sizing's values on the baseline moved as that sizing takes for granted
    (:meth:`~.sizing.FreeSizing.point`; one simulation to cost it).

    The held sizing holds the baseline the score's first-order shift moved it to
    (:func:`~.sizing.first_order_start`); where that start is far off, it can stop
    several times above the baseline's cost (a slew-limited drive sized at 4.8x it,
    while its free sizing fell to 0.7x): a refit from there first undoes the entry (its
    first step ran the drive's pole to 1e7 MHz, where the entry does nothing) rather
    than fit it. The start and its cost are recorded (:attr:`~.results.CandidateResult.
    refit_start`)."""
    res.refit_start, res.refit_start_cost = "held sizing", held.cost
    if held.cost <= at.rss or free is None or free.extrapolated:
        return held.start
    problem = setup.problem
    try:
        point = free.point(setup.base_names)
        cost = problem.evaluate(point)[0]
    except ValueError as err:
        problem.say(f"[refit {res.name}] its free sizing's point is not a model: {err}")
        return held.start
    problem.say(f"[refit {res.name}] its held sizing costs {held.cost:.5g}, above the "
                f"round's {at.rss:.5g}; its free sizing's point (baseline moved by up "
                f"to {free.reach:.3g}) costs {cost:.5g}")
    if not cost < held.cost:
        return held.start
    res.refit_start = "free sizing's point"
    res.refit_start_cost = cost
    return point


def refit(setup: RefitSetup, at: RoundStart, res: CandidateResult, cand: Candidate,
          held: HeldSizing, free: FreeSizing | None = None, *,
          budgeted: bool = True) -> None:
    """Refit ``res`` (entry ``cand``, sized as ``held`` and ``free``) with every
    baseline parameter freed, from :func:`refit_start`; skipped, and set aside, when
    ``budgeted`` and its estimated work would pass the budget (keeping
    ``at.reserve``)."""
    problem = setup.problem
    budget, say = problem.budget, problem.say
    specs = held.specs
    need = problem.refit_estimate(held.start, setup.columns(held.start, specs),
                                  setup.max_steps)
    refused = budget.refuse(f"refit {cand.name}", need, at.reserve) if budgeted else None
    if refused:
        res.set_aside(CandidateStatus.SKIPPED, refused)
        say(f"[budget] refit {cand.name} {refused}")
        return
    t0 = time.perf_counter()
    start = refit_start(setup, at, res, held, free)
    try:
        fitted, _, out = problem.refit(start, setup.base_names + list(specs), specs,
                                       label=f"refit {cand.name}",
                                       max_steps=setup.max_steps,
                                       reserve=at.reserve if budgeted else None)
    except OverBudget as over:
        res.set_aside(CandidateStatus.SKIPPED,
                      budget.skip(f"second stage of the refit of {cand.name}", over.need))
        res.wall_s += time.perf_counter() - t0
        say(f"[budget] refit {cand.name}: {res.note}")
        return
    except ValueError as err:  # no valid start (e.g. a PI loop at the edge)
        res.set_aside(CandidateStatus.REFIT_FAILED, f"refit not possible: {err}")
        say(f"[refit {cand.name}] {res.note}")
        return
    record_refit(setup, at, res, fitted, out, specs, t0)
    judge_plausibility(res, cand, say)
    say(f"[budget] {budget.progress()}")


def reidentify(setup: RefitSetup, at: RoundStart, res: CandidateResult, cand: Candidate,
               source: Actuator, specs: dict, bar: float, *, init: Actuator, fix: dict,
               staged: Sequence[str]) -> None:
    """Re-identify ``res`` (entry ``cand``, sized to ``source`` with its ``specs``): the
    identification's ``staged`` steps from ``init`` with the entry attached (its
    component carried over, :meth:`~.catalogue.base.CatalogueEntry.carry`, at its
    refitted values, else its sized ones) and free in every step, then the refit; it
    replaces the entry's refit when it ends lower. Only a re-identification whose staged
    steps cost less than ``bar`` is refitted.

    The identification bends the paper's model to mimic a large effect (an 8 µs delay:
    Mp 12x off), a valley a refit from the bent baseline does not leave in its steps;
    the staged steps with the entry free find the other."""
    problem = setup.problem
    budget, say, data = problem.budget, problem.say, problem.data
    # The staged steps (assumed; charged as they ran afterwards), then the refit.
    columns = setup.columns(source, specs)
    need = (REIDENTIFY_EVALUATIONS * problem.evaluation_work(source, columns)
            + problem.refit_estimate(source, columns, setup.max_steps))
    note = budget.refuse(f"re-identification of {cand.name}", need, at.reserve)
    if note:
        res.add_note(note)
        if not res.refitted:
            res.status = CandidateStatus.SKIPPED
        say(f"[budget] re-identification of {cand.name} {note}")
        return
    t0 = time.perf_counter()
    if res.actuator is not None:
        source = res.actuator  # the entry's values after its refit
    try:
        entry_init = cand.carry(init, source)  # the entry's slot, refitted
        ident = identify(data.recordings, init=entry_init, fix=fix, steps=staged,
                         extra=specs, max_steps=setup.identify_max_steps,
                         uncertainty=False)
        budget.charge(problem.identification_work(ident, entry_init))
        rss_staged = problem.cost_of_output(ident.actuator, ident.q_sim)
    except ValueError as err:
        say(f"[re-identify {cand.name}] not possible: {err}")
        return
    say(f"[re-identify {cand.name}] {', '.join(staged)} with the entry free: "
        f"cost {rss_staged:.5g} against the identified baseline's {bar:.5g} "
        f"(before its polish), {time.perf_counter() - t0:.1f} s")
    if not rss_staged < bar:
        res.wall_s += time.perf_counter() - t0
        return  # the entry did not help the staged steps
    try:
        fitted, _, out = problem.refit(ident.actuator, setup.base_names + list(specs),
                                       specs, label=f"refit {cand.name} (re-identified)",
                                       max_steps=setup.max_steps)
    except ValueError as err:
        say(f"[re-identify {cand.name}] refit not possible: {err}")
        res.wall_s += time.perf_counter() - t0
        return
    if not out.cost_end >= res.rss_after:  # also when not refitted (nan)
        record_refit(setup, at, res, fitted, out, specs, t0)
        res.add_note("re-identified: the staged identification from the start with the "
                     "entry free, then the refit", first=True)
        judge_plausibility(res, cand, say)
    else:
        res.wall_s += time.perf_counter() - t0


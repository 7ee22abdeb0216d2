"""The refit rules: which sized entries are refitted, in which order, which one is
accepted, and why an entry got no refit.

Each rule reads its thresholds from a :class:`~.policy.Policy` and takes the round's
:class:`~.results.CandidateResult` list ``ranked`` (sized entries, best rank value
first). In a round, the refit passes (:mod:`.passes`) apply them in this order:

1. :func:`first_refits`: the leader, and the competitive entries beside it (the leader
   alone when its sizing already removed nearly all of the excess); once one of them
   would be accepted, the next is refitted only when its refit could rival it (not
   :func:`cannot_rival`);
2. :func:`fallback_refits`, when no first refit explains the residual (:func:`any_explains`),
   of the entries whose :func:`refit_reach` reaches what an acceptance needs
   (:func:`acceptance_reach`); and, when a refit would then be accepted, the entries
   out of reach that could still end indistinguishable from it (:func:`rivals_in_reach`);
3. :func:`second_look`, when the explaining refits all stay :func:`far_from_noise`;
4. :func:`reidentify_order`, when none explains and the identification was
   :func:`identification_bent`;
5. :func:`why_not_refitted` for the note of each sized entry left without a refit.
"""

from __future__ import annotations

import numpy as np

from ..significance import Significance
from .policy import DEFAULT_POLICY, Policy
from .results import CandidateResult, CandidateStatus


def rank_value(r: CandidateResult) -> float:
    """What the refit order goes by: the largest of the score and the sizing's drops,
    the baseline held and free to first order (:mod:`.sizing`)."""
    return max(r.score, r.size_drop, r.size_drop_free)


def explains(r: CandidateResult, policy: Policy = DEFAULT_POLICY) -> bool:
    """The refit removes :attr:`~.Policy.explained_min` of the excess or leaves a
    residual within the tolerance of the noise (:attr:`~.CandidateResult.adequate`,
    :mod:`~stickslip_jax.significance`), with values the entry calls plausible
    (:attr:`~.CandidateResult.implausible` empty)."""
    return not r.implausible and (
        bool(np.isfinite(r.explained) and r.explained >= policy.explained_min)
        or r.adequate)


def acceptable(r: CandidateResult, policy: Policy = DEFAULT_POLICY) -> bool:
    """The refit would be accepted: ΔBIC below :attr:`~.Policy.bic_min`, what it
    removed is :attr:`~.CandidateResult.material` (more than the tolerance of
    :mod:`~stickslip_jax.significance`), it :attr:`~.CandidateResult.predicts` the regimes left out
    of it at least as well as the model it extends (:mod:`.holdout`), and it
    :func:`explains` the residual."""
    return (r.criterion_delta < policy.bic_min and r.material and r.predicts
            and explains(r, policy))


def acceptable_partly(r: CandidateResult, policy: Policy = DEFAULT_POLICY) -> bool:
    """The refit would be accepted as a partial answer: every test of :func:`acceptable`
    but the share, and it removes at least :attr:`~.Policy.partial_min` of the excess
    (most of it) without reaching :attr:`~.Policy.explained_min`, with values the entry
    calls plausible."""
    return (not r.implausible and r.criterion_delta < policy.bic_min and r.material
            and r.predicts and bool(np.isfinite(r.explained))
            and r.explained >= policy.partial_min)


def indistinguishable(rival: CandidateResult, best: CandidateResult,
                      significance: Significance,
                      policy: Policy = DEFAULT_POLICY) -> bool:
    """``rival``'s refit is accepted-grade (ΔBIC below :attr:`~.Policy.bic_min`, its
    values plausible) and
    its cost exceeds ``best``'s by no more than the tolerance (not
    :meth:`~stickslip_jax.significance.Significance.material`): the data cannot tell the two fits
    apart. (A share of the best ΔBIC, the former test, called an entry that left five
    times the best's residual indistinguishable wherever the effect was strong.)"""
    return (not rival.implausible and rival.criterion_delta < policy.bic_min
            and not significance.material(rival.rss_after, best.rss_after))


def leader_alone(ranked: list[CandidateResult], excess: float | None,
                 policy: Policy = DEFAULT_POLICY) -> bool:
    """The leader's sizing removed :attr:`~.Policy.leader_alone_share` of ``excess`` (the
    (e/σ)² over the noise) and every other entry's less than
    :attr:`~.Policy.leader_alone_lead` of that (``ranked``: entries that show promise,
    best first)."""
    if not ranked or excess is None or excess <= 0:
        return False
    lead = ranked[0].size_drop
    return (lead >= policy.leader_alone_share * excess
            and all(r.size_drop < policy.leader_alone_lead * lead for r in ranked[1:]))


def first_refits(ranked: list[CandidateResult], top: int, excess: float | None = None,
                 policy: Policy = DEFAULT_POLICY) -> list[CandidateResult]:
    """The entries refitted first: the leader of ``ranked`` (best first) and, among the
    next ``top − 1``, those whose rank value reaches :attr:`~.Policy.competitive_share`
    of its and whose held sizing does not contradict the entry
    (:func:`sizing_contradicts`). An entry with the wrong
    first-order sign whose sizing did not lower the cost either (rank value ≤ 0) has
    shown nothing a refit could build on: never first. The leader alone when its
    sizing already removed nearly all of ``excess`` and clearly more than any other's
    (:func:`leader_alone`). The others wait for :func:`fallback_refits`."""
    ranked = [r for r in ranked if shows_promise(r)]
    if not ranked:
        return []
    if leader_alone(ranked, excess, policy):
        return ranked[:1]
    lead = rank_value(ranked[0])
    return [ranked[0]] + [r for r in ranked[1:top]
                          if rank_value(r) >= policy.competitive_share * lead
                          and not sizing_contradicts(r)]


def sizing_contradicts(r: CandidateResult) -> bool:
    """``r``'s sizing with the baseline held converged (:attr:`~.CandidateResult.
    size_converged`) at a cost above the baseline's: an optimum of the entry's own
    parameters worse than no entry, which contradicts the score's first-order promise.
    One that stopped at its step cap above the baseline (a seeded start far off, which
    15 steps did not bring down) has shown nothing yet either way: its rank value
    judges it, as it does the others. (Read from the cost alone, an unconverged sizing
    decided between two entries that each explained all of the excess by where it
    happened to stop.)"""
    return r.size_drop < 0 and r.size_converged


NO_PROMISE = ("not refitted: wrong first-order sign, and its sizing raised the cost "
              "over the baseline's")
"""The note of an entry that does not :func:`shows_promise`."""


def shows_promise(r: CandidateResult) -> bool:
    """False for an entry whose first-order sign is wrong and whose sizing raised the
    cost (rank value ≤ 0): no refit, first or fallback, is spent on it."""
    return rank_value(r) > 0


def refit_reach(r: CandidateResult) -> float:
    """What ``r``'s refit can remove at most, as its sizings bound it: the larger of
    its score and ``2·D_free − D_held`` (``D_held``, ``D_free``: the drops of its sizing
    with the baseline held and free to first order); ``inf`` when the free sizing did
    not converge or ended extrapolated (it then bounds nothing).

    A refit frees the baseline in full where the free sizing frees it to first order,
    so it can remove more than ``D_free`` only through the baseline's response beyond
    first order; the bound lets that buy as much again as the baseline's first-order
    freedom bought (``D_free − D_held``). An entry the baseline cannot mimic
    (``D_free ≈ D_held``) is bounded by its sizing, which its refit then repeats; one
    the baseline absorbed is given room in proportion. An argument, not a theorem: on
    the 31 sizing/refit pairs whose free sizing converged in the diagnosis logs kept
    from the concealed, development and frozen-split sets, no refit removed more than
    this bound (the closest equalled it: entries with ``D_free = D_held``), and in
    generated cases with a bent baseline the refit removes more than ``D_free`` and
    less than the bound (tests/test_diagnose_rules.py)."""
    if not r.size_free_converged:
        return np.inf
    return reach_so_far(r)


def reach_so_far(r: CandidateResult) -> float:
    """:func:`refit_reach`'s bound at where ``r``'s free sizing stopped, converged or
    not: the least the bound can be once it converges, as carrying the sizing on only
    lowers its cost (raises ``D_free``)."""
    return max(r.score, 2.0 * r.size_drop_free - r.size_drop)


def acceptance_reach(excess: float, tolerance_rss: float,
                     policy: Policy = DEFAULT_POLICY) -> float:
    """The least a refit must remove to be accepted when no refit explains the
    residual: :attr:`~.Policy.partial_min` of ``excess`` (the (e/σ)² over the noise: a
    partial answer), or what leaves the residual within the tolerance
    (``tolerance_rss``: :attr:`~stickslip_jax.significance.Significance.tolerance_rss`),
    whichever is less."""
    return min(policy.partial_min * excess, excess - tolerance_rss)


def out_of_reach_note(r: CandidateResult, reach: float) -> str:
    """The note of an entry :func:`fallback_refits` sets aside as out of reach."""
    return (f"not refitted: its sizings bound what a refit could remove by "
            f"{refit_reach(r):.4g} (held {r.size_drop:.4g}, baseline free to first "
            f"order {r.size_drop_free:.4g}), below the {reach:.4g} any acceptance "
            f"needs, and no refit explained the residual")


def fallback_refits(ranked: list[CandidateResult],
                    reach: float = -np.inf) -> list[CandidateResult]:
    """The entries refitted when no first refit explained the residual: every sized
    entry still :attr:`~.CandidateResult.waiting` that :func:`shows_promise` and whose
    :func:`refit_reach` reaches ``reach`` (:func:`acceptance_reach`: such a refit could
    be accepted); the others are set aside with a note saying why not (an entry with
    the wrong first-order sign whose sizing raised the cost rarely ends a refit below
    the baseline; one out of reach could not be accepted)."""
    waiting = [r for r in ranked if r.waiting]
    for r in waiting:
        if not shows_promise(r):
            r.set_aside(CandidateStatus.NO_PROMISE, NO_PROMISE)
        elif refit_reach(r) < reach:
            r.set_aside(CandidateStatus.OUT_OF_REACH, out_of_reach_note(r, reach))
    return [r for r in waiting if r.waiting]


def unbounded(ranked: list[CandidateResult], below: float = np.inf) -> list[CandidateResult]:
    """The entries a fallback refit would take whose free sizing stopped short of its
    optimum (:func:`refit_reach` is then unbounded): carried on first
    (:func:`~.sizing.carry_on_free_sizing`). Not one that stopped
    :attr:`~.results.CandidateResult.size_free_extrapolated`: carried on, it would
    extrapolate further; nor one whose bound where it stopped (:func:`reach_so_far`)
    already reaches ``below`` (the reach a decision needs): carried on, its bound
    could only rise."""
    return [r for r in ranked if r.waiting and shows_promise(r)
            and not r.size_free_converged and not r.size_free_extrapolated
            and np.isfinite(r.size_drop_free) and reach_so_far(r) < below]


def rival_bar(ranked: list[CandidateResult], rss: float, tolerance_rss: float,
              n_obs: float, policy: Policy = DEFAULT_POLICY) -> float | None:
    """The least a refit must remove (from ``rss``, the round's start) to matter beside
    the refits of ``ranked`` that would be accepted, whole or partly: to end
    :func:`indistinguishable` from one (within ``tolerance_rss`` of its drop) or ahead of
    it by ΔBIC (its drop less the penalty of the parameters it has beyond one, the
    least a rival adds). None when no refit would be accepted."""
    bars = [(rss - r.rss_after) - max(tolerance_rss, (r.added - 1) * np.log(n_obs))
            for r in ranked if r.refitted
            and (acceptable(r, policy) or acceptable_partly(r, policy))]
    return min(bars) if bars else None


def rivals_in_reach(ranked: list[CandidateResult], rss: float, tolerance_rss: float,
                    n_obs: float, policy: Policy = DEFAULT_POLICY) -> list[CandidateResult]:
    """The entries set aside as out of reach whose refit could still end
    :func:`indistinguishable` from an acceptance or ahead of it: their
    :func:`refit_reach` reaches :func:`rival_bar`. Refitted so that the report names
    every rival the data cannot tell from the entry it accepts."""
    bar = rival_bar(ranked, rss, tolerance_rss, n_obs, policy)
    return [r for r in ranked if r.status is CandidateStatus.OUT_OF_REACH
            and bar is not None and not cannot_rival(r, bar)]


def cannot_rival(r: CandidateResult, bar: float | None) -> bool:
    """``r``'s :func:`refit_reach` falls short of ``bar`` (:func:`rival_bar`; None when
    no refit would be accepted): its refit could neither be preferred to the
    acceptance nor named indistinguishable from it, so, once a refit of the round would
    be accepted (:func:`any_explains`, the caller's test), it would change no decision
    (a first refit beside the leader, :func:`first_refits`, is then not spent)."""
    return bar is not None and refit_reach(r) < bar


def cannot_rival_note(r: CandidateResult, bar: float) -> str:
    """The note of an entry set aside because it :func:`cannot_rival` ``bar``."""
    return (f"not refitted: its sizings bound what a refit could remove by "
            f"{refit_reach(r):.4g} (held {r.size_drop:.4g}, baseline free to first "
            f"order {r.size_drop_free:.4g}), below the {bar:.4g} it would need to rival "
            f"the refit that explained the residual")


def any_explains(ranked: list[CandidateResult], policy: Policy = DEFAULT_POLICY) -> bool:
    """Some refitted entry of ``ranked`` would be accepted (ΔBIC and share)."""
    return any(r.refitted and acceptable(r, policy) for r in ranked)


def far_from_noise(ranked: list[CandidateResult], n_obs: int,
                   policy: Policy = DEFAULT_POLICY) -> bool:
    """Every refit of ``ranked`` that would be accepted leaves a mean (e/σ)² above
    :attr:`~.Policy.second_look_chi2`."""
    chi2 = [r.chi2_after for r in ranked if r.refitted and acceptable(r, policy)]
    return bool(chi2) and min(chi2) > policy.second_look_chi2


def second_look(ranked: list[CandidateResult], seeded: set[str]) -> list[CandidateResult]:
    """The entries of ``ranked`` refitted when the explaining refits are
    :func:`far_from_noise`: the seeded ones (``seeded``: names) sized and still
    :attr:`~.CandidateResult.waiting` that :func:`shows_promise`."""
    return [r for r in ranked if r.name in seeded and r.waiting and shows_promise(r)]


def identification_bent(rss_identified: float, rss_polished: float,
                        policy: Policy = DEFAULT_POLICY) -> bool:
    """The polish divided the identified baseline's cost by at least
    :attr:`~.Policy.reidentify_polish_gain` (False when either is not finite)."""
    return bool(np.isfinite(rss_identified) and np.isfinite(rss_polished)
                and rss_identified >= policy.reidentify_polish_gain * rss_polished)


def size_before_polish(rss_identified: float, rss_polished: float,
                       significance: Significance) -> bool:
    """Round one sizes each entry on the baseline before its polish too (:mod:`.sizing`):
    the polish removed a material part of the identified baseline's cost
    (:meth:`~stickslip_jax.significance.Significance.material`: more than the noise estimate's
    uncertainty and the numerical floor), so the two baselines differ to the data and
    the polish may have bent one of them to mimic part of an effect. Otherwise they are
    one baseline to the data (as after an identification whose joint step already
    minimised the whitened residual) and a second sizing would only repeat the first
    from a cruder start. False when either cost is not finite."""
    return significance.material(rss_identified, rss_polished)


def reidentify_order(ranked: list[CandidateResult], top: int) -> list[CandidateResult]:
    """The entries re-identified when no refit explained the residual: the ``top`` of
    ``ranked`` (best first) that :func:`shows_promise`. The first-order ranking is the
    better guide here: refits from a bent baseline can rank a mimic above the right
    entry."""
    return [r for r in ranked if shows_promise(r)][:top]


def why_not_refitted(r: CandidateResult, ranked: list[CandidateResult], top: int,
                     excess: float | None = None,
                     policy: Policy = DEFAULT_POLICY) -> str:
    """The note of a sized entry that got no refit (``ranked``: best first; ``excess``
    the (e/σ)² over the noise the round started from)."""
    if not shows_promise(r):
        return NO_PROMISE
    promising = [x for x in ranked if shows_promise(x)]
    if leader_alone(promising, excess, policy) and r is not promising[0]:
        why = (f"the leader's sizing alone removed "
               f"{100 * promising[0].size_drop / excess:.0f} % of the excess, this "
               f"entry's {100 * r.size_drop / excess:.0f} %")
    elif sizing_contradicts(r):
        why = "its sizing converged above the baseline's cost"
    elif rank_value(r) < policy.competitive_share * rank_value(ranked[0]):
        why = f"ranked below {100 * policy.competitive_share:.0f} % of the leader"
    else:
        why = f"ranked below the top {top}"
    return f"not refitted: {why}, and a higher-ranked refit explained the residual"

"""The first refits of a round: the leader and the entries that compete with it."""

from __future__ import annotations

from dataclasses import dataclass

from ..results import CandidateResult, CandidateStatus
from ..rules import (
    any_explains,
    cannot_rival,
    cannot_rival_note,
    far_from_noise,
    first_refits,
    rival_bar,
    unbounded,
)
from ..sizing import carry_on_free_sizing
from .base import RefitPass, RefitRound


@dataclass(frozen=True)
class FirstRefits(RefitPass):
    """The leader of the round's ranking and, among the next ``top − 1``, those whose
    rank value reaches :attr:`~..policy.Policy.competitive_share` of the leader's and
    whose held sizing does not contradict them (:func:`~..rules.first_refits`; the
    leader alone when its sizing removed nearly all of the excess). Once one of these
    refits would be accepted, the next is refitted only when its sizings let it rival
    that acceptance (:func:`~..rules.cannot_rival`).

    What it is for: the refits are the diagnosis's costly step (every baseline
    parameter freed, tens of solver steps over the whole data); the first-order ranking
    (score and sizings) orders them so that an answer is usually found in one to three.
    """

    name = "first"
    reads = ("competitive_share", "leader_alone_share", "leader_alone_lead")

    def run(self, rnd: RefitRound) -> None:
        for res in first_refits(rnd.ranked, rnd.top, rnd.excess_or_none, rnd.policy):
            if not self._cannot_rival(rnd, res):
                rnd.refit(res, self, budgeted=rnd.first_budgeted)

    @staticmethod
    def _cannot_rival(rnd: RefitRound, res: CandidateResult) -> bool:
        """Set ``res`` aside, before its first refit, when a refit already done would
        be accepted and ``res``'s cannot rival it (a free sizing that stopped short of
        its optimum is carried on first, as it bounds nothing, unless its bound where it
        stopped already reaches the bar). A seeded entry waits for the second look when
        the acceptance stays far from the noise (:class:`~.second_look.SecondLook`)."""
        problem, policy, ranked = rnd.setup.problem, rnd.policy, rnd.ranked
        n_obs = problem.n_obs
        if not any_explains(ranked, policy) or (
                res.name in rnd.seeded and far_from_noise(ranked, n_obs, policy)):
            return False
        bar = rival_bar(ranked, rnd.at.rss, problem.significance.tolerance_rss, n_obs,
                        policy)
        if bar is None:
            return False
        if unbounded([res], bar) and res.name in rnd.free_sizings:
            carry_on_free_sizing(problem, res, rnd.free_sizings, rnd.at.rss,
                                 max_steps=rnd.setup.carry_on_steps)
        if not cannot_rival(res, bar):
            return False
        res.set_aside(CandidateStatus.CANNOT_RIVAL, cannot_rival_note(res, bar))
        problem.say(f"[refit {res.name}] {res.note}")
        return True

"""Carry on the deciding refits that stopped at their step cap."""

from __future__ import annotations

import time
from dataclasses import dataclass

from ..catalogue import Candidate
from ..refit import RefitSetup, RoundStart, judge_plausibility, record_refit
from ..results import CandidateResult
from .base import RefitPass, RefitRound


@dataclass(frozen=True)
class CarryOnDeciding(RefitPass):
    """The round's ``top`` refits by ΔBIC (the acceptance chooses among them) that
    stopped at their step cap, their values plausible, are carried on from where they
    stopped by up to the refit's step cap (:func:`carry_on_refit`), once.

    What it is for: a refit's share of the excess and its ΔBIC are judged at its
    convergence; one stopped at its cap is judged short (#63: on two held-out sets the
    deciding refit stopped at its 25-step cap, a Stribeck rise named a partial answer
    at 74 %). A carried-on refit only lowers its cost, so it can turn a partial answer
    into a whole one, or a rival into the better answer; it never adds a name the
    acceptance's tests would not give."""

    name = "carry_on"

    def run(self, rnd: RefitRound) -> None:
        refitted = sorted((r for r in rnd.ranked if r.refitted),
                          key=lambda r: r.criterion_delta)
        for res in refitted[:rnd.top]:
            if not res.refit_converged and not res.implausible:
                cand, held, _ = rnd.entry(res)
                carry_on_refit(rnd.setup, rnd.at, res, cand, held.specs)


def carry_on_refit(setup: RefitSetup, at: RoundStart, res: CandidateResult,
                   cand: Candidate, specs: dict) -> None:
    """Carry ``res``'s refit (entry ``cand`` with its ``specs``), which stopped at its
    step cap, on from where it stopped by at most the refit's step cap, every parameter
    free, starting nearly Gauss-Newton; kept when it ends lower (always, but where the
    simulator cannot step the model it reaches). Skipped, and said, when its estimated
    work would pass the budget (keeping ``at.reserve``)."""
    problem = setup.problem
    budget, say = problem.budget, problem.say
    start, names = res.actuator, setup.base_names + list(specs)
    need = problem.fit_estimate(start, setup.columns(start, specs), setup.max_steps)
    note = budget.refuse(f"carrying on the refit of {cand.name}", need, at.reserve)
    if note:
        res.add_note(note)
        say(f"[budget] carrying on the refit of {cand.name} {note}")
        return
    t0 = time.perf_counter()
    before = res.rss_after
    try:
        fitted, _, out = problem.fit(start, names, specs, label=f"refit {cand.name}, "
                                     f"carried on", max_steps=setup.max_steps,
                                     initial_damping=1e-3)
        problem.plan_factor(fitted)  # a model the simulator can step on these data
    except ValueError as err:
        say(f"[refit {cand.name}] carrying it on is not possible: {err}")
        res.wall_s += time.perf_counter() - t0
        return
    if not out.cost_end < before:
        res.wall_s += time.perf_counter() - t0
        return
    record_refit(setup, at, res, fitted, out, specs, t0)
    res.carried_on = True
    res.add_note(f"carried on from its step cap (cost {before:.6g} -> {out.cost_end:.6g})")
    judge_plausibility(res, cand, say)

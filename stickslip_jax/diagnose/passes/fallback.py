"""The fallback refits: every other sized entry that could still be accepted, when no
first refit explains the residual."""

from __future__ import annotations

from dataclasses import dataclass

from ..rules import acceptance_reach, any_explains, fallback_refits, unbounded
from ..sizing import carry_on_free_sizing
from .base import RefitPass, RefitRound


@dataclass(frozen=True)
class FallbackRefits(RefitPass):
    """When no refit so far explains the residual, every other sized entry whose
    sizings leave room for an acceptance (:func:`~..rules.refit_reach` reaches
    :func:`~..rules.acceptance_reach`) is refitted; those with the wrong first-order
    sign whose sizing raised the cost, and those out of reach, are set aside with a
    note. A free sizing that stopped short of its optimum bounds nothing and is carried
    on first (a few parameters, on the compiled program).

    What it is for: the first-order ranking misleads when the identification absorbed
    much of a large effect. Measured (bench_ablation on the concealed sets' rows of
    2026-12-06): on the slew-limited drive the first refits explained 12 % and an
    implausible 52 % of the excess, and the fallback's refit of the drive stage,
    ranked below them, removed all of it; without the fallback nothing would have been
    accepted (the acceptance replayed on the first refits). On 34 dev2 sets it
    refitted on five and decided none."""

    name = "fallback"
    reads = ("partial_min",)

    def run(self, rnd: RefitRound) -> None:
        if any_explains(rnd.ranked, rnd.policy):
            return
        setup = rnd.setup
        reach = acceptance_reach(rnd.at.excess, setup.problem.significance.tolerance_rss,
                                 rnd.policy)
        if reach > 0:
            for res in unbounded(rnd.ranked, reach):
                carry_on_free_sizing(setup.problem, res, rnd.free_sizings, rnd.at.rss,
                                     max_steps=setup.carry_on_steps)
        rnd.refit_all(fallback_refits(rnd.ranked, reach), self)

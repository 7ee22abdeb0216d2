"""The rivals in reach: entries the fallback set aside whose refit could still tie with
an acceptance."""

from __future__ import annotations

from dataclasses import dataclass

from ..rules import rivals_in_reach
from .base import RefitPass, RefitRound


@dataclass(frozen=True)
class RivalsInReach(RefitPass):
    """After the fallback, the entries it set aside as out of reach of an acceptance
    whose sizings still let their refit end indistinguishable from, or ahead of, a
    refit that would now be accepted (:func:`~..rules.rivals_in_reach`; none when the
    fallback did not run, as only it sets entries out of reach).

    What it is for: the report names every rival the data cannot tell from the entry it
    accepts; an entry out of reach of an acceptance on its own can still be within the
    tolerance of the accepted refit's cost.

    Opt-in (``--with-pass rivals``; a default until the ablation on 70
    development sets, :data:`~.OPT_IN_PASSES`, found it never ran)."""

    name = "rivals"

    def run(self, rnd: RefitRound) -> None:
        problem = rnd.setup.problem
        rnd.refit_all(rivals_in_reach(rnd.ranked, rnd.at.rss,
                                      problem.significance.tolerance_rss, problem.n_obs,
                                      rnd.policy), self)

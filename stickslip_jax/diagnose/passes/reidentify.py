"""The re-identification: the leading entries attached to the identification itself,
when the baseline was bent to mimic an effect."""

from __future__ import annotations

import time
from dataclasses import dataclass

from ..refit import reidentify
from ..rules import any_explains, identification_bent, reidentify_order
from .base import RefitPass, RefitRound


@dataclass(frozen=True)
class Reidentify(RefitPass):
    """In round one of an identified baseline, when no refit explains the residual and
    the polish divided the identified cost by
    :attr:`~..policy.Policy.reidentify_polish_gain` or more
    (:func:`~..rules.identification_bent`), the ``top`` entries that show promise are
    re-identified (:func:`~..refit.reidentify`): the staged identification steps from
    the start with the entry attached and free in every step, then the refit, which
    replaces the entry's refit when it ends lower. Only one whose staged steps cost
    less than the identified baseline before its polish (the bar) is refitted.

    What it is for: the identification can bend the paper's model to mimic a large
    effect into a valley that a refit from the bent baseline does not leave (an 8 µs
    sensor delay bent Mp 12x; re-identified, the delay was refitted to the noise; since
    then the first refits name that delay).

    Opt-in (``--with-pass reidentify``; a default until the ablation on 70
    development sets, :data:`~.OPT_IN_PASSES`, found it never ran)."""

    name = "reidentify"
    reads = ("reidentify_polish_gain",)

    def run(self, rnd: RefitRound) -> None:
        again = rnd.reidentification
        if (again is None or not again.staged or any_explains(rnd.ranked, rnd.policy)
                or not identification_bent(again.rss_identified, rnd.at.rss, rnd.policy)):
            return
        t0 = time.perf_counter()
        # The bar: the identified baseline's cost before its polish (the staged steps
        # stop short of a joint fit).
        bar = max(rnd.at.rss, again.rss_identified)
        for res in reidentify_order(rnd.ranked, rnd.top):
            cand, held, _ = rnd.entry(res)
            with rnd.attributed(res, self):
                reidentify(rnd.setup, rnd.at, res, cand, held.start, held.specs, bar,
                           init=again.init, fix=again.fix, staged=list(again.staged))
        rnd.timings["reidentify_s"] = time.perf_counter() - t0

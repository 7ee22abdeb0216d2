"""The second look: the seeded entries' refits when the explaining refits stay far from
the noise."""

from __future__ import annotations

from dataclasses import dataclass

from ..rules import any_explains, far_from_noise, second_look
from .base import RefitPass, RefitRound


@dataclass(frozen=True)
class SecondLook(RefitPass):
    """When refits explain the residual but every one of them leaves a mean (e/σ)²
    above :attr:`~..policy.Policy.second_look_chi2`, the seeded entries sized and still
    waiting (:func:`~..rules.second_look`) are refitted before one is named.

    What it is for: a seeded entry's cost is rugged in a nonlinear parameter (a
    resonance's frequency, an amplifier's poles), so its score at zero strength and its
    sizing from one seed say little; an entry of another form can then explain most of
    its effect and still leave twice the noise variance (a rate lag mimicking a
    two-pole amplifier left 6.6).

    Opt-in (``--with-pass second_look``; a default until the ablation on 70
    development sets, :data:`~.OPT_IN_PASSES`, found it deciding nothing: it
    refitted a drive stage on two of them and on one concealed set, never accepted)."""

    name = "second_look"
    reads = ("second_look_chi2",)

    def run(self, rnd: RefitRound) -> None:
        n_obs = rnd.setup.problem.n_obs
        if any_explains(rnd.ranked, rnd.policy) and far_from_noise(rnd.ranked, n_obs,
                                                                   rnd.policy):
            rnd.refit_all(second_look(rnd.ranked, rnd.seeded), self)

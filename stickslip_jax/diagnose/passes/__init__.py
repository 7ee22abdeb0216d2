"""The refit passes of a diagnosis round, each one class (:mod:`.base`), run in the
order of :data:`DEFAULT_PASSES`."""

from .base import RefitPass, RefitRound, Reidentification
from .carry_on import CarryOnDeciding
from .fallback import FallbackRefits
from .first import FirstRefits
from .reidentify import Reidentify
from .rivals import RivalsInReach
from .second_look import SecondLook

DEFAULT_PASSES: tuple[RefitPass, ...] = (
    FirstRefits(), FallbackRefits(), RivalsInReach(), SecondLook(), Reidentify())
"""The passes a round runs, in order."""

PASS_NAMES = {p.name: type(p) for p in (*DEFAULT_PASSES, CarryOnDeciding())}
"""Every pass's class by its name, the default ones first (ablations: ``--without-pass
second_look``; an opt-in pass: ``--with-pass carry_on``). :class:`CarryOnDeciding` is
not a default: on 36 development sets it ran on 7 and changed no decision (#66's
ablation, benchmarks/README.md)."""

__all__ = ["DEFAULT_PASSES", "PASS_NAMES", "CarryOnDeciding", "FallbackRefits", "FirstRefits",
           "RefitPass", "RefitRound", "Reidentification", "Reidentify", "RivalsInReach",
           "SecondLook"]

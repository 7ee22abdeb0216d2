"""The refit passes of a diagnosis round, each one class (:mod:`.base`), run in the
order of :data:`DEFAULT_PASSES`."""

from .base import RefitPass, RefitRound, Reidentification
from .carry_on import CarryOnDeciding
from .fallback import FallbackRefits
from .first import FirstRefits
from .reidentify import Reidentify
from .rivals import RivalsInReach
from .second_look import SecondLook

DEFAULT_PASSES: tuple[RefitPass, ...] = (FirstRefits(), FallbackRefits())
"""The passes a round runs, in order. The fallback stays although it decided nothing on
the development splits (it ran on 7 of 70 sets): it is what refits an entry the
first-order ranking put low, or whose sizing pointed the wrong way, before the
diagnosis gives up on it (issue #63, item 3)."""

OPT_IN_PASSES: tuple[RefitPass, ...] = (
    RivalsInReach(), SecondLook(), Reidentify(), CarryOnDeciding())
"""Passes run only when asked for (``--with-pass``, :meth:`~..config.DiagnoseConfig.
with_passes`), after the default ones in this order: on the two development splits (70
sets, ``benchmarks/results/ablation_dev.json`` and ``ablation_dev2.json``) and the eight
concealed sets and variants they were written for (``ablation_concealed_passes.json``)
none of them changed a name or a verdict. ``rivals`` and ``reidentify`` never ran;
``second_look`` ran on one concealed set and two development sets (a drive stage each
time) and refitted nothing that was accepted or named a rival; ``carry_on`` ran on 7
of the first split's sets and changed no name or verdict (which sets: #66's ablation,
benchmarks/README.md)."""

PASS_NAMES = {p.name: type(p) for p in (*DEFAULT_PASSES, *OPT_IN_PASSES)}
"""Every pass's class by its name, the default ones first (ablations: ``--without-pass
fallback``; opt-in passes: ``--with-pass second_look,reidentify``)."""

__all__ = ["DEFAULT_PASSES", "OPT_IN_PASSES", "PASS_NAMES", "CarryOnDeciding",
           "FallbackRefits", "FirstRefits", "RefitPass", "RefitRound", "Reidentification",
           "Reidentify", "RivalsInReach", "SecondLook"]

"""External load: a constant force on the slider."""

from __future__ import annotations

from typing import final

from ...identify.parameters import ParameterSpec
from .base import CatalogueEntry, Probe
from .slots import carry_slider_load, set_value


def _slider_f_ext(a):
    return a.slider.F_ext


@final
class ExternalLoadEntry(CatalogueEntry):
    """The slider's constant external force F_ext [N] (either sign), added to the
    baseline's; the refit frees it."""

    name = "external_load"
    slot = "slider"
    signature = "direction asymmetry of step lengths, offset of stick"

    def probes(self, act, hints):
        return [Probe("constant force", lambda a: a,
                      ParameterSpec(_slider_f_ext, "linear", 0.01, "N"), 0)]

    def attach(self, act, strength, probe):
        new = set_value(_slider_f_ext, float(act.slider.F_ext) + strength)(act)
        return new, {"F_ext": ParameterSpec(_slider_f_ext, "linear",
                                            probe.strength_scale(strength), "N")}

    def carry(self, init, fitted):
        return carry_slider_load(init, fitted)

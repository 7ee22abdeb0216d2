"""The probe and the abstract catalogue entry every entry file makes final."""

from __future__ import annotations

import abc
import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

from ...identify.parameters import ParameterSpec
from ...model.actuator import Actuator


@dataclass(frozen=True)
class Probe:
    """One zero-strength variant of an effect: ``install`` puts the component in the
    actuator at zero strength; ``spec`` addresses the strength (θ = 1 is ``spec.scale``
    of it); ``sign`` +1 when only positive strengths are physical, 0 for any sign.
    Probes of one entry that share one ``spec`` object address the elements of one
    vector quantity, the k-th of them element k (one quantity in the score test's
    programs, :func:`~stickslip_jax.diagnose.scores.install_probes`)."""

    label: str
    install: Callable[[Actuator], Actuator] | None
    spec: ParameterSpec
    sign: int = 0
    setting: dict = field(default_factory=dict)
    extension: object = None  # appended by the probe builder, which addresses it by index
    field: str | Callable = ""  # the extension's strength: an attribute, or its getter

    def strength_getter(self) -> Callable:
        """The getter of the strength in :attr:`extension` (its attribute :attr:`field`
        names, or :attr:`field` itself when it is a getter)."""
        field = self.field
        return field if callable(field) else (lambda e: getattr(e, field))

    def strength_scale(self, strength: float) -> float:
        """A θ unit for refitting a linear strength that starts at ``strength``."""
        return abs(strength) if abs(strength) > 1e-3 * self.spec.scale else self.spec.scale


class CatalogueEntry(abc.ABC):
    """A catalogue entry (see the package docstring): abstract. Each entry is a final
    subclass in its own module, and no entry is subclassed, so what one entry does is
    read in one file; what several share is in :mod:`.slots`."""

    name: ClassVar[str]
    """The entry's name, the issue's exact one."""
    slot: ClassVar[str]
    """Where its component acts: ``input_stage``, ``extension``, ``friction``,
    ``slider`` or ``output_map``."""
    signature: ClassVar[str]
    """Where the effect should show (regime, phase of the period, band)."""

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        # Abstract/final: a concrete entry (no abstract method left) is never extended,
        # so no entry's behaviour hides in another's file.
        for parent in cls.__mro__[1:]:
            if (issubclass(parent, CatalogueEntry) and parent is not CatalogueEntry
                    and not inspect.isabstract(parent)):
                raise TypeError(f"{cls.__name__}: the catalogue entry {parent.__name__} "
                                f"is final")

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    @abc.abstractmethod
    def probes(self, act: Actuator, hints: dict) -> list[Probe]:
        """Zero-strength versions of the effect on ``act``, one per setting of its
        nonlinear parameter; ``hints`` what the located residual suggests
        (``peaks_Hz``: shared residual peaks [Hz]; ``max_slew_V_s``: the fastest
        voltage slope of the commands [V/s]; ``sample_interval_s``: the shortest
        sample interval [s]; ``outputs_m``, ``residuals_m``: each recording's model
        output and measured − model [m] on its samples, and ``noise_m`` its noise
        level [m], where the model stands; any may be missing)."""

    @abc.abstractmethod
    def attach(self, act: Actuator, strength: float,
               probe: Probe) -> tuple[Actuator, dict[str, ParameterSpec]]:
        """``act`` with the effect at ``strength`` (``probe``'s strength, in its
        ``spec.unit``), and the parameters a refit frees, by name."""

    def attach_options(self, act: Actuator, strength: float,
                       probe: Probe) -> list[tuple[Actuator, dict[str, ParameterSpec]]]:
        """Where the entry could start at ``strength``: :meth:`attach`'s start first,
        then others, for an entry whose first-order strength leaves a parameter's start
        open (the sizing evaluates each and starts from the cheapest,
        :func:`~stickslip_jax.diagnose.sizing.first_order_start`). By default
        :meth:`attach`'s alone."""
        return [self.attach(act, strength, probe)]

    @abc.abstractmethod
    def carry(self, init: Actuator, fitted: Actuator) -> Actuator:
        """``init`` with the entry's component that ``fitted`` (the baseline plus the
        entry, refitted) carries in :attr:`slot`: the component with its refitted
        values, every baseline quantity from ``init``."""

    def implausible(self, params: dict[str, float]) -> str:
        """Why refitted ``params`` (the names of :meth:`attach`'s specs) are not the
        physics the entry names, in words; empty when they are (the default: any value
        its parametrisation reaches)."""
        return ""

    def describe(self, params: dict[str, float]) -> str:
        """The form the refit found, in words, from its refitted ``params``; empty (the
        default) when the parameters say it themselves."""
        return ""

    def plot_form(self, ax, params: dict[str, float], draws=None) -> bool:
        """Draw the form the refit found (its refitted ``params``) on the axes ``ax``,
        with the band of ``draws`` (:func:`~..form_band.parameter_draws`: its own
        parameters drawn from the refit's covariance) where the form has a curve to
        band; False (the default) when the entry has no figure of it."""
        return False

    def needs(self, recordings: Sequence) -> str | None:
        """Why the effect cannot show in ``recordings``; None when it can."""
        return None

    def seeds(self, act: Actuator) -> list[tuple[Actuator, dict[str, ParameterSpec]]]:
        """Extra starting points for the sizing (the entry attached at settings spread
        over its plausible range, independent of the data), for effects whose cost is
        too rugged in a nonlinear parameter for the first-order strength to be a usable
        start; none by default."""
        return []

    def refined_forms(self, act: Actuator,
                      hints: dict) -> list[tuple[Actuator, dict[str, ParameterSpec]]]:
        """Richer forms of the class, for a model ``act`` that holds this entry's
        refitted component (``hints`` as :meth:`probes`'): each ``(start, specs)``
        equals ``act`` at its start (the richer form's extra parameter at the value
        that reduces it to the fitted one) and frees ``specs`` (the component's
        parameters and the new one). Tried after the entry is accepted and leaves the
        model beyond the noise tolerance (:mod:`~stickslip_jax.diagnose.
        form_refinement`); none by default."""
        return []

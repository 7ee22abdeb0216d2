"""The catalogue of candidate physics: model extensions with parameters and signatures.

Every entry adds one component to the actuator in the slot where the effect acts
(input stage, extension, friction law, slider, output map): the diagnosis never
special-cases an effect. Each entry is one final class in its own module of this
package, a subclass of the abstract :class:`~.base.CatalogueEntry`
(:class:`Candidate`); what several entries share is in :mod:`.slots`. An entry provides

- ``name``, and ``slot``: where its component goes;
- ``signature``: where the effect should show (regime, phase of the period, band);
- ``probes``: zero-strength versions of the effect, each with one strength parameter.
  The derivative of the residual with respect to the strength at zero is the
  effect's first-order signature, which the score test projects the residual on.
  Effects with a nonlinear parameter (a time constant, a frequency) get one probe
  per setting of it;
- ``attach``: the effect at a starting strength (from the probe's least-squares
  coefficient), with the parameters a refit frees;
- ``carry``: where it attaches: its component of a refitted actuator put on another
  (the re-identification's start, :func:`~stickslip_jax.diagnose.refit.reidentify`);
- ``needs``: why it cannot show in a data set, if it cannot (default: it can);
- ``seeds``: extra starting points for the sizing, for effects whose cost is too
  rugged for the first-order strength to be a usable start (default: none).
"""

from __future__ import annotations

from .base import CatalogueEntry, Probe
from .contact_damping import ContactDampingEntry
from .creep import CreepEntry
from .drive_bandwidth import PROBE_TAU_DRIVE, PROBE_TAU_SLEW, DriveBandwidthEntry
from .external_load import ExternalLoadEntry
from .preload_dependence import PreloadDependenceEntry
from .rate_dependent_hysteresis import RateDependentHysteresisEntry
from .sensor_delay import SensorDelayEntry
from .sensor_drift import SensorDriftEntry
from .sensor_periodic import SensorPeriodicEntry
from .stribeck import StribeckEntry
from .structural_mode import StructuralModeEntry
from .viscous_friction import ViscousFrictionEntry

Candidate = CatalogueEntry
"""The abstract entry, under the name the diagnosis's modules use."""

CATALOGUE: tuple[Candidate, ...] = (
    CreepEntry(),
    StribeckEntry(),
    ViscousFrictionEntry(),
    ContactDampingEntry(),
    RateDependentHysteresisEntry(),
    DriveBandwidthEntry(),
    StructuralModeEntry(),
    SensorDelayEntry(),
    SensorDriftEntry(),
    SensorPeriodicEntry(),
    ExternalLoadEntry(),
    PreloadDependenceEntry(),
)
"""Every entry; names are the issue's exact names. The order is that of the probes'
columns in the score test (:func:`~stickslip_jax.diagnose.scores.install_probes`)."""

NAMES = tuple(c.name for c in CATALOGUE)


def candidate(name: str) -> Candidate:
    """The entry called ``name``."""
    for c in CATALOGUE:
        if c.name == name:
            return c
    raise KeyError(f"no catalogue entry {name!r}; entries: {', '.join(NAMES)}")


__all__ = [
    "CATALOGUE", "NAMES", "PROBE_TAU_DRIVE", "PROBE_TAU_SLEW", "Candidate", "CatalogueEntry",
    "ContactDampingEntry", "CreepEntry", "DriveBandwidthEntry", "ExternalLoadEntry",
    "PreloadDependenceEntry", "Probe", "RateDependentHysteresisEntry", "SensorDelayEntry",
    "SensorDriftEntry", "SensorPeriodicEntry", "StribeckEntry", "StructuralModeEntry",
    "ViscousFrictionEntry",
    "candidate",
]

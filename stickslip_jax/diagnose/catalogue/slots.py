"""What several catalogue entries share: reaching into their slot (the sensor output
map, a friction quantity, the n-th extension of a type), the two forms of a linear
strength (a first-order extension, a friction damping), and carrying a refitted
slot onto another actuator (:meth:`~.base.CatalogueEntry.carry`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ...identify.parameters import ParameterSpec, law_fittable
from ...model.actuator import Actuator
from ...model.extensions import SensorOutput
from ...model.stages import IdentityOutput
from .base import Probe


# ---- reaching into a slot -----------------------------------------------------------
def ext(cls, index: int = -1):
    """Getter factory: the ``index``-th extension of type ``cls``."""
    def get(a):
        found = [e for e in a.extensions if isinstance(e, cls)]
        return found[index]
    return get


def with_sensor(act: Actuator) -> Actuator:
    """``act`` with a :class:`SensorOutput` (at zero delay and drift) in the output
    slot, unless one is there; another output map there is an error."""
    if isinstance(act.output_map, SensorOutput):
        return act
    if not isinstance(act.output_map, IdentityOutput):
        raise ValueError("the output slot holds another map")
    return eqx.tree_at(lambda a: a.output_map, act, SensorOutput())


def sensor_attr(name):
    """Getter of the output map's quantity ``name``."""
    return lambda a: getattr(a.output_map, name)


def friction_attr(name):
    """Getter of the friction law's quantity ``name``."""
    return lambda a: getattr(a.friction, name)


def set_value(getter, value):
    """A function setting the quantity ``getter`` reads to ``value`` (a scalar)."""
    return lambda a: eqx.tree_at(getter, a, jnp.asarray(float(value)))


def pi_slope(act: Actuator) -> float:
    """The PI loading curve's first slope [m/V]: the scale of stroke-like strengths."""
    return float(np.asarray(act.hysteresis.weights)[0])


# ---- forms of a strength ------------------------------------------------------------
# A first-order rate lag is a first-order creep plus a change of the PI slope (which
# the refit frees), so the two entries differ only in time scale: rate dependence at
# the drive's time scale (probes up to 0.8 ms, below the 2 ms period of 500 Hz), creep
# the slower settling (probes from 1.5 ms). If both refits reach the same time
# constant they are reported as indistinguishable.
def first_order_probes(act: Actuator, cls, label: str,
                       taus: tuple[float, ...]) -> list[Probe]:
    """Probes of an extension ``cls(gain [m/V], tau [s])`` (creep, rate lag): one per
    time constant in ``taus``, the gain the strength (θ = 1 is 1 % of the PI slope)."""
    w = pi_slope(act)
    return [Probe(f"{label} tau={tau * 1e3:g} ms", None,
                  ParameterSpec(None, "linear", 0.01 * w, "m/V"), +1, {"tau": tau},
                  cls(0.0, tau), "gain")
            for tau in taus]


def first_order_attach(act: Actuator, strength: float, probe: Probe, cls,
                       prefix: str) -> tuple[Actuator, dict[str, ParameterSpec]]:
    """``act`` with ``cls(strength, probe's tau)`` appended; the refit frees
    ``{prefix}_gain`` [m/V] and ``{prefix}_tau`` [s]."""
    new = act.with_extension(cls(strength, probe.setting["tau"]))
    g = ext(cls)
    return new, {f"{prefix}_gain": ParameterSpec(lambda a: g(a).gain, "linear",
                                                 probe.strength_scale(strength), "m/V"),
                 f"{prefix}_tau": ParameterSpec(lambda a: g(a).tau, "log", 1.0, "s")}


def damping_probes(name: str) -> list[Probe]:
    """The probe of the friction law's damping ``name`` (rho1, rho2) [N·s/m], which
    the baseline law already holds: installed as it is, θ = 1 is 1 N·s/m more."""
    return [Probe(name, lambda a: a, ParameterSpec(friction_attr(name), "linear", 1.0,
                                                   "N·s/m"), +1)]


def damping_attach(act: Actuator, strength: float,
                   name: str) -> tuple[Actuator, dict[str, ParameterSpec]]:
    """``act`` with the damping ``name`` raised by ``strength``, by 0.05 N·s/m at
    least; the refit frees it."""
    start = float(getattr(act.friction, name)) + max(strength, 0.05)
    new = set_value(friction_attr(name), start)(act)
    return new, {name: ParameterSpec(friction_attr(name), "softplus", 1.0, "N·s/m")}


# ---- carrying a slot onto another actuator ------------------------------------------
def carry_output_map(init: Actuator, fitted: Actuator) -> Actuator:
    """``init`` with ``fitted``'s output map."""
    return eqx.tree_at(lambda a: a.output_map, init, fitted.output_map)


def carry_input_stage(init: Actuator, fitted: Actuator) -> Actuator:
    """``init`` with ``fitted``'s input stage."""
    return eqx.tree_at(lambda a: a.input_stage, init, fitted.input_stage)


def carry_extensions(init: Actuator, fitted: Actuator) -> Actuator:
    """``init`` with the extensions ``fitted`` has beyond ``init``'s count (the entry
    is appended after the baseline's own)."""
    for e in fitted.extensions[len(init.extensions):]:
        init = init.with_extension(e)
    return init


def carry_friction(init: Actuator, fitted: Actuator) -> Actuator:
    """``init`` with ``fitted``'s friction law, less the baseline's own friction
    quantities (those its steps fit by default: rho0 and z_ba for the paper's law),
    which stay ``init``'s."""
    f, g = fitted.friction, init.friction
    kept = {p.attr for p in law_fittable(f)}
    attrs = tuple(p.attr for p in law_fittable(g)
                  if p.step and not p.on_request and p.attr in kept)
    f = eqx.tree_at(lambda f: tuple(getattr(f, a) for a in attrs), f,
                    tuple(getattr(g, a) for a in attrs))
    return eqx.tree_at(lambda a: a.friction, init, f)

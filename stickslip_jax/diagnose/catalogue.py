"""The catalogue of candidate physics: model extensions with parameters and signatures.

Every entry adds one component to the actuator in the slot where the effect acts
(input stage, extension, friction law, slider, output map): the diagnosis never
special-cases an effect. An entry provides

- ``signature``: where the effect should show (regime, phase of the period, band);
- ``probes``: zero-strength versions of the effect, each with one strength parameter.
  The derivative of the residual with respect to the strength at zero is the
  effect's first-order signature, which the score test projects the residual on.
  Effects with a nonlinear parameter (a time constant, a frequency) get one probe
  per setting of it;
- ``attach``: the effect at a starting strength (from the probe's least-squares
  coefficient), with the parameters a refit frees;
- ``needs``: why it cannot show in a data set, if it cannot.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..identify.parameters import ParameterSpec
from ..model.actuator import Actuator
from ..model.extensions import (
    Creep,
    LowPassInput,
    ParallelInputs,
    RateDependentStroke,
    SecondOrderInput,
    SensorOutput,
    SlewLimitedInput,
    StructuralMode,
)
from ..model.friction import ElastoPlastic, StribeckElastoPlastic
from ..model.stages import IdentityInput, IdentityOutput

PROBE_TAU_DRIVE = 20e-6
"""Time constant [s] of the drive low-pass probe; its strength is the mix."""
PROBE_TAU_SLEW = 5e-6
"""Small-signal time constant [s] of the slew-limit probe (above the RK4 stability
limit of the default sub-step, 2.5 µs at 25 kHz)."""


@dataclass(frozen=True)
class Probe:
    """One zero-strength variant of an effect: ``install`` puts the component in the
    actuator at zero strength; ``spec`` addresses the strength (θ = 1 is ``spec.scale``
    of it); ``sign`` +1 when only positive strengths are physical, 0 for any sign."""

    label: str
    install: Callable[[Actuator], Actuator] | None
    spec: ParameterSpec
    sign: int = 0
    setting: dict = field(default_factory=dict)
    extension: object = None  # appended by the probe builder, which addresses it by index
    field: str = ""

    def strength_scale(self, strength: float) -> float:
        """A θ unit for refitting a linear strength that starts at ``strength``."""
        return abs(strength) if abs(strength) > 1e-3 * self.spec.scale else self.spec.scale


@dataclass(frozen=True)
class Candidate:
    """A catalogue entry (see the module docstring)."""

    name: str
    slot: str
    signature: str
    probes: Callable[[Actuator, dict], list[Probe]]
    attach: Callable[[Actuator, float, Probe], tuple[Actuator, dict[str, ParameterSpec]]]
    needs: Callable[[list], str | None] = lambda recs: None
    seeds: Callable[[Actuator, dict], list[tuple[Actuator, dict[str, ParameterSpec]]]] = \
        lambda act, hints: []
    """Extra starting points for the sizing (the entry attached at settings spread over
    its plausible range), for effects whose cost is too rugged in a nonlinear parameter
    for the first-order strength to be a usable start."""


def _ext(cls, index: int = -1):
    """Getter factory: the ``index``-th extension of type ``cls``."""
    def get(a):
        found = [e for e in a.extensions if isinstance(e, cls)]
        return found[index]
    return get


# ---- slots: install each probe only where the slot is still free -------------------
def _with_sensor(act: Actuator) -> Actuator:
    if isinstance(act.output_map, SensorOutput):
        return act
    if not isinstance(act.output_map, IdentityOutput):
        raise ValueError("the output slot holds another map")
    return eqx.tree_at(lambda a: a.output_map, act, SensorOutput())


def _sensor_attr(name):
    return lambda a: getattr(a.output_map, name)


def _with_stribeck(act: Actuator, v_s: float) -> Actuator:
    f = act.friction
    if isinstance(f, StribeckElastoPlastic):
        return act
    if not isinstance(f, ElastoPlastic):
        raise ValueError("stribeck extends the elasto-plastic law")
    new = StribeckElastoPlastic(f.rho0, f.z_ba_forward, f.z_ba_backward, stribeck_ratio=1.0,
                                v_s=v_s, zba_ratio=f.zba_ratio, rho1=f.rho1, rho2=f.rho2)
    return eqx.tree_at(lambda a: a.friction, act, new)


def _set(getter, value):
    return lambda a: eqx.tree_at(getter, a, jnp.asarray(float(value)))


def _pi_slope(act: Actuator) -> float:
    return float(np.asarray(act.hysteresis.weights)[0])


# ---- entries -------------------------------------------------------------------------
def _first_order_entry(cls, label: str, prefix: str, taus: tuple[float, ...]):
    """Probes and attach for an extension ``cls(gain [m/V], tau [s])`` (creep, rate lag):
    one probe per time constant in ``taus``; the refit frees gain and tau."""
    def probes(act, hints):
        w = _pi_slope(act)
        return [Probe(f"{label} tau={tau * 1e3:g} ms", None,
                      ParameterSpec(None, "linear", 0.01 * w, "m/V"), +1, {"tau": tau},
                      cls(0.0, tau), "gain")
                for tau in taus]

    def attach(act, strength, probe):
        new = act.with_extension(cls(strength, probe.setting["tau"]))
        g = _ext(cls)
        return new, {f"{prefix}_gain": ParameterSpec(lambda a: g(a).gain, "linear",
                                                     probe.strength_scale(strength), "m/V"),
                     f"{prefix}_tau": ParameterSpec(lambda a: g(a).tau, "log", 1.0, "s")}

    return probes, attach


# A first-order rate lag is a first-order creep plus a change of the PI slope (which
# the refit frees), so the two entries differ only in time scale: rate dependence at
# the drive's time scale (probes up to 0.8 ms, below the 2 ms period of 500 Hz), creep
# the slower settling (probes from 1.5 ms). If both refits reach the same time
# constant they are reported as indistinguishable.
_creep_probes, _creep_attach = _first_order_entry(Creep, "creep", "creep",
                                                  (1.5e-3, 4e-3, 10e-3, 30e-3))
_rate_probes, _rate_attach = _first_order_entry(RateDependentStroke, "rate lag", "rate",
                                                (0.05e-3, 0.1e-3, 0.2e-3, 0.4e-3, 0.8e-3))


def _mode_probes(act, hints):
    freqs = list(hints.get("peaks_Hz", []))[:2] or [2000.0]
    return [Probe(f"mode {f:.0f} Hz", None, ParameterSpec(None, "linear", 1e-8, "m/N"), 0,
                  {"frequency": f}, StructuralMode(f, 0.03, 0.0), "compliance")
            for f in freqs]


def _mode_attach(act, strength, probe):
    new = act.with_extension(StructuralMode(probe.setting["frequency"], 0.03, strength))
    g = _ext(StructuralMode)
    return new, {"mode_frequency": ParameterSpec(lambda a: g(a).frequency, "log", 1.0, "Hz"),
                 "mode_damping": ParameterSpec(lambda a: g(a).damping, "log", 1.0, "-"),
                 "mode_compliance": ParameterSpec(lambda a: g(a).compliance, "linear",
                                                  probe.strength_scale(strength), "m/N")}


def _bandwidth_probes(act, hints):
    """Two forms of a slow drive side by side in the input slot (:class:`ParallelInputs`):
    a first-order low-pass and a slew-rate limit at half the fastest slope the commands
    have (a stage that never limits leaves no trace). An under-damped amplifier is not
    probed: its first-order score at zero effect is unreliable (the cost is rugged in
    the corner frequency), so it enters through :func:`_bandwidth_seeds`."""
    def install(stage):
        def put(a):
            slot = a.input_stage
            if isinstance(slot, IdentityInput):
                stages = (stage,)
            elif isinstance(slot, ParallelInputs) and all(
                    float(st.mix) == 0.0 for st in slot.stages):
                stages = (*slot.stages, stage)  # a probe of this entry is there already
            else:
                raise ValueError("the input slot is taken")
            return eqx.tree_at(lambda x: x.input_stage, a, ParallelInputs(stages))
        return put

    def mix(i):
        return ParameterSpec(lambda a: a.input_stage.stages[i].mix, "linear", 0.1, "-")

    probes = [Probe(f"drive low-pass tau={PROBE_TAU_DRIVE * 1e6:g} us",
                    install(LowPassInput(PROBE_TAU_DRIVE, 0.0)), mix(0), +1,
                    {"form": "low-pass", "tau": PROBE_TAU_DRIVE})]
    top = float(hints.get("max_slew_V_s", 0.0))
    if top > 0:
        slew = 0.5 * top
        probes.append(Probe(f"drive slew limit {slew * 1e-6:.3g} V/us",
                            install(SlewLimitedInput(slew, PROBE_TAU_SLEW, 0.0)), mix(1), +1,
                            {"form": "slew", "slew": slew, "tau": PROBE_TAU_SLEW,
                             "max_slew": top}))
    return probes


def _bandwidth_attach(act, strength, probe):
    # The probe measured a share ``mix`` of its stage's lag. A low-pass of time
    # constant mix·τ0 lags as much on a ramp; a slew limit S lags by (|u̇| − S)·t on
    # the fastest slope |u̇|, so the share maps to S = |u̇| − mix·(|u̇| − S0).
    st = probe.setting
    mix = max(float(strength), 1e-3)
    if st["form"] == "low-pass":
        new = eqx.tree_at(lambda a: a.input_stage, act,
                          LowPassInput(max(mix * st["tau"], 2e-6), 1.0))
        return new, {"drive_tau": ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0,
                                                "s")}
    top = st["max_slew"]
    slew = max(top - min(mix, 1.0) * (top - st["slew"]), 0.05 * top)
    new = eqx.tree_at(lambda a: a.input_stage, act, SlewLimitedInput(slew, st["tau"]))
    return new, {"drive_slew": ParameterSpec(lambda a: a.input_stage.slew, "log", 1.0, "V/s"),
                 "drive_tau": ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0, "s")}


def _bandwidth_seeds(act, hints):
    """Under-damped two-pole amplifiers over 3-20 kHz and damping 0.3-0.7: a step
    edge's overshoot sets the slip of every period, so the cost in the corner frequency
    is rugged and a start from the first-order strength is often in the wrong valley."""
    specs = {"drive_frequency": ParameterSpec(lambda a: a.input_stage.frequency, "log", 1.0,
                                              "Hz"),
             "drive_damping": ParameterSpec(lambda a: a.input_stage.damping, "log", 1.0, "-")}
    return [(eqx.tree_at(lambda a: a.input_stage, act, SecondOrderInput(f0, zeta)), specs)
            for f0 in np.geomspace(3e3, 20e3, 6) for zeta in (0.3, 0.5, 0.7)]


def _delay_probes(act, hints):
    return [Probe("sensor delay", _with_sensor,
                  ParameterSpec(_sensor_attr("delay"), "linear", 1e-5, "s"), +1)]


def _delay_attach(act, strength, probe):
    new = _set(_sensor_attr("delay"), max(strength, 1e-6))(_with_sensor(act))
    return new, {"sensor_delay": ParameterSpec(_sensor_attr("delay"), "log", 1.0, "s")}


def _drift_probes(act, hints):
    return [Probe("sensor drift", _with_sensor,
                  ParameterSpec(_sensor_attr("drift"), "linear", 1e-6, "m/s"), 0)]


def _drift_attach(act, strength, probe):
    new = _set(_sensor_attr("drift"), strength)(_with_sensor(act))
    return new, {"sensor_drift": ParameterSpec(_sensor_attr("drift"), "linear",
                                               probe.strength_scale(strength), "m/s")}


def _slider_f_ext(a):
    return a.slider.F_ext


def _load_probes(act, hints):
    return [Probe("constant force", lambda a: a,
                  ParameterSpec(_slider_f_ext, "linear", 0.01, "N"), 0)]


def _load_attach(act, strength, probe):
    new = _set(_slider_f_ext, float(act.slider.F_ext) + strength)(act)
    return new, {"F_ext": ParameterSpec(_slider_f_ext, "linear",
                                        probe.strength_scale(strength), "N")}


def _friction_attr(name):
    return lambda a: getattr(a.friction, name)


def _rho_probes(name):
    def probes(act, hints):
        return [Probe(name, lambda a: a, ParameterSpec(_friction_attr(name), "linear", 1.0,
                                                       "N·s/m"), +1)]
    return probes


def _rho_attach(name):
    def attach(act, strength, probe):
        start = float(getattr(act.friction, name)) + max(strength, 0.05)
        new = _set(_friction_attr(name), start)(act)
        return new, {name: ParameterSpec(_friction_attr(name), "softplus", 1.0, "N·s/m")}
    return attach


def _stribeck_probes(act, hints):
    return [Probe(f"stribeck v_s={v * 1e3:g} mm/s", lambda a, v=v: _with_stribeck(a, v),
                  ParameterSpec(_friction_attr("stribeck_ratio"), "linear", 0.1, "-"), +1,
                  {"v_s": v})
            for v in (2e-3,)]


def _stribeck_attach(act, strength, probe):
    new = _with_stribeck(act, probe.setting["v_s"])
    new = _set(_friction_attr("stribeck_ratio"), 1.0 + max(strength, 1e-3))(new)
    return new, {"stribeck_excess": ParameterSpec(
                     lambda a: a.friction.stribeck_ratio, "linear", max(strength, 1e-3), "-"),
                 "v_s": ParameterSpec(_friction_attr("v_s"), "log", 1.0, "m/s")}


def _needs_several_preloads(recs) -> str | None:
    return ("indistinguishable: all recordings share one preload (normal force); CEIM "
            "preload dependence only shows across preloads")


def _no_probes(act, hints):
    return []


def _no_attach(act, strength, probe):  # pragma: no cover - never probed
    raise ValueError("preload_dependence cannot be attached without several preloads")


CATALOGUE: tuple[Candidate, ...] = (
    Candidate("creep", "extension", "slow drift of the stroke after each voltage change: "
              "step-response tail, period-to-period trend of low-frequency drives",
              _creep_probes, _creep_attach),
    Candidate("stribeck", "friction", "velocity-dependent steady state: slip phases of "
              "stepping, more where slip is fast", _stribeck_probes, _stribeck_attach),
    Candidate("viscous_friction", "friction", "force proportional to sliding velocity: "
              "slip phases, step length falling with drive rate",
              _rho_probes("rho2"), _rho_attach("rho2")),
    Candidate("contact_damping", "friction", "damping of the contact (rho1): decay of "
              "stick ringing after the edge, step-response damping",
              _rho_probes("rho1"), _rho_attach("rho1")),
    Candidate("rate_dependent_hysteresis", "extension", "stroke lag growing with the "
              "voltage rate: loop width and phase of sine and ramp phases",
              _rate_probes, _rate_attach),
    Candidate("drive_bandwidth", "input_stage", "the piezo voltage lags the command "
              "(low-pass) or cannot follow fast edges (slew limit), or overshoots them "
              "(under-damped two-pole amplifier): edges and slips change with the drive",
              _bandwidth_probes, _bandwidth_attach, seeds=_bandwidth_seeds),
    Candidate("structural_mode", "extension", "an extra resonance in the residual PSD, "
              "ringing after edges", _mode_probes, _mode_attach),
    Candidate("sensor_delay", "output_map", "residual proportional to the output's rate: "
              "largest at edges, all regimes alike", _delay_probes, _delay_attach),
    Candidate("sensor_drift", "output_map", "residual growing with time in every recording",
              _drift_probes, _drift_attach),
    Candidate("external_load", "slider", "direction asymmetry of step lengths, offset of "
              "stick", _load_probes, _load_attach),
    Candidate("preload_dependence", "friction", "step length and breakaway change with "
              "the preload (needs recordings at several preloads)", _no_probes, _no_attach,
              _needs_several_preloads),
)
"""Every entry; names are the issue's exact names."""

NAMES = tuple(c.name for c in CATALOGUE)


def candidate(name: str) -> Candidate:
    """The entry called ``name``."""
    for c in CATALOGUE:
        if c.name == name:
            return c
    raise KeyError(f"no catalogue entry {name!r}; entries: {', '.join(NAMES)}")

"""Concealed-effect recording sets: the identification protocol with one hidden effect.

Test data, not part of the model: the diagnosis never imports this module (its sets are
in ``fixtures/concealed/``, made by ``scripts/make_concealed_fixtures.py``).

Each effect is added to a known baseline truth as a model component (the classes of
:mod:`stickslip_jax.model.extensions`), deliberately *not* always in the form that the
diagnosis catalogue fits:

==========================  ==========================================================
effect                      generator form (catalogue form, when different)
==========================  ==========================================================
creep                       four first-order modes, 0.5 to 150 ms, equal gains: a
                            log-in-time law (catalogue: one first-order mode)
drive_bandwidth             amplifier hard-limited at 1.2 V/µs, 8 µs small-signal lag
                            (catalogue: a low-pass, or a tanh-smoothed slew limit)
structural_mode             mount resonance at 3.3 kHz excited by the contact force
sensor_delay                15 µs interferometer delay
sensor_drift                thermal drift settling exponentially (catalogue: linear)
external_load               constant 0.01 N on the slider
contact_damping             rho1 = 6 N·s/m
viscous_friction            rho2 = 2 N·s/m
stribeck                    Stribeck steady state, peak 1.6x, v_s = 2 mm/s
rate_dependent_hysteresis   stroke lag growing with the voltage rate
uncatalogued                a force periodic in slider position (guide waviness)
none                        the baseline alone (the null set)
==========================  ==========================================================

``preload_dependence`` (CEIM) cannot show in this protocol: every recording shares one
normal force, and at a fixed preload its effect is absorbed by z_ba, z_ss and rho0.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np

from ..model.actuator import Actuator
from ..model.extensions import (
    ChainedOutput,
    ClippedSlewInput,
    Creep,
    ExponentialDrift,
    PeriodicSensorError,
    PositionRipple,
    RateDependentStroke,
    SecondOrderInput,
    SensorOutput,
    StructuralMode,
)
from ..model.friction import StribeckElastoPlastic

CANNOT_SHOW = {
    "preload_dependence": "every recording of the protocol is taken at one preload; CEIM "
                          "changes z_ba, z_ss and rho0 with the normal force, which at a "
                          "single normal force is a reparametrisation the baseline fit "
                          "absorbs. It needs recordings at several preloads.",
}


def pi_slope(act: Actuator) -> float:
    """Small-signal stroke per volt of the PI loop [m/V] (first weight)."""
    return float(np.asarray(act.hysteresis.weights)[0])


def _stribeck(act: Actuator) -> Actuator:
    f = act.friction
    new = StribeckElastoPlastic(f.rho0, f.z_ba_forward, f.z_ba_backward, stribeck_ratio=1.6,
                                v_s=2e-3, zba_ratio=f.zba_ratio, rho1=f.rho1, rho2=f.rho2)
    return eqx.tree_at(lambda a: a.friction, act, new)


def with_effect(act: Actuator, effect: str) -> Actuator:
    """``act`` with the hidden ``effect`` (see the module table) added."""
    w = pi_slope(act)
    if effect == "none":
        return act
    if effect == "creep":
        for tau in (0.5e-3, 4e-3, 25e-3, 150e-3):
            act = act.with_extension(Creep(0.02 * w, tau))
        return act
    if effect == "drive_bandwidth":
        return eqx.tree_at(lambda a: a.input_stage, act, ClippedSlewInput(1.2e6, 8e-6))
    if effect == "structural_mode":
        return act.with_extension(StructuralMode(3300.0, 0.03, 1.2e-7))
    if effect == "sensor_delay":
        return eqx.tree_at(lambda a: a.output_map, act, SensorOutput(delay=15e-6))
    if effect == "sensor_drift":
        return eqx.tree_at(lambda a: a.output_map, act, ExponentialDrift(60e-9, 0.04))
    if effect == "external_load":
        return eqx.tree_at(lambda a: a.slider.F_ext, act, np.asarray(0.01))
    if effect == "contact_damping":
        return eqx.tree_at(lambda a: a.friction.rho1, act, np.asarray(6.0))
    if effect == "viscous_friction":
        return eqx.tree_at(lambda a: a.friction.rho2, act, np.asarray(2.0))
    if effect == "stribeck":
        return _stribeck(act)
    if effect == "rate_dependent_hysteresis":
        return act.with_extension(RateDependentStroke(0.03 * w, 0.3e-3))
    if effect == "uncatalogued":
        return act.with_extension(PositionRipple(0.03, 0.8e-6))
    raise ValueError(f"unknown effect {effect!r}")


EFFECTS = ("creep", "drive_bandwidth", "structural_mode", "sensor_delay", "sensor_drift",
           "external_load", "contact_damping", "viscous_friction", "stribeck",
           "rate_dependent_hysteresis", "uncatalogued", "none")
"""Every concealed set the generator makes (``none``: the null set)."""


VARIANTS: dict[str, tuple[str, str]] = {
    "creep_two_modes": ("creep", "two unequal modes, 3 % at 8 ms and 1 % at 60 ms "
                                 "of the small-signal stroke per volt"),
    "drive_second_order": ("drive_bandwidth", "second-order amplifier, 9 kHz, damping "
                                              "0.5 (catalogue: first-order or slew)"),
    "drive_two_pole_mild": ("drive_bandwidth", "second-order amplifier, 15 kHz, damping "
                                               "0.7"),
    "mode_2k": ("structural_mode", "2.2 kHz mount mode, damping 0.05, 0.8e-7 m/N"),
    "delay_8us": ("sensor_delay", "8 µs interferometer delay"),
    "load_negative": ("external_load", "-0.02 N on the slider"),
    "rho1_small": ("contact_damping", "rho1 = 3 N·s/m"),
    "rate_fast": ("rate_dependent_hysteresis", "stroke lag 5 % at 0.12 ms"),
    "interferometer_periodic": ("sensor_periodic", "interferometer periodic error, 2.5 "
                                                   "nm at a 316.4 nm period, one sine"),
    "interferometer_double_pass": ("sensor_periodic", "a double-pass interferometer's "
                                                      "periodic error, 2.5 nm at 158.2 nm"),
    "interferometer_skewed": ("sensor_periodic", "periodic error of 3 nm at 316.4 nm, then "
                                                 "1.2 nm at a third of it on the reading"),
}
"""Independent variants of the concealed effects: other functional forms and magnitudes
than :func:`with_effect` (which the catalogue was developed on), to check that the
diagnosis is not tuned to one generator. ``name → (expected verdict name, form)``;
``uncatalogued`` expects no name."""


def with_variant(act: Actuator, variant: str) -> Actuator:
    """``act`` with the hidden variant effect (see :data:`VARIANTS`)."""
    w = pi_slope(act)
    if variant == "creep_two_modes":
        return act.with_extension(Creep(0.03 * w, 8e-3)).with_extension(Creep(0.01 * w, 60e-3))
    if variant == "drive_second_order":
        return eqx.tree_at(lambda a: a.input_stage, act, SecondOrderInput(9000.0, 0.5))
    if variant == "drive_two_pole_mild":
        return eqx.tree_at(lambda a: a.input_stage, act, SecondOrderInput(15000.0, 0.7))
    if variant == "mode_2k":
        return act.with_extension(StructuralMode(2200.0, 0.05, 0.8e-7))
    if variant == "delay_8us":
        return eqx.tree_at(lambda a: a.output_map, act, SensorOutput(delay=8e-6))
    if variant == "load_negative":
        return eqx.tree_at(lambda a: a.slider.F_ext, act, np.asarray(-0.02))
    if variant == "rho1_small":
        return eqx.tree_at(lambda a: a.friction.rho1, act, np.asarray(3.0))
    if variant == "rate_fast":
        return act.with_extension(RateDependentStroke(0.05 * w, 0.12e-3))
    if variant == "interferometer_periodic":
        return eqx.tree_at(lambda a: a.output_map, act, PeriodicSensorError(2.5e-9))
    if variant == "interferometer_double_pass":
        return eqx.tree_at(lambda a: a.output_map, act, PeriodicSensorError(2.5e-9, 158.2e-9))
    if variant == "interferometer_skewed":
        return eqx.tree_at(lambda a: a.output_map, act, ChainedOutput((
            PeriodicSensorError(3e-9), PeriodicSensorError(1.2e-9, 316.4e-9 / 3))))
    raise ValueError(f"unknown variant {variant!r}; choose from {', '.join(VARIANTS)}")



FRINGE_START_VARIANTS: dict[str, tuple[str, str]] = {
    "interferometer_fringe_starts": ("sensor_periodic", "interferometer periodic error, "
                                     "2.5 nm at 316.4 nm, one sine, each recording "
                                     "starting at a random point of the fringe"),
    "interferometer_skewed_fringe_starts": ("sensor_periodic", "3 nm at 316.4 nm, then "
                                            "1.2 nm at a third of it on the reading, each "
                                            "recording starting at a random point of the "
                                            "fringe"),
}
"""Variants read recording by recording (:func:`read_from_fringe_starts`), as a real
interferometer reads a set: ``name → (expected verdict name, form)``, like
:data:`VARIANTS`; :func:`fringe_start_sensor` gives each one's sensor at an offset."""


def fringe_start_sensor(variant: str, offset: float):
    """The output map of ``variant`` (:data:`FRINGE_START_VARIANTS`) for a recording
    starting ``offset`` [m] along the fringe."""
    if variant == "interferometer_fringe_starts":
        return PeriodicSensorError(2.5e-9, offset=offset)
    if variant == "interferometer_skewed_fringe_starts":
        return ChainedOutput((PeriodicSensorError(3e-9, offset=offset),
                              PeriodicSensorError(1.2e-9, 316.4e-9 / 3, offset)))
    raise ValueError(f"unknown variant {variant!r}; choose from "
                     f"{', '.join(FRINGE_START_VARIANTS)}")

def read_from_fringe_starts(recordings, sensor_at, *, noise_m: float, seed: int,
                            fringe_m: float = 316.4e-9):
    """``recordings`` (noise-free) as a real set's interferometer reads them, each
    starting at another point of its fringe: recording i's positions through the
    output map ``sensor_at(o_i)``, the offsets o_i drawn uniformly over
    ``[0, fringe_m)`` [m], then white noise of ``noise_m`` [m]. Returns the recordings
    and the offsets [m]."""
    rng = np.random.default_rng(seed)
    offsets = rng.uniform(0.0, fringe_m, len(recordings))
    out = []
    for rec, offset in zip(recordings, offsets, strict=True):
        t = rec.dt * np.arange(rec.n)
        read = np.asarray(sensor_at(float(offset))(t, np.asarray(rec.position_m)))
        out.append(rec.with_position_m(read + noise_m * rng.standard_normal(rec.n)))
    return out, offsets

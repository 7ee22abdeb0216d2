"""Random recording sets with one hidden effect, for measuring how the diagnosis
generalises (issue #27). Test data: the library never imports this module.

A set is the 17-recording protocol (:func:`~stickslip_jax.synthetic.paper_protocol`)
simulated with :func:`~stickslip_jax.synthetic.simulate_set` (at
:data:`~stickslip_jax.stepping.REFERENCE_STEPPING`, 16x finer than fits use) from a
random truth, plus one hidden effect or none, plus white Gaussian noise. Everything
follows from ``(split seed, set index)``: :func:`draw_set` gives the
:class:`SetSpec`, :func:`make_recordings` the recordings, :func:`effect_size` how
large the effect is on them.

Truth
-----
:func:`~.truth.draw_truth`: the identification fixtures' truth
(:func:`~.truth.identification_truth`) with each value below times a log-uniform
factor (held: Ms = 0.0247 kg, zba_ratio = 0.667, the PI thresholds, no load):

=================================  =============  ===============
value                              central        factor
=================================  =============  ===============
Mp, Kp                             2.8e-4 kg,     0.8 - 1.25
                                   2.4e6 N/m
Dp, Ds, rho0                       14, 70 N·s/m,  0.75 - 1.33
                                   3.2e5 N/m
z_ba forward, backward (each)      0.42, 0.48 µm  0.8 - 1.25
PI linear weight                   1.9e-8 m/V     0.8 - 1.25
PI tail weights (their sum)        0.6e-8 m/V     0.7 - 1.43
PI tail decay, ∝ exp(−r/decay)     12 V           0.67 - 1.5
=================================  =============  ===============

Noise: σ log-uniform 0.5 - 2 nm per set, white Gaussian.

Hidden effect
-------------
In each block of three consecutive indices one set, at a seed-drawn place, is null
(so every split of 3k sets holds k nulls); the others take the effects in turn from a
seed-shuffled order of the ten catalogue entries that can show in this protocol plus
``uncatalogued`` (all eleven before any repeats). The form is uniform among the
entry's forms; at most one form per entry is one the catalogue fits (``*``).
Strengths are log-uniform over the range (in magnitude; ``±``: a uniform random
sign); the other parameters log-uniform over theirs. ``w``: the truth's first PI
weight (its small-signal stroke per volt). Components that are not the library's are
in :mod:`.effects`.

==========================  ================  ===========================  =====================
entry: form                 strength          range                        other parameters
==========================  ================  ===========================  =====================
creep: one_mode *           Σ gains / w       0.001 - 0.1                  τ 2 - 50 ms
creep: log_law              Σ gains / w       0.001 - 0.1                  7 equal modes, τ
                                                                           0.32 ms - 316 ms
creep: fractional           Σ gains / w       0.002 - 0.2                  9 modes 0.1 ms - 1 s,
                                                                           gain ∝ τ^α, α 0.2-0.6
stribeck: lorentzian *      f_max/f_c − 1     0.01 - 1                     v_s 1 - 10 mm/s
stribeck: exponential       f_max/f_c − 1     0.015 - 2.5                  v_s 1 - 10 mm/s
stribeck: gaussian          f_max/f_c − 1     0.02 - 3                     v_s 2 - 20 mm/s
viscous_friction: linear *  ρ2                0.01 - 1.2 N·s/m
viscous_friction:           ρ2 (ρ2·v·tanh(ẋ/  0.1 - 10 N·s/m               v 1 - 10 mm/s
saturating                  v))
viscous_friction:           ρ2 (ρ2·(ẋ − ż))   0.013 - 1.4 N·s/m
slip_only
contact_damping: linear *   ρ1                0.05 - 5 N·s/m
contact_damping:            ρ1 (ρ1·v·tanh(ż/  0.3 - 35 N·s/m               v 0.1 - 1 mm/s
saturating                  v))
rate_dependent_hysteresis:  lag gain / w      2e-4 - 0.02                  τ 0.05 - 0.8 ms
first_order *
rate_dependent_hysteresis:  lag gain / w      0.003 - 0.3                  τ 0.05 - 0.8 ms,
saturating                                                                 u_sat 1 - 5 V
rate_dependent_hysteresis:  lag gain / w      2e-4 - 0.02 (half each)      τ 0.05 - 0.4 ms,
two_lags                                                                   τ2/τ 4 - 16
drive_bandwidth: low_pass * τ                 0.4 - 4 µs
drive_bandwidth:            slew limit        1.5 - 1.4 V/µs (lower is     small-signal τ
clipped_slew                                  stronger; the steepest       0.4 - 0.8 µs
                                              command edge: 1.5 V/µs)
drive_bandwidth:            ramp lag 2ζ/ω + τ 1 - 5 µs                     two-pole ζ 0.4 - 0.7,
third_order                                                                τ's share 0.2 - 0.5
structural_mode: single *   ± compliance      5.5e-9 - 5.5e-7 m/N          f 1.5 - 8 kHz,
                                                                           ζ 0.01 - 0.1
structural_mode: two_modes  ± Σ compliance    7e-9 - 7e-7 m/N              f, ζ as above; f2/f
                                                                           1.5 - 3, ζ2 0.01-0.1,
                                                                           first's share 0.3-0.7
structural_mode:            ± compliance      8e-9 - 8e-7 m/N              f, ζ as single
reaction_mode
sensor_delay: pure_delay *  delay             0.2 - 20 µs
sensor_delay: low_pass      τ                 0.2 - 20 µs
sensor_drift: linear *      ± drift at 0.1 s  1.1 - 110 nm
sensor_drift: exponential   ± drift at 0.1 s  1 - 100 nm                   settling 10 - 100 ms
external_load: constant *   ± force           5e-5 - 5e-3 N
external_load: spring       k (−k·x2)         16 - 1600 N/m                x2 = 0 at the start
uncatalogued:               force amplitude   8e-5 - 8e-3 N                wavelength 0.3 - 3 µm
position_ripple
uncatalogued:               amplitude         0.36 - 36 nm                 period 316.4 nm
interferometer
uncatalogued: coulomb_drag  force             5e-5 - 5e-3 N                −F·tanh(v2/0.1 mm/s)
none: null                  (the truth alone)
==========================  ================  ===========================  =====================

The drive's weak ends are bounded by the cost of simulating a fast pole (a 0.4 µs
stage takes 27x the sub-steps of the piezo's own 14.7 kHz mode).
``preload_dependence`` cannot show in this protocol (one preload); it is not drawn.
The interferometer error was drawn as ``uncatalogued`` before the catalogue had the
sensor's periodic error; it is drawn so still (the splits stay as drawn) and judged
as the class ``sensor_periodic`` (:attr:`Form.named`, :attr:`SetSpec.hidden`).

Effect size
-----------
Strength ranges are in the entry's units, and what the data show of a strength
depends on the truth and the protocol, so every set records its **effect size**
(:func:`effect_size`): the RMS over all samples of all recordings of the noise-free
trace with the effect minus the trace without it (same truth, same stepping), each
recording's offset removed as every fit removes it [m], and its ratio to the set's
noise σ. The ranges put it at about 0.25 nm at the weak end and 25 nm at the strong
end at the central truth, so that with σ 0.5 - 2 nm it spans about 0.1x to 50x the
noise; the exceptions (measured on the 17 recordings, default stepping):
drive_bandwidth low_pass 0.9 - 26 nm, clipped_slew 1.4 - 24 nm, third_order 2.6 - 19
nm. ``scripts/make_random_split.py --calibrate`` prints these numbers.

How much of it the baseline can take up differs by form: with ``beyond_baseline``,
:func:`effect_size` also gives the part no change of the baseline's free parameters
absorbs to first order. Its share of the effect size, measured at the central truth
(range top): friction entries (stribeck, viscous, contact damping), the first-order
rate lag and a constant load 3 - 14 %; saturating rate lag, two lags, drive stages,
spring, Coulomb drag 7 - 35 %; creep 40 - 60 %; modes, sensor delay and drift 50 -
80 %; position ripple and interferometer error 84 - 97 %.

Splits
------
:data:`SPLITS` names each split's seed and :class:`SplitDesign`. Version 1 (``dev``,
``test``): 24 sets, one null per block of three, the truths on the fit's PI grid.
Version 2 (``dev2``, ``test2``, issue #63): 48 sets, one null per block of four (12
nulls); every truth draws its own PI operators (count and thresholds,
:func:`~.truth.draw_pi_grid`), so the nulls test a hysteresis shape the fit's grid
cannot follow exactly; and in every second block the set after the null hides a second
effect of another place in the actuator (:data:`PLACES`; compound sets, when the first
is a catalogue entry). Develop on ``dev``/``dev2`` freely; ``test``/``test2`` are
frozen: report on them, never tune on them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import equinox as eqx
import numpy as np

from ..model.actuator import Actuator
from ..model.extensions import (
    ClippedSlewInput,
    Creep,
    ExponentialDrift,
    LowPassInput,
    PeriodicSensorError,
    PositionRipple,
    RateDependentStroke,
    SecondOrderInput,
    SensorOutput,
    StructuralMode,
)
from ..model.friction import StribeckElastoPlastic
from ..params import actuator_from_params
from ..stepping import REFERENCE_STEPPING
from .concealed import pi_slope as _w  # the truth's stroke per volt [m/V]
from .effects import (
    CascadeInput,
    CoulombDrag,
    ReactionMode,
    SaturatingRateStroke,
    SensorLowPass,
    VariantElastoPlastic,
)
from .truth import draw_pi_grid, draw_truth, log_uniform

DEV_SEED = 20261126
"""The development split: develop, tune and debug on it freely."""

TEST_SEED = 2292930091
"""The test split's seed, drawn once with ``secrets.randbits(32)`` on 2026-11-26.
Frozen; do not tune on it: run it once the policy is fixed, and report what it gives."""

DEV2_SEED = 71883275
"""The version-2 development split (:data:`SPLITS`): develop on it freely."""

TEST2_SEED = 1725938153
"""The version-2 test split's seed, drawn once with ``secrets.randbits(32)`` on
2026-12-04. Frozen: run it once the method is fixed, and report what it gives."""

SET_SIZE = 24
"""Sets per split by default (8 of them null) in version 1."""


@dataclass(frozen=True)
class SplitDesign:
    """How a split's sets are drawn (module docstring, "Splits")."""

    version: int
    size: int
    """Sets in the split by default."""
    block: int
    """One null set per block of this many consecutive sets."""
    pi_grid: bool
    """The truths draw their own PI operators (:func:`~.truth.draw_pi_grid`)."""
    compound: bool
    """In every second block the set after the null hides a second effect."""


V1 = SplitDesign(1, SET_SIZE, 3, pi_grid=False, compound=False)
V2 = SplitDesign(2, 48, 4, pi_grid=True, compound=True)

SPLITS: dict[str, tuple[int, SplitDesign]] = {
    "dev": (DEV_SEED, V1), "test": (TEST_SEED, V1),
    "dev2": (DEV2_SEED, V2), "test2": (TEST2_SEED, V2),
}
"""Split name → ``(seed, design)``."""

PLACES: dict[str, str] = {
    "stribeck": "friction", "viscous_friction": "friction", "contact_damping": "friction",
    "drive_bandwidth": "drive stage", "sensor_delay": "sensor", "sensor_drift": "sensor",
    "creep": "stroke", "rate_dependent_hysteresis": "stroke",
    "structural_mode": "structure", "external_load": "slider", "sensor_periodic": "sensor",
}
"""Where each catalogue entry's effect acts: a compound set's second effect acts in
another place than its first (two effects in one place would replace one another)."""

NOISE_RANGE_M = (0.5e-9, 2e-9)
"""Noise σ per set, log-uniform [m]."""

DRIFT_AT_S = 0.1
"""Time [s] at which the drift strength is taken (the longest recordings' length)."""


# ---- forms ----------------------------------------------------------------------------
Build = Callable[[Actuator, float, dict], Actuator]


@dataclass(frozen=True)
class Form:
    """One functional form of a hidden effect.

    ``entry`` the catalogue entry it belongs to (``uncatalogued``, ``none``);
    ``catalogue`` whether the catalogue fits exactly this form; ``strength`` what the
    strength is, in ``unit`` (SI), log-uniform in ``[low, high]`` in magnitude,
    with a random sign when ``signed``; ``others`` the other parameters, each
    log-uniform in its ``(low, high)``; ``build(actuator, strength, others)`` the truth
    with the effect; ``named`` the class a right diagnosis names when it is not
    ``entry``: a form drawn as ``uncatalogued`` before the catalogue had its class (the
    draws keep ``entry``, so that the frozen splits stay as they were drawn).
    """

    entry: str
    name: str
    catalogue: bool
    strength: str
    unit: str
    low: float
    high: float
    build: Build
    signed: bool = False
    others: dict[str, tuple[float, float]] = field(default_factory=dict)
    named: str = ""

    @property
    def right_name(self) -> str:
        """The class a right diagnosis names (``uncatalogued``: none)."""
        return self.named or self.entry


def _friction(act: Actuator, new) -> Actuator:
    return eqx.tree_at(lambda a: a.friction, act, new)


def _set_field(getter, value):
    return lambda act: eqx.tree_at(getter, act, np.asarray(float(value)))


def _input(act: Actuator, stage) -> Actuator:
    return eqx.tree_at(lambda a: a.input_stage, act, stage)


def _output(act: Actuator, out) -> Actuator:
    return eqx.tree_at(lambda a: a.output_map, act, out)


def _extend(act: Actuator, *extensions) -> Actuator:
    for e in extensions:
        act = act.with_extension(e)
    return act


def _creep_log_law(act, s, o):
    taus = 10.0 ** np.arange(-3.5, -0.49, 0.5)  # 0.32 ms to 316 ms, 7 modes
    return _extend(act, *(Creep(s * _w(act) / taus.size, t) for t in taus))


def _creep_fractional(act, s, o):
    # J(t) ∝ t^α between the extreme time constants: a Prony series with gains ∝ τ^α
    # on log-spaced time constants.
    taus = 10.0 ** np.arange(-4.0, 0.01, 0.5)  # 0.1 ms to 1 s, 9 modes
    share = taus ** o["alpha"] / np.sum(taus ** o["alpha"])
    return _extend(act, *(Creep(s * _w(act) * g, t) for g, t in zip(share, taus, strict=True)))


def _stribeck(shape):
    def build(act, s, o):
        f = act.friction
        if shape == "lorentzian":  # the catalogue's own law
            return _friction(act, StribeckElastoPlastic(
                f.rho0, f.z_ba_forward, f.z_ba_backward, stribeck_ratio=1.0 + s,
                v_s=o["v_s"], zba_ratio=f.zba_ratio, rho1=f.rho1, rho2=f.rho2))
        return _friction(act, VariantElastoPlastic.like(
            f, stribeck_ratio=1.0 + s, v_s=o["v_s"], stribeck_shape=shape))
    return build


def _viscous(shape):
    def build(act, s, o):
        if shape == "linear":
            return _set_field(lambda a: a.friction.rho2, s)(act)
        return _friction(act, VariantElastoPlastic.like(
            act.friction, rho2=s, v_visc=o.get("v_visc", 1e-3), viscous_shape=shape))
    return build


def _damping(shape):
    def build(act, s, o):
        if shape == "linear":
            return _set_field(lambda a: a.friction.rho1, s)(act)
        return _friction(act, VariantElastoPlastic.like(
            act.friction, rho1=s, v_damp=o["v_damp"], damping_shape=shape))
    return build


def _third_order(act, s, o):
    # Split the ramp lag s between the low-pass (share) and the two-pole stage, whose
    # ramp lag is 2ζ/ω.
    tau = o["share"] * s
    omega = 2 * o["zeta"] / ((1 - o["share"]) * s)
    return _input(act, CascadeInput(SecondOrderInput(omega / (2 * math.pi), o["zeta"]),
                                    LowPassInput(tau)))


def _two_modes(act, s, o):
    return _extend(act, StructuralMode(o["frequency"], o["damping"], o["share"] * s),
                   StructuralMode(o["frequency"] * o["ratio"], o["damping2"],
                                  (1 - o["share"]) * s))


def _reaction_mode(act, s, o):
    return _extend(act, ReactionMode(o["frequency"], o["damping"], s, act.piezo.Kp,
                                     act.piezo.Dp))


def _exp_drift(act, s, o):
    return _output(act, ExponentialDrift(s / (1 - math.exp(-DRIFT_AT_S / o["time"])),
                                         o["time"]))


_MODE = {"frequency": (1.5e3, 8e3), "damping": (0.01, 0.1)}

FORMS: tuple[Form, ...] = (
    Form("creep", "one_mode", True, "total creep gain / w", "-", 0.001, 0.1,
         lambda a, s, o: _extend(a, Creep(s * _w(a), o["tau"])), others={"tau": (2e-3, 50e-3)}),
    Form("creep", "log_law", False, "total creep gain / w", "-", 0.001, 0.1, _creep_log_law),
    Form("creep", "fractional", False, "total creep gain / w", "-", 0.002, 0.2,
         _creep_fractional, others={"alpha": (0.2, 0.6)}),
    Form("stribeck", "lorentzian", True, "f_max/f_c - 1", "-", 0.01, 1.0,
         _stribeck("lorentzian"), others={"v_s": (1e-3, 10e-3)}),
    Form("stribeck", "exponential", False, "f_max/f_c - 1", "-", 0.015, 2.5,
         _stribeck("exponential"), others={"v_s": (1e-3, 10e-3)}),
    Form("stribeck", "gaussian", False, "f_max/f_c - 1", "-", 0.02, 3.0,
         _stribeck("gaussian"), others={"v_s": (2e-3, 20e-3)}),
    Form("viscous_friction", "linear", True, "rho2", "N·s/m", 0.01, 1.2, _viscous("linear")),
    Form("viscous_friction", "saturating", False, "rho2", "N·s/m", 0.1, 10.0,
         _viscous("saturating"), others={"v_visc": (1e-3, 10e-3)}),
    Form("viscous_friction", "slip_only", False, "rho2", "N·s/m", 0.013, 1.4,
         _viscous("slip_only")),
    Form("contact_damping", "linear", True, "rho1", "N·s/m", 0.05, 5.0, _damping("linear")),
    Form("contact_damping", "saturating", False, "rho1", "N·s/m", 0.3, 35.0,
         _damping("saturating"), others={"v_damp": (0.1e-3, 1e-3)}),
    Form("rate_dependent_hysteresis", "first_order", True, "lag gain / w", "-", 2e-4, 0.02,
         lambda a, s, o: _extend(a, RateDependentStroke(s * _w(a), o["tau"])),
         others={"tau": (0.05e-3, 0.8e-3)}),
    Form("rate_dependent_hysteresis", "saturating", False, "lag gain / w", "-", 0.003, 0.3,
         lambda a, s, o: _extend(a, SaturatingRateStroke(s * _w(a), o["tau"], o["u_sat"])),
         others={"tau": (0.05e-3, 0.8e-3), "u_sat": (1.0, 5.0)}),
    Form("rate_dependent_hysteresis", "two_lags", False, "lag gain / w", "-", 2e-4, 0.02,
         lambda a, s, o: _extend(a, RateDependentStroke(0.5 * s * _w(a), o["tau"]),
                                 RateDependentStroke(0.5 * s * _w(a), o["tau"] * o["ratio"])),
         others={"tau": (0.05e-3, 0.4e-3), "ratio": (4.0, 16.0)}),
    Form("drive_bandwidth", "low_pass", True, "time constant", "s", 0.4e-6, 4e-6,
         lambda a, s, o: _input(a, LowPassInput(s))),
    Form("drive_bandwidth", "clipped_slew", False, "slew limit (lower is stronger)", "V/s",
         1.4e6, 1.5e6, lambda a, s, o: _input(a, ClippedSlewInput(s, o["tau"])),
         others={"tau": (0.4e-6, 0.8e-6)}),
    Form("drive_bandwidth", "third_order", False, "ramp lag 2ζ/ω + τ", "s", 1e-6, 5e-6,
         _third_order, others={"zeta": (0.4, 0.7), "share": (0.2, 0.5)}),
    Form("structural_mode", "single", True, "compliance", "m/N", 5.5e-9, 5.5e-7,
         lambda a, s, o: _extend(a, StructuralMode(o["frequency"], o["damping"], s)),
         signed=True, others=dict(_MODE)),
    Form("structural_mode", "two_modes", False, "compliance (sum of both)", "m/N", 7e-9, 7e-7,
         _two_modes, signed=True,
         others={**_MODE, "ratio": (1.5, 3.0), "damping2": (0.01, 0.1), "share": (0.3, 0.7)}),
    Form("structural_mode", "reaction_mode", False, "compliance", "m/N", 8e-9, 8e-7,
         _reaction_mode, signed=True, others=dict(_MODE)),
    Form("sensor_delay", "pure_delay", True, "delay", "s", 0.2e-6, 20e-6,
         lambda a, s, o: _output(a, SensorOutput(delay=s))),
    Form("sensor_delay", "low_pass", False, "time constant", "s", 0.2e-6, 20e-6,
         lambda a, s, o: _output(a, SensorLowPass(s))),
    Form("sensor_drift", "linear", True, "drift at 0.1 s", "m", 1.1e-9, 110e-9,
         lambda a, s, o: _output(a, SensorOutput(drift=s / DRIFT_AT_S)), signed=True),
    Form("sensor_drift", "exponential", False, "drift at 0.1 s", "m", 1e-9, 100e-9,
         _exp_drift, signed=True, others={"time": (10e-3, 100e-3)}),
    Form("external_load", "constant", True, "force", "N", 5e-5, 5e-3,
         lambda a, s, o: _set_field(lambda x: x.slider.F_ext, s)(a), signed=True),
    Form("external_load", "spring", False, "stiffness", "N/m", 16.0, 1600.0,
         lambda a, s, o: _set_field(lambda x: x.slider.k_load, s)(a)),
    Form("uncatalogued", "position_ripple", False, "force amplitude", "N", 8e-5, 8e-3,
         lambda a, s, o: _extend(a, PositionRipple(s, o["wavelength"])),
         others={"wavelength": (0.3e-6, 3e-6)}),
    Form("uncatalogued", "interferometer", False, "amplitude", "m", 0.36e-9, 36e-9,
         lambda a, s, o: _output(a, PeriodicSensorError(s, 316.4e-9)),
         named="sensor_periodic"),
    Form("uncatalogued", "coulomb_drag", False, "force", "N", 5e-5, 5e-3,
         lambda a, s, o: _extend(a, CoulombDrag(s, 1e-4))),
)
"""Every form of every hidden effect (see the module docstring's table)."""

NULL = Form("none", "null", False, "", "", 0.0, 0.0, lambda a, s, o: a)

EFFECTS: tuple[str, ...] = tuple(dict.fromkeys(f.entry for f in FORMS))
"""The hidden effects other than none: the catalogue entries that can show in this
protocol, then ``uncatalogued``."""

CLASSES: tuple[str, ...] = tuple(dict.fromkeys(f.right_name for f in FORMS))
"""The classes a right diagnosis names (``uncatalogued``: none): :data:`EFFECTS` and
the classes of forms drawn as ``uncatalogued`` that the catalogue now has."""


def forms_of(entry: str) -> tuple[Form, ...]:
    """The forms of ``entry`` (``none``: the null form)."""
    if entry == "none":
        return (NULL,)
    found = tuple(f for f in FORMS if f.entry == entry)
    if not found:
        raise KeyError(f"no forms for {entry!r}; effects: {', '.join(EFFECTS)}, none")
    return found


def form(entry: str, name: str) -> Form:
    """The form ``name`` of ``entry``."""
    for f in forms_of(entry):
        if f.name == name:
            return f
    raise KeyError(f"{entry!r} has no form {name!r}")


# ---- sets ------------------------------------------------------------------------------
@dataclass(frozen=True)
class SetSpec:
    """Everything one random set is made from (:func:`draw_set`); SI units."""

    seed: int
    """The split's seed."""
    index: int
    """The set's index in the split."""
    effect: str
    """Catalogue entry hidden, ``uncatalogued`` or ``none``."""
    form: str
    """Its functional form (:data:`FORMS`)."""
    catalogue_form: bool
    """Whether the catalogue fits exactly this form."""
    strength: float
    """In :attr:`strength_unit` (signed where the form is); 0 for a null set."""
    strength_name: str
    strength_unit: str
    others: dict
    """The form's other parameters (SI)."""
    noise_m: float
    """White noise σ [m]."""
    truth: dict
    """The truth without the effect: a parameter dictionary (docs/model.md)."""
    truth_factors: dict
    """The factors the truth was drawn with (:data:`~.truth.TRUTH_RANGES`)."""
    recording_seed: int
    """The noise draw's seed."""
    also: tuple = ()
    """Further hidden effects (compound sets of version 2): dictionaries with
    ``effect``, ``form``, ``strength`` and ``others`` as above."""
    version: int = 1
    """The split design's version (:class:`SplitDesign`)."""

    @property
    def hidden(self) -> tuple[str, ...]:
        """The class of every effect hidden, as a right diagnosis names it
        (:attr:`Form.right_name`): :attr:`effect`'s, then those of :attr:`also`."""
        if self.effect == "none":
            return ("none",)
        return tuple(form(e, f).right_name for e, f in
                     ((self.effect, self.form), *((e["effect"], e["form"]) for e in self.also)))

    @property
    def name(self) -> str:
        """Folder name, ``set_NN``."""
        return f"set_{self.index:02d}"

    def to_json(self) -> dict:
        """A JSON-ready dictionary of the spec."""
        return dataclasses.asdict(self)


def _null_place(seed: int, block: int, size: int) -> int:
    return int(np.random.default_rng([seed, block, 0]).integers(size))


def _effect_at(seed: int, index: int, size: int = 3) -> str:
    """The effect of set ``index``: one null per block of ``size`` at a seed-drawn
    place; the others run through seed-shuffled rounds of :data:`EFFECTS`."""
    block, place = divmod(index, size)
    null_place = _null_place(seed, block, size)
    if place == null_place:
        return "none"
    j = (size - 1) * block + place - (place > null_place)  # non-null sets before it
    rnd, pos = divmod(j, len(EFFECTS))
    return EFFECTS[int(np.random.default_rng([seed, rnd, 1]).permutation(len(EFFECTS))[pos])]


def _is_compound(seed: int, index: int, design: SplitDesign) -> bool:
    block, place = divmod(index, design.block)
    return (design.compound and block % 2 == 1
            and place == (_null_place(seed, block, design.block) + 1) % design.block)


def _draw_effect(rng: np.random.Generator, f: Form) -> tuple[float, dict]:
    """A strength (signed where the form is) and the other parameters of form ``f``."""
    strength = log_uniform(rng, f.low, f.high)
    if f.signed and rng.uniform() < 0.5:
        strength = -strength
    return strength, {k: log_uniform(rng, lo, hi) for k, (lo, hi) in f.others.items()}


def _second_effect(rng: np.random.Generator, first: str) -> dict:
    """A second effect for a compound set whose first is ``first``: a catalogue entry
    acting in another place (:data:`PLACES`), its form and values drawn as a first's."""
    entries = [e for e in EFFECTS if e in PLACES and PLACES[e] != PLACES[first]]
    effect = entries[int(rng.integers(len(entries)))]
    forms = forms_of(effect)
    f = forms[int(rng.integers(len(forms)))]
    strength, others = _draw_effect(rng, f)
    return {"effect": effect, "form": f.name, "catalogue_form": f.catalogue,
            "strength": strength, "others": others}


def draw_set(seed: int, index: int, design: SplitDesign = V1) -> SetSpec:
    """The spec of set ``index`` of the split with seed ``seed`` drawn by ``design``
    (deterministic; version 1's draws are those before version 2 existed)."""
    if index < 0:
        raise ValueError(f"index must be ≥ 0, got {index}")
    effect = _effect_at(seed, index, design.block)
    rng = np.random.default_rng([seed, index, 2])
    truth, factors = draw_truth(rng)
    noise = log_uniform(rng, *NOISE_RANGE_M)
    rec_seed = int(rng.integers(2**31))
    forms = forms_of(effect)
    f = forms[int(rng.integers(len(forms)))]
    strength, others = (0.0, {}) if effect == "none" else _draw_effect(rng, f)
    also = ()
    if design.pi_grid:  # streams of their own: version 1's draws stay as they were
        truth, drawn = draw_pi_grid(np.random.default_rng([seed, index, 3]), truth, factors)
        factors = {**factors, **drawn}
    if effect in PLACES and _is_compound(seed, index, design):
        also = (_second_effect(np.random.default_rng([seed, index, 4]), effect),)
    return SetSpec(seed, index, effect, f.name, f.catalogue, strength, f.strength, f.unit,
                   others, noise, truth, factors, rec_seed, also, design.version)


def fixed_set(effect: str, form_name: str, strength: float, *, others: dict | None = None,
              noise_m: float = 1e-9, truth: dict | None = None) -> SetSpec:
    """A set chosen rather than drawn (calibration, tests): the form's other parameters
    at the geometric middle of their ranges unless given, the central truth
    (:func:`~.truth.identification_truth`) unless given; seed and index −1."""
    from .truth import identification_truth

    f = form(effect, form_name)
    mid = {k: math.sqrt(lo * hi) for k, (lo, hi) in f.others.items()}
    return SetSpec(-1, -1, effect, f.name, f.catalogue, float(strength), f.strength, f.unit,
                   {**mid, **(others or {})}, float(noise_m),
                   identification_truth() if truth is None else truth, {}, 0)


def draw_split(seed: int, n: int | None = None, design: SplitDesign = V1) -> list[SetSpec]:
    """Sets ``0 … n−1`` (default the design's size) of the split with seed ``seed``."""
    return [draw_set(seed, i, design) for i in range(design.size if n is None else n)]


def split_sets(name: str, n: int | None = None) -> list[SetSpec]:
    """The sets of the split ``name`` (:data:`SPLITS`)."""
    seed, design = SPLITS[name]
    return draw_split(seed, n, design)


def truth_actuator(spec: SetSpec) -> Actuator:
    """The set's truth without its effect."""
    return actuator_from_params(spec.truth)


def hidden_actuator(spec: SetSpec) -> Actuator:
    """The set's truth with its hidden effects."""
    act = form(spec.effect, spec.form).build(truth_actuator(spec), spec.strength, spec.others)
    for e in spec.also:
        act = form(e["effect"], e["form"]).build(act, e["strength"], e["others"])
    return act


def _drives(drives):
    from ..synthetic import paper_protocol

    return paper_protocol() if drives is None else list(drives)


def make_recordings(spec: SetSpec, drives: Sequence | None = None, *,
                    stepping=REFERENCE_STEPPING) -> list:
    """The set's recordings: ``drives`` (:class:`~stickslip_jax.synthetic.DriveSpec`;
    default the 17 of :func:`~stickslip_jax.synthetic.paper_protocol`) simulated from
    the truth with the effect, plus the set's noise."""
    from ..synthetic import simulate_set

    return simulate_set(hidden_actuator(spec), _drives(drives), noise_m=spec.noise_m,
                        seed=spec.recording_seed, stepping=stepping)


def _offset_removed(x: np.ndarray) -> np.ndarray:
    return x - np.mean(x)


def effect_size(spec: SetSpec, drives: Sequence | None = None, *,
                stepping=REFERENCE_STEPPING, beyond_baseline: bool = False,
                fix: dict | None = None) -> dict[str, float]:
    """How large the hidden effect is on the recordings, from the noise-free traces of
    ``drives`` simulated with and without it (same truth, same ``stepping``), over all
    samples of all recordings [m] (all 0 for a null set):

    - ``rms_m``: RMS of (with − without), each recording's mean difference removed
      (every fit removes each recording's offset, so an offset alone shows nothing);
      ``to_noise`` its ratio to the set's σ: *the* effect size of the benchmarks;
    - ``rms_raw_m``: the same with the offsets kept;
    - with ``beyond_baseline``, ``beyond_baseline_m`` and its ratio
      ``beyond_to_noise``: the RMS of the part of the offset-removed difference that
      the baseline's free parameters (those ``diagnose`` fits, ``fix`` held; default
      Ms) cannot absorb to first order at the truth: the difference minus its
      least-squares projection on their Jacobian (default stepping). About 20 s more
      on the 17 recordings.
    """
    keys = ("rms_m", "to_noise", "rms_raw_m")
    if spec.effect == "none":
        return dict.fromkeys(keys + (("beyond_baseline_m", "beyond_to_noise")
                                     if beyond_baseline else ()), 0.0)
    from ..simulate import simulate_recordings

    recs = [d.recording() for d in _drives(drives)]
    with_effect = simulate_recordings(hidden_actuator(spec), recs, stepping=stepping)
    without = simulate_recordings(truth_actuator(spec), recs, stepping=stepping)
    diffs = [a - b for a, b in zip(with_effect, without, strict=True)]
    raw = np.concatenate(diffs)
    centred = np.concatenate([_offset_removed(d) for d in diffs])
    rms = float(np.sqrt(np.mean(centred**2)))
    out = {"rms_m": rms, "to_noise": rms / spec.noise_m,
           "rms_raw_m": float(np.sqrt(np.mean(raw**2)))}
    if beyond_baseline:
        recs = [r.with_position_m(q) for r, q in zip(recs, with_effect, strict=True)]
        left = _beyond_baseline(truth_actuator(spec), recs, diffs,
                                {"Ms": spec.truth["Ms"]} if fix is None else fix)
        out.update(beyond_baseline_m=left, beyond_to_noise=left / spec.noise_m)
    return out


def _beyond_baseline(act: Actuator, recs: list, diffs: list[np.ndarray], fix: dict) -> float:
    """RMS [m] of the offset-removed differences ``diffs`` less their least-squares
    projection on the Jacobian of the (offset-removed) simulated traces in the
    baseline parameters at ``act`` (see :func:`effect_size`)."""
    from ..diagnose.problem import baseline_free
    from ..identify.dataset import Dataset
    from ..identify.parameters import ParameterMap
    from ..identify.residuals import TraceResiduals
    from ..identify.solve import value_and_jacobian

    data = Dataset.from_recordings(recs)
    pmap = ParameterMap.make(act, baseline_free(act, data, fix))
    _, jac = value_and_jacobian(TraceResiduals.make(pmap, data, in_metres=True),
                                pmap.zeros())
    # The residual vector's layout: recordings padded to the longest, padding 0.
    mask = np.asarray(data.mask) > 0
    d = np.zeros(mask.shape)
    for i, x in enumerate(diffs):
        d[i, mask[i]] = _offset_removed(x)
    d = d.reshape(-1)
    norms = np.linalg.norm(jac, axis=0)
    q, _ = np.linalg.qr(jac / np.where(norms > 0, norms, 1.0))
    left = d - q @ (q.T @ d)
    return float(np.sqrt(left @ left / mask.sum()))

"""Drive bandwidth: the piezo voltage lags the command, cannot follow its fast edges,
or overshoots them."""

from __future__ import annotations

from typing import final

import equinox as eqx
import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.extensions import (
    LowPassInput,
    ParallelInputs,
    SecondOrderInput,
    ShapedSlewInput,
    SlewLimitedInput,
)
from ...model.stages import IdentityInput
from ..form_band import draw_band
from .base import CatalogueEntry, Probe
from .slots import carry_input_stage

PROBE_TAU_DRIVE = 20e-6
"""Time constant [s] of the drive low-pass probe; its strength is the mix."""
PROBE_TAU_SLEW = 5e-6
"""Small-signal time constant [s] of the slew-limit probe (chosen above the RK4
stability limit of the default sub-step, 2.5 µs at 25 kHz, when the stage took RK4
steps; it now advances exactly, :mod:`stickslip_jax.model.slew_exact`)."""
SLEW_TAU_FLOOR_SHARE = 0.01
"""Least small-signal time constant a refit gives the slew limit, as a share of the
shortest sample interval [-]. Towards τ = 0 the tanh becomes a sign and the derivatives
in τ vanish: a fit walked it from 5 µs to 1e-280 s on 40 µs samples, where no later
fit could move it. A judgment, not a resolution limit: the data see τ mostly as the
stage's steady lag on a ramp (slope·τ), which stays visible below a hundredth of a
sample on fast ramps. The floor also acts as where the held sizing leaves τ (it walks
to the floor with the baseline held), so the refit's start: from a thousandth, one
concealed set's drive refit stalled near the floor (1.23e5 against 80 669 from a
hundredth) and a dev set's reached a better fit below a hundredth (27 847 against
35 405). Neither is a reason for a value (8e406bf; benchmarks/experiments/results/
diagnose_set03_slew_exact.json and diagnose_dev_slew_exact.json)."""


SECOND_POLE_SHARE = 0.25
"""Where a fitted low-pass's second pole starts, as a share of its time constant [-]:
the refit moves it either way (a log quantity); started at the fitted pole it would be
that pole's twin (no new shape to first order). A fitted complex pair's real pole
starts at the same share of its natural period over 2π, ``1/(2π·f₀)``."""


@final
class DriveBandwidthEntry(CatalogueEntry):
    """A slow drive in the input slot: a first-order low-pass (time constant [s]), a
    slew-rate limit (slew [V/s], small-signal time constant [s]) or an under-damped
    two-pole amplifier (corner frequency [Hz], damping [-], seeded only)."""

    name = "drive_bandwidth"
    slot = "input_stage"
    signature = ("the piezo voltage lags the command (low-pass) or cannot follow fast "
                 "edges (slew limit), or overshoots them (under-damped two-pole "
                 "amplifier): edges and slips change with the drive")

    def probes(self, act, hints):
        """Two forms of a slow drive side by side in the input slot
        (:class:`ParallelInputs`): a first-order low-pass and a slew-rate limit at half
        the fastest slope the commands have (a stage that never limits leaves no
        trace). An under-damped amplifier is not probed: its first-order score at zero
        effect is unreliable (the cost is rugged in the corner frequency), so it enters
        through :meth:`seeds`."""
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
                                install(SlewLimitedInput(slew, PROBE_TAU_SLEW, 0.0)), mix(1),
                                +1, {"form": "slew", "slew": slew, "tau": PROBE_TAU_SLEW,
                                     "max_slew": top,
                                     "tau_floor": SLEW_TAU_FLOOR_SHARE
                                     * float(hints.get("sample_interval_s", 0.0))}))
        return probes

    def attach(self, act, strength, probe):
        # The probe measured a share ``mix`` of its stage's lag. A low-pass of time
        # constant mix·τ0 lags as much on a ramp; a slew limit S lags by (|u̇| − S)·t on
        # the fastest slope |u̇|, so the share maps to S = |u̇| − mix·(|u̇| − S0).
        st = probe.setting
        mix = max(float(strength), 1e-3)
        if st["form"] == "low-pass":
            # No floor on τ: the low-pass advances in closed form, apart from the
            # mechanics (:mod:`stickslip_jax.drive_path`), so a sub-µs amplifier costs
            # no sub-steps. (A floor of 2 µs, from when the stage sat inside the
            # mechanical RK4 step, started a 0.67 µs amplifier at 3x its lag, a start
            # its sizing never left.)
            new = eqx.tree_at(lambda a: a.input_stage, act,
                              LowPassInput(mix * st["tau"], 1.0))
            return new, {"drive_tau": ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0,
                                                    "s")}
        return _slew_start(act, mix, st, st["tau"])

    def attach_options(self, act, strength, probe):
        """:meth:`attach`'s start, and for a slew limit a second one whose small-signal
        lag is the probe's share too, ``τ = mix·τ0`` (not below the floor a refit gives
        τ): below its slew rate a slew limit lags by τ·u̇, so the share maps to it as a
        low-pass's does. Neither is right everywhere, so the start's cost chooses
        (:func:`~stickslip_jax.diagnose.sizing.first_order_start`): at τ0 whatever the
        share, a weak share's start lags S·τ0 (7.5 V at 1.5 V/µs) on every fast edge,
        far from a model without a drive stage; on a strong, hard limit the
        first-order share underrates τ and τ0 is the nearer start. (Measured:
        benchmarks/README.md, "A weak slew share starts with its lag scaled too".)"""
        first = self.attach(act, strength, probe)
        st = probe.setting
        floor = float(st.get("tau_floor", 0.0))
        mix = min(max(float(strength), 1e-3), 1.0)
        if st["form"] != "slew" or floor <= 0 or mix >= 1.0:
            return [first]
        return [first, _slew_start(act, mix, st, max(mix * st["tau"], floor))]

    def seeds(self, act):
        """Under-damped two-pole amplifiers over 3-20 kHz and damping 0.3-0.7: a step
        edge's overshoot sets the slip of every period, so the cost in the corner
        frequency is rugged and a start from the first-order strength is often in the
        wrong valley."""
        specs = {"drive_frequency": ParameterSpec(lambda a: a.input_stage.frequency, "log",
                                                  1.0, "Hz"),
                 "drive_damping": ParameterSpec(lambda a: a.input_stage.damping, "log", 1.0,
                                                "-")}
        return [(eqx.tree_at(lambda a: a.input_stage, act, SecondOrderInput(f0, zeta)), specs)
                for f0 in np.geomspace(3e3, 20e3, 6) for zeta in (0.3, 0.5, 0.7)]

    def refined_forms(self, act, hints):
        """The drive stage's richer forms, each starting at the fitted one:

        - a tanh slew limit gets its corner freed (:class:`ShapedSlewInput` from
          sharpness 1, the tanh itself): a current-limited amplifier follows the command
          linearly up to its slew rate and then exactly at it, a corner no tanh reaches
          (on the concealed hard-limited set the tanh's best, the baseline at its truth,
          leaves mean (e/σ)² 3.3; the shaped form reaches the noise);
        - a first-order low-pass gets a second real pole beside it
          (:class:`ParallelInputs` of two low-passes, ``u + Σ mᵢ·(sᵢ − u)``, the new one
          at mix 0 and a quarter of the fitted time constant): with both mixes free,
          ``H(s) = 1 − m₁ − m₂ + m₁/(1 + τ₁s) + m₂/(1 + τ₂s)``, two real poles and the
          zeros their mix makes (a zero, a direct feed-through), unity gain at DC;
        - an under-damped two-pole amplifier (a seed's fit) gets a real pole beside
          it, the same way: ``H(s) = ω²/(s² + 2ζωs + ω²) + m·(1/(1 + τs) − 1)``, three
          poles and the zeros the mix makes, the new one at mix 0 and
          ``τ = SECOND_POLE_SHARE/(2π·f₀)``.

        A refined stage has none: the class's filter stops at three poles."""
        stage = act.input_stage
        if type(stage) is SlewLimitedInput and float(stage.mix) == 1.0:
            start = eqx.tree_at(lambda a: a.input_stage, act,
                                ShapedSlewInput(stage.slew, stage.tau, 1.0))
            floor = min(SLEW_TAU_FLOOR_SHARE * float(hints.get("sample_interval_s", 0.0)),
                        float(stage.tau))
            return [(start, {
                "drive_slew": ParameterSpec(lambda a: a.input_stage.slew, "log", 1.0, "V/s"),
                "drive_tau": ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0, "s",
                                           floor=floor),
                "drive_sharpness": ParameterSpec(lambda a: a.input_stage.sharpness, "log",
                                                 1.0, "-")})]
        if type(stage) is LowPassInput and float(stage.mix) == 1.0:
            tau = float(stage.tau)
            start = eqx.tree_at(lambda a: a.input_stage, act, ParallelInputs((
                LowPassInput(tau, 1.0), LowPassInput(SECOND_POLE_SHARE * tau, 0.0))))

            def part(i, name):
                return lambda a: getattr(a.input_stage.stages[i], name)

            return [(start, {
                "drive_tau": ParameterSpec(part(0, "tau"), "log", 1.0, "s"),
                "drive_mix": ParameterSpec(part(0, "mix"), "linear", 0.1, "-"),
                "drive_tau2": ParameterSpec(part(1, "tau"), "log", 1.0, "s"),
                "drive_mix2": ParameterSpec(part(1, "mix"), "linear", 0.1, "-")})]
        if type(stage) is SecondOrderInput:
            tau = SECOND_POLE_SHARE / (2.0 * np.pi * float(stage.frequency))
            start = eqx.tree_at(lambda a: a.input_stage, act, ParallelInputs((
                stage, LowPassInput(tau, 0.0))))

            def pair(name):
                return lambda a: getattr(a.input_stage.stages[0], name)

            def pole(name):
                return lambda a: getattr(a.input_stage.stages[1], name)

            return [(start, {
                "drive_frequency": ParameterSpec(pair("frequency"), "log", 1.0, "Hz"),
                "drive_damping": ParameterSpec(pair("damping"), "log", 1.0, "-"),
                "drive_tau2": ParameterSpec(pole("tau"), "log", 1.0, "s"),
                "drive_mix2": ParameterSpec(pole("mix"), "linear", 0.1, "-")})]
        return []

    def describe(self, params):
        if "drive_tau2" in params and "drive_frequency" in params:
            f3 = _half_power_hz(params)
            return (f"drive filter of three poles: an under-damped pair at "
                    f"{params['drive_frequency'] / 1e3:.3g} kHz (damping "
                    f"{params['drive_damping']:.3g}) and a real pole at "
                    f"{params['drive_tau2'] * 1e6:.3g} µs (mix {params['drive_mix2']:.3g}), "
                    f"unity gain at DC"
                    + (f", half power at {f3 / 1e3:.3g} kHz" if np.isfinite(f3) else ""))
        if "drive_tau2" in params:
            f3 = _half_power_hz(params)
            return (f"drive filter of two real poles: {params['drive_tau'] * 1e6:.3g} µs "
                    f"(mix {params['drive_mix']:.3g}) and {params['drive_tau2'] * 1e6:.3g} µs "
                    f"(mix {params['drive_mix2']:.3g}), unity gain at DC"
                    + (f", half power at {f3 / 1e3:.3g} kHz" if np.isfinite(f3) else ""))
        p = params.get("drive_sharpness")
        if p is None or "drive_slew" not in params:
            return ""
        at_corner = float(np.tanh(1.0)) ** (1.0 / p)
        return (f"slew limit {params['drive_slew'] * 1e-6:.3g} V/µs after a "
                f"{params['drive_tau'] * 1e6:.3g} µs small-signal lag, corner sharpness "
                f"{p:.3g}: at a lag of S·τ it slews at {100 * at_corner:.0f} % of S (a tanh "
                f"76 %, a hard clip 100 %)")

    def plot_form(self, ax, params, draws=None):
        """The refined drive filter's gain against frequency (:func:`_response`), with
        its 95 % band (``draws``)."""
        if "drive_tau2" not in params:
            return False
        f = np.geomspace(10.0, 1e7, 600)
        banded = draw_band(ax, f, lambda p: np.abs(_response(p, f)), params, draws)
        ax.loglog(f, np.abs(_response(params, f)), color="tab:blue")
        f3 = _half_power_hz(params)
        if np.isfinite(f3):
            ax.axvline(f3, color="0.5", linestyle=":", label=f"half power {f3 / 1e3:.3g} kHz")
        if np.isfinite(f3) or banded:
            ax.legend(fontsize=7)
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("piezo voltage per command [-]")
        ax.set_title("drive filter found", fontsize=9)
        return True

    def carry(self, init, fitted):
        return carry_input_stage(init, fitted)


def _slew_start(act, mix: float, setting: dict, tau: float):
    """``act`` with the slew limit a probe of ``setting`` measured a share ``mix`` of
    (:meth:`DriveBandwidthEntry.attach`), its small-signal lag ``tau`` [s], and the
    parameters a refit frees."""
    top = setting["max_slew"]
    slew = max(top - min(mix, 1.0) * (top - setting["slew"]), 0.05 * top)
    new = eqx.tree_at(lambda a: a.input_stage, act, SlewLimitedInput(slew, tau))
    return new, {"drive_slew": ParameterSpec(lambda a: a.input_stage.slew, "log", 1.0, "V/s"),
                 "drive_tau": ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0, "s",
                                            floor=min(setting.get("tau_floor", 0.0), tau))}


def _response(params, f):
    """``H(2πif)`` of the refined drive filter of ``params`` (:meth:`DriveBandwidthEntry.
    refined_forms`): ``1 − m₁ − m₂ + m₁/(1 + τ₁s) + m₂/(1 + τ₂s)`` (two real poles), or
    ``ω²/(s² + 2ζωs + ω²) + m₂·(1/(1 + τ₂s) − 1)`` (a complex pair and a real pole)."""
    s = 2j * np.pi * np.asarray(f)
    m2 = params["drive_mix2"]
    extra = m2 * (1 / (1 + params["drive_tau2"] * s) - 1)
    if "drive_frequency" in params:
        w = 2 * np.pi * params["drive_frequency"]
        return w**2 / (s**2 + 2 * params["drive_damping"] * w * s + w**2) + extra
    m1 = params["drive_mix"]
    return 1 - m1 + m1 / (1 + params["drive_tau"] * s) + extra


def _half_power_hz(params) -> float:
    """The lowest frequency [Hz] where the refined filter's gain falls below 1/√2: on
    a 1 Hz-100 MHz grid, interpolated in log gain against log frequency between the
    grid points either side (NaN when it never falls there)."""
    f = np.geomspace(1.0, 1e8, 4001)
    log_gain = np.log(np.abs(_response(params, f)))
    below = np.nonzero(log_gain < np.log(np.sqrt(0.5)))[0]
    if not below.size or below[0] == 0:
        return float("nan")
    k = below[0]
    w = (np.log(np.sqrt(0.5)) - log_gain[k - 1]) / (log_gain[k] - log_gain[k - 1])
    return float(np.exp(np.log(f[k - 1]) + w * (np.log(f[k]) - np.log(f[k - 1]))))

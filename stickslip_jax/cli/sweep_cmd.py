"""``stickslip sweep``: velocity map over an amplitude × frequency × direction grid."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import (
    check_amplitudes,
    check_frequencies,
    check_outputs,
    check_periods,
    fail,
    load_actuator,
    make_folders,
    reported_errors,
    setup_jax,
)

EPILOG = """Examples:

  stickslip sweep --amplitudes 10:80:15 --frequencies 50,100,200,500,1000 --out out/sweep

  stickslip sweep --params P.json --amplitudes 20,40,60 --frequencies 100:1000:10
  --directions backward --periods 20 --chunk 64 --out out/sweep --force

Writes DIR/velocity_map.csv (amplitude_V, frequency_Hz, direction, velocity_um_s,
step_nm, regime) and DIR/velocity_map.png. Velocity is phase-locked (period end to
period end) over the periods after --settle start-up periods. The grid runs as one
compiled, vmapped simulation sharded over every JAX device; --chunk bounds memory.
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
        from ..sweep import DriveGrid, parse_values, velocity_map

        try:
            amps = parse_values(amplitudes, name="--amplitudes")
            freqs = parse_values(frequencies, name="--frequencies")
            check_amplitudes(amps, "--amplitudes")
            check_frequencies(freqs, "--frequencies")
            grid = DriveGrid.make(amps, freqs, directions)
        except ValueError as err:
            raise fail(str(err)) from None
        check_periods(periods, settle)
        if chunk is not None and chunk < 1:
            raise fail("--chunk must be ≥ 1")
        if sample_rate < 2 * float(grid.frequency_Hz.max()):
            raise fail(f"--sample-rate {sample_rate:g} Hz is below twice the highest "
                       f"frequency; at least 20 samples per period are advisable")
        csv_path, fig_path = out / "velocity_map.csv", out / "velocity_map.png"
        check_outputs({csv_path: None, None if no_figure else fig_path: None}, force=force,
                      inputs=[params, zba_surface])
        actuator = load_actuator(params, zba_surface)
        typer.echo(f"{len(grid)} grid point(s), {periods} periods each", err=True)
        last = [-1]

        def progress(done, total):
            pct = 100 * done // total
            if pct // 10 != last[0] // 10:
                last[0] = pct
                typer.echo(f"  {done}/{total} points", err=True)

        vmap_ = velocity_map(actuator, grid, periods=periods, settle=settle,
                             sample_rate_Hz=sample_rate, chunk=chunk, progress=progress)
        make_folders(csv_path)
        vmap_.save_csv(csv_path, force=force)
        if not no_figure:
            vmap_.plot(fig_path)
    run = vmap_.run
    typer.echo(f"simulated {run.samples_needed} samples ({run.samples_simulated} with slot "
               f"padding) in {run.segments_run} segments of {run.chunk} slots on "
               f"{run.devices} device(s), {run.wall_s:.1f} s")
    typer.echo(f"wrote {csv_path}" + ("" if no_figure else f" and {fig_path}"))

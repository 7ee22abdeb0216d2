"""``stickslip zba-surface``: z_ba per stepping recording (one batched solve) and a
smooth surface z_ba(amplitude, frequency, direction)."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import fail, load_actuator, reported_errors, setup_jax

EPILOG = """Examples:

  stickslip zba-surface grid_recordings/ --params out/id/params.json --out out/zba

  stickslip sweep --params out/id/params.json --zba-surface out/zba/zba_surface.json
  --out out/sweep

Writes DIR/zba_points.csv (per recording: drive, z_ba, standard error, NRMSE,
converged, determined), DIR/zba_surface.json (per direction: a quadratic in amplitude
and log10 frequency, its ranges, RMS, leave-one-out RMS and R²) and DIR/zba_surface.png.
Only the sawtooth recordings are used; all other parameters stay at --params.
"""


def zba_command(
    data: list[Path] = typer.Argument(..., help="Sawtooth recordings (files or folders), "
                                      "one per amplitude/frequency/direction."),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    params: Path | None = typer.Option(None, "--params", help="Identified parameters "
                                       "(JSON). Default: the lu2015_slc1720 profile."),
    force: bool = typer.Option(False, "--force", help="Replace existing outputs."),
) -> None:
    """Fit z_ba per recording in one vmapped solve, then a z_ba surface over the drives."""
    with reported_errors():
        setup_jax()
        from ..files import atomic_write_text, check_output_path
        from ..io import load_recordings
        from ..sweep.zba_surface import fit_zba_points, fit_zba_surface, plot_zba_surface

        recordings = load_recordings(data)
        paths = [out / n for n in ("zba_points.csv", "zba_surface.json", "zba_surface.png")]
        for p in paths:
            check_output_path(p, force=force, inputs=[r.source for r in recordings if r.source])
        actuator = load_actuator(params)
        typer.echo(f"{len(recordings)} recording(s); fitting z_ba per sawtooth recording...",
                   err=True)
        try:
            points = fit_zba_points(actuator, recordings)
        except ValueError as err:
            raise fail(str(err)) from None
        fit = fit_zba_surface(points)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(paths[0], points.to_csv())
        fit.save(paths[1], force=True)
        plot_zba_surface(points, fit, paths[2])
    n_bad = int((~points.determined).sum())
    typer.echo(f"{len(points.names)} z_ba point(s), {n_bad} not determined (excluded)")
    for name, st in fit.stats.items():
        if st.get("supported"):
            typer.echo(f"  {name}: {st['points']} points, {st['terms']} terms, RMS "
                       f"{100 * st['rms_rel']:.3f} %, leave-one-out {100 * st['loo_rms_rel']:.3f}"
                       f" %, R² {st['r2']:.5f}; supported for A in {st['amplitude_range_V']} V,"
                       f" f in {st['frequency_range_Hz']} Hz")
        else:
            typer.echo(f"  {name}: no surface ({st.get('note', '')})")
    typer.echo(f"wrote {', '.join(str(p) for p in paths)}")

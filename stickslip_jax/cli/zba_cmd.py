"""``stickslip zba-surface``: z_ba per stepping recording (one batched solve) and a
smooth surface z_ba(amplitude, frequency, direction)."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import (
    EXIT_FAILED,
    check_outputs,
    fail,
    load_actuator,
    load_recordings_reporting_all,
    reported_errors,
    setup_jax,
)

EPILOG = """Examples:

  stickslip zba-surface grid_recordings/ --params out/id/params.json --out out/zba

  stickslip sweep --params out/id/params.json --zba-surface out/zba/zba_surface.json
  --out out/sweep

Writes DIR/zba_points.csv (per recording: drive, z_ba, standard error, NRMSE,
converged, determined), DIR/zba_surface.json (per direction: a quadratic in amplitude
and log10 frequency, its ranges, RMS, leave-one-out RMS and R²) and DIR/zba_surface.png.
Only the sawtooth recordings are used; all other parameters stay at --params.

A direction needs at least 3 determined points at 2 or more amplitudes or frequencies
for a surface (the full quadratic: 7 points at 3 amplitudes x 3 frequencies); fewer
are refused before the fit. The fit weights each point by 1/standard error², so R² (of
the unweighted points) can be negative: the surface then predicts the points worse
than their mean, and the output says so.
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
        from ..files import atomic_write_text
        from ..plausibility import check_actuator_plausible
        from ..staging import staged_folder
        from ..sweep.zba_surface import (
            fit_zba_points,
            fit_zba_surface,
            plot_zba_surface,
        )

        recordings = load_recordings_reporting_all(data)
        _check_enough_recordings(recordings)
        paths = [out / n for n in ("zba_points.csv", "zba_surface.json", "zba_surface.png")]
        check_outputs(dict.fromkeys(paths), force=force,
                      inputs=[params, *(r.source for r in recordings)])
        # Locked before the fit, written whole or not at all (stickslip_jax.staging).
        with staged_folder(out, "zba-surface", force=force) as stage:
            actuator = load_actuator(params)
            check_actuator_plausible(actuator, params)
            typer.echo(f"{len(recordings)} recording(s); fitting z_ba per sawtooth recording...",
                       err=True)
            try:
                points = fit_zba_points(actuator, recordings)
            except ValueError as err:
                raise fail(str(err)) from None
            fit = fit_zba_surface(points)
            atomic_write_text(stage / paths[0].name, points.to_csv())
            plot_zba_surface(points, fit, stage / paths[2].name)
            supported = any(st.get("supported") for st in fit.stats.values())
            if supported:
                fit.save(stage / paths[1].name)
    n_bad = int((~points.determined).sum())
    typer.echo(f"{len(points.names)} z_ba point(s), {n_bad} not determined (excluded)")
    for name, st in fit.stats.items():
        if st.get("supported"):
            typer.echo(f"  {name}: {st['points']} points, {st['terms']} terms, RMS "
                       f"{100 * st['rms_rel']:.3f} %, leave-one-out {100 * st['loo_rms_rel']:.3f}"
                       f" %, R² {st['r2']:.5f}; supported for A in {st['amplitude_range_V']} V,"
                       f" f in {st['frequency_range_Hz']} Hz")
            if "r2_note" in st:
                typer.echo(f"    note: {st['r2_note']}")
        else:
            typer.echo(f"  {name}: no surface ({st.get('note', '')})")
    if not supported:
        typer.echo(f"wrote {paths[0]} and {paths[2]}")
        raise fail("no direction has enough determined z_ba points for a surface (see "
                   f"above); {paths[1].name} was not written. Fix: add stepping recordings "
                   "at more drives.", EXIT_FAILED)
    typer.echo(f"wrote {', '.join(str(p) for p in paths)}")


def _check_enough_recordings(recordings) -> None:
    """Refuse, before the fit, recordings that cannot give a surface in either direction
    even if every z_ba is determined."""
    from ..sweep.zba_surface import MIN_POINTS, N_TERMS, surface_shortfall

    saw = [r for r in recordings if r.drive.waveform == "sawtooth"]
    counts = []
    for name, backward in (("forward", False), ("backward", True)):
        drives = [(r.drive.amplitude_V, r.drive.frequency_Hz) for r in saw
                  if bool(r.drive.is_backward) == backward]
        if drives and surface_shortfall([a for a, _ in drives],
                                        [f for _, f in drives]) is None:
            return
        counts.append(f"{name} {len(drives)} at {len(set(drives))} drive(s)")
    raise fail(f"too few sawtooth recordings for a z_ba surface ({', '.join(counts)}): a "
               f"direction needs at least {MIN_POINTS} at 2 or more amplitudes or "
               f"frequencies (the full quadratic: {N_TERMS + 1} at 3 amplitudes x 3 "
               f"frequencies). Fix: add stepping (sawtooth) recordings at more drives.")

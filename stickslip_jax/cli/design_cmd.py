"""``stickslip design-experiment``: the next recordings, designed through the model to
settle what a diagnosis left open."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import (
    check_outputs,
    fail,
    load_recordings_reporting_all,
    parse_fix,
    reported_errors,
    setup_jax,
)

EPILOG = """Examples:

  stickslip design-experiment my_runs/ --diagnosis out/diag --out out/plan --fix Ms=0.0247

  stickslip design-experiment my_runs/ --diagnosis out/diag --out out/plan --total-time 0.5
  --max-voltage 80 --entries creep,rate_dependent_hysteresis

Reads the diagnosis's diagnosis.json, params.json, baseline_params.json and rivals/.
Writes plan.json, plan.md, drives/NAME.csv (one per proposed recording: the recording
format without a position column, for a signal generator or `stickslip simulate
--voltage-from`) and figures/plan.png. Exit codes: 0 done; 2 bad input.
"""


def design_command(
    data: list[Path] = typer.Argument(..., help="The recordings the diagnosis was run on "
                                      "(files and/or folders)."),
    diagnosis: Path = typer.Option(..., "--diagnosis", help="The diagnosis's output folder "
                                   "(or its diagnosis.json)."),
    out: Path = typer.Option(..., "--out", help="Output folder for plan.json, plan.md, "
                             "drives/ and figures/."),
    total_time: float | None = typer.Option(None, "--total-time", help="Recording time the "
                                            "plan may take [s] (default: as long as the "
                                            "recordings given, together)."),
    max_voltage: float | None = typer.Option(None, "--max-voltage", help="The amplifier's "
                                             "largest amplitude [V] (default: the largest "
                                             "the recordings drove)."),
    min_frequency: float | None = typer.Option(None, "--min-frequency", help="Lowest drive "
                                               "frequency [Hz] (default: the recordings' "
                                               "lowest)."),
    max_frequency: float | None = typer.Option(None, "--max-frequency", help="Highest drive "
                                               "frequency [Hz] (default: four times the "
                                               "recordings' highest, at least 25 samples "
                                               "a period)."),
    entries: str = typer.Option("", "--entries", help="Comma-separated catalogue entries "
                                "to ask about (default: every tie and every entry with a "
                                "detection limit)."),
    fix: list[str] = typer.Option([], "--fix", help="Quantities the diagnosis held, as its "
                                  "--fix NAME=VALUE (SI)."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figure."),
    force: bool = typer.Option(False, "--force", help="Replace existing outputs in --out."),
) -> None:
    """Choose the drive recordings (waveform, amplitude, frequency, direction, duration)
    that best settle the diagnosis's open questions (ties between entries, entries
    below their detection limits), and write them as drive files."""
    with reported_errors():
        setup_jax()
        from ..design import DriveLimits, design_experiment
        from ..design.report import write_plan
        from ..diagnose import NAMES
        from ..staging import staged_folder

        chosen = [c.strip() for c in entries.split(",") if c.strip()] or None
        bad = [c for c in chosen or [] if c not in NAMES]
        if bad:
            raise fail(f"--entries: unknown entr(y/ies) {bad}; choose from {', '.join(NAMES)}")
        if total_time is not None and not total_time > 0:
            raise fail("--total-time must be a positive number of seconds")
        fixed = parse_fix(fix)
        recordings = load_recordings_reporting_all(data)
        inputs = [r.source for r in recordings if r.source]
        check_outputs(dict.fromkeys(out / n for n in ("plan.json", "plan.md")),
                      force=force, inputs=inputs)
        try:
            limits = DriveLimits.from_recordings(
                recordings, max_voltage_V=max_voltage, min_frequency_Hz=min_frequency,
                max_frequency_Hz=max_frequency)
        except ValueError as err:
            raise fail(f"drive limits: {err}") from None
        with staged_folder(out, "design-experiment", force=force) as stage:
            try:
                plan = design_experiment(recordings, diagnosis, total_time_s=total_time,
                                         limits=limits, fix=fixed, entries=chosen,
                                         echo=lambda s: typer.echo(s, err=True))
            except (ValueError, FileNotFoundError) as err:
                raise fail(str(err)) from None
            written = write_plan(plan, stage, figures=not no_figures)
    for q in plan.questions:
        if q.kind == "limit":
            unit = "" if q.unit in ("", "-") else f" {q.unit}"
            typer.echo(f"  {q.entry}: detection limit {q.limit_now:.3g}{unit} now, "
                       f"{q.limit_default:.3g} with the protocol again, "
                       f"{q.limit_designed:.3g} with the plan")
        else:
            typer.echo(f"  {q.label}: evidence/tolerance {q.ratio_now:.3g} now, "
                       f"{q.ratio_default:.3g} with the protocol again, "
                       f"{q.ratio_designed:.3g} with the plan (at least 1: told apart)")
    typer.echo(f"wrote {out / written['plan'].relative_to(stage)} and "
               f"{len(plan.recordings)} drive file(s) in {out / 'drives'}")

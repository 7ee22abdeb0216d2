"""``stickslip diagnose``: locate model/recording mismatch, name the missing physics,
add it, refit and show the fit improve."""

from __future__ import annotations

from pathlib import Path

import typer

from ..diagnose.budget import DEFAULT_WORK_BUDGET, UNIT
from .common import (
    check_outputs,
    fail,
    load_params_noting,
    load_recordings_reporting_all,
    parse_fix,
    reported_errors,
    setup_jax,
)

EPILOG = """Examples:

  stickslip diagnose fixtures/concealed/set_05 --out out/diag --fix Ms=0.0247

  stickslip diagnose fixtures/concealed/set_05 --params out/id/params.json --skip-identify
  --fix Ms=0.0247 --out out/diag

  stickslip diagnose my_runs/ --out out/diag --candidates creep,sensor_delay --max-rounds 1

Writes diagnosis.json (baseline, mismatch, missing_physics, final, verdict), report.md
and figures/. Exit codes: 0 done (whatever the verdict); 2 bad input.
"""


def diagnose_command(
    data: list[Path] = typer.Argument(..., help="Recording files and/or folders (docs/model.md "
                                      "CSV or NPZ, with a position column)."),
    out: Path = typer.Option(..., "--out", help="Output folder for diagnosis.json, "
                             "report.md and figures/."),
    params: Path | None = typer.Option(None, "--params", help="Starting parameters (JSON). "
                                       "Default: the lu2015_slc1720 profile."),
    fix: list[str] = typer.Option([], "--fix", help="Hold NAME at VALUE (SI), repeatable, "
                                  "e.g. --fix Ms=0.0247."),
    skip_identify: bool = typer.Option(False, "--skip-identify", help="Take --params as an "
                                       "identified baseline: only polish it, do not run the "
                                       "identification steps first."),
    candidates: str = typer.Option("", "--candidates", help="Comma-separated catalogue "
                                   "entries to consider (default: all)."),
    max_rounds: int = typer.Option(3, "--max-rounds", help="Accept at most this many "
                                   "effects."),
    top: int = typer.Option(3, "--top", help="Refit at most this many leading entries per "
                            "round."),
    max_steps: int = typer.Option(25, "--max-steps", help="Levenberg-Marquardt steps per "
                                  "refit."),
    no_fallback: bool = typer.Option(False, "--no-fallback", help="Do not fit the learned "
                                     "correction when no entry explains the residual."),
    work_budget: float = typer.Option(
        1.0, "--work-budget", help=f"Work the diagnosis may do, as a multiple of the "
        f"default ({DEFAULT_WORK_BUDGET:.0e} {UNIT} of counted solver work; 17-recording "
        f"sets that refit several entries spent a quarter to a half of it, 8-22 minutes "
        f"on a busy 2-core CPU): optional refits whose counted work "
        f"would pass it are skipped, and the notes say which (the baseline's own work "
        f"is counted apart, never against it); 0: no limit. Counted, not "
        f"timed: machine speed and load never change the decisions."),
    time_budget: float | None = typer.Option(
        None, "--time-budget", hidden=True, help="Replaced by --work-budget."),
    without_pass: str = typer.Option(
        "", "--without-pass", metavar="PASS[,PASS]",
        help="An ablation: leave these refit passes out of every round (first, "
             "fallback); diagnosis.json records the passes run and which pass refitted "
             "each entry."),
    with_pass: str = typer.Option(
        "", "--with-pass", metavar="PASS[,PASS]",
        help="Add opt-in refit passes after the default ones, in this order whatever "
             "the order given: rivals (entries the fallback set aside that could still "
             "tie with an acceptance), second_look (seeded entries when the explaining "
             "refits stay far from the noise), reidentify (round one of a bent "
             "identification: the leading entries attached to the identification "
             "itself), carry_on (the top three refits by ΔBIC that stopped at their step "
             "cap carried on once more). None of them changed a decision on 70 "
             "development sets."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures."),
    force: bool = typer.Option(False, "--force", help="Replace existing outputs in --out."),
) -> None:
    """Find where simulation and recordings differ, name the physics the model leaves
    out (from a catalogue of model extensions), add it, refit, and report the fit
    before and after."""
    with reported_errors():
        setup_jax()
        from ..diagnose import NAMES, DiagnoseConfig, diagnose
        from ..diagnose.report import (
            final_fit_status,
            left_line,
            named_line,
            unexplained_line,
            write_diagnosis,
        )
        from ..model.profiles import lu2015_slc1720
        from ..plausibility import check_actuator_plausible
        from ..staging import staged_folder

        chosen = [c.strip() for c in candidates.split(",") if c.strip()] or None
        bad = [c for c in chosen or [] if c not in NAMES]
        if bad:
            raise fail(f"--candidates: unknown entr(y/ies) {bad}; choose from {', '.join(NAMES)}")
        if max_rounds < 1 or top < 1 or max_steps < 1:
            raise fail("--max-rounds, --top and --max-steps must be at least 1")
        if time_budget is not None:
            # Refused, not mapped: a budget in seconds would make the verdict depend on
            # the machine's speed and load (issue #27).
            raise fail("--time-budget is replaced by --work-budget: a multiple of the "
                       "default counted work (1 = default, 2 = twice, 0 = no limit), "
                       "so that machine load never changes the decisions")
        if work_budget < 0:
            raise fail("--work-budget must be 0 (no limit) or a positive multiple of the "
                       "default")
        try:
            config = DiagnoseConfig().without(
                *[p.strip() for p in without_pass.split(",") if p.strip()])
        except ValueError as err:
            raise fail(f"--without-pass: {err}") from None
        try:
            config = config.with_passes(*[p.strip() for p in with_pass.split(",")
                                          if p.strip()])
        except ValueError as err:
            raise fail(f"--with-pass: {err}") from None
        if skip_identify and params is None:
            raise fail("--skip-identify needs --params (the identified baseline)")
        fixed = parse_fix(fix)
        recordings = load_recordings_reporting_all(data)
        inputs = [r.source for r in recordings if r.source]
        names = ["diagnosis.json", "report.md", "params.json",
                 "baseline_params.json"] + ([] if no_figures else [
            f"figures/{n}.png" for n in ("residual_map", "overlays", "residual_psd")])
        check_outputs(dict.fromkeys(out / n for n in names), force=force,
                      inputs=[params, *inputs])
        start = load_params_noting(params) if params is not None else lu2015_slc1720()
        check_actuator_plausible(start, params)
        # Locked before the diagnosis, written whole or not at all (stickslip_jax.staging).
        with staged_folder(out, "diagnose", force=force) as stage:
            typer.echo(f"{len(recordings)} recording(s); start: "
                       f"{params if params is not None else 'profile lu2015_slc1720'}",
                       err=True)
            try:
                result = diagnose(recordings, init=start, fix=fixed,
                                  identify_steps=() if skip_identify else
                                  ("dynamics", "hysteresis", "friction", "joint"),
                                  candidates=chosen, config=config,
                                  max_rounds=max_rounds, top=top,
                                  max_steps=max_steps, fallback=not no_fallback,
                                  work_budget=work_budget * DEFAULT_WORK_BUDGET,
                                  echo=lambda s: typer.echo(s, err=True))
            except ValueError as err:
                raise fail(str(err)) from None
            written = write_diagnosis(result, stage, inputs=inputs, figures=not no_figures)
    written = {k: out / p.relative_to(stage) for k, p in written.items()}
    typer.echo(f"verdict: {result.verdict}")
    typer.echo(f"NRMSE {100 * result.nrmse_baseline.mean():.4f} % -> "
               f"{100 * result.nrmse_final.mean():.4f} %")
    for c in result.accepted:
        typer.echo(f"  named: {named_line(c)}")
    if result.left is not None:
        typer.echo(f"  left: {left_line(result.left)}")
    if result.unexplained is not None:
        typer.echo(f"  {unexplained_line(result)}")
    marked = ("" if final_fit_status(result) is None else
              " (marked misspecified: it does not describe these recordings to the noise)")
    typer.echo(f"wrote {written['diagnosis']} and {written['report']}; the final model "
               f"{written['params']}{marked}")

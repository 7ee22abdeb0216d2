"""``stickslip identify``: fit an actuator to a set of interferometer recordings."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import (
    EXIT_FAILED,
    EXIT_MISSPECIFIED,
    check_outputs,
    fail,
    load_params_noting,
    load_recordings_reporting_all,
    parse_fix,
    reported_errors,
    setup_jax,
)

EPILOG = """Examples:

  stickslip identify fixtures/identification --out out/id

  stickslip identify fixtures/identification/*.csv --out out/id --fix Ms=0.0247
  --init fixtures/reference/params.json

  stickslip identify my_runs/ --out out/id --steps dynamics,hysteresis --force

Exit codes: 0 converged; 2 bad input; 3 a fit did not converge (the parameters are
then written as params.unconverged.json, never as params.json; an early step's cap
does not count when a later step refitted its parameters and converged), or the
recordings
cannot determine a parameter of the steps asked for: nothing is fitted and nothing
written, and the message names the parameters, why, and the recording that would
determine them (a step response for Mp, Dp, Kp, Ds, rho0; a sine for the PI weights;
a sawtooth that steps, per direction, for z_ba). --steps limits the check to the
steps asked for: sine recordings alone can still be fitted with --steps hysteresis;
4 the fit converged but the model does not describe the recordings (its error is
larger than their noise; fit.json: model_check): params.json is written, marked
"fit_status": "misspecified: ...". Whenever the residual is beyond the noise, each
value is printed with its spread over leave-one-regime-out fits beside its standard
error (which assumes the model right). `stickslip diagnose` names what is left out.
"""


def identify_command(
    data: list[Path] = typer.Argument(..., help="Recording files and/or folders (docs/model.md "
                                      "CSV or NPZ, with a position column)."),
    out: Path = typer.Option(..., "--out", help="Output folder for params.json, fit.json "
                             "and figures/."),
    init: Path | None = typer.Option(None, "--init", help="Starting parameters (JSON). "
                                     "Default: the lu2015_slc1720 profile."),
    fix: list[str] = typer.Option([], "--fix", help="Hold NAME at VALUE (SI), repeatable, "
                                  "e.g. --fix Ms=0.0247. Position data fix only ratios of "
                                  "masses, dampings and stiffnesses: fix one of them."),
    steps: str = typer.Option("dynamics,hysteresis,friction,joint", "--steps",
                              help="Comma-separated steps to run, in this order."),
    n_pi: int = typer.Option(35, "--n-pi", help="Number of PI play operators, spread over "
                             "the recorded voltages (replacing --init's thresholds)."),
    keep_thresholds: bool = typer.Option(False, "--keep-thresholds", help="Fit the PI "
                                         "weights on --init's own thresholds instead of "
                                         "--n-pi thresholds over the recorded voltages."),
    free_ratio: bool = typer.Option(False, "--free-ratio", help="Also fit zba_ratio "
                                    "(z_ba/z_ss; fixed at the start value otherwise)."),
    fit_rho1: bool = typer.Option(False, "--fit-rho1", help="Also fit the contact damping "
                                  "rho1."),
    max_steps: int = typer.Option(60, "--max-steps", help="Levenberg-Marquardt step limit "
                                  "per identification step."),
    no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures."),
    force: bool = typer.Option(False, "--force", help="Replace existing outputs in --out."),
) -> None:
    """Identify the actuator's parameters from recordings (Lu 2015's three steps plus a
    joint refinement), with standard errors, and write params.json, fit.json and
    figures into --out."""
    with reported_errors():
        setup_jax()
        from ..figure_helper import figure_helper
        from ..identify import STEPS, identify
        from ..identify.report import fit_summary, output_paths, write_identification
        from ..model.profiles import lu2015_slc1720
        from ..params import ParameterError
        from ..plausibility import check_actuator_plausible
        from ..staging import staged_folder

        step_list = [s.strip() for s in steps.split(",") if s.strip()]
        bad = [s for s in step_list if s not in STEPS]
        if bad or not step_list:
            raise fail(f"--steps {steps!r}: unknown step(s) {bad}; choose from "
                       f"{','.join(STEPS)}")
        if n_pi < 1:
            raise ParameterError(f"--n-pi {n_pi}: need at least one play operator")
        fixed = parse_fix(fix)
        recordings = load_recordings_reporting_all(data)
        # Every file the identification may write, checked before the fit.
        paths = [p for p in output_paths(out, recordings)
                 if not (no_figures and p.parent == out / "figures")]
        check_outputs(dict.fromkeys(paths), force=force,
                      inputs=[init, *(r.source for r in recordings)])
        from ..model.slot_files import slots_to_json

        start = load_params_noting(init) if init is not None else lu2015_slc1720()
        check_actuator_plausible(start, init)
        if init is not None and not keep_thresholds and (
                "hysteresis" in step_list or "joint" in step_list):
            n_start = int(start.hysteresis.thresholds.shape[0])
            typer.echo(f"note: the PI weights are fitted on {n_pi} thresholds over the "
                       f"recorded voltages (--n-pi), not on the {n_start} of {init}; "
                       f"--keep-thresholds keeps those", err=True)
        held = list(slots_to_json(start))
        if held:
            typer.echo(f"note: {init}'s {', '.join(held)} (what `stickslip diagnose` adds) "
                       f"are held at their values: identify fits the baseline's "
                       f"quantities", err=True)
        # Locked before the fit, written whole or not at all (stickslip_jax.staging);
        # the figures' helper process starts now, so that its start-up overlaps the fit,
        # and stops before the staged outputs are moved or removed.
        with (staged_folder(out, "identify", force=force) as stage,
              figure_helper(enabled=not no_figures) as helper):
            typer.echo(f"{len(recordings)} recording(s); start: "
                       f"{init if init is not None else 'profile lu2015_slc1720'}", err=True)
            try:
                result = identify(recordings, init=start, fix=fixed, steps=step_list,
                                  n_pi=n_pi, free_ratio=free_ratio, fit_rho1=fit_rho1,
                                  max_steps=max_steps, spread_if_mismatch=True,
                                  keep_thresholds=keep_thresholds,
                                  echo=lambda s: typer.echo(s, err=True))
            except ValueError as err:
                raise fail(str(err)) from None
            if result.undetermined is not None and result.undetermined.blocking:
                raise fail(result.undetermined.statement(), EXIT_FAILED)
            written = write_identification(result, stage, figures=not no_figures,
                                           inputs=[r.source for r in recordings if r.source],
                                           helper=helper)
            summary = fit_summary(result)
    written = {k: out / p.relative_to(stage) for k, p in written.items()}
    print_identification(result, summary, written)


def print_identification(result, summary: dict, written: dict) -> None:
    """The verdict first (when the model does not describe the recordings), then the
    fit against the noise, each parameter with its standard error (and its spread over
    leave-one-regime-out fits when beyond the noise), and what was written; exits 3 or 4
    with one ``error:`` line when the fit is not a plain result."""
    check = result.model_check
    if result.misspecified:
        typer.echo(f"MISSPECIFIED: {check.statement()}. The values below are the "
                   f"least-squares fit of a model that lacks something: their ± standard "
                   f"errors assume it does not; the spread over fits that leave one regime "
                   f"out is what holds. `stickslip diagnose` names what is missing.")
    for note in result.notes:
        typer.echo(f"note: {note}")
    o = summary["overall"]
    ratio = o["nrmse_over_floor"]  # None when the data show no noise at all
    typer.echo(f"overall NRMSE {o['nrmse_percent']:.4f} % (noise floor "
               f"{o['noise_floor_nrmse_percent']:.4f} %, ratio "
               f"{'n/a' if ratio is None else format(ratio, '.3f')})")
    if check is not None and not result.misspecified:
        typer.echo(f"check: {check.statement()}")
    for label, p in summary["parameters"].items():
        if "[" in label:
            continue
        typer.echo(f"  {label:14s} {p['value']:.6g} {_uncertainty(p)}")
    curve = summary.get("hysteresis_loading_curve")
    if curve:
        weights = [p for lab, p in summary["parameters"].items() if lab.startswith("pi_weights[")]
        top, se = curve["stroke_m"][-1], curve["stroke_std_error_m"][-1]
        typer.echo(f"  hysteresis     loading curve determined at "
                   f"{sum(curve['stroke_determined'])}/{len(curve['voltage_V'])} knots; stroke "
                   f"at {curve['voltage_V'][-1]:.3g} V {top:.6g} ± "
                   f"{'?' if se is None else format(se, '.3g')} m; individual PI weights "
                   f"determined: {sum(p['determined'] for p in weights)}/{len(weights)} "
                   f"(fit.json: hysteresis_loading_curve)")
    typer.echo(f"wrote {', '.join(str(p) for p in written.values() if p.suffix == '.json')} "
               f"and {len(written) - 2} figure(s)")
    if not result.converged:
        failed = [s.name for s in result.unconverged_steps]
        raise fail(f"step(s) {', '.join(failed)} did not converge; parameters written to "
                   f"{written['params']} (not trustworthy)", EXIT_FAILED)
    if result.misspecified:
        raise fail(f"the model does not describe these recordings (mean (e/σ)² "
                   f"{check.chi2_overall:.3g}); parameters written to {written['params']}, "
                   f"marked misspecified; run `stickslip diagnose` to name what is missing",
                   EXIT_MISSPECIFIED)


def _uncertainty(p: dict) -> str:
    """``± SE unit`` (and the regime spread where there is one) of a fit.json
    parameter entry; a held one has no standard error."""
    if not p["fitted"]:
        return f"{p['unit']}   (held: not fitted)"
    se = f"± {p['std_error']:.3g}" if p["std_error"] is not None else "± ?"
    if "regime_spread" in p:
        spread = p["regime_spread"]
        se += (f" (spread {spread:.3g} over fits leaving one regime out)" if spread
               is not None else " (no spread: fewer than two regime-out fits)")
    flag = "" if p["determined"] else "   (not determined by these data)"
    return f"{se} {p['unit']}{flag}"

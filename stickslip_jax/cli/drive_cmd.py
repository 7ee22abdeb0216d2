"""``stickslip drive``: amplitude and frequency choices for a wanted velocity."""

from __future__ import annotations

import json
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

  stickslip drive --velocity 50um/s

  stickslip drive --params out/id/params.json --velocity 0.12mm/s --direction backward
  --frequencies 100,200,500,1000 --out choices.json

  stickslip drive --velocity -50um/s        (the same as 50um/s --direction backward)

For every frequency the amplitude whose simulated steady-state velocity (phase-locked,
after --settle start-up periods) is the wanted one, found by bracketing on a velocity
map over --amplitudes and secant refinement, with the step per period it gives.
A drive counts only where it is stepping (docs/model.md, "Drives and recordings") and
within 0.5 % of the velocity; a printed row that is not is marked NOT REACHED and the
command exits 3 (frequencies beyond the amplitude range are listed, not printed as
drives).
"""


def drive_command(
    velocity: str = typer.Option(..., "--velocity", help="Wanted velocity, e.g. 50um/s, "
                                 "0.05mm/s (a bare number is µm/s). Signed as in the "
                                 "velocity map: negative is backward."),
    direction: str | None = typer.Option(None, "--direction", help="forward or backward "
                                         "(default: the sign of --velocity). With a "
                                         "positive --velocity it sets the direction; "
                                         "with a negative one it must be backward."),
    params: Path | None = typer.Option(None, "--params", help="Parameters (JSON). Default: "
                                       "the lu2015_slc1720 profile."),
    frequencies: str = typer.Option("50,100,200,500,1000", "--frequencies",
                                    help="Candidate frequencies [Hz] (list or a:b:n)."),
    amplitudes: str = typer.Option("5:100:20", "--amplitudes", help="Amplitude range [V] "
                                   "searched (list or a:b:n)."),
    periods: int = typer.Option(10, "--periods", help="Periods simulated per drive."),
    settle: int = typer.Option(2, "--settle", help="Start-up periods left out."),
    out: Path | None = typer.Option(None, "--out", help="Also write the choices as JSON."),
    force: bool = typer.Option(False, "--force", help="Replace an existing --out."),
) -> None:
    """Drives (amplitude per frequency) that move the slider at a wanted velocity."""
    with reported_errors():
        setup_jax(all_cpu_cores=True)
        from ..files import JSON_SUFFIXES, atomic_write_text
        from ..plausibility import check_actuator_plausible
        from ..staging import staged_files
        from ..sweep import drive_for_velocity, parse_values, parse_velocity

        if direction not in (None, "forward", "backward"):
            raise fail(f"--direction {direction!r}: choose forward or backward")
        try:
            wanted = parse_velocity(velocity)
            freqs = parse_values(frequencies, name="--frequencies")
            amps = parse_values(amplitudes, name="--amplitudes")
        except ValueError as err:
            raise fail(str(err)) from None
        check_amplitudes(amps, "--amplitudes")
        check_frequencies(freqs, "--frequencies")
        check_periods(periods, settle)
        if wanted < 0 and direction == "forward":
            raise fail(f"--velocity {velocity} is backward (negative) but --direction is "
                       f"forward. Fix: give the speed alone ({velocity.strip()[1:]}) with "
                       f"--direction forward, or leave out --direction.")
        direction = direction or ("backward" if wanted < 0 else "forward")
        speed = abs(wanted)
        check_outputs({out: JSON_SUFFIXES}, force=force, inputs=[params])
        # Locked before the search, written whole or not at all (stickslip_jax.staging).
        with staged_files([out], force=force) as staged:
            actuator = load_actuator(params)
            check_actuator_plausible(actuator, params)
            signed = -speed if direction == "backward" else speed
            choices, unreachable = drive_for_velocity(actuator, signed, frequencies=freqs,
                                                      amplitudes=amps, periods=periods,
                                                      settle=settle)
            if out is not None:
                payload = {"velocity_m_s": signed, "direction": direction,
                           "choices": [c.__dict__ for c in choices],
                           "unreachable_Hz": unreachable}
                atomic_write_text(staged[out], json.dumps(payload, indent=1) + "\n")
    typer.echo(f"{direction} at {speed * 1e6:g} µm/s:")
    typer.echo(f"  {'frequency_Hz':>12s} {'amplitude_V':>12s} {'velocity_um_s':>14s} "
               f"{'step_nm':>10s}  note")
    for c in choices:
        typer.echo(f"  {c.frequency_Hz:12.6g} {c.amplitude_V:12.4f} "
                   f"{c.velocity_m_s * 1e6:14.5g} {c.step_m * 1e9:10.4g}  {_note(c, signed)}")
    for f in unreachable:
        typer.echo(f"  {f:12.6g} {'-':>12s} {'-':>14s} {'-':>10s}  beyond the amplitude range")
    if out is not None:
        typer.echo(f"wrote {out}")
    missed = [c for c in choices if not c.reached]
    if missed or not choices:
        # A printed drive that does not give the velocity is not a result: exit 3.
        where = ", ".join(f"{c.frequency_Hz:g} Hz" for c in missed) or "any frequency"
        stand = "; the other rows stand" if len(missed) < len(choices) else ""
        raise fail(f"the velocity was not reached at {where}{stand}. Fix: drop those "
                   f"frequencies, or widen --amplitudes.", code=3)


def _note(choice, wanted_m_s: float) -> str:
    """Why a printed drive is not a result: off the wanted velocity, or not stepping
    (stickslip_jax.regime: velocity there is no monotone function of amplitude)."""
    if choice.reached:
        return ""
    off = 100 * (abs(choice.velocity_m_s) / abs(wanted_m_s) - 1)
    if choice.regime != "stepping":
        return f"NOT REACHED: scanning, not stepping ({off:+.1f} % off)"
    return f"NOT REACHED: {off:+.1f} % off after the refinement"

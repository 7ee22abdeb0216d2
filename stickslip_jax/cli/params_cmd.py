"""``stickslip params``: write a default profile, list the parameter names."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import check_outputs, reported_errors, setup_jax

EPILOG = """Examples:

  stickslip params --list

  stickslip params --out out/params.json
"""


def params_command(
    out: Path | None = typer.Option(None, "--out", help="Write the profile as JSON here "
                                    "(.json; values as float64, so they read back exactly)."),
    profile: str = typer.Option("lu2015_slc1720", help="Which documented profile."),
    list_names: bool = typer.Option(False, "--list", help="List every parameter name."),
    force: bool = typer.Option(False, "--force", help="Replace an existing output file."),
) -> None:
    """Write a documented parameter profile, or list the parameter names and units
    (each registered friction law's with its defaults and bounds)."""
    with reported_errors():
        from ..params import ParameterError, describe_parameters, save_params

        if list_names or out is None:
            for line in describe_parameters():
                typer.echo(line)
            if out is None:
                return
        from ..files import JSON_SUFFIXES
        from ..model.profiles import PROFILES

        if profile not in PROFILES:
            raise ParameterError(f"unknown profile {profile!r}.",
                                 fix=f"use one of {', '.join(PROFILES)}.")
        check_outputs({out: JSON_SUFFIXES}, force=force)
        # float64 before the profile is built: without it JAX stores every parameter
        # as float32 and the file would hold e.g. Ms = 0.024700000882148743.
        setup_jax()
        path = save_params(PROFILES[profile](), out, force=force)
        typer.echo(f"wrote {path}")

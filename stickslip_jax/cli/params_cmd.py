"""``stickslip params``: write a default profile, list the parameter names."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import reported_errors

EPILOG = """Examples:

  stickslip params --list

  stickslip params --out P.json
"""


def params_command(
    out: Path | None = typer.Option(None, "--out", help="Write the profile as JSON here."),
    profile: str = typer.Option("lu2015_slc1720", help="Which documented profile."),
    list_names: bool = typer.Option(False, "--list", help="List every parameter name."),
    force: bool = typer.Option(False, "--force", help="Replace an existing output file."),
) -> None:
    """Write a documented parameter profile, or list the parameter names and units."""
    with reported_errors():
        from ..params import PARAMETER_DOCS, ParameterError, save_params

        if list_names or out is None:
            for name, doc in PARAMETER_DOCS.items():
                typer.echo(f"{name:16s} {doc}")
            if out is None:
                return
        from ..model.profiles import PROFILES

        if profile not in PROFILES:
            raise ParameterError(f"unknown profile {profile!r}.",
                                 fix=f"use one of {', '.join(PROFILES)}.")
        path = save_params(PROFILES[profile](), out, force=force)
        typer.echo(f"wrote {path}")

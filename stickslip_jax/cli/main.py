"""The ``stickslip`` command line: thin commands over the library.

Heavy imports (jax, matplotlib) happen inside the commands, so ``--help`` is fast.
"""

from __future__ import annotations

import typer

from . import (
    contacts_cmd,
    diagnose_cmd,
    drive_cmd,
    identify_cmd,
    params_cmd,
    simulate,
    sweep_cmd,
    zba_cmd,
)

app = typer.Typer(
    name="stickslip",
    help="Simulate and identify piezoelectric stick-slip actuators (JAX).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.command("simulate", epilog=simulate.EPILOG)(simulate.simulate_command)
app.command("params", epilog=params_cmd.EPILOG)(params_cmd.params_command)
app.command("identify", epilog=identify_cmd.EPILOG)(identify_cmd.identify_command)
app.command("sweep", epilog=sweep_cmd.EPILOG)(sweep_cmd.sweep_command)
app.command("drive", epilog=drive_cmd.EPILOG)(drive_cmd.drive_command)
app.command("zba-surface", epilog=zba_cmd.EPILOG)(zba_cmd.zba_command)
app.command("diagnose", epilog=diagnose_cmd.EPILOG)(diagnose_cmd.diagnose_command)
app.command("contacts", epilog=contacts_cmd.EPILOG)(contacts_cmd.contacts_command)


def _version(value: bool) -> None:
    if value:
        from .. import __version__

        typer.echo(f"stickslip_jax {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
) -> None:
    """Simulate and identify piezoelectric stick-slip actuators (JAX)."""

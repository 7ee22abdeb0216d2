"""The ``stickslip`` command line: thin commands over the library.

Heavy imports (jax, matplotlib) happen inside the commands, so ``--help`` is fast.
Help is plain text (no Rich markup, which would eat "[s]" and turn "a:b:n" into an
emoji); epilog paragraphs keep their line breaks.
"""

from __future__ import annotations

import typer

from . import (
    contacts_cmd,
    design_cmd,
    diagnose_cmd,
    drive_cmd,
    identify_cmd,
    params_cmd,
    simulate,
    sweep_cmd,
    zba_cmd,
)
from .common import ReportingGroup, set_debug

EPILOG = """Exit codes: 0 done; 1 an unexpected error (a bug: rerun with --debug and report
it); 2 bad input (a wrong option, recording, parameter file or output path, refused
before any computation); 3 the computation failed (a fit did not converge, a velocity
was not reached); 4 a fit converged but the model does not describe the recordings
(identify: the parameters are written, marked misspecified); 130 interrupted by
Ctrl-C (143: SIGTERM), within a second, leaving no partial output. Errors are one
line, "error: ...", on stderr.

--debug (anywhere on the line) or STICKSLIP_DEBUG=1 shows the traceback instead.
"""


def plain_epilog(text: str) -> str:
    """``text`` with every paragraph marked to keep its line breaks (click's ``\\b``):
    the examples stay one command per line."""
    return "\n\n".join("\b\n" + p.strip("\n") for p in text.strip().split("\n\n"))


app = typer.Typer(
    name="stickslip",
    help="Simulate and identify piezoelectric stick-slip actuators (JAX).",
    epilog=plain_epilog(EPILOG),
    cls=ReportingGroup,
    rich_markup_mode=None,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
# name, module, command, one line for the command list (click would cut the docstring)
for _name, _module, _command, _short in (
    ("simulate", simulate, simulate.simulate_command,
     "Simulate the actuator; write q = x1 + x2 as a recording."),
    ("params", params_cmd, params_cmd.params_command,
     "Write a parameter profile, or list the parameter names."),
    ("identify", identify_cmd, identify_cmd.identify_command,
     "Identify the parameters from recordings."),
    ("sweep", sweep_cmd, sweep_cmd.sweep_command,
     "Velocity map over amplitude x frequency x direction."),
    ("drive", drive_cmd, drive_cmd.drive_command,
     "Amplitude per frequency for a wanted velocity."),
    ("zba-surface", zba_cmd, zba_cmd.zba_command,
     "z_ba per recording, and a surface over the drives."),
    ("diagnose", diagnose_cmd, diagnose_cmd.diagnose_command,
     "Find, name and add the physics the model leaves out."),
    ("design-experiment", design_cmd, design_cmd.design_command,
     "The next recordings: drives that settle a diagnosis's ties."),
    ("contacts", contacts_cmd, contacts_cmd.contacts_command,
     "Preload, multi-contact runners, force generation."),
):
    app.command(_name, epilog=plain_epilog(_module.EPILOG), short_help=_short)(_command)


def _version(value: bool) -> None:
    if value:
        from .. import __version__

        typer.echo(f"stickslip_jax {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
    debug: bool = typer.Option(False, "--debug", help="Show the traceback of an error "
                               "instead of the one-line message. Global: it applies to "
                               "every command and may stand anywhere on the line."),
) -> None:
    """Simulate and identify piezoelectric stick-slip actuators (JAX)."""
    set_debug(debug)

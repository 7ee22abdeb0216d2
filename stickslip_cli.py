"""The ``stickslip`` console command: Ctrl-C (or a kill) stops it within a second.

A compiled JAX loop does not return to Python for tens of seconds, and Python runs
signal handlers only between its own instructions, in the main thread; a
KeyboardInterrupt raised elsewhere (in a garbage-collection callback of XLA's) is
printed and ignored. So the command runs in a worker thread, and the main thread does
nothing but wait for it and for signals. On SIGINT or SIGTERM the handler kills the figure
helper processes (:func:`stickslip_jax.figure_helper.stop_all`), aborts the
outputs being staged (:func:`stickslip_jax.staging.abort_active`: waits for a move into
place under way, removes what was staged, releases the output locks), prints one line
and ends the process with 130 (SIGINT) or 143 (SIGTERM), whatever the worker is doing.

This module sits outside the ``stickslip_jax`` package on purpose: importing the
package imports JAX (seconds), and the handler must be in place before that.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

POLL_S = 0.1
"""How often the waiting main thread wakes [s] (a signal also wakes it at once)."""


def _stop(signum, frame) -> None:  # noqa: ARG001 - the signal module's signature
    """Abort the staged outputs, say so in one line, exit 128 + the signal number."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)  # a second Ctrl-C must not cut this short
    # The command goes on in its thread until the process ends: from here on, what it
    # prints goes nowhere (this line is the last one), and what it writes fails.
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    quiet = open(os.devnull, "w")  # noqa: SIM115 - open until the process ends
    sys.stdout = sys.stderr = quiet
    staging = sys.modules.get("stickslip_jax.staging")  # not imported: nothing staged
    helpers = sys.modules.get("stickslip_jax.figure_helper")
    try:
        if helpers is not None:  # first: no figure may land in what is removed next
            helpers.stop_all()
        if staging is not None:
            staging.abort_active(barrier=True)
        name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
        with contextlib.suppress(OSError):
            os.write(2, f"error: interrupted ({name}): stopped; no partial output was "
                        f"left\n".encode())
        if staging is not None:
            staging.lift_barriers()
    finally:
        os._exit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    """Run ``stickslip`` with ``argv`` (default: the command line) in a worker thread;
    returns its exit code."""
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("stickslip_cli.main must run in the main thread")
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _stop)
    outcome: dict[str, object] = {"code": 0}

    def work() -> None:
        try:
            from stickslip_jax.cli.main import app

            app(args=argv, prog_name="stickslip")
        except SystemExit as done:  # click ends every command this way
            outcome["code"] = done.code
        except BaseException as err:  # noqa: BLE001 - handed to the main thread
            outcome["error"] = err

    worker = threading.Thread(target=work, name="stickslip-command", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(POLL_S)
    if "error" in outcome:
        raise outcome["error"]  # type: ignore[misc]
    code = outcome["code"]
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    sys.stderr.write(f"{code}\n")
    return 1


if __name__ == "__main__":
    sys.exit(main())

"""Shared CLI plumbing: JAX set-up, error reporting, progress."""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from pathlib import Path

import typer

from ..xla_flags import add_xla_flag, fast_cpu_loops

EXIT_BAD_INPUT = 2
EXIT_FAILED = 3


def use_all_cpu_cores() -> None:
    """Expose every CPU core as a JAX device, so sharded batches (sweeps) use them all.

    XLA runs one small batched computation on one core; as separate devices the cores
    each take a shard. Must run before JAX starts its backends (too late afterwards,
    e.g. in-process tests); a device count already in ``XLA_FLAGS`` is kept, and GPU
    platforms are unaffected.
    """
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    add_xla_flag("xla_force_host_platform_device_count", n or 1)


def fast_cpu_loops_quietly() -> None:
    """:func:`~stickslip_jax.xla_flags.fast_cpu_loops`, without its warning when JAX has
    already started (a command called in-process, e.g. by the tests)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fast_cpu_loops()


def setup_jax(*, all_cpu_cores: bool = False) -> None:
    """float64, XLA's native compilation of small loops on a CPU
    (:func:`~stickslip_jax.xla_flags.fast_cpu_loops`), and a persistent compilation
    cache, so a second run skips compiling.

    The cache lives in ``$STICKSLIP_CACHE_DIR`` (default ``~/.cache/stickslip_jax``);
    set ``STICKSLIP_CACHE_DIR=off`` to disable it. ``all_cpu_cores``: see
    :func:`use_all_cpu_cores` (for batched commands).
    """
    fast_cpu_loops_quietly()
    if all_cpu_cores:
        use_all_cpu_cores()
    import jax

    jax.config.update("jax_enable_x64", True)
    cache = os.environ.get("STICKSLIP_CACHE_DIR", str(Path.home() / ".cache" / "stickslip_jax"))
    if cache.lower() != "off":
        with contextlib.suppress(Exception):  # a read-only home must not stop the tool
            Path(cache).mkdir(parents=True, exist_ok=True)
            jax.config.update("jax_compilation_cache_dir", cache)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def fail(message: str, code: int = EXIT_BAD_INPUT) -> typer.Exit:
    """Print ``error: message`` on stderr and return the Exit to raise."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


def user_errors():
    """Exception types that are the user's to fix (reported without a traceback)."""
    from ..files import InputOverwriteError, OutputExistsError
    from ..io import RecordingError
    from ..params import ParameterError

    return (RecordingError, ParameterError, OutputExistsError, InputOverwriteError,
            IsADirectoryError, FileNotFoundError)


@contextlib.contextmanager
def reported_errors():
    """Turn user errors into a one-line message and exit code 2."""
    try:
        yield
    except user_errors() as err:
        raise fail(str(err)) from None


@contextlib.contextmanager
def status(message: str):
    """A spinner on stderr while slow work runs (plain line when not a terminal)."""
    if sys.stderr.isatty():
        from rich.console import Console

        with Console(stderr=True).status(message):
            yield
    else:
        typer.echo(message, err=True)
        yield


def load_actuator(params: Path | None, zba_surface: Path | None = None):
    """The actuator of ``--params`` (default profile without it), with its z_ba read
    from ``--zba-surface`` when given. Bad files raise user errors (exit 2)."""
    from ..model.profiles import lu2015_slc1720
    from ..params import load_params

    actuator = load_params(params) if params is not None else lu2015_slc1720()
    if zba_surface is not None:
        from ..sweep.zba_surface import load_zba_surface, with_zba_surface

        try:
            actuator = with_zba_surface(actuator, load_zba_surface(zba_surface))
        except (KeyError, ValueError) as err:
            raise fail(f"--zba-surface {zba_surface}: {err}") from None
    return actuator

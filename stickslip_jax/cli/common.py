"""Shared CLI plumbing: JAX set-up, error reporting, output checks, progress.

Exit codes: 0 done; 1 an unexpected error (a bug, or a mistake the tool does not
recognise); 2 bad input (:data:`EXIT_BAD_INPUT`); 3 the computation failed, e.g. a fit
did not converge (:data:`EXIT_FAILED`); 4 a fit converged to a model that does not
describe the recordings (:data:`EXIT_MISSPECIFIED`). Every error is one ``error: ...`` line on
stderr (one per bad recording); ``stickslip --debug`` (or ``STICKSLIP_DEBUG=1``) shows
the traceback instead.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import typer
from typer.core import TyperGroup

from ..blas_threads import limit_blas_threads
from ..compilation_cache import cache_dir_from_env, use_compilation_cache
from ..io import RecordingErrors
from ..xla_flags import add_xla_flag, device_side_gpu_loops, fast_cpu_loops

EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2
EXIT_FAILED = 3
EXIT_MISSPECIFIED = 4
"""A fit converged, but the model does not describe the recordings (identify)."""

#: The most samples ``simulate`` generates: about 270 bytes of memory per sample at
#: the peak (drive, output, the solver's arrays and the CSV text), so about 2.7 GB.
MAX_SAMPLES = 10_000_000
BYTES_PER_SAMPLE = 270


def use_all_cpu_cores() -> None:
    """Expose every CPU core as a JAX device, so sharded batches (sweeps) use them all.

    XLA runs one small batched computation on one core; as separate devices the cores
    each take a shard. Must run before JAX starts its backends (too late afterwards,
    e.g. in-process tests); a device count already in ``XLA_FLAGS`` is kept, and GPU
    platforms are unaffected.
    """
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    add_xla_flag("xla_force_host_platform_device_count", n or 1)


def loop_flags_quietly() -> None:
    """:func:`~stickslip_jax.xla_flags.fast_cpu_loops` and
    :func:`~stickslip_jax.xla_flags.device_side_gpu_loops`, without their warning when
    JAX has already started (a command called in-process, e.g. by the tests)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fast_cpu_loops()
        device_side_gpu_loops()


def setup_jax(*, all_cpu_cores: bool = False) -> None:
    """float64, XLA's native compilation of small loops on a CPU
    (:func:`~stickslip_jax.xla_flags.fast_cpu_loops`) and device-side loops on a GPU
    (:func:`~stickslip_jax.xla_flags.device_side_gpu_loops`), a persistent compilation
    cache, so a second run skips compiling (:mod:`~stickslip_jax.compilation_cache`),
    and BLAS on one thread
    (:mod:`~stickslip_jax.blas_threads`; unless ``OPENBLAS_NUM_THREADS`` says otherwise).

    The cache lives in ``$STICKSLIP_CACHE_DIR`` (default ``~/.cache/stickslip_jax``);
    set ``STICKSLIP_CACHE_DIR=off`` to disable it. ``all_cpu_cores``: see
    :func:`use_all_cpu_cores` (for batched commands).
    """
    loop_flags_quietly()
    if all_cpu_cores:
        use_all_cpu_cores()
    if "OPENBLAS_NUM_THREADS" not in os.environ:
        import numpy  # noqa: F401 - loads numpy's OpenBLAS (scipy's comes with stickslip_jax)

        limit_blas_threads(1)
    import jax

    jax.config.update("jax_enable_x64", True)
    use_compilation_cache(cache_dir_from_env())


def fail(message: str, code: int = EXIT_BAD_INPUT) -> typer.Exit:
    """Print ``error: message`` on stderr (one such line per line of ``message``) and
    return the Exit to raise."""
    for line in str(message).splitlines() or [""]:
        typer.echo(f"error: {line}", err=True)
    return typer.Exit(code)


_debug = False


def set_debug(on: bool) -> None:
    """Record ``stickslip --debug`` (the app's callback, at every invocation)."""
    global _debug
    _debug = bool(on)


def debug_enabled() -> bool:
    """True under ``stickslip --debug`` or ``STICKSLIP_DEBUG=1``: errors then show their
    traceback."""
    env = os.environ.get("STICKSLIP_DEBUG", "").strip().lower()
    return _debug or env not in ("", "0", "false", "no")


def user_errors():
    """Exception types that are the user's to fix (reported without a traceback)."""
    from ..files import InputOverwriteError, OutputExistsError, OutputPathError
    from ..io import RecordingError
    from ..params import ParameterError
    from ..simulate import NonFiniteSimulation
    from ..staging import OutputLockedError
    from ..stepping import SteppingError

    return (RecordingError, RecordingErrors, ParameterError, OutputExistsError,
            InputOverwriteError, OutputPathError, IsADirectoryError, NotADirectoryError,
            FileNotFoundError, PermissionError, NonFiniteSimulation, SteppingError,
            OutputLockedError)


def _error_message(err: BaseException) -> str:
    """One line for ``err``: its own message, or, for an error of the operating system
    (errno set), the file, the system's reason and what to check."""
    if isinstance(err, OSError) and err.errno is not None and err.strerror:
        import errno

        where = f"{err.filename}: " if err.filename else ""
        fix = ("free some disk space" if err.errno == errno.ENOSPC else
               "check the path and its permissions")
        return f"{where}{err.strerror}. Fix: {fix}."
    if isinstance(err, RecordingErrors):
        return str(err)  # one line per file
    return " ".join(str(err).split())


@contextlib.contextmanager
def reported_errors():
    """Turn user errors into a one-line message and exit code 2 (under ``--debug``,
    let them through with their traceback)."""
    try:
        yield
    except user_errors() as err:
        if debug_enabled():
            raise
        raise fail(_error_message(err)) from None


def report_unexpected(err: Exception) -> typer.Exit:
    """The one-line report of an error no command caught: a user error or an OS error
    exits 2, running out of memory 3, anything else (a bug) 1, with the way to see
    the traceback."""
    hint = "rerun as `stickslip --debug ...` to see the traceback"
    if isinstance(err, user_errors()):
        return fail(_error_message(err))
    if isinstance(err, MemoryError):
        return fail(f"out of memory. Fix: make the job smaller (shorter --duration, fewer "
                    f"grid points or a smaller --chunk); {hint}.", EXIT_FAILED)
    if isinstance(err, OSError):
        return fail(_error_message(err))
    text = " ".join(str(err).split()) or "(no message)"
    return fail(f"unexpected {type(err).__name__}: {text}. This is probably a bug: {hint} "
                f"and report it.", EXIT_INTERNAL)


class ReportingGroup(TyperGroup):
    """The ``stickslip`` command group: any exception a command lets through becomes
    one ``error:`` line and an exit code (see :func:`report_unexpected`), except under
    ``--debug``, which may stand anywhere on the line (it is moved before the command,
    where the group's option is parsed)."""

    def parse_args(self, ctx, args):
        end = args.index("--") if "--" in args else len(args)
        if "--debug" in args[:end]:
            args = ["--debug"] + [a for i, a in enumerate(args) if i >= end or a != "--debug"]
        return super().parse_args(ctx, args)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (typer.Exit, typer.Abort, typer.TyperException):
            raise  # typer's own exits, usage errors and aborts
        except Exception as err:
            if debug_enabled():
                raise
            raise report_unexpected(err) from None


def check_outputs(outputs: Mapping[Path | None, Sequence[str] | None], *, force: bool,
                  inputs=()) -> list[Path]:
    """Check every output a command will write, before any input is read or anything
    computed: format, folder, overwrite (``--force``) and input rules of
    :func:`stickslip_jax.files.check_outputs`. ``outputs``: path (None: not asked for)
    → the extensions its writer knows (None: any). Creates nothing: the command stages its outputs
    (:mod:`~stickslip_jax.staging`) when it writes. Returns the paths given."""
    from ..files import check_outputs as check

    return check({p: s for p, s in outputs.items() if p is not None}, force=force,
                 inputs=[i for i in inputs if i is not None], create_folders=False)


def check_sample_count(n: int, what: str) -> None:
    """Refuse, before allocating anything, a generated drive of more than
    :data:`MAX_SAMPLES` samples (``what`` says how it was asked for)."""
    if n <= MAX_SAMPLES:
        return
    raise fail(f"{what} is {n:.3g} samples, which would need about "
               f"{_bytes(n * BYTES_PER_SAMPLE)} of memory; the limit is {MAX_SAMPLES:,} "
               f"samples (about {_bytes(MAX_SAMPLES * BYTES_PER_SAMPLE)}). Fix: shorten "
               f"--duration or lower --sample-rate.")


def _bytes(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.3g} {unit}"
        n /= 1000
    raise AssertionError  # unreachable


def check_amplitudes(values, option: str) -> None:
    """Drive amplitudes [V] must be finite and positive: the amplitude is the peak of
    the 0 → A drive, and a sawtooth's direction is chosen by --direction(s), not by a
    sign. One rule for every command."""
    import numpy as np

    a = np.atleast_1d(np.asarray(values, dtype=float))
    bad = a[~(np.isfinite(a) & (a > 0))]
    if bad.size:
        raise fail(f"{option} {bad[0]:g}: an amplitude must be a positive number of volts "
                   f"(the peak of the 0 → A drive). Fix: give a positive amplitude; choose "
                   f"the direction with --direction (forward or backward).")


def check_frequencies(values, option: str) -> None:
    """Drive frequencies [Hz] must be finite and positive."""
    import numpy as np

    f = np.atleast_1d(np.asarray(values, dtype=float))
    bad = f[~(np.isfinite(f) & (f > 0))]
    if bad.size:
        raise fail(f"{option} {bad[0]:g}: a frequency must be a positive number of Hz.")


def check_periods(periods: int, settle: int) -> None:
    """--periods and --settle of a sawtooth sweep: the velocity needs at least one
    period after the ``settle`` start-up periods."""
    if periods < 2 or not 0 <= settle < periods:
        raise fail(f"--periods {periods} --settle {settle}: need periods ≥ 2 and "
                   f"0 ≤ settle < periods")


def load_recordings_reporting_all(paths, *, require_output: bool = True):
    """:func:`stickslip_jax.io.load_recordings` (files and folders, each file once, in
    the order given), but every file is read and every bad one reported: raises
    :class:`RecordingErrors` naming them all instead of stopping at the first."""
    from ..io import RecordingError, load_recording, load_recordings, recording_files

    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir() and recording_files(p):
            files.extend(recording_files(p))
        else:
            files.append(p)
    unique: dict[Path, Path] = {}
    for f in files:
        unique.setdefault(f.resolve(), f)
    recordings, errors = [], []
    for f in unique.values():
        try:
            if f.is_dir():
                recordings.extend(load_recordings([f], require_output=require_output))
            else:
                recordings.append(load_recording(f, require_output=require_output))
        except RecordingError as err:
            errors.append(err)
    if len(errors) == 1:
        raise errors[0]
    if errors:
        raise RecordingErrors(errors)
    return recordings


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


def load_params_noting(path: Path):
    """:func:`~stickslip_jax.params.load_params`, with one ``warning:`` line on stderr
    when the file is marked as the result of a fit that was not a plain result
    (``fit_status``, e.g. misspecified)."""
    from ..params import fit_status_of, load_params

    actuator = load_params(path)
    status = fit_status_of(path)
    if status:
        typer.echo(f"warning: {path}: these parameters are marked \"{status.split(':')[0]}\" "
                   f"by the fit that wrote them (fit_status in the file).", err=True)
    return actuator


def load_actuator(params: Path | None, zba_surface: Path | None = None):
    """The actuator of ``--params`` (default profile without it), with its z_ba read
    from ``--zba-surface`` when given. Bad files raise user errors (exit 2)."""
    from ..model.profiles import lu2015_slc1720

    actuator = load_params_noting(params) if params is not None else lu2015_slc1720()
    if zba_surface is not None:
        from ..sweep.zba_surface import load_zba_surface, with_zba_surface

        try:
            actuator = with_zba_surface(actuator, load_zba_surface(zba_surface))
        except (KeyError, ValueError) as err:
            raise fail(f"--zba-surface {zba_surface}: {err}") from None
    return actuator


def parse_fix(items: list[str]) -> dict[str, float]:
    """``--fix NAME=VALUE`` options [SI] as a dictionary, each name checked against
    what the identification may hold (the piezo and slider mechanics and every
    registered law's fittable quantities); ParameterError otherwise."""
    from ..identify.parameters import MECHANICS, law_fittable
    from ..model.registry import FRICTION_LAWS
    from ..params import ParameterError

    # The fittable quantities of every registered law that the identification fits
    # (the starting file says which law; identify checks the names against it).
    may_be_zero = {}
    for law in FRICTION_LAWS.values():
        if any(p.step for p in law_fittable(law)):
            for p in law_fittable(law):
                may_be_zero.setdefault(p.name, p.fit_kind == "softplus")
    fixable = list(MECHANICS) + list(may_be_zero)
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise ParameterError(f"--fix {item!r}: expected NAME=VALUE (SI), e.g. Ms=0.0247")
        if name not in fixable:
            raise ParameterError(f"--fix {item!r}: {name!r} is not a fixable parameter; "
                                 f"choose from {', '.join(fixable)}")
        try:
            out[name] = float(value)
        except ValueError:
            raise ParameterError(f"--fix {item!r}: {value!r} is not a number") from None
        if not out[name] > 0 and not may_be_zero.get(name, False):
            raise ParameterError(f"--fix {item!r}: {name} must be positive")
    return out

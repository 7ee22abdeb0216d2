"""Safe output writing: never clobber an input, never leave a half-written file.

Every file the package writes goes through these helpers:

- :func:`check_output_path` refuses to write over one of the command's own input
  files (even with ``--force``: that would destroy the data the output was computed
  from), refuses to overwrite an existing output unless ``force`` is given, and
  refuses a format it cannot write or a folder it cannot write into.
- :func:`check_outputs` checks every output of a command that way before any of them
  is written (and before any computation), so a mistake in the last output never
  leaves the first one written.
- :func:`atomic_writer` (and :func:`atomic_write_text` / :func:`atomic_write_bytes`)
  write to a temporary file in the destination folder and ``os.replace`` it into
  place only once the write has succeeded, so a crash or an exception leaves either
  the old file or the new one, never a truncated mix. The temporary file lives in
  the same folder because ``os.replace`` is atomic only within one file system.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

__all__ = [
    "JSON_SUFFIXES",
    "RECORDING_SUFFIXES",
    "InputOverwriteError",
    "OutputExistsError",
    "OutputPathError",
    "atomic_write_bytes",
    "atomic_write_text",
    "atomic_writer",
    "check_output_path",
    "check_outputs",
    "image_suffixes",
]

PathLike = str | os.PathLike[str]


class OutputExistsError(FileExistsError):
    """The output file exists already and overwriting was not allowed."""

    def __init__(self, path: PathLike):
        self.path = Path(path)
        super().__init__(
            f"{self.path}: the output file exists already. "
            "Fix: pass --force to overwrite it, or choose another output path."
        )

    def __str__(self) -> str:
        # FileExistsError's default str() would show "[Errno None]"; keep our message.
        return str(self.args[0])


class InputOverwriteError(ValueError):
    """The output path is one of the inputs; refused even with ``force``."""

    def __init__(self, path: PathLike, input_path: PathLike):
        self.path = Path(path)
        self.input_path = Path(input_path)
        same = "" if str(self.path) == str(self.input_path) else f" ({self.input_path})"
        super().__init__(
            f"{self.path}: the output path is also an input file{same}; writing it would "
            "destroy the input. --force does not allow this. Fix: choose another output path."
        )


class OutputPathError(ValueError):
    """The output path cannot be written: a format the writer does not know, the same
    file named for two outputs, or a folder that is a file or is not writable."""

    def __init__(self, path: PathLike, problem: str, fix: str):
        self.path = Path(path)
        super().__init__(f"{self.path}: {problem}. Fix: {fix}.")


RECORDING_SUFFIXES = (".csv", ".npz")
JSON_SUFFIXES = (".json",)


def image_suffixes() -> tuple[str, ...]:
    """The image formats matplotlib writes, the usual ones first (``.png``, ``.pdf``,
    ``.svg``, ``.jpg``, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase

    usual = (".png", ".pdf", ".svg", ".jpg")
    known = {f".{k}" for k in FigureCanvasBase.get_supported_filetypes()}
    return tuple(s for s in usual if s in known) + tuple(sorted(known - set(usual)))


def _check_suffix(out: Path, suffixes: Sequence[str]) -> None:
    if out.suffix.lower() in suffixes:
        return
    shown = ", ".join(suffixes[:4]) + (" and more" if len(suffixes) > 4 else "")
    problem = (f"the file name has no extension (formats: {shown})" if not out.suffix else
               f"cannot write a {out.suffix!r} file here (formats: {shown})")
    raise OutputPathError(out, problem, "end the file name in one of these extensions")


def _check_folder(out: Path) -> None:
    """The folder of ``out`` is (or can be created as) a writable folder."""
    probe = out.parent
    # pathlib's exists() is False (not an error) below a file, so this climbs to the
    # nearest thing that exists.
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        raise OutputPathError(probe, f"this is a file, but it must be a folder to hold "
                              f"{out.relative_to(probe)}", "choose another output path "
                              "(where a command writes several files, --out names a folder)")
    if not os.access(probe, os.W_OK | os.X_OK):
        where = ("its folder" if probe == out.parent else
                 f"{probe}, where its folder would be created,")
        raise OutputPathError(out, f"{where} is not writable",
                              "choose a folder you can write to, or change its permissions")


def _same_file(a: Path, b: Path) -> bool:
    """True when ``a`` and ``b`` name the same file (symlinks and hard links included)."""
    try:
        # samefile compares device and inode, so it sees through links and "..".
        return os.path.samefile(a, b)
    except OSError:
        # One of them does not exist (yet): compare the resolved names instead.
        return a.expanduser().resolve() == b.expanduser().resolve()


def check_output_path(path: PathLike, *, force: bool, inputs: Iterable[PathLike] = (),
                      suffixes: Sequence[str] | None = None,
                      create_folder: bool = True) -> Path:
    """Check that ``path`` may be written, and create its parent folder.

    Parameters
    ----------
    path:
        Output file path.
    force:
        Allow overwriting an existing output file (the CLI's ``--force``).
    inputs:
        The files the output is computed from. Writing over any of them is refused
        even with ``force``.
    suffixes:
        The extensions the writer knows (lower case, with the dot), e.g.
        :data:`RECORDING_SUFFIXES`; None: any.
    create_folder:
        Create the parent folder once the checks pass.

    Returns
    -------
    Path
        ``path`` as a :class:`~pathlib.Path` (``~`` expanded).

    Raises
    ------
    InputOverwriteError
        ``path`` is (or links to) one of ``inputs``.
    OutputExistsError
        ``path`` exists and ``force`` is false.
    IsADirectoryError
        ``path`` is an existing folder.
    OutputPathError
        The extension is not one of ``suffixes``, or the folder is a file or is not
        writable.
    """
    out = Path(path).expanduser()
    for inp in inputs:
        if _same_file(out, Path(inp)):
            raise InputOverwriteError(out, inp)
    if out.is_dir():
        raise IsADirectoryError(
            f"{out}: the output path is a folder. Fix: give a file name, e.g. {out / 'out.csv'}."
        )
    if suffixes is not None:
        _check_suffix(out, suffixes)
    if out.exists() and not force:
        raise OutputExistsError(out)
    _check_folder(out)
    if create_folder:
        out.parent.mkdir(parents=True, exist_ok=True)
    return out


def check_outputs(outputs: Mapping[PathLike, Sequence[str] | None], *, force: bool,
                  inputs: Iterable[PathLike] = (), create_folders: bool = True) -> list[Path]:
    """Check every output of a command (see :func:`check_output_path`) before any is
    written, then (``create_folders``) create their folders.

    Parameters
    ----------
    outputs:
        Output path → the extensions its writer knows (None: any).
    force, inputs:
        As for :func:`check_output_path`.
    create_folders:
        Create the folders once every check has passed; False leaves that to the
        writer (nothing is created when a later input check fails).

    Returns
    -------
    list of Path
        The outputs, in the order given.

    Raises
    ------
    OutputPathError
        One of :func:`check_output_path`'s errors, or one file named for two outputs.
    """
    inputs = list(inputs)
    checked: list[Path] = []
    for path, suffixes in outputs.items():
        out = check_output_path(path, force=force, inputs=inputs, suffixes=suffixes,
                                create_folder=False)
        if any(_same_file(out, earlier) for earlier in checked):
            raise OutputPathError(out, "the same file is named for two outputs",
                                  "give each output its own file name")
        checked.append(out)
    if create_folders:
        for out in checked:
            out.parent.mkdir(parents=True, exist_ok=True)
    return checked


def _open_temp(folder: Path, name: str, mode: str) -> tuple[Path, IO[Any]]:
    """Create and open a new hidden temporary file next to the destination."""
    text = "b" not in mode
    for _ in range(100):
        tmp = folder / f".{name}.{secrets.token_hex(4)}.tmp"
        try:
            # Mode 0o666 lets the umask decide the final permissions, as for a plain
            # open(); tempfile.mkstemp would leave the output readable by its owner only.
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except OSError as err:
            # Name the destination, not the temporary file the user never asked for.
            raise type(err)(err.errno, err.strerror, str(folder / name)) from None
        if text:
            # newline="" writes "\n" as is on every platform: files are byte-identical.
            return tmp, os.fdopen(fd, mode, encoding="utf-8", newline="")
        return tmp, os.fdopen(fd, mode)
    raise FileExistsError(f"{folder}: could not create a temporary file for {name}")


@contextlib.contextmanager
def atomic_writer(path: PathLike, mode: str = "w") -> Iterator[IO[Any]]:
    """Open a temporary file that replaces ``path`` when the ``with`` block succeeds.

    Parameters
    ----------
    path:
        Final file path. Its folder must exist (see :func:`check_output_path`).
    mode:
        ``"w"`` (text, UTF-8, ``\\n`` line ends) or ``"wb"`` (bytes).

    Yields
    ------
    file object
        Open on a temporary file in the same folder as ``path``. On normal exit it is
        flushed, synced to disk and moved onto ``path`` with :func:`os.replace`; if the
        block raises, the temporary file is removed and ``path`` is left untouched.

    Notes
    -----
    No existence check is made here: call :func:`check_output_path` first.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_writer: mode must be 'w' or 'wb', not {mode!r}")
    dest = Path(path).expanduser()
    tmp, fh = _open_temp(dest.parent, dest.name, mode)
    try:
        with fh:
            yield fh
            fh.flush()
            # fsync before the rename: otherwise a power cut can leave an empty file
            # under the final name on some file systems.
            os.fsync(fh.fileno())
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def atomic_write_text(path: PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically; see :func:`atomic_writer`."""
    with atomic_writer(path, "w") as fh:
        fh.write(text)


def atomic_write_bytes(path: PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; see :func:`atomic_writer`."""
    with atomic_writer(path, "wb") as fh:
        fh.write(data)

"""Outputs that appear whole or not at all, and one command at a time per output.

A command's outputs are written into a hidden staging folder beside their final place
(same file system, so a rename moves them) and moved into place only when the command
has written every one of them. An error, Ctrl-C or a kill before that leaves the
previous outputs as they were and no trace of the new ones (the staging folder is
removed; one left by a killed process is hidden and named for what it is).

While a command works on an output it holds a lock on it (:class:`OutputLock`), taken
before any computation: a second command aimed at the same output is refused at once
instead of finding out after its computation, or mixing its files with the first's.

A folder of outputs (``identify --out DIR``) keeps a manifest of what each command
wrote there (:data:`MANIFEST`): a later run of the same command refuses to add to it
without ``force``, and with ``force`` replaces those outputs, stale ones included (an
overlay of a recording the new run does not have), and nothing else in the folder.

The moves into place run under :data:`COMMIT_GUARD`; an interrupt handler that takes
it (:func:`abort_active`) waits for a commit under way to finish, so an interrupt
never leaves half the files moved.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import secrets
import shutil
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

from .files import OutputExistsError, atomic_write_text

__all__ = ["MANIFEST", "OutputLock", "OutputLockedError", "Stage", "StageAborted",
           "abort_active", "lift_barriers",
           "staged_files", "staged_folder"]

MANIFEST = ".stickslip-outputs.json"
"""The file in an output folder that lists, per command, the files it wrote there."""

STAGING_PREFIX = ".stickslip-staging-"

COMMIT_GUARD = threading.RLock()
"""Held while staged outputs move into place, and by :func:`abort_active`."""

_active: set[Stage] = set()
_active_lock = threading.Lock()


class StageAborted(RuntimeError):
    """The outputs were discarded (:func:`abort_active`) before they could be moved
    into place."""


def _commit_allowed(stage: Stage) -> None:
    if stage.aborted:
        raise StageAborted(f"{stage.root}: the outputs were discarded (interrupted)")


class OutputLockedError(RuntimeError):
    """Another command is writing the same output now."""

    def __init__(self, path: Path, holder: str):
        self.path = path
        super().__init__(f"{path}: another stickslip command is writing there now "
                         f"({holder}). Fix: wait for it to finish, or choose another "
                         f"output path.")


def _lock_folder() -> Path:
    """Where the locks live: one per output, in a private folder under the system's
    temporary folder (an output's own folder may not exist yet, and a lock file there
    would be one more file the user did not ask for)."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    folder = Path(tempfile.gettempdir()) / f"stickslip-locks-{uid}"
    folder.mkdir(mode=0o700, exist_ok=True)
    return folder


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(Path(path).expanduser())).resolve()


class OutputLock:
    """An exclusive, non-blocking lock on an output path (file or folder), held by this
    process until :meth:`release` (the operating system drops it when the process
    dies, so a killed command never leaves its output locked)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        key = hashlib.sha256(str(_resolved(path)).encode()).hexdigest()[:24]
        self.file = _lock_folder() / f"{key}.lock"
        self._fd: int | None = None

    def acquire(self) -> OutputLock:
        try:
            import fcntl
        except ImportError:  # not a POSIX system: outputs are staged, not locked
            return self
        while True:
            fd = os.open(self.file, os.O_RDWR | os.O_CREAT, 0o600)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as err:
                holder = os.pread(fd, 200, 0).decode(errors="replace").strip()
                os.close(fd)
                if err.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise OutputLockedError(self.path, holder or "pid unknown") from None
                raise
            # The holder before us may have removed the file as it released it: a lock
            # on a file no longer at that name locks nothing. Take the new one.
            try:
                same = os.fstat(fd).st_ino == os.stat(self.file).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()}, output {_resolved(self.path)}".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            self.file.unlink()  # while still held: see acquire
        os.close(self._fd)
        self._fd = None


def _existing_ancestor(path: Path) -> Path:
    probe = Path(os.path.abspath(path.expanduser()))
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    return probe


def _read_manifest(folder: Path) -> dict[str, list[str]]:
    try:
        data = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {k: [f for f in v if isinstance(f, str)] for k, v in data.items()
            if isinstance(v, list)}


class Stage:
    """One command's staging folder, the locks it holds on its outputs, and whether
    they were committed or aborted. Made by :func:`staged_folder` and
    :func:`staged_files`."""

    def __init__(self, root: Path, locks: list[OutputLock]):
        self.root = root
        """The staging folder (hidden, beside the outputs)."""
        self.locks = locks
        self.committed = False
        self.aborted = False
        self._aborting = threading.Lock()

    def abort(self, *, barrier: bool = False) -> None:
        """Remove what was staged and release the locks (idempotent). ``barrier``: the
        command may still be writing into the staging folder (an interrupt handler in
        another thread): leave a file in its place, so that a write under it fails
        instead of creating it again, until :func:`lift_barriers`."""
        with self._aborting:
            if not (self.aborted or self.committed):
                self.aborted = True
                if barrier:
                    _discard_behind_barrier(self.root)
                else:
                    shutil.rmtree(self.root, ignore_errors=True)
            elif self.committed:
                shutil.rmtree(self.root, ignore_errors=True)  # emptied by the commit
            for lock in self.locks:
                lock.release()
            self.locks = []
        with _active_lock:
            _active.discard(self)


_barriers: list[Path] = []


def _discard_behind_barrier(root: Path) -> None:
    """Move ``root`` aside, put an empty file at its name (retrying when a writer made
    the folder again in between), and remove what was moved aside."""
    for _ in range(100):
        trash = root.with_name(f"{root.name}.discarded-{secrets.token_hex(2)}")
        with contextlib.suppress(FileNotFoundError):
            os.rename(root, trash)
        try:
            os.close(os.open(root, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        except FileExistsError:
            shutil.rmtree(trash, ignore_errors=True)
            continue
        _barriers.append(root)
        shutil.rmtree(trash, ignore_errors=True)
        return
    shutil.rmtree(root, ignore_errors=True)


def lift_barriers() -> None:
    """Remove the files :meth:`Stage.abort` left in place of staging folders (just
    before the process ends)."""
    while _barriers:
        with contextlib.suppress(OSError):
            _barriers.pop().unlink()


def abort_active(*, barrier: bool = False) -> int:
    """Abort every stage of this process that has not been committed (an interrupt
    handler calls this, with ``barrier``, before the process exits); waits for a commit
    under way. Returns how many were aborted."""
    with COMMIT_GUARD:
        with _active_lock:
            stages = list(_active)
        for stage in stages:
            stage.abort(barrier=barrier)
        return len(stages)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _sweep_stale(parent: Path) -> None:
    """Remove staging folders in ``parent`` whose process is gone (killed with no chance
    to clean up: SIGKILL, a power cut); their names carry the process id."""
    for p in parent.glob(f"{STAGING_PREFIX}*"):
        pid = p.name[len(STAGING_PREFIX):].split("-")[0]
        if pid.isdigit() and not _alive(int(pid)):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    p.unlink()


def _new_staging(near: Path) -> Path:
    parent = _existing_ancestor(near)
    _sweep_stale(parent)
    for _ in range(100):
        root = parent / f"{STAGING_PREFIX}{os.getpid()}-{secrets.token_hex(4)}"
        try:
            root.mkdir()
        except FileExistsError:
            continue
        return root
    raise FileExistsError(f"{parent}: could not create a staging folder")


@contextlib.contextmanager
def _staged(paths: Iterable[Path], near: Path) -> Iterator[Stage]:
    locks: list[OutputLock] = []
    try:
        for p in paths:
            locks.append(OutputLock(p).acquire())
        stage = Stage(_new_staging(near), locks)
    except BaseException:
        for lock in locks:
            lock.release()
        raise
    with _active_lock:
        _active.add(stage)
    try:
        yield stage
    finally:
        stage.abort()  # after a commit: only the empty staging folder and the locks


def _move(src: Path, dest: Path) -> None:
    """Rename ``src`` (file or folder) onto ``dest``, creating its folder; across file
    systems (a target folder mounted elsewhere), by a copy beside ``dest`` renamed
    into place."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.replace(src, dest)
        return
    except OSError as err:
        if err.errno != errno.EXDEV:
            raise
    tmp = dest.parent / f"{STAGING_PREFIX}{os.getpid()}-{secrets.token_hex(4)}"
    if src.is_dir():
        shutil.copytree(src, tmp)
    else:
        shutil.copy2(src, tmp)
    os.replace(tmp, dest)


@contextlib.contextmanager
def staged_folder(out: Path, command: str, *, force: bool) -> Iterator[Path]:
    """Lock the output folder ``out`` and yield a staging folder to write the
    command's outputs into, as if it were ``out``; when the block ends without an
    exception they move into ``out`` (a new ``out`` appears in one rename).

    Refused at once (before the block runs) when another command holds ``out``
    (:class:`OutputLockedError`), or, without ``force``, when ``out`` holds outputs of
    an earlier run of ``command`` (:class:`~stickslip_jax.files.OutputExistsError`);
    with ``force`` those are replaced, stale ones included (:data:`MANIFEST`).
    """
    out = Path(out).expanduser()
    with _staged([out], out.parent) as stage:
        previous = [f for f in _read_manifest(out).get(command, []) if (out / f).exists()]
        if previous and not force:
            raise OutputExistsError(out / previous[0])
        yield stage.root
        with COMMIT_GUARD:
            _commit_allowed(stage)
            written = sorted(str(p.relative_to(stage.root)) for p in stage.root.rglob("*")
                             if p.is_file())
            manifest = _read_manifest(out) if out.exists() else {}
            manifest[command] = written
            atomic_write_text(stage.root / MANIFEST, json.dumps(manifest, indent=1) + "\n")
            if not out.exists():
                _move(stage.root, out)
            else:
                for rel in written + [MANIFEST]:
                    _move(stage.root / rel, out / rel)
                for rel in set(previous) - set(written):
                    with contextlib.suppress(OSError):
                        (out / rel).unlink()
            stage.committed = True


@contextlib.contextmanager
def staged_files(paths: Iterable[Path | None], *, force: bool) -> Iterator[dict[Path, Path]]:
    """Lock the output files ``paths`` (None: not asked for) and yield final path →
    staged path; when the block ends without an exception, every staged file that was
    written moves onto its final path. The caller has checked the paths
    (:func:`~stickslip_jax.files.check_outputs`: overwrite, inputs, formats); under the
    lock they are checked again for existence (without ``force``), in case a command
    that held them finished in between."""
    finals = [Path(p).expanduser() for p in paths if p is not None]
    near = Path(os.path.commonpath([os.path.abspath(p.parent) for p in finals])) if finals \
        else Path(".")
    with _staged(finals, near) as stage:
        if not force:
            for p in finals:
                if p.exists():
                    raise OutputExistsError(p)
        staged = {p: stage.root / f"{i}-{p.name}" for i, p in enumerate(finals)}
        yield staged
        with COMMIT_GUARD:
            _commit_allowed(stage)
            for final, tmp in staged.items():
                if tmp.exists():
                    _move(tmp, final)
            stage.committed = True

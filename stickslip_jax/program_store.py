"""Traced programs kept on disk, so that a later process skips tracing and lowering.

JAX's persistent compilation cache (:mod:`.compilation_cache`) keeps compiled
executables, but finds them by the lowered program: every process still traces the
simulator's Python and lowers it before the cache can answer. For the per-recording
programs of the identification and the diagnosis that is most of a warm run's
compiling: a reduced diagnosis traced 31 of them in 11 s and lowered them in 3.6 s,
while reading their executables took 3.7 s (issue #64). :func:`stored_jit` wraps a
function like ``equinox.filter_jit`` and, once a store folder is set
(:func:`use_program_store`, which :func:`~.compilation_cache.use_compilation_cache`
calls with a folder inside its own), keeps each traced program there as a serialized
``jax.export.Exported`` (StableHLO). A later process that calls the function with the
same program key deserializes it (milliseconds) instead of tracing it; it then compiles
it, or reads the executable from the compilation cache.

The key is everything the trace depends on: the function, the source of this package
(:func:`source_digest`; a changed line anywhere makes new keys, and a process whose
source was edited after it started stores nothing more), the versions of JAX, jaxlib,
equinox and numpy, the backend and the configuration options read while tracing, the
pytree structure of the arguments with their static (non-array) values, and the shape,
dtype and weak type of every array. Arguments that cannot be keyed across processes are
traced as before: a type defined outside this package, numpy and Python's builtins
(:data:`KNOWN_MODULES`: a notebook's own class can change without this package's source
changing), or a static value whose text names a memory address.

The program run is the one tracing would make (the same StableHLO): results are
identical to the last bit (checked in tests/test_program_store.py), only the time
changes. Calls with tracers (the function used inside another transformation) or
with arrays sharded over several devices go through ``equinox.filter_jit`` unchanged;
so does everything while no store is set. Stored: the per-recording programs of the
identification and the diagnosis, the planning's rest Jacobian, the single and batched
simulations, the contact's linearisation and the diagnosis's batched outputs.

A program can also be made ready ahead of its first call, in another thread
(``precompile``): XLA compiles one program on one core, and an identification's first
step, compiling its own programs, leaves the second core idle (a cold identify on the
fixtures ran on one core for 11 of its 32 s).
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import os
import re
import threading
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from .files import atomic_write_bytes

STORE_MAX_BYTES = 512 * 1024**2
"""The store's size limit, bytes (512 MiB): past it the least recently used programs
are removed (a program is about 50 kB: a reduced diagnosis stored 41 in 1.9 MB)."""

FORMAT = "stickslip-exported-1"
"""Part of every key: a change of how programs are stored makes new keys."""

_ADDRESS = re.compile(r"0x[0-9a-fA-F]{6,}")

_store: dict[str, Path | None] = {"dir": None}
_lock = threading.Lock()  # the in-memory tables
_export_lock = threading.Lock()  # tracing and exporting, one program at a time


def use_program_store(path: Path | str | None) -> bool:
    """Keep traced programs in ``path`` (created if missing; None: keep none). Returns
    whether the store is on; a folder that cannot be created leaves it off."""
    if path is None:
        _store["dir"] = None
        return False
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError:
        _store["dir"] = None
        return False
    try:  # serialization needs flatbuffers (an optional dependency of jax)
        from jax._src.export import serialization  # noqa: F401
    except ImportError:
        _store["dir"] = None
        return False
    _store["dir"] = Path(path)
    return True


def program_store_dir() -> Path | None:
    """The store's folder, None when off."""
    return _store["dir"]


def _digest() -> str:
    """SHA-256 of this package's Python source as it is on disk now (every ``.py`` file
    under it, by relative path and content; about 4 ms)."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


_LOADED_DIGEST = _digest()
"""The source this process imported (read with the package's first import)."""


def source_digest() -> str:
    """SHA-256 of the package's source this process runs: the digest taken at import."""
    return _LOADED_DIGEST


def source_unchanged() -> bool:
    """Whether the source on disk is still the one this process imported. A program
    traced after an edit (a long run, a notebook kept open) is the old code's: stored
    under the new source's key it would be read by processes running the new code."""
    return _digest() == _LOADED_DIGEST


def _trace_settings() -> str:
    """What else a trace reads: the versions of what the stored functions call (JAX,
    jaxlib, equinox, numpy), the backend and the configuration options that change the
    program."""
    import jaxlib

    cfg = jax.config
    return "|".join(str(v) for v in (
        jax.__version__, jaxlib.__version__, eqx.__version__, np.__version__,
        jax.default_backend(),
        cfg.jax_enable_x64, cfg.jax_default_matmul_precision,
        cfg.jax_numpy_dtype_promotion, cfg.jax_numpy_rank_promotion,
        cfg.jax_default_prng_impl))


def _aval(x) -> tuple:
    """Shape, dtype and weak type of an array argument: what a program is traced for."""
    return tuple(np.shape(x)), str(x.dtype), bool(getattr(x, "weak_type", False))


def _spec(x) -> jax.ShapeDtypeStruct:
    shape, dtype, weak = _aval(x)
    return jax.ShapeDtypeStruct(shape, np.dtype(dtype), weak_type=weak)


KNOWN_MODULES = ("builtins", "numpy", "stickslip_jax")
"""Where every type in a stored program's arguments must come from: a class defined
elsewhere (a user's own law in a notebook) can change without this package's source
changing, so its programs are traced every time, as before."""


def _known(t: type) -> bool:
    module = getattr(t, "__module__", "") or ""
    return module.split(".")[0] in KNOWN_MODULES


def _node_types(treedef) -> list[str] | None:
    """The qualified type of every node of ``treedef``, None where one is not
    :func:`_known`."""
    out = []
    stack = [treedef]
    while stack:
        td = stack.pop()
        data = td.node_data()
        if data is not None:
            t = data[0]
            if not _known(t):
                return None
            out.append(f"{t.__module__}.{t.__qualname__}")
        stack.extend(td.children())
    return out


def _disk_key(name: str, source: str, treedef, static_def, static_leaves, avals) -> str | None:
    """The program's key on disk (hex), None when the arguments cannot be keyed across
    processes: a type from outside :data:`KNOWN_MODULES`, a static value whose text
    names a memory address, or a source edited since this process imported it
    (:func:`source_unchanged`)."""
    types = [_node_types(td) for td in (treedef, static_def)]
    if None in types or not all(_known(type(x)) for x in static_leaves):
        return None
    if not source_unchanged():
        return None
    text = "\n".join((FORMAT, name, source, source_digest(), _trace_settings(), str(treedef),
                      str(static_def), repr(types), repr(static_leaves), repr(avals)))
    if _ADDRESS.search(text):
        return None
    return hashlib.sha256(text.encode()).hexdigest()


def _read(path: Path):
    try:
        blob = path.read_bytes()
        exported = jax.export.deserialize(bytearray(blob))
    except FileNotFoundError:
        return None
    except Exception:  # noqa: BLE001 - a damaged entry is traced again and replaced
        path.unlink(missing_ok=True)
        return None
    try:
        os.utime(path)  # least recently used goes first
    except OSError:
        pass
    return exported


def _write(path: Path, exported) -> None:
    """Write atomically (:func:`~stickslip_jax.files.atomic_write_bytes`: a reader sees
    the whole program or none); a store that cannot be written is skipped (the program
    still runs)."""
    try:
        atomic_write_bytes(path, exported.serialize())
    except Exception:  # noqa: BLE001 - e.g. a full or read-only disk
        return
    _evict(path.parent)


def _evict(folder: Path, limit: int = STORE_MAX_BYTES) -> None:
    """Past ``limit`` bytes, remove the least recently used programs (by modification
    time, which a read renews) down to four fifths of it."""
    entries = []
    for p in folder.glob("*.bin"):
        try:
            st = p.stat()
        except OSError:
            continue
        entries.append((st.st_mtime, st.st_size, p))
    total = sum(size for _, size, _ in entries)
    for _, size, p in sorted(entries, key=lambda e: e[0]):
        if total <= limit * 0.8:
            break
        p.unlink(missing_ok=True)
        total -= size


def stored_jit(fn: Callable) -> Callable:
    """``equinox.filter_jit(fn)`` whose traced programs are kept in the store (module
    docstring): arrays (``equinox.is_array``) are the program's arguments, everything
    else is static and part of its key. Meant for this package's functions: the key
    holds ``fn``'s own source and the package's, not that of code elsewhere that ``fn``
    calls.

    ``call.precompile(*args)`` makes the program of ``args`` ready to run (loaded or
    traced, then compiled) without running it, for a thread that prepares a program
    while another computes (:meth:`~.identify.sensitivities.RecordingPrograms.prefetch`);
    a call of the same program meanwhile waits for it instead of compiling it again.
    It returns whether the program is now compiled (False while no store is set: the
    call then compiles as before)."""
    jitted = eqx.filter_jit(fn)
    name = f"{fn.__module__}.{fn.__qualname__}"
    # in-memory key -> compiled callable, None: traced as before; a Future while a
    # thread is making it
    programs: dict = {}

    def program_of(args, *, compile_now: bool):
        """``(program, leaves)`` of ``args``: program None where the call goes through
        ``jitted`` (no store, inside a transformation, an argument that cannot be
        keyed)."""
        folder = _store["dir"]
        if folder is None:
            return None, None
        key, leaves = _call_key(args, folder)
        if key is None:
            return None, None
        try:
            program = programs.get(key, False)
        except TypeError:  # an unhashable static value
            return None, None
        if program is False or isinstance(program, Future):
            dynamic, static = eqx.partition(args, eqx.is_array)
            treedef = jax.tree.structure(dynamic)
            static_leaves, static_def = jax.tree.flatten(static)
            avals = tuple(_aval(x) for x in leaves)
            program = _made_once(programs, key, lambda: _load_or_export(
                fn, name, folder, treedef, static, static_def, static_leaves, leaves,
                avals), leaves if compile_now else None)
        return program, leaves

    @functools.wraps(fn)
    def call(*args):
        program, leaves = program_of(args, compile_now=False)
        if program is None:
            return jitted(*args)
        return program(*leaves)

    def precompile(*args) -> bool:
        program, _ = program_of(args, compile_now=True)
        return isinstance(program, jax.stages.Compiled)

    call.jitted = jitted
    call.precompile = precompile
    return call


def _call_key(args, folder) -> tuple:
    """``(key, leaves)``: the in-memory key of the program that ``args`` call (the
    arguments' pytree structure, each leaf's shape, dtype and weak type if an array
    (``equinox.is_array``), else its type and value, and the store folder) and the
    array leaves, in the order ``equinox.partition(args, is_array)`` flattens them;
    ``(None, None)`` for tracers (inside a transformation) or arrays sharded over
    several devices. Made at every call from one flattening: the way through
    ``equinox.partition`` and :func:`_aval` took 0.6 ms of a 4.4 ms recording's
    simulation (issue #64), and is taken only for a new program (its disk key)."""
    flat, treedef = jax.tree.flatten(args)
    parts, leaves = [], []
    for x in flat:
        if eqx.is_array(x):
            if isinstance(x, jax.core.Tracer) or (
                    isinstance(x, jax.Array) and len(x.sharding.device_set) > 1):
                return None, None
            leaves.append(x)
            parts.append((x.shape, x.dtype, bool(getattr(x, "weak_type", False))))
        else:
            parts.append((type(x), x))
    return (treedef, tuple(parts), folder), leaves


def _made_once(programs: dict, key, make: Callable, leaves) -> Callable | None:
    """``programs[key]``, made by ``make()`` in the first thread that asks (compiled for
    ``leaves`` too when given) while the others wait for it; a thread whose maker
    failed makes it again itself."""
    while True:
        with _lock:
            entry = programs.get(key, False)
            mine = entry is False
            if mine:
                entry = programs[key] = Future()
        if not isinstance(entry, Future):
            return entry
        if not mine:
            try:
                return entry.result()
            except Exception:  # noqa: BLE001 - the maker's failure: try ourselves
                continue
        try:
            with _export_lock:  # one trace at a time, as before
                program = make()
            if program is not None and leaves is not None:
                program = program.lower(*leaves).compile()
        except BaseException as err:
            with _lock:
                programs.pop(key, None)
            entry.set_exception(err)
            raise
        with _lock:
            programs[key] = program
        entry.set_result(program)
        return program


def _load_or_export(fn, name, folder, treedef, static, static_def, static_leaves, leaves,
                    avals):
    """The compiled callable of one program (from the store, else traced, exported and
    stored), None when it cannot be keyed or exported (then traced as before)."""
    try:
        source = inspect.getsource(fn)
    except (OSError, TypeError):
        return None
    key = _disk_key(name, source, treedef, static_def, static_leaves, avals)
    if key is None:
        return None
    path = folder / f"{key}.bin"
    exported = _read(path)
    if exported is None:
        def flat(*dynamic_leaves):
            dynamic = jax.tree.unflatten(treedef, dynamic_leaves)
            return fn(*eqx.combine(dynamic, static))

        try:
            exported = jax.export.export(jax.jit(flat))(*(_spec(x) for x in leaves))
        except Exception:  # noqa: BLE001 - e.g. an output that is not an array
            return None
        _write(path, exported)
    return jax.jit(exported.call)

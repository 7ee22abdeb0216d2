"""JAX's persistent compilation cache, as the command line and the tests use it.

Compiling is most of a short run's time (a reduced diagnosis: about 70 %; each actuator
structure's programs ~9 s of XLA apiece). The persistent cache keeps every compiled
program on disk, keyed by the program, the XLA flags and the device, so that a second
process compiling the same program reads it instead: a second run on the same
protocol and actuator (new recordings of it: a diagnosis in 34 s instead of 76 s), or
a second test worker diagnosing the same recordings. A program is the actuator's
structure at the recordings' lengths and a stepping plan, whose sub-steps are planned
from the actuator's time scales, so another actuator's data compile their own (issue
#27, 9c9b250; benchmarks/experiments/results/compilation_cache.json). An executable
read from the cache is the one a compile would make: results do not change, only the time.
JAX compresses each entry with ``zstandard`` when it can import it (a dependency), zlib
otherwise: a cold reduced diagnosis writing a fresh cache took 72.3 and 77.6 s with it,
77.6 and 82.0 s with zlib (2026-12-07, alternating, the same result). The compressor is
part of an entry's key, so a cache written with zlib is not read, only aged out.

Several processes share one cache (the two pytest workers; commands run side by side).
JAX locks the cache's reads and writes, and evicts its least recently used entries,
only when the cache has a size limit and ``filelock`` is installed; without both, a
process could read an entry half written by another (JAX then warns and compiles
again) and the cache would grow without end. :func:`use_compilation_cache` therefore
always sets a limit (:data:`CACHE_MAX_BYTES`).
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

from .program_store import use_program_store

CACHE_ENV = "STICKSLIP_CACHE_DIR"
"""The environment variable naming the cache's folder; ``off`` disables the cache."""

DEFAULT_CACHE_DIR = Path.home() / ".cache" / "stickslip_jax"
"""The cache's folder when :data:`CACHE_ENV` is unset."""

PROGRAMS_SUBDIR = "programs"
"""The folder inside the cache that keeps traced programs (:mod:`.program_store`): the
compilation cache answers only after a program is traced and lowered; these skip that."""

CACHE_MAX_BYTES = 2 * 1024**3
"""The cache's size limit, bytes (2 GiB). The programs are small (465 entries from many
sessions' runs took 11 MB), so the limit exists for the locking it brings, and as a
bound on a cache nobody clears."""


def cache_dir_from_env(default: Path | None = DEFAULT_CACHE_DIR) -> Path | None:
    """The folder :data:`CACHE_ENV` names (``default`` when it is unset or empty); None
    when it says ``off`` or when it is unset and ``default`` is None."""
    value = os.environ.get(CACHE_ENV, "").strip()
    if value.lower() == "off":
        return None
    return Path(value) if value else default


FROM_ENVIRONMENT = "from-environment"
""":func:`use_compilation_cache`'s default: the folder :func:`cache_dir_from_env` gives
(``$STICKSLIP_CACHE_DIR``, else :data:`DEFAULT_CACHE_DIR`; none when it says ``off``)."""


def use_compilation_cache(path: Path | str | None = FROM_ENVIRONMENT) -> bool:
    """Keep JAX's compiled programs in ``path`` (default: the command line's folder,
    :data:`FROM_ENVIRONMENT`, so a notebook reads what commands compiled; created if
    missing; None: do nothing), and the traced programs of
    :mod:`.program_store` in its subfolder :data:`PROGRAMS_SUBDIR`. JAX keeps
    every program however short its compile (identify compiles ~70 of 0.05 to 0.5 s:
    its Levenberg-Marquardt steps, single operations; about 3 s a second run would
    compile again, issue #28), locked and bounded by :data:`CACHE_MAX_BYTES`. Call it
    before JAX compiles anything. Returns whether the cache is on; a folder that cannot
    be created (a read-only home) leaves it off rather than stopping the caller."""
    if path == FROM_ENVIRONMENT:
        path = cache_dir_from_env()
    if path is None:
        return False
    import jax

    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    if importlib.util.find_spec("filelock") is not None:  # JAX refuses a limit without it
        jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    use_program_store(Path(path) / PROGRAMS_SUBDIR)
    return True

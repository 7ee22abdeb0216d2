"""How many threads the BLAS libraries of numpy and scipy run (OpenBLAS).

OpenBLAS starts one thread per core and lets them wait for work by spinning (yielding
in a loop for about a tenth of a second before they sleep). The fits already keep the
cores busy with their own threads (the Jacobian's recordings, :mod:`.identify.solve`)
and XLA's, and their BLAS work is small (JᵀJ of a 42500 × 42 Jacobian: 11 ms on one
thread). Next to them the spinning threads took the cores from the simulations: on
the 2-core CPU, with other work on the machine, `stickslip identify` of the fixture
set took 84 s with OpenBLAS's default threads and 56 s with one (issue #28;
``numpy``'s ``JᵀJ`` alone 1.4 s instead of 11 ms, and the Levenberg-Marquardt steps,
whose QR runs in scipy's OpenBLAS through XLA, as slow). The command line therefore
runs BLAS on one thread (:func:`limit_blas_threads`, from ``cli/common.py``), and so
do :func:`~stickslip_jax.identify`, :func:`~stickslip_jax.diagnose` and
:func:`~stickslip_jax.design_experiment` while they run (:func:`one_blas_thread`), for a
notebook or script that calls them. Two reduced diagnoses side by side on the 2-core
CPU (the test suite's two workers; issue #64, two pairs each): the null set's 20.6-21.6 s
with OpenBLAS's default threads, 18.6-19.3 s with one; the structural mode's 88-89 s
either way.
"""

from __future__ import annotations

import ctypes
import functools
import os
import re
import threading

_GETTERS = ("openblas_get_num_threads", "scipy_openblas_get_num_threads",
            "scipy_openblas_get_num_threads64_")
"""OpenBLAS's thread getters, the same three builds as :data:`_SETTERS`."""

_SETTERS = ("openblas_set_num_threads", "scipy_openblas_set_num_threads",
            "scipy_openblas_set_num_threads64_")
"""OpenBLAS's thread setters: the plain library's, and those of the builds that numpy
(64-bit integers, suffix ``64_``) and scipy bundle."""


def _loaded_openblas() -> list[str]:
    """Paths of the OpenBLAS libraries loaded in this process (Linux; none elsewhere)."""
    try:
        with open("/proc/self/maps") as fh:
            maps = fh.read()
    except OSError:
        return []
    return sorted({m.group(0) for m in re.finditer(r"/\S*openblas\S*\.so[.\w-]*", maps,
                                                    flags=re.IGNORECASE)})


def _function(path: str, names: tuple[str, ...]):
    """The first of ``names`` that the library at ``path`` exports, None if none (or
    the library does not load)."""
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        return None
    for name in names:
        fn = getattr(lib, name, None)
        if fn is not None:
            return fn
    return None


def _set_threads(path: str, threads: int) -> bool:
    """Set the OpenBLAS at ``path`` to ``threads`` threads; whether it could be."""
    setter = _function(path, _SETTERS)
    if setter is None:
        return False
    setter.argtypes = [ctypes.c_int]
    setter.restype = None
    setter(int(threads))
    return True


def limit_blas_threads(threads: int = 1) -> list[str]:
    """Set every OpenBLAS loaded in this process to ``threads`` threads; returns the
    libraries set. Libraries loaded later keep their own setting (numpy and scipy load
    theirs on import; ``OPENBLAS_NUM_THREADS`` set before that does the same)."""
    threads = int(threads)
    if threads < 1:
        raise ValueError(f"threads must be ≥ 1, got {threads}")
    return [path for path in _loaded_openblas() if _set_threads(path, threads)]


def blas_thread_counts() -> dict[str, int]:
    """``{path: threads}`` of every OpenBLAS loaded in this process."""
    counts = {}
    for path in _loaded_openblas():
        getter = _function(path, _GETTERS)
        if getter is not None:
            getter.argtypes = []
            getter.restype = ctypes.c_int
            counts[path] = int(getter())
    return counts


_HELD = {"depth": 0, "saved": {}}
_HELD_LOCK = threading.Lock()


def one_blas_thread(fn):
    """Decorator: ``fn`` runs with every loaded OpenBLAS on one thread (module
    docstring), and the counts it found are put back when the last such call running
    in the process returns (calls may nest, or run in threads side by side). Where
    ``OPENBLAS_NUM_THREADS`` is set, the user's choice stands and nothing is changed."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if "OPENBLAS_NUM_THREADS" in os.environ:
            return fn(*args, **kwargs)
        with _HELD_LOCK:
            if _HELD["depth"] == 0:
                _HELD["saved"] = blas_thread_counts()
                limit_blas_threads(1)
            _HELD["depth"] += 1
        try:
            return fn(*args, **kwargs)
        finally:
            with _HELD_LOCK:
                _HELD["depth"] -= 1
                if _HELD["depth"] == 0:
                    for path, threads in _HELD["saved"].items():
                        _set_threads(path, threads)

    return wrapper

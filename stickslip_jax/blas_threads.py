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
runs BLAS on one thread (:func:`limit_blas_threads`, from ``cli/common.py``).
"""

from __future__ import annotations

import ctypes
import re

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


def limit_blas_threads(threads: int = 1) -> list[str]:
    """Set every OpenBLAS loaded in this process to ``threads`` threads; returns the
    libraries set. Libraries loaded later keep their own setting (numpy and scipy load
    theirs on import; ``OPENBLAS_NUM_THREADS`` set before that does the same)."""
    threads = int(threads)
    if threads < 1:
        raise ValueError(f"threads must be ≥ 1, got {threads}")
    done = []
    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _SETTERS:
            setter = getattr(lib, name, None)
            if setter is not None:
                setter.argtypes = [ctypes.c_int]
                setter.restype = None
                setter(threads)
                done.append(path)
                break
    return done

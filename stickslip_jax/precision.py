"""The precision the fits need: float64, which the library never switches on itself.

Double precision is a process-wide JAX setting (``jax_enable_x64``) and the library
never changes global settings on import (the package docstring). A fit or a diagnosis
run in single precision does not fail at once: its residuals, whitened by noise of a
nanometre on strokes of micrometres, sit at the float32 rounding level (one part in
1e7), and it ends minutes later somewhere unrelated (seen: a diagnosis stopped after
four minutes with a "folded" PI loop whose partial sums were float32 roundings of
2⁻⁴⁷). :func:`require_float64` says so before any work.
"""

from __future__ import annotations

import jax


def require_float64(what: str) -> None:
    """Raise RuntimeError, saying how to fix it, unless JAX runs in double precision;
    ``what`` names the work that needs it (e.g. ``"diagnose"``)."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            f"{what} needs double precision: its residuals are nanometres on strokes of "
            f"micrometres, below float32's resolution. Call "
            f"jax.config.update('jax_enable_x64', True) before any JAX computation (the "
            f"`stickslip` command line does this for you).")

"""XLA settings that must be made before JAX starts its backends (``XLA_FLAGS``).

Why the simulator wants one of them: XLA on a CPU runs a compiled program as a
sequence of kernels ("thunks"), each a function call with some bookkeeping, and a
``while`` loop runs its body's kernels once per iteration. The simulator's RK4
sub-step is a handful of scalar kernels (one per stage, one for the saturation, the
loop counter and test), so the per-kernel overhead, not the arithmetic, sets its
speed: about 370 ns per sub-step, 150 ms for a 1 s trace at 25 kHz and 16 sub-steps,
2.6x a scalar numba loop of the same scheme. XLA compiles a *small* loop, one whose
body touches fewer bytes than ``xla_cpu_small_while_loop_byte_threshold`` (1 kB by
default), into a single kernel with a native loop inside. Raising that threshold to
:data:`SMALL_LOOP_BYTES` takes in the sub-step loop of a simulation and of its
forward-mode derivatives (measured on the 2-core CPU, after compilation, same
numbers to rounding):

- one 1 s trace (25 000 samples): 145 ms by default, 45 ms with 100 kB;
- the identification residual over the 17 fixture recordings: 126 ms, 46 ms;
- its Jacobian with 1, 2 or 21 tangents in one vmapped pass: 0.43, 0.82, 1.19 s by
  default; 0.17, 0.28, 0.88 s with 100 kB;
- the same with all 42 tangents in one pass: 1.40 s, 1.60 s.

Only very wide vmapped tangents lose a little, and the fits do not build those in one
pass on a multi-core CPU (``identify/solve.py`` shares the columns among threads).
``benchmarks/bench_simulator.py`` records the setting it ran with. The option
concerns the CPU backend only; XLA does not pass ``xla_*`` backend options to LLVM,
and accelerators' compilers ignore it.

The library itself changes nothing global on import. The command line calls
:func:`fast_cpu_loops` (``cli/common.py``); in a script or notebook, call it before
the first JAX computation::

    import stickslip_jax as ss
    ss.fast_cpu_loops()
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings

SMALL_LOOP_BYTES = 100_000
"""The small-loop threshold [bytes] :func:`fast_cpu_loops` sets (XLA's default: 1000).
Chosen from 3e4, 1e5 and 1e9 by the timings in the module docstring: 3e4 leaves a 1 s
trace's loop out (59 ms), 1e9 also takes in the batched 17-recording loop, which then
runs slower (115 ms per recording against 77 ms)."""

_OPTION = "xla_cpu_small_while_loop_byte_threshold"


def backends_started() -> bool:
    """True once JAX has created its backends (``XLA_FLAGS`` is then read and fixed)."""
    if "jax" not in sys.modules:
        return False
    with contextlib.suppress(Exception):
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    return False


def native_loops_requested() -> bool:
    """True when ``XLA_FLAGS`` asks for XLA's small-loop threshold (set by
    :func:`fast_cpu_loops` or by the user). It takes effect if it was there before
    JAX started, which is how the CLI, the tests and the scripts set it."""
    return _OPTION in os.environ.get("XLA_FLAGS", "")


def add_xla_flag(name: str, value) -> bool:
    """Append ``--name=value`` to ``XLA_FLAGS`` unless ``name`` is there already.

    Returns True when the flag is (now) in ``XLA_FLAGS`` with a value of ours or the
    user's, False when the backends have started and it came too late to add.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if name in flags:
        return True
    if backends_started():
        return False
    os.environ["XLA_FLAGS"] = f"{flags} --{name}={value}".strip()
    return True


def fast_cpu_loops(threshold_bytes: int = SMALL_LOOP_BYTES) -> bool:
    """Let XLA compile the simulator's small loops into single native-loop kernels.

    Sets ``--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=N`` in
    ``XLA_FLAGS`` (see the module docstring: about 3x faster simulations and
    forward-mode Jacobians of a few columns on a CPU). Must run before JAX's first
    computation in the process; ``import stickslip_jax`` does not start JAX.

    Returns True when the setting is in place. Returns False, with a warning, when it
    comes too late (JAX has already run something: restart the kernel and call this
    first), and leaves ``XLA_FLAGS`` alone when it already holds backend options of
    the user's own (returning True if those include the threshold).
    """
    threshold_bytes = int(threshold_bytes)
    if threshold_bytes < 0:
        raise ValueError(f"threshold_bytes must be ≥ 0, got {threshold_bytes}")
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_extra_options" in flags:
        return _OPTION in flags
    if add_xla_flag("xla_backend_extra_options", f"{_OPTION}={threshold_bytes}"):
        return True
    warnings.warn(
        "stickslip_jax.fast_cpu_loops() came after JAX's first computation, so XLA keeps "
        "its default loop compilation (simulations about 3x slower on a CPU). Call it "
        "before running anything with JAX (e.g. first thing in the notebook).",
        stacklevel=2,
    )
    return False

"""XLA settings that must be made before JAX starts its backends (``XLA_FLAGS``).

Why the simulator wants them: XLA on a CPU runs a compiled program as a sequence of
kernels ("thunks"), each a function call with some bookkeeping, and a ``while`` loop
runs its body's kernels once per iteration. The simulator's RK4 sub-step is a handful
of scalar kernels (one per stage, one for the saturation, the loop counter and test),
so the per-kernel overhead, not the arithmetic, sets its speed: about 370 ns per
sub-step, 150 ms for a 1 s trace at 25 kHz and 16 sub-steps, 2.6x a scalar numba loop
of the same scheme. XLA compiles a *small* loop, one whose cost analysis counts fewer
bytes accessed than ``xla_cpu_small_while_loop_byte_threshold`` (1 kB by default),
into a single kernel with a native loop inside, unless the loop holds an operation
that such a kernel cannot call (a custom call, a sort, a library fusion).
:func:`fast_cpu_loops` does two things:

- It raises the threshold to :data:`SMALL_LOOP_BYTES`, so that every loop counts as
  small. At 100 kB (the setting until issue #28) the sub-step loop of a plain
  simulation was taken in (a 1 s trace: 145 ms by default, 45 ms), but not the loops
  of a forward-mode pass with several tangents, whose counted bytes grow with the
  tangents and the trip counts.
- It turns off XLA's YNNPACK library fusions (``xla_cpu_experimental_ynn_fusion_type``
  empty): a reduction or product over a batched axis inside a loop (the PI output
  ``weights·plays`` with vmapped tangents) became such a fusion, which keeps every
  loop around it out of the native kernel.

Measured on the 2-core CPU (issue #28), after compilation, same numbers to rounding:
the identification's Jacobian of one 0.1 s recording (2500 samples) with 21 vmapped
tangents 65 ms (175 ms with the 100 kB setting; 6 ms with one tangent, 4 ms without);
the gradient of a 0.2 s trace over five parameters (default adjoint) 73 ms (180 ms);
17 fixture recordings vmapped in one pass 0.15 s (0.24 s); a plain simulation and the
17 recordings mapped one after the other unchanged (63 and 61 ms). The options concern
the CPU backend only; XLA does not pass ``xla_*`` backend options to LLVM, and
accelerators' compilers ignore them.

The library itself changes nothing global on import. The command line calls
:func:`fast_cpu_loops` (``cli/common.py``); in a script or notebook, call it before
the first JAX computation::

    import stickslip_jax as ss
    ss.fast_cpu_loops()

On a GPU the question is the other way round: XLA runs the scan's ``while`` loop and
every ``cond`` from the host, a launch and a wait per sub-step, unless its command
buffers (CUDA graphs) take them in. :func:`device_side_gpu_loops` asks for that (an
H200, 17 rows of a 0.02 s trace at the default stepping: 0.752 s by default, 0.457 s
with it; ``benchmarks/README.md``). The CPU ignores those options.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings

SMALL_LOOP_BYTES = 10**15
"""The small-loop threshold [bytes] :func:`fast_cpu_loops` sets (XLA's default: 1000):
every loop of the simulator and of its forward-mode derivatives, whatever the
tangents and the trace length (a 10 s trace with 42 tangents counts under 1e13). It
was 100 kB until issue #28; 1e9 then left the loops of a pass with 8 or more tangents
out, and a larger value changed neither a plain simulation nor a batch of them."""

LIBRARY_FUSIONS = "xla_cpu_experimental_ynn_fusion_type"
"""The XLA option that lists the YNNPACK library fusions; :func:`fast_cpu_loops` sets
it empty (none), see the module docstring."""

_OPTION = "xla_cpu_small_while_loop_byte_threshold"

GPU_COMMAND_BUFFER = "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,CONDITIONAL,WHILE"
"""The command types :func:`device_side_gpu_loops` lets XLA put in CUDA graphs: jax's
defaults plus ``WHILE`` (the scan) and ``CONDITIONAL`` (the stepping's branches)."""


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
    """Let XLA compile the simulator's loops into single native-loop kernels.

    Sets ``--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=N`` and
    ``--xla_cpu_experimental_ynn_fusion_type=`` (no library fusions) in ``XLA_FLAGS``
    (see the module docstring: about 3x faster simulations, and forward-mode Jacobians
    of many columns, on a CPU). Must run before JAX's first computation in the
    process; ``import stickslip_jax`` does not start JAX.

    Returns True when the threshold is in place. Returns False, with a warning, when it
    comes too late (JAX has already run something: restart the kernel and call this
    first), and leaves the threshold alone when ``XLA_FLAGS`` already holds backend
    options of the user's own (returning True if those include it); a library-fusion
    setting of the user's own is kept too.
    """
    threshold_bytes = int(threshold_bytes)
    if threshold_bytes < 0:
        raise ValueError(f"threshold_bytes must be ≥ 0, got {threshold_bytes}")
    if not backends_started():
        add_xla_flag(LIBRARY_FUSIONS, "")
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


def device_side_gpu_loops() -> bool:
    """Let XLA run the simulator's loops and branches on a GPU without the host.

    Sets ``--xla_gpu_enable_command_buffer=`` :data:`GPU_COMMAND_BUFFER` and
    ``--xla_gpu_graph_min_graph_size=1`` in ``XLA_FLAGS`` (each unless the user set it),
    so each sub-step's kernels, the loop test and the branch predicates stay on the
    device as one CUDA graph. Measured on an H200 (jax 0.11.2, ``results/gpu_h200.json``),
    after compilation: 17 rows of a 0.02 s trace at the default stepping 0.457 s against
    0.752 s, an 8-point velocity map 0.680 s against 1.103 s, a 3-column forward-mode
    Jacobian 0.712 s against 0.819 s; the old fixed stepping (no branches) 0.181 s
    against 0.146 s. Same arithmetic, so the same numbers. A CPU ignores both options.

    Returns True when both are in ``XLA_FLAGS`` (ours or the user's), False when JAX
    had already started (they come too late; no warning: a CPU user loses nothing).
    """
    ok = add_xla_flag("xla_gpu_enable_command_buffer", GPU_COMMAND_BUFFER)
    return add_xla_flag("xla_gpu_graph_min_graph_size", 1) and ok

"""How reverse-mode derivatives of a simulation are computed (the ``adjoint=`` option).

Reverse mode through a long ``lax.scan`` of tiny scalar steps runs the sample loop
forward, then a transposed loop of many small operations backwards. With XLA's
default CPU loop compilation every one of those operations pays a kernel's overhead
(a gradient over nine parameters of a 1 s trace cost 15-21 forward runs, measured by
``benchmarks/bench_simulator.py``); there, when only a few numbers are
differentiated, forward mode is cheaper: one pass that carries one tangent per
parameter through the same loop gives every sensitivity dq/dθ, and a gradient is
then a product with that Jacobian. With :func:`~stickslip_jax.xla_flags.fast_cpu_loops`
(the CLI's, tests' and notebooks' setting) the loops compile natively, reverse mode
cost about 3.5-5 forward runs with the plain fixed-step scheme; with the default
stepping's located switches and refined intervals (``cond``s whose both branches
reverse mode stores and replays) a gradient costs as much as forward sensitivities
over about 85 parameters, and compiles about 10x longer (over two minutes against
11-13 s: the native loop kernels of the backward pass are large), so forward
sensitivities are the default up to 128 parameters (:func:`default_max_directions`).

- :class:`ForwardSensitivities` (the default): the simulation gets a custom JVP whose
  tangent is ``J·t`` with ``J`` the dense Jacobian with respect to the *perturbed*
  inputs (found through JAX's symbolic zeros), built by one vmapped forward-mode pass.
  Its transpose, which ``jax.grad`` uses, is ``Jᵀ·c``: a gradient costs about as much
  as a ``jax.jacfwd`` over the perturbed parameters. ``jax.jacfwd`` and ``jax.linearize``
  build ``J`` once, so they cost what they would without it. The recorded voltage
  keeps the ordinary derivative (a gradient with respect to thousands of samples is
  what reverse mode is for), and so does everything when more than ``max_directions``
  scalars are perturbed (a network's weights; ``eqx.filter_grad`` over a whole
  default actuator, 85 scalars, stays below the default limit). For a function of a
  few numbers that reach the simulator through the voltage (a waveform's knots), see
  :func:`with_forward_jacobian`. Values and derivatives are the same as with plain
  differentiation; only the cost changes. The price: one ``jax.jvp`` whose tangent
  mixes n parameters costs the whole n-column Jacobian (a tangent in one parameter
  costs one tangent).
- :class:`CheckpointedScan`: plain JAX differentiation of the scan, each sample step
  checkpointed. Any argument, any mode; the choice for a single ``jax.jvp`` along a
  direction that mixes many parameters.

Identification and diagnosis do not go through this choice: their solvers build the
Jacobian of their residuals directly in forward mode (``identify/solve.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero


def value_and_jacfwd(fn: Callable, x: jax.Array,
                     basis: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """``(fn(x), ∂fn/∂x)`` for a 1-D ``x`` from one vmapped forward-mode pass: the primal
    runs once, the Jacobian's last axis runs over ``x``. With ``basis`` (rows: tangent
    directions) the derivatives along those rows instead, one column each."""
    if basis is None:
        basis = jnp.eye(x.size, dtype=x.dtype)
    if basis.shape[0] == 1:
        # One direction: a plain JVP. Under vmap every operation of the loop becomes a
        # length-1 vector operation, which XLA's native CPU loops run about 2x slower
        # (measured on a 1 s trace: 3.7 against 1.9 forward runs).
        value, tangent = jax.jvp(fn, (x,), (basis[0],))
        return value, tangent[..., None]
    return jax.vmap(lambda t: jax.jvp(fn, (x,), (t,)), out_axes=(None, -1))(basis)


class AbstractAdjoint(eqx.Module):
    """How a simulation is differentiated; see the module docstring."""

    def wrap(self, fn: Callable) -> Callable:
        """``fn(params, voltage) -> q`` with this adjoint's derivative rule."""
        raise NotImplementedError


def default_max_directions() -> int:
    """Where :class:`ForwardSensitivities` hands over to reverse mode, in perturbed scalars.

    Measured with native CPU loops and the simulator's default stepping (located
    switches and refined intervals, whose ``cond``s reverse mode must store and
    replay), ``benchmarks/bench_gradient_modes.py``: the gradient over every leaf of
    the default actuator (85 scalars) runs as fast from forward sensitivities as in
    reverse mode (1 s trace: 17.75 against 17.80 s; 376 samples: 0.295 against
    0.304 s) and compiles in 11-13 s against 138-140 s. Forward mode's run time grows
    with the directions (at 128 about 1.5x reverse mode's on the 1 s trace), so a
    fit that takes more than a dozen gradients over 100-128 parameters of long traces
    gains from ``ForwardSensitivities(max_directions=64)``; one gradient, or many of
    short traces, from this default: 128, on every backend.
    """
    return 128


class CheckpointedScan(AbstractAdjoint):
    """JAX's own derivatives of the scan (per-sample ``jax.checkpoint``)."""

    def wrap(self, fn: Callable) -> Callable:
        return fn


class ForwardSensitivities(AbstractAdjoint):
    """Gradients from dense forward sensitivities of the perturbed parameters.

    ``max_directions``: above this many perturbed scalars the ordinary derivative is
    used (forward mode's cost grows with them, reverse mode's does not). ``None``
    (default): :func:`default_max_directions`, which depends on how XLA compiles the
    simulator's loops.
    """

    max_directions: int | None = eqx.field(static=True, default=None)

    def wrap(self, fn: Callable) -> Callable:
        limit = default_max_directions() if self.max_directions is None else self.max_directions

        @jax.custom_jvp
        def wrapped(params, voltage):
            return fn(params, voltage)

        def rule(primals, tangents):
            params, voltage = primals
            t_params, t_voltage = tangents
            leaves, treedef = jax.tree.flatten(params)
            t_leaves = treedef.flatten_up_to(t_params)
            live = [i for i, t in enumerate(t_leaves) if not isinstance(t, SymbolicZero)]
            voltage_live = not isinstance(t_voltage, SymbolicZero)
            n = sum(int(jnp.size(leaves[i])) for i in live)
            if n == 0 or n > limit:
                # The ordinary derivative, through the perturbed inputs only (dense zero
                # tangents for the others would carry their tangent arithmetic along).
                def of_perturbed(live_leaves, v):
                    new = list(leaves)
                    for i, leaf in zip(live, live_leaves, strict=True):
                        new[i] = leaf
                    return fn(treedef.unflatten(new), v)

                primal = [leaves[i] for i in live]
                tangent = [t_leaves[i] for i in live]
                if voltage_live:
                    return jax.jvp(of_perturbed, (primal, voltage), (tangent, t_voltage))
                return jax.jvp(lambda p: of_perturbed(p, voltage), (primal,), (tangent,))

            x0 = jnp.concatenate([jnp.ravel(leaves[i]) for i in live])

            def of_live(x):
                new, offset = list(leaves), 0
                for i in live:
                    size = int(jnp.size(leaves[i]))
                    new[i] = x[offset:offset + size].reshape(jnp.shape(leaves[i]))
                    offset += size
                return fn(treedef.unflatten(new), voltage)

            value, jac = value_and_jacfwd(of_live, x0)
            t_x = jnp.concatenate([jnp.ravel(t_leaves[i]) for i in live])
            t_out = jac @ t_x
            if voltage_live:
                t_out = t_out + jax.jvp(lambda v: fn(params, v), (voltage,), (t_voltage,))[1]
            return value, t_out

        wrapped.defjvp(rule, symbolic_zeros=True)
        return wrapped


DEFAULT_ADJOINT = ForwardSensitivities()
"""The adjoint ``simulate`` and ``simulate_batch`` use unless told otherwise."""


def with_forward_jacobian(fn: Callable) -> Callable:
    """``fn`` whose derivatives all come from its dense Jacobian, built in forward mode.

    For a function of a few numbers that drive a simulation through a long input,
    e.g. the knots of a drive waveform: the simulator's rule keeps the *voltage's*
    ordinary derivative (reverse mode, built for thousands of samples), and reverse
    mode through the simulator compiles slowly with
    :func:`~stickslip_jax.xla_flags.fast_cpu_loops` (measured in
    ``benchmarks/bench_gradient_modes.py``: an 8-knot waveform's gradient over 3
    periods compiled in about 67 s and ran in 0.11 s, against 9 s and 0.04 s here).

    ``fn(x)``: one argument, a pytree of floating arrays (close over the others), any
    pytree of arrays out. The wrapped function has the same value; a JVP along ``t``
    is ``J·t``, with ``J`` from one vmapped forward-mode pass over every scalar of
    ``x`` (:func:`value_and_jacfwd`), and ``jax.grad`` takes its transpose ``Jᵀ·c``.
    So any derivative costs the whole Jacobian: worth it while ``x`` holds a few
    dozen scalars at most.
    """
    from jax.flatten_util import ravel_pytree

    @jax.custom_jvp
    def wrapped(x):
        return fn(x)

    @wrapped.defjvp
    def rule(primals, tangents):
        (x,), (t,) = primals, tangents
        flat, unravel = ravel_pytree(x)
        value, jac = value_and_jacfwd(lambda f: fn(unravel(f)), flat)
        t_flat, _ = ravel_pytree(t)
        return value, jax.tree.map(lambda j: jnp.tensordot(j, t_flat, axes=1), jac)

    return wrapped

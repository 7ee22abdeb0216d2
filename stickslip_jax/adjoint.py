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
reverse mode stores and replays) a gradient costs about 45 forward runs, so forward
sensitivities win up to about 60 parameters (:func:`default_max_directions`).

- :class:`ForwardSensitivities` (the default): the simulation gets a custom JVP whose
  tangent is ``J·t`` with ``J`` the dense Jacobian with respect to the *perturbed*
  inputs (found through JAX's symbolic zeros), built by one vmapped forward-mode pass.
  Its transpose, which ``jax.grad`` uses, is ``Jᵀ·c``: a gradient costs about as much
  as a ``jax.jacfwd`` over the perturbed parameters. ``jax.jacfwd`` and ``jax.linearize``
  build ``J`` once, so they cost what they would without it. The recorded voltage
  keeps the ordinary derivative (a gradient with respect to thousands of samples is
  what reverse mode is for), and so does everything when more than ``max_directions``
  scalars are perturbed (``eqx.filter_grad`` over a whole actuator, a network's
  weights). Values and derivatives are the same as with plain differentiation; only
  the cost changes. The price: one ``jax.jvp`` whose tangent mixes n parameters costs
  the whole n-column Jacobian (a tangent in one parameter costs one tangent).
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

    Measured on the benchmark trace (1 s, 25 kHz) with the simulator's default stepping
    (located switches and refined intervals, whose ``cond``s reverse mode must store and
    replay), as multiples of one forward run: ``jax.jacfwd`` costs 1.3, 3.1, 14.7 and
    33.9 for 1, 3, 9 and 44 parameters, reverse-mode ``jax.grad`` about 45 whatever
    their number (and 7x longer to compile). Forward sensitivities win up to about 60
    parameters: 64, on every backend.
    """
    return 64


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

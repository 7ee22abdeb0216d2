"""How reverse-mode derivatives of a simulation are computed (the ``adjoint=`` option).

Reverse mode through a long ``lax.scan`` of tiny scalar steps is slow on a CPU: the
backward pass replays every checkpointed sample, then runs a transposed loop of many
small operations (about 15 forward runs for the gradient over nine parameters of a
1 s trace, measured by ``benchmarks/bench_simulator.py``). When only a few numbers are
differentiated (the physical parameters, say), forward mode is cheaper: one pass that
carries one tangent per parameter through the same loop gives every sensitivity
dq/dθ, and a gradient is then a product with that Jacobian.

- :class:`CheckpointedScan` (the default): plain JAX differentiation of the scan, each
  sample step checkpointed. Any argument, any mode.
- :class:`ForwardSensitivities`: the simulation gets a custom JVP whose tangent is
  ``J·t`` with ``J`` the dense Jacobian with respect to the *perturbed* inputs (found
  through JAX's symbolic zeros), built by one vmapped forward-mode pass. Its
  transpose, which ``jax.grad`` uses, is ``Jᵀ·c``: a gradient costs about as much as
  a ``jax.jacfwd`` over the perturbed parameters. The recorded voltage keeps the
  ordinary derivative (a gradient with respect to thousands of samples is what
  reverse mode is for), and so does everything when more than ``max_directions``
  scalars are perturbed. Values and derivatives are the same as with the default;
  only the cost changes. A single ``jax.jvp`` in one direction becomes as costly as
  the whole Jacobian, so keep the default for that.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero


def value_and_jacfwd(fn: Callable, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(fn(x), ∂fn/∂x)`` for a 1-D ``x`` from one vmapped forward-mode pass: the primal
    runs once, the Jacobian's last axis runs over ``x``."""
    basis = jnp.eye(x.size, dtype=x.dtype)
    return jax.vmap(lambda t: jax.jvp(fn, (x,), (t,)), out_axes=(None, -1))(basis)


class AbstractAdjoint(eqx.Module):
    """How a simulation is differentiated; see the module docstring."""

    def wrap(self, fn: Callable) -> Callable:
        """``fn(params, voltage) -> q`` with this adjoint's derivative rule."""
        raise NotImplementedError


class CheckpointedScan(AbstractAdjoint):
    """JAX's own derivatives of the scan (per-sample ``jax.checkpoint``); the default."""

    def wrap(self, fn: Callable) -> Callable:
        return fn


DEFAULT_ADJOINT = CheckpointedScan()
"""The adjoint ``simulate`` uses unless told otherwise."""


class ForwardSensitivities(AbstractAdjoint):
    """Gradients from dense forward sensitivities of the perturbed parameters.

    ``max_directions``: above this many perturbed scalars the ordinary derivative is
    used (forward mode's cost grows with them; about 60 is where reverse mode wins
    on the benchmark trace).
    """

    max_directions: int = eqx.field(static=True, default=64)

    def wrap(self, fn: Callable) -> Callable:
        limit = self.max_directions

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
                dense = [jnp.zeros_like(p) if isinstance(t, SymbolicZero) else t
                         for p, t in zip(leaves, t_leaves, strict=True)]
                tv = jnp.zeros_like(voltage) if not voltage_live else t_voltage
                return jax.jvp(fn, (params, voltage), (treedef.unflatten(dense), tv))

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

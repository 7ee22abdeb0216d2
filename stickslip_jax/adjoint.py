"""How reverse-mode derivatives of a simulation are computed (the ``adjoint=`` option).

Reverse mode through a long ``lax.scan`` of tiny scalar steps is slow on a CPU: the
backward pass replays every checkpointed sample, then runs a transposed loop of many
small operations (about 15 forward runs for the gradient over nine parameters of a
1 s trace, measured by ``benchmarks/bench_simulator.py``). When only a few numbers are
differentiated (the physical parameters, say), forward mode is cheaper: one pass that
carries one tangent per parameter through the same loop gives every sensitivity
dq/dθ, and a gradient is then a product with that Jacobian.

- :class:`ForwardSensitivities` (the default): the simulation gets a custom JVP whose
  tangent is ``J·t`` with ``J`` the dense Jacobian with respect to the *perturbed*
  inputs (found through JAX's symbolic zeros), built by one vmapped forward-mode pass.
  Its transpose, which ``jax.grad`` uses, is ``Jᵀ·c``: a gradient costs about as much
  as a ``jax.jacfwd`` over the perturbed parameters (about 6 forward runs for nine
  parameters against about 20 in reverse mode). ``jax.jacfwd`` and ``jax.linearize``
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
    return jax.vmap(lambda t: jax.jvp(fn, (x,), (t,)), out_axes=(None, -1))(basis)


class AbstractAdjoint(eqx.Module):
    """How a simulation is differentiated; see the module docstring."""

    def wrap(self, fn: Callable) -> Callable:
        """``fn(params, voltage) -> q`` with this adjoint's derivative rule."""
        raise NotImplementedError


class CheckpointedScan(AbstractAdjoint):
    """JAX's own derivatives of the scan (per-sample ``jax.checkpoint``)."""

    def wrap(self, fn: Callable) -> Callable:
        return fn


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


DEFAULT_ADJOINT = ForwardSensitivities()
"""The adjoint ``simulate`` and ``simulate_batch`` use unless told otherwise."""

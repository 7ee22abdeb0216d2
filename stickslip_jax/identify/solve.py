"""One least-squares solve: optimistix Levenberg-Marquardt with progress and a verdict.

The Jacobian is built in forward mode, so its cost grows with the number of
parameters, not the length of the traces. Optimistix linearises the residual function
at every iterate and then materialises the damped operator column by column; through
a long scan, replaying the linearised scan for each column is several times slower
than one forward-mode pass with all tangents at once. :func:`dense_jacobian` therefore
gives the residual function a custom JVP that builds the dense Jacobian once per
iterate and applies it as a matrix product.

That Jacobian is one ``jax.jit``-ed function (value and Jacobian from a single
vmapped JVP, so the primal runs once): optimistix's transformations then see one
call, not the whole simulator, and tracing a solve costs a fraction of a second
instead of seconds (measured on the 15-recording friction step: 5.7 s → 1.0 s of
tracing, and one simulation per LM step instead of two).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..adjoint import value_and_jacfwd


@dataclass(frozen=True)
class SolveResult:
    """Outcome of one solve.

    ``theta`` the solution in fitted coordinates; ``converged`` True only when
    optimistix reports success; ``message`` its verdict in words; ``iterations`` the
    number of LM steps; ``wall_s`` [s] including compilation; ``cost_start`` and
    ``cost_end`` the sum of squared residuals at the start and the end;
    ``residual_start`` and ``residual`` the residual vectors there; ``jacobian`` the
    Jacobian d residual / d theta at the solution (the last accepted point), which
    the solver computed anyway.
    """

    theta: np.ndarray
    converged: bool
    message: str
    iterations: int
    wall_s: float
    cost_start: float
    cost_end: float
    residual_start: np.ndarray | None = None
    residual: np.ndarray | None = None
    jacobian: np.ndarray | None = None


def dense_jacobian(fn: Callable):
    """``fn(θ, args)`` with a JVP rule ``J(θ)·t``, ``J = ∂fn/∂θ`` dense; and the jitted
    ``value_and_jacobian(θ, args)`` that rule calls.

    Values and derivatives are those of ``fn``; only the way the derivative is
    evaluated changes (once, vectorised over the parameters, then stored). ``args``
    are never differentiated.
    """

    @jax.jit
    def value_and_jacobian(theta, args):
        return value_and_jacfwd(lambda th: fn(th, args), theta)

    @jax.custom_jvp
    def wrapped(theta, args):
        return value_and_jacobian(theta, args)[0]

    @wrapped.defjvp
    def _jvp(primals, tangents):
        (theta, args), (t, _) = primals, tangents
        value, jac = value_and_jacobian(theta, args)
        return value, jac @ t

    return wrapped, value_and_jacobian


def value_and_jacobian(residuals: Callable, theta):
    """``(residuals(θ), ∂residuals/∂θ)`` from one forward-mode pass (numpy arrays)."""
    _, both = dense_jacobian(lambda th, args: residuals(th))
    value, jac = both(jnp.asarray(theta, dtype=float), None)
    return np.asarray(value), np.asarray(jac)


def solve_least_squares(residuals, theta0, *, max_steps: int = 60, rtol: float = 1e-4,
                        atol: float = 1e-6, ftol: float | None = None, window: int = 5,
                        scale_by_jacobian: bool = True, label: str = "fit",
                        echo: Callable[[str], None] | None = None) -> SolveResult:
    """Minimise ``Σ residuals(θ)²`` from ``theta0`` with Levenberg-Marquardt.

    Optimistix's solver takes the steps; this loop drives them one at a time (as
    ``optx.least_squares`` does inside a while loop) so that it can report progress
    and apply a second convergence test. Two ways to converge, whichever comes first:

    - optimistix's Cauchy test: the change of θ and of the residual vector between
      accepted steps are small in RMS over their entries, ``rms(|Δθ| / (atol +
      rtol·|θ|)) < 1`` and the same for the residuals. θ is a relative change of each
      parameter, so ``atol = 1e-6`` is 1 ppm.
    - a stationary cost (MINPACK's ftol test): over the last ``window`` accepted steps
      the cost fell by less than ``ftol`` of itself. Near the optimum of N residuals
      moving the parameters by one standard error changes the cost by about cost/N,
      so the default ``ftol = 0.1/N`` stops once the steps move the fit by well under
      a standard error; this ends fits whose poorly determined directions (e.g. a PI
      weight) keep drifting without effect, which the θ test alone would hold open.

    ``scale_by_jacobian`` (MINPACK's and scipy's ``x_scale='jac'``): the solve runs in
    φ = d·(θ − θ0) with d the column norms of the Jacobian at the start, so every
    direction has unit sensitivity and the LM damping (λ = 1 at the start) is on the
    scale of JᵀJ from the first step. Without it a well-scaled residual (cost ~1e-5)
    starts with a damping thousands of times too strong and creeps for ~10 steps. The
    Cauchy tolerances then apply to φ: atol = 1e-6 is a change worth 1e-6 of one
    unit-sensitivity direction.

    Never raises on failure: the verdict is in the result.
    """
    theta0 = jnp.asarray(theta0, dtype=float)
    start = time.perf_counter()
    if theta0.size == 0:
        r = np.asarray(residuals(theta0))
        cost = float(np.sum(r**2))
        return SolveResult(np.asarray(theta0), True, "converged (nothing free)", 0,
                           time.perf_counter() - start, cost, cost, r, r,
                           np.zeros((r.size, 0)))

    # The solve runs in φ = d·(θ − θ0); d and θ0 are arguments of the compiled step,
    # so the scaling is chosen after the first step without compiling again.
    def scaled(phi, args):
        origin, d = args
        return residuals(origin + phi / d)

    dense, _ = dense_jacobian(scaled)

    def fn(phi, args):
        return dense(phi, args), None

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol, norm=optx.rms_norm)
    options, tags = {"jac": "fwd"}, frozenset()
    args = (theta0, jnp.ones_like(theta0))
    phi0 = jnp.zeros_like(theta0)
    f_struct = jax.eval_shape(lambda: dense(phi0, args))
    if ftol is None:
        ftol = 0.1 / max(int(np.prod(f_struct.shape)), 1)
    state = solver.init(fn, phi0, args, options, f_struct, None, tags)
    dynamic0, static = eqx.partition(state, eqx.is_array)

    @jax.jit
    def step(y, dynamic, args):
        new_y, new_state, _ = solver.step(fn, y, args, options, eqx.combine(static, dynamic),
                                          tags)
        loss = jnp.sum(new_state.f_info.residual ** 2)
        return new_y, eqx.partition(new_state, eqx.is_array)[0], loss

    def jacobian_at_accepted(dynamic, d):
        # The Jacobian optimistix holds for the last accepted point, in θ coordinates.
        jac = eqx.combine(static, dynamic).f_info.jac.as_matrix()
        return np.asarray(jac) * np.asarray(d)[None, :]

    y, dynamic = phi0, dynamic0
    if scale_by_jacobian:
        # MINPACK's x_scale='jac': the first call evaluates the start, whose Jacobian
        # gives the column norms; then the solve restarts in the scaled coordinates.
        _, first, _ = step(y, dynamic, args)
        jac0 = jacobian_at_accepted(first, args[1])
        d = np.sqrt(np.sum(jac0**2, axis=0))
        d = np.where(np.isfinite(d) & (d > 1e-12 * max(float(d.max()), 1e-300)), d,
                     max(float(d.max()), 1.0))
        args = (theta0, jnp.asarray(d))

    costs: list[float] = []  # cost at each accepted point, the start first
    residual_start = None
    ok, message, n = False, f"not converged: hit max_steps={max_steps}", 0
    # The first call only evaluates the start (optimistix accepts it as the first
    # point); each later call proposes one LM step and accepts or rejects it.
    for n in range(max_steps + 1):
        y, dynamic, loss = step(y, dynamic, args)
        st = eqx.combine(static, dynamic)
        cost, accepted = float(loss), int(st.num_accepted_steps)
        if accepted > len(costs):
            costs.append(cost)
        if residual_start is None:
            residual_start = np.asarray(st.f_info.residual)
        if echo is not None:
            echo(f"  {label}: step {n:3d}  accepted {accepted - 1:3d}  cost {cost:.4e}")
        if not (np.all(np.isfinite(np.asarray(y))) and np.isfinite(cost)):
            ok, message = False, "failed: non-finite parameters or cost"
            break
        if not bool(st.result == optx.RESULTS.successful):
            ok, message = False, f"failed: {optx.RESULTS[st.result]}"
            break
        if bool(st.terminate):
            ok, message = True, "converged (parameter and residual changes below tolerance)"
            break
        if len(costs) > window and costs[-window - 1] - costs[-1] <= ftol * costs[-1]:
            ok, message = True, (f"converged (cost stationary: fell by less than {ftol:.2g} "
                                 f"of itself over {window} accepted steps)")
            break
    # y is the last accepted point, so the costs the steps reported and the residual
    # and Jacobian the state holds are the ones at the start and the end (no extra
    # compiled evaluation needed).
    st = eqx.combine(static, dynamic)
    residual = np.asarray(st.f_info.residual)
    jac = jacobian_at_accepted(dynamic, args[1])
    wall = time.perf_counter() - start
    cost_start, cost_end = (costs[0], costs[-1]) if costs else (np.nan, np.nan)
    theta = np.asarray(args[0] + y / args[1])
    return SolveResult(theta, ok, message, n, wall, cost_start, cost_end, residual_start,
                       residual, jac)

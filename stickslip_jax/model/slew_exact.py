"""The exact step of the tanh slew-limited drive stage under a linear command.

The stage (:class:`~stickslip_jax.model.extensions.SlewLimitedInput`) obeys
``ṡ = S·tanh((u − s)/(S·τ))``. With the command linear over a step, ``u = u0 + b·t``,
the lag ``e = u − s`` obeys the autonomous scalar equation ``ė = b − S·tanh(e/(S·τ))``;
in ``x = e/(S·τ)``, ``β = b/S`` and the time ``t/τ``:

    dx/d(t/τ) = β − tanh x.

Separating variables (``1/(β − tanh x) = cosh x/(β cosh x − sinh x)``) gives the
trajectory in implicit form, ``t/τ = F(x) − F(x0)`` with
``F(x) = [β·x + ln|β·cosh x − sinh x|]/(β² − 1)``. Two regimes, each written so that
nothing cancels:

* ``|β| < 1`` (the command slower than the slew rate): ``x`` relaxes monotonically
  towards ``x* = atanh β`` without crossing it. With ``β = tanh x*``,
  ``β cosh x − sinh x = sinh(x* − x)/cosh x*``, so in ``a = |x − x*|`` and ``c = ±β``
  (the sign of ``x0 − x*``): ``c·a + ln sinh a = c·a0 + ln sinh a0 − (1 − β²)·t/τ``.
  It is solved for ``ln a``: linear there near the equilibrium (``ln sinh a ≈ ln a``),
  so a step of any length, ``τ → 0`` included, lands on ``x*`` to rounding.
* ``|β| > 1`` (faster than the slew rate): the lag grows without bound. With
  ``|β| = coth y0``, ``β cosh x − sinh x = ±cosh(x − y0)/sinh y0``, so in
  ``w = ±x − y0``: ``|β|·w + ln cosh w = |β|·w0 + ln cosh w0 + (β² − 1)·t/τ``, convex
  and increasing in ``w``.

Either equation is solved by Newton steps kept inside a bracket that the regime's rate
bounds give (bisection where a step leaves it), until a step moves the root by less
than ``1e-13`` relative or the two sides agree to rounding, at most
:data:`MAX_ITERATIONS` steps: a count, never a time.
The derivative comes from one more Newton step taken with the parameters live (the
implicit function theorem at the converged root), so no derivative flows through the
iterations. ``|β| = 1`` (a ramp exactly at the slew rate) is the removable singularity
of both forms: ``|β|`` within :data:`SLEW_EDGE` of 1 is moved to that distance, a change
of the ramp's rate by ``1e-7`` relative (the lag moves by ``1e-7·S·t``, pV on any drive
this package meets), where the derivative in ``β`` is 0.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

SLEW_EDGE = 1e-7
"""How far from 1 the ratio ``|β|`` of the command's slope to the slew rate is kept [-]
(module docstring)."""
MAX_ITERATIONS = 60
"""Most Newton (or bisection) steps of one solve [-]; the solve stops earlier once a
step moves the root by less than :data:`RELATIVE_TOLERANCE`."""
RELATIVE_TOLERANCE = 1e-13
"""A solve has converged when a step moves the root by less than this times
``1 + |root|`` [-]."""
_TINY = 1e-300
_ROUNDING = 8 * float(np.finfo(float).eps)
_LN2 = float(np.log(2.0))


def _log_sinhc(a):
    """``ln(sinh(a)/a)`` for ``a ≥ 0``, without overflow or cancellation."""
    small, big = 1e-3, 30.0
    a_small = jnp.minimum(a, small)
    a_mid = jnp.clip(a, small, big)
    a_big = jnp.maximum(a, big)
    series = a_small**2 / 6 - a_small**4 / 180
    mid = jnp.log(jnp.sinh(a_mid) / a_mid)
    large = a_big - _LN2 - jnp.log(a_big)            # + ln(1 − e^(−2a)) < 1e-26
    return jnp.where(a < small, series, jnp.where(a > big, large, mid))


def _a_coth_a(a):
    """``a·coth(a)`` for ``a ≥ 0`` (1 at 0)."""
    small = 1e-3
    a_small = jnp.minimum(a, small)
    a_rest = jnp.maximum(a, small)
    return jnp.where(a < small, 1 + a_small**2 / 3 - a_small**4 / 45,
                     a_rest / jnp.tanh(a_rest))


def _log_cosh(w):
    aw = jnp.abs(w)
    return aw + jnp.log1p(jnp.exp(-2 * aw)) - _LN2


def _relaxing(log_a, c):
    """``c·a + ln sinh a`` in ``ln a`` and its derivative in ``ln a``."""
    a = jnp.exp(log_a)
    return c * a + log_a + _log_sinhc(a), c * a + _a_coth_a(a)


def _growing(w, beta):
    """``β·w + ln cosh w`` and its derivative (``β > 1``)."""
    return beta * w + _log_cosh(w), beta + jnp.tanh(w)


def _solve_increasing(f, param, target, lo, hi, start):
    """The root of ``f(z, param) = target`` for ``f`` increasing in ``z`` with the root in
    ``[lo, hi]``: Newton steps from ``start``, a bisection wherever one leaves the
    bracket, then one Newton step with the arguments live for the derivative. Returns
    the root and the steps taken before that one."""
    stop = jax.lax.stop_gradient
    p, t = stop(param), stop(target)

    def body(carry):
        z, lo, hi, k, _ = carry
        value, slope = f(z, p)
        r = value - t
        lo = jnp.where(r < 0, z, lo)
        hi = jnp.where(r > 0, z, hi)
        step = r / slope
        # A step below the tolerance, or a residual at the rounding of the two sides
        # (near |β| = 1 the slope is ~1e-4 and the step cannot get below the tolerance),
        # is the last one, wherever rounding puts it; a larger one outside the bracket
        # (or NaN) becomes a bisection.
        done = ((jnp.abs(step) <= RELATIVE_TOLERANCE * (1 + jnp.abs(z)))
                | (jnp.abs(r) <= _ROUNDING * (jnp.abs(value) + jnp.abs(t))))
        new = z - step
        inside = (new >= lo) & (new <= hi)
        new = jnp.where(done | inside, new, 0.5 * (lo + hi))
        return new, lo, hi, k + 1, jnp.all(done)

    def running(carry):
        return (carry[3] < MAX_ITERATIONS) & ~carry[4]

    z0 = jnp.clip(stop(start), stop(lo), stop(hi))
    z, _, _, steps, _ = jax.lax.while_loop(
        running, body, (z0, stop(lo), stop(hi), jnp.asarray(0), jnp.asarray(False)))
    value, slope = f(z, param)
    return z - (value - target) / slope, steps


def _relaxing_setup(x0, beta, elapsed):
    """``|β| < 1`` (module docstring): the equation in ``ln a``, as ``(c, target, lo, hi,
    start)``, and the map from its root back to ``x``."""
    x_eq = jnp.arctanh(beta)
    d0 = x0 - x_eq
    sign = jnp.where(d0 >= 0, 1.0, -1.0)
    a0 = jnp.maximum(jnp.abs(d0), _TINY)
    c = sign * beta
    log_a0 = jnp.log(a0)
    target = _relaxing(log_a0, c)[0] - (1 - beta**2) * elapsed
    # d(ln a)/d(t/τ) ≥ −(1 + |β|) (the slope of the left side in ln a is ≥ 1 − |β|), and
    # a falls at most at the saturated rate 1 − c.
    by_rate = log_a0 - (1 + jnp.abs(beta)) * elapsed
    least = a0 - (1 - c) * elapsed
    lo = jnp.where(least > 0, jnp.maximum(by_rate, jnp.log(jnp.maximum(least, _TINY))),
                   by_rate)
    start = jnp.maximum(log_a0 - (1 - beta**2) * elapsed, lo)
    return (c, target, lo, log_a0, start), lambda log_a: x_eq + sign * jnp.exp(log_a)


def _growing_setup(x0, beta, elapsed):
    """``|β| > 1`` (module docstring): the equation in ``w``, as ``(|β|, target, lo, hi,
    start)``, and the map from its root back to ``x``."""
    sign = jnp.where(beta >= 0, 1.0, -1.0)
    b = jnp.abs(beta)
    y0 = jnp.arctanh(1 / b)
    w0 = sign * x0 - y0
    target = _growing(w0, b)[0] + (b**2 - 1) * elapsed
    # The rate of w lies between |β| − 1 and |β| + 1; the first rate (an Euler step) is
    # the largest along the path, so the start is right of the root.
    start = w0 + (b - jnp.tanh(w0)) * elapsed
    bracket = (w0 + (b - 1) * elapsed, w0 + (b + 1) * elapsed)
    return (b, target, *bracket, start), lambda w: sign * (w + y0)


def _either(slower, z, param):
    """The regime's left side and its slope at ``z``; each regime is evaluated at a
    harmless point where it is not the lane's, so neither value nor derivative is NaN."""
    c, b = param
    relax = _relaxing(jnp.where(slower, z, 0.0), c)
    grow = _growing(jnp.where(slower, 0.0, z), b)
    return tuple(jnp.where(slower, r, g) for r, g in zip(relax, grow, strict=True))


def slew_lag_after(x0, beta, elapsed):
    """The scaled lag ``x = (u − s)/(S·τ)`` after ``elapsed = t/τ`` [-] from ``x0``, under
    a command whose slope is ``β`` times the slew rate (module docstring). Broadcasts."""
    return lag_and_steps(x0, beta, elapsed)[0]


def lag_and_steps(x0, beta, elapsed):
    """:func:`slew_lag_after` and the solver steps it took [-] (one solve per element,
    whichever regime is its own)."""
    slower = jnp.abs(beta) < 1
    # Each regime sees a β of its own range (|β| moved off 1 by SLEW_EDGE); the other's
    # lanes get β = 0 or 2 and a lag of 0, whose solves end at once.
    beta_below = jnp.where(slower, jnp.clip(beta, -1 + SLEW_EDGE, 1 - SLEW_EDGE), 0.0)
    beta_above = jnp.where(slower, 2.0, jnp.where(beta >= 0, 1.0, -1.0)
                           * jnp.maximum(jnp.abs(beta), 1 + SLEW_EDGE))
    (c, *below), to_x_below = _relaxing_setup(jnp.where(slower, x0, 0.0), beta_below, elapsed)
    (b, *above), to_x_above = _growing_setup(jnp.where(slower, 0.0, x0), beta_above, elapsed)
    target, lo, hi, start = (jnp.where(slower, p, q) for p, q in zip(below, above, strict=True))
    root, steps = _solve_increasing(partial(_either, slower), (c, b), target, lo, hi, start)
    x = jnp.where(slower, to_x_below(jnp.where(slower, root, 0.0)),
                  to_x_above(jnp.where(slower, 0.0, root)))
    return x, steps


def advance_slew_limited(state, u_start, u_end, h, slew, tau):
    """The state ``s`` [V] of ``ṡ = S·tanh((u − s)/(S·τ))`` after ``h`` [s] from
    ``state``, the command linear from ``u_start`` to ``u_end`` [V]; ``slew`` S [V/s],
    ``tau`` [s]. Exact to rounding at any ``h/τ`` (module docstring)."""
    scale = slew * tau
    beta = (u_end - u_start) / (h * slew)
    x = slew_lag_after((u_start - state) / scale, beta, h / tau)
    return u_end - scale * x

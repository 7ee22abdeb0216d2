"""The learned force correction the diagnosis falls back on when no catalogue entry
explains the residual: :class:`~stickslip_jax.model.extensions.LearnedForce`, fitted by
sparse regression with the baseline free."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..identify.parameters import ParameterMap, ParameterSpec
from ..model.actuator import Actuator
from ..model.extensions import LEARNED_FEATURES, LearnedForce
from .policy import DEFAULT_POLICY, Policy
from .problem import Problem


def learned_scales(problem: Problem) -> tuple[float, ...]:
    """The scale of each feature of
    :data:`~stickslip_jax.model.extensions.LEARNED_FEATURES` (x2: the recordings'
    largest travel [m]; u: their largest voltage [V]; the others fixed)."""
    travel = max(float(np.max(np.ptp(problem.data.measured, axis=1))), 1e-9)
    u = max(float(np.max(np.abs(problem.data.voltages))), 1.0)
    return (travel, 1e-3, 1e-3, 1e-4, u, 1e-7)


def fit_learned(problem: Problem, act: Actuator, base_names, rss0: float,
                max_steps: int, policy: Policy = DEFAULT_POLICY) -> dict:
    """Sparse regression of a force correction on ``act`` (whitened RSS ``rss0``): fit
    every feature with the baseline free (:meth:`~.problem.Problem.refit`: the PI
    weights held first), drop those with ``|t| <`` :attr:`~.Policy.learned_t_min`, and,
    if any was dropped, refit from where the full fit ended with them switched off
    (``LearnedForce.active``): the same compiled programs, and a start next to the
    sparse optimum (the kept coefficients barely move when a feature with a small
    ``|t|`` goes)."""
    n = len(LEARNED_FEATURES)
    names = list(base_names) + ["learned_coef"]
    spec = {"learned_coef": ParameterSpec(_coef, "linear", COEF_SCALE_N, "N")}
    trial = act.with_extension(LearnedForce(np.zeros(n), learned_scales(problem)))
    fitted, rss, out = problem.refit(trial, names, spec, label="learned full",
                                     max_steps=max_steps)
    # t-statistics of the coefficients from the whitened Jacobian at the optimum
    # (σ = 1), which the solver holds.
    jac = out.jacobian
    cov = np.linalg.pinv(jac.T @ jac)
    sl = ParameterMap.make(fitted, names, spec).slices()["learned_coef"]
    c = np.asarray(_coef(fitted))
    t = c / (np.sqrt(np.maximum(np.diag(cov)[sl], 1e-300)) * COEF_SCALE_N)
    keep = [i for i in range(n) if abs(t[i]) >= policy.learned_t_min]
    if not keep:
        return {"features": [], "rss": rss0, "actuator": act, "t": t.tolist()}
    if len(keep) < n:
        active = np.array([1.0 if i in keep else 0.0 for i in range(n)])
        start = eqx.tree_at(lambda a: (a.extensions[-1].coef, a.extensions[-1].active),
                            fitted, (jnp.asarray(c * active), jnp.asarray(active)))
        fitted, rss, _ = problem.fit(start, names, spec, label="learned sparse",
                                     max_steps=max_steps, initial_damping=1e-3)
    coef = np.asarray(_coef(fitted))
    order = sorted(keep, key=lambda i: -abs(coef[i]))
    return {"features": [LEARNED_FEATURES[i] for i in order],
            "coefficients_N": {LEARNED_FEATURES[i]: float(coef[i]) for i in order},
            "rss": rss, "actuator": fitted, "t": t.tolist()}


COEF_SCALE_N = 0.01
"""The θ scale of the coefficients [N] (linear): a force of 10 mN on the slider."""


def _coef(a: Actuator):
    """The learned correction's coefficients [N] (the last extension of ``a``)."""
    return a.extensions[-1].coef

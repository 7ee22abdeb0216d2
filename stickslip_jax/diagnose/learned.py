"""The learned force correction the diagnosis falls back on when no catalogue entry
explains the residual: :class:`~stickslip_jax.model.extensions.LearnedForce`, fitted by
sparse regression with the baseline free."""

from __future__ import annotations

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
    """Sparse regression of a force correction (fit, drop the features with
    ``|t| <`` :attr:`~.Policy.learned_t_min`, refit if any was dropped)."""
    scales = learned_scales(problem)
    keep = list(range(len(LEARNED_FEATURES)))
    fitted, rss = act, rss0
    for stage in ("full", "sparse"):
        coef = np.zeros(len(LEARNED_FEATURES))
        trial = act.with_extension(LearnedForce(coef, scales))

        def get(a):
            return a.extensions[-1].coef
        spec = {"learned_coef": ParameterSpec(get, "linear", 0.01, "N")}
        fitted, rss, out = problem.fit(trial, base_names + ["learned_coef"], spec,
                                       label=f"learned {stage}", max_steps=max_steps)
        if stage == "sparse":
            break
        # t-statistics of the coefficients from the whitened Jacobian at the optimum
        # (σ = 1), which the solver holds.
        jac = out.jacobian
        cov = np.linalg.pinv(jac.T @ jac)
        sl = ParameterMap.make(trial, base_names + ["learned_coef"], spec).slices()["learned_coef"]
        c = np.asarray(fitted.extensions[-1].coef)
        se = np.sqrt(np.maximum(np.diag(cov)[sl], 1e-300)) * 0.01
        t = c / se
        keep = [i for i in range(len(c)) if abs(t[i]) >= policy.learned_t_min]
        if not keep:
            return {"features": [], "rss": rss, "actuator": act, "t": t.tolist()}
        if len(keep) == len(c):
            break  # nothing dropped: the refit would repeat this fit exactly
        # Refit with the others held at zero: a library with only the kept columns.
        scales = tuple(s if i in keep else np.inf for i, s in enumerate(scales))
    coef = np.asarray(fitted.extensions[-1].coef)
    order = sorted(keep, key=lambda i: -abs(coef[i]))
    return {"features": [LEARNED_FEATURES[i] for i in order],
            "coefficients_N": {LEARNED_FEATURES[i]: float(coef[i]) for i in order},
            "rss": rss, "actuator": fitted}


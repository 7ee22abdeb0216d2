"""Standard errors and correlations of fitted parameters from the Jacobian.

With residuals ``r(θ)`` whose noise is white with variance σ² (estimated as
``RSS/(N − p)`` at the optimum), the covariance of θ is ``σ²·(JᵀJ)⁻¹``; physical
values follow by the delta method through the transform's Jacobian. Directions that
the data do not determine (tiny singular values of J) get no finite error: the
pseudo-inverse drops them and the parameters that load on them are flagged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Uncertainty:
    """Per entry of the physical parameter vector (labels): value, standard error,
    relative error, and whether the data determine it; plus the correlation matrix."""

    labels: list[str]
    values: np.ndarray
    std_errors: np.ndarray
    correlations: np.ndarray
    determined: np.ndarray
    sigma: float
    dof: int

    def as_dict(self) -> dict:
        out = {}
        for i, lab in enumerate(self.labels):
            se = self.std_errors[i]
            rel = se / abs(self.values[i]) if self.values[i] != 0 else np.inf
            out[lab] = {"value": float(self.values[i]),
                        "std_error": float(se) if np.isfinite(se) else None,
                        "relative_error": float(rel) if np.isfinite(rel) else None,
                        "determined": bool(self.determined[i])}
        return out


def parameter_uncertainty(jac: np.ndarray, residual: np.ndarray, value_jac: np.ndarray,
                          values: np.ndarray, labels: list[str], *,
                          rel_threshold: float = 0.5, rcond: float = 1e-9,
                          n_obs: int | None = None) -> Uncertainty:
    """Uncertainty of physical parameters from the residual Jacobian in θ.

    ``jac`` (N, p) = dr/dθ at the optimum, ``residual`` (N,), ``value_jac`` (p, p) =
    d(values)/dθ, ``values`` (p,) physical values. A parameter is *undetermined* when
    its relative standard error exceeds ``rel_threshold`` or it loads on a direction
    whose singular value is below ``rcond`` times the largest. ``n_obs`` the number of
    independent observations behind the residual (default: its length; less when it
    holds padding or removed offsets).
    """
    n, p = jac.shape
    n = n if n_obs is None else n_obs
    dof = max(n - p, 1)
    sigma2 = float(np.sum(residual**2) / dof)
    if not (np.all(np.isfinite(jac)) and np.isfinite(sigma2)):
        # A simulation that overflowed at the optimum (e.g. a diverging extension):
        # nothing can be said about any parameter; the SVD would not converge.
        return Uncertainty(list(labels), np.asarray(values), np.full(p, np.inf),
                           np.full((p, p), np.nan), np.zeros(p, dtype=bool),
                           float(np.sqrt(sigma2)), dof)
    u, s, vt = np.linalg.svd(jac, full_matrices=False)
    keep = s > rcond * s[0] if s.size and s[0] > 0 else np.zeros_like(s, dtype=bool)
    inv_s2 = np.where(keep, 1.0 / np.where(keep, s, 1.0) ** 2, 0.0)
    cov_theta = (vt.T * inv_s2) @ vt * sigma2
    cov = value_jac @ cov_theta @ value_jac.T
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    null = vt[~keep]  # directions the data do not see
    on_null = np.any(np.abs(null) > 1e-3, axis=0) if null.size else np.zeros(p, dtype=bool)
    se = np.where(on_null, np.inf, se)
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = np.outer(se, se)
        corr = np.where(np.isfinite(denom) & (denom > 0), cov / denom, np.nan)
        rel = se / np.abs(values)
    determined = (~on_null) & (rel <= rel_threshold)
    return Uncertainty(list(labels), np.asarray(values), se, corr, determined,
                       float(np.sqrt(sigma2)), dof)

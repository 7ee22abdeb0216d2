"""Standard errors and correlations of fitted parameters from the Jacobian.

The fit minimises ``Σ r(θ)²`` with r the residual whitened by each recording's noise
level (:class:`~.residuals.TraceResiduals` ``whiten``). Linearised at the optimum,
θ̂ − θ = −A⁺Jᵀe with A = JᵀJ and e the noise, so

    Cov θ̂ = A⁺ · Var(Jᵀe) · A⁺        (the "sandwich").

With white noise of the assumed level Var(Jᵀe) = A and this is the familiar A⁺. A
model's residual on real recordings is rarely white, though: what the model leaves
out is coloured, and the noise level is an estimate. So Var(Jᵀe) is estimated from
the residual itself (:func:`spectral_meat`): per recording, the residual's periodogram,
smoothed, weights the Jacobian's own spectrum (Parseval: for a flat spectrum of level
s² it is s²·JᵀJ). A residual that is white at the assumed level gives back A⁺; one
with structure where the parameters act widens their errors accordingly.

Physical values follow by the delta method through the transform's Jacobian.
Directions that the data do not determine (tiny singular values of J) get no finite
error: the pseudo-inverse drops them and the parameters that load on them are flagged.
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
    cov_theta: np.ndarray | None = None
    """Covariance of the fitted coordinates θ (the pseudo-inverse's, finite)."""
    null_directions: np.ndarray | None = None
    """Unit vectors in θ (rows) along which the data say nothing."""

    def of(self, gradient: np.ndarray, value: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Standard errors of derived quantities g(θ) with ``gradient`` (k, p) = dg/dθ
        and values ``value`` (k,), by the delta method: ``(std_errors, determined)``.
        A quantity is determined when it does not move along a null direction and its
        relative error is at most 0.5 (as for the parameters); else its error is inf."""
        g = np.atleast_2d(np.asarray(gradient, dtype=float))
        if self.cov_theta is None:
            return np.full(g.shape[0], np.inf), np.zeros(g.shape[0], dtype=bool)
        se = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", g, self.cov_theta, g), 0.0, None))
        scale = np.linalg.norm(g, axis=1)
        if self.null_directions is not None and self.null_directions.size:
            leak = np.abs(g @ self.null_directions.T).max(axis=1)
            on_null = leak > 1e-6 * np.where(scale > 0, scale, 1.0)
        else:
            on_null = np.zeros(g.shape[0], dtype=bool)
        se = np.where(on_null, np.inf, se)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = se / np.abs(np.asarray(value, dtype=float))
        return se, (~on_null) & (rel <= 0.5)

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


def smoothing_half_widths(n_bins: int, n: int, *, relative: float = 0.25,
                          least: int = 8) -> np.ndarray:
    """Half-width [bins] of the moving average that smooths an n-sample residual's
    periodogram at each of its ``n_bins`` rfft bins: ±``relative`` of the bin's
    frequency (a coloured residual's spectrum varies on that scale, so a peak at low
    frequency is not flattened into its neighbours), at least ``least`` bins (the
    average of 2·8 + 1 periodogram bins scatters by ~25 %) and at most n^(2/3)/2, the
    rate of the usual lag-window estimators."""
    k = np.arange(n_bins)
    top = max(least, int(np.ceil(0.5 * n ** (2.0 / 3.0))))
    return np.clip(np.ceil(relative * k).astype(int), least, top)


def smoothed_periodogram(pgram: np.ndarray, n: int) -> np.ndarray:
    """``pgram`` (rfft bins of an n-sample series) averaged over
    :func:`smoothing_half_widths`, reflected at both ends."""
    m = smoothing_half_widths(pgram.size, n)
    pad = int(m.max())
    ext = np.concatenate([pgram[1:pad + 1][::-1], pgram, pgram[-pad - 1:-1][::-1]])
    if ext.size < pgram.size + 2 * pad:  # fewer bins than the window: one average
        return np.full(pgram.size, float(np.mean(pgram)))
    csum = np.concatenate([[0.0], np.cumsum(ext)])
    k = np.arange(pgram.size) + pad
    return (csum[k + m + 1] - csum[k - m]) / (2 * m + 1)


def spectral_meat(jac_rows: np.ndarray, resid_rows: np.ndarray, mask: np.ndarray
                  ) -> np.ndarray:
    """Var(Jᵀe) estimated from the residual's own spectrum, summed over recordings.

    ``jac_rows`` (B, T, p) and ``resid_rows`` (B, T): the Jacobian and residual rows of
    each recording (padding zero), ``mask`` (B, T) its real samples. Each recording's
    noise is taken as stationary and independent of the others'; Σ_t,s J_t γ(t−s) J_sᵀ
    is evaluated in the frequency domain, (1/n)·Σ_f S(f)·Re(F(f)* F(f)ᵀ), with F the
    DFT of the Jacobian's columns and S the residual's periodogram smoothed
    (:func:`smoothed_periodogram`; circular end effects are of order (correlation
    length)/n).
    """
    b, _, p = jac_rows.shape
    meat = np.zeros((p, p))
    for i in range(b):
        n = int(np.sum(mask[i]))
        if n < 2:
            continue
        e = np.asarray(resid_rows[i, :n], dtype=float)
        jr = np.asarray(jac_rows[i, :n], dtype=float)
        ef = np.fft.rfft(e)
        jf = np.fft.rfft(jr, axis=0)
        s = smoothed_periodogram(np.abs(ef) ** 2 / n, n)
        # rfft bins stand for two of the full DFT, except DC and (even n) Nyquist.
        weight = np.full(s.size, 2.0)
        weight[0] = 1.0
        if n % 2 == 0:
            weight[-1] = 1.0
        meat += np.real((jf.conj().T * (weight * s)) @ jf) / n
    return meat


def parameter_uncertainty(jac: np.ndarray, residual: np.ndarray, value_jac: np.ndarray,
                          values: np.ndarray, labels: list[str], *,
                          rel_threshold: float = 0.5, rcond: float = 1e-9,
                          n_obs: int | None = None, mask: np.ndarray | None = None
                          ) -> Uncertainty:
    """Uncertainty of physical parameters from the residual Jacobian in θ.

    ``jac`` (N, p) = dr/dθ at the optimum, ``residual`` (N,), ``value_jac`` (p, p) =
    d(values)/dθ, ``values`` (p,) physical values. A parameter is *undetermined* when
    its relative standard error exceeds ``rel_threshold`` or it loads on a direction
    whose singular value is below ``rcond`` times the largest. ``n_obs`` the number of
    independent observations behind the residual (default: its length; less when it
    holds padding or removed offsets).

    ``mask`` (B, T), the real samples of B recordings of T rows each (the residual's
    layout): the covariance is the sandwich with :func:`spectral_meat`, corrected by
    N/(N − p) for the degrees of freedom the fit took from the residual. Without it,
    the white-noise form σ̂²·A⁺ with σ̂² = RSS/(N − p).
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
    a_pinv = (vt.T * inv_s2) @ vt
    if mask is None:
        cov_theta = a_pinv * sigma2
    else:
        rows = np.asarray(mask).shape
        meat = spectral_meat(jac.reshape(rows + (p,)), residual.reshape(rows),
                             np.asarray(mask)) * (n / dof)
        cov_theta = a_pinv @ meat @ a_pinv
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
                       float(np.sqrt(sigma2)), dof, cov_theta, null)

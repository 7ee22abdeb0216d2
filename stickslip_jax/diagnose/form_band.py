"""How well the data fix an entry's form: draws of its own parameters from its refit's
covariance, and the band they give a curve of the form (the F(v) curve, a filter's
response, a creep spectrum).

The refit ends with the whitened residual's Jacobian ``J`` at its optimum θ̂, over every
parameter it freed (the baseline's and the entry's). To first order θ − θ̂ is normal
with covariance ``s²·(JᵀJ)⁻¹`` (σ = 1 after whitening); ``s² = max(1, RSS/(N − p))``
widens it where the model leaves more than the noise, as a sandwich-free allowance for
misfit. The entry's block of that covariance (its coordinates' marginal: the baseline's
uncertainty is in it) is drawn :data:`DRAWS` times with a fixed seed, and each draw is
mapped to values through the parameter's own transform (a log parameter stays
positive, a non-negative weight non-negative), so the band respects the domains where a
linear propagation would not. The same refit gives the same draws on every machine.

The covariance is formed from the normal matrix ``JᵀJ`` (p × p) and its eigenvectors,
not from an SVD of ``J`` itself: that costs about ``N·p²`` (tens of milliseconds) where
the SVD took most of a second per refit (N ≈ 24 000, p ≈ 50), and every refit draws,
accepted or not. Squaring the condition number is why :data:`RCOND` is 1e-7, not
smaller: eigenvalues of ``JᵀJ`` below about 1e-14 of the largest are rounding.

Directions the data do not determine (singular values below :data:`RCOND` of the
largest) are left out of the covariance rather than given infinite spread: the band
then shows what the data fix, and an entry whose own parameters are undetermined has
no band (the report's interval then equals the value). So does a non-negative weight
the fit drove to its bound: its transform is flat there, and how far above 0 the data
would still allow it (a one-sided interval) is not drawn.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

DRAWS = 200
"""Draws of an entry's parameters: the 2.5 and 97.5 percentiles of 200 draws are within
about ±1 percentile point of the band's."""

BAND_PERCENTILES = (2.5, 97.5)
"""The pointwise band drawn and reported: 95 %."""

RCOND = 1e-7
"""Singular values of ``J`` below this share of the largest are left out of the
covariance (undetermined directions): eigenvalues of ``JᵀJ`` below RCOND² = 1e-14 of
the largest, about fifty rounding errors of the largest (float64) above the noise of
their computation."""

SEED = 20261206
"""The draws' fixed seed: the same refit, the same band."""


def parameter_draws(pmap, theta, jacobian, names: Sequence[str], *, rss: float,
                    count: int = DRAWS) -> dict[str, np.ndarray]:
    """``{name: values (count,)}``: draws of the parameters ``names`` (scalar ones of
    ``pmap``, the refit's :class:`~stickslip_jax.identify.parameters.ParameterMap`) from
    the refit's first-order covariance at ``theta`` (its optimum), with the whitened
    Jacobian ``jacobian`` (N × p) and whitened cost ``rss`` there. Empty when a name is
    not a scalar parameter of ``pmap`` or the Jacobian is not finite."""
    jac = np.asarray(jacobian, dtype=float)
    theta = np.asarray(theta, dtype=float)
    slices = pmap.slices()
    free = dict(zip(pmap.names, pmap.free, strict=True))
    if (not names or jac.ndim != 2 or not np.all(np.isfinite(jac))
            or any(n not in slices or free[n].size != 1 for n in names)):
        return {}
    n_obs, p = jac.shape
    with np.errstate(over="ignore", invalid="ignore"):
        normal = jac.T @ jac
    if not np.all(np.isfinite(normal)):
        return {}
    try:
        w, v = np.linalg.eigh(normal)
    except np.linalg.LinAlgError:
        return {}
    # Largest first (as an SVD orders them), each eigenvector's sign fixed by its
    # largest component, so that the same draws pair with the same directions
    # whatever sign the eigensolver returned.
    w, v = w[::-1], v[:, ::-1]
    v = v * np.where(v[np.argmax(np.abs(v), axis=0), np.arange(v.shape[1])] < 0, -1.0, 1.0)
    kept = w > RCOND**2 * w[0] if w.size and w[0] > 0 else np.zeros(0, bool)
    scale2 = max(1.0, rss / max(n_obs - p, 1))
    index = np.array([slices[n].start for n in names])
    # Rows of V·Λ^(−1/2) for the entry's coordinates (V, Λ: eigenvectors and eigenvalues
    # of JᵀJ, so Λ^(1/2) are J's singular values): their covariance is that times its
    # transpose, and a normal draw of them is it times a standard normal vector.
    factor = (v[index][:, kept] / np.sqrt(w[kept])) * np.sqrt(scale2)
    rng = np.random.default_rng(SEED)
    steps = rng.standard_normal((count, factor.shape[1])) @ factor.T
    return {n: np.array([float(free[n].to_physical(theta[index[i]:index[i] + 1] + step,
                                                    xp=np)) for step in steps[:, i]])
            for i, n in enumerate(names)}


def band(curve: Callable[[dict], np.ndarray], params: dict[str, float],
         draws: dict[str, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray] | None:
    """The pointwise band (:data:`BAND_PERCENTILES`) of ``curve(params)`` over the
    ``draws`` (:func:`parameter_draws`; the parameters not drawn keep ``params``'
    values); None without draws."""
    if not draws:
        return None
    count = len(next(iter(draws.values())))
    curves = np.array([curve({**params, **{n: float(v[i]) for n, v in draws.items()}})
                       for i in range(count)])
    lo, hi = np.percentile(curves, BAND_PERCENTILES, axis=0)
    return lo, hi


def intervals(draws: dict[str, np.ndarray] | None) -> dict[str, list[float]]:
    """``{name: [low, high]}``: each drawn parameter's :data:`BAND_PERCENTILES`."""
    return {n: [float(x) for x in np.percentile(v, BAND_PERCENTILES)]
            for n, v in (draws or {}).items()}


def draw_band(ax, x, curve: Callable[[dict], np.ndarray], params: dict[str, float],
              draws: dict[str, np.ndarray] | None, *, scale: float = 1.0,
              colour: str = "tab:blue") -> bool:
    """Shade on ``ax`` the :func:`band` of ``curve`` over ``x`` (both axes' values times
    ``scale`` on y: the figure's units), labelled; False, and nothing drawn, without
    draws."""
    spread = band(curve, params, draws)
    if spread is None:
        return False
    ax.fill_between(x, spread[0] * scale, spread[1] * scale, color=colour, alpha=0.2, lw=0,
                    label="95 % band (the refit's errors)")
    return True

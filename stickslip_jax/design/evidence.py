"""The evidence a set of recordings would give between two models, before recording it.

Two models, the truth ``T`` and a rival ``F`` fitted to the truth's data. With white
noise of known level, the expected excess of ``F``'s least-squares cost over ``T``'s on
recordings of the truth is the non-centrality

    ``λ = min_δ |e + J δ|²``,

``e`` the whitened difference of the two models' traces (each recording's offset
removed, as the residual does) and ``J`` the whitened Jacobian of ``F``'s residual in its
free quantities, both over every recording, old and new: ``F`` may move to absorb the
difference, but a move away from its fit to the old recordings costs there too. To
first order in ``F``'s move (the linearised fit, exact for a model linear in its
quantities), with each recording ``i`` summarised by ``Dᵢ = eᵢ·eᵢ``, ``gᵢ = Jᵢᵀeᵢ`` and
``Kᵢ = JᵢᵀJᵢ``,

    ``λ(w) = Σ wᵢDᵢ − (Σ wᵢgᵢ)ᵀ (Σ wᵢKᵢ)⁺ (Σ wᵢgᵢ)``,

``wᵢ`` how many times recording ``i`` is taken (a recording of a periodic drive ``w``
times as long: its steady periods repeated; its first period's transient is counted
``w`` times too, a small overstatement for a recording of five periods or more).

:func:`tolerance_rss` is what the diagnosis needs ``λ`` to exceed to tell the two apart
(:mod:`~stickslip_jax.significance`: the uncertainty of the noise level and the
simulator's error), on the same recordings: ``λ/τ ≥ 1`` separates them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

RCOND = 1e-12
"""The ridge added to the equilibrated normal matrix ``Σ wK`` (unit diagonal): a
direction whose eigenvalue is far below it (one the recordings do not determine) moves
nowhere, as in the least-norm fit. The equilibration takes out each quantity's scale,
so what is left is the recordings' own ill-conditioning squared: 1e-12 keeps the
directions the whitened Jacobian resolves to 1e-6 of its best one."""


@dataclass(frozen=True)
class Separation:
    """The summaries of one (truth, rival) pair per recording (module docstring):
    ``D`` (R,), ``g`` (R, p), ``K`` (R, p, p), whitened."""

    D: np.ndarray
    g: np.ndarray
    K: np.ndarray

    @classmethod
    def of(cls, e, jacobian, rows) -> Separation:
        """From the whitened difference ``e`` (N,) and the rival's whitened Jacobian
        ``jacobian`` (N, p), their rows grouped into recordings by ``rows`` (a list of
        index arrays or slices, one per recording)."""
        e = np.asarray(e, dtype=float)
        jac = np.asarray(jacobian, dtype=float)
        D = np.array([float(e[r] @ e[r]) for r in rows])
        g = np.stack([jac[r].T @ e[r] for r in rows])
        K = np.stack([jac[r].T @ jac[r] for r in rows])
        return cls(D, g, K)

    def __len__(self) -> int:
        return len(self.D)

    def totals(self, weights) -> tuple[float, np.ndarray, np.ndarray]:
        """``(Σ wD, Σ wg, Σ wK)`` for the recordings taken ``weights`` (R,) times."""
        w = np.asarray(weights, dtype=float)
        return (float(w @ self.D), np.tensordot(w, self.g, axes=1),
                np.tensordot(w, self.K, axes=1))

    def at(self, weights) -> float:
        """``λ(w)`` (module docstring) for the recordings taken ``weights`` (R,) times
        [whitened RSS], at least 0."""
        return separation_of(*self.totals(weights))


ROUNDOFF = 1e-9
"""A separation below this share of the difference's own sum of squares ``Σ wD`` is
none: the normal equations (squared conditioning, :data:`RCOND`'s ridge) leave that
much of a difference the rival mimics exactly."""


def separation_of(D: float, g: np.ndarray, K: np.ndarray) -> float:
    """``λ = D − gᵀK⁺g`` from the totals (:meth:`Separation.totals`); 0 below
    :data:`ROUNDOFF` of ``D``."""
    left = D - absorbed(K, g)
    return left if left > ROUNDOFF * D else 0.0


def absorbed(K: np.ndarray, g: np.ndarray) -> float:
    """``gᵀK⁺g``: the part of the difference the rival's move takes out [whitened RSS]
    (``K`` symmetric positive semi-definite). ``K`` is equilibrated to a unit diagonal
    and regularised by :data:`RCOND` (a Cholesky factor of ``K + RCOND·I``): directions
    the recordings do not determine move nowhere, as in the least-norm fit."""
    if K.size == 0:
        return 0.0
    d = np.sqrt(np.clip(np.diag(K), 0.0, None))
    live = d > 0
    if not np.any(live):
        return 0.0
    scale = 1.0 / d[live]
    Ks = K[np.ix_(live, live)] * scale[:, None] * scale[None, :]
    gs = g[live] * scale
    factor = np.linalg.cholesky(Ks + RCOND * np.eye(len(gs)))
    y = solve_triangular(factor, gs, lower=True)  # gᵀK⁻¹g = |L⁻¹g|²
    return float(y @ y)


def tolerance_rss(weights, counts, sigma_rel_se, numerical_chi2_per_sample,
                  z: float) -> float:
    """The tolerance of :mod:`~stickslip_jax.significance` as a whitened RSS on the
    recordings taken ``weights`` times: ``z·√(Σ wᵢ((2nᵢsᵢ)² + 2nᵢ)) + Σ wᵢnᵢ(εᵢ/σᵢ)²``
    (a recording ``w`` times as long has ``w·n`` samples and its σ's relative standard
    error ``s/√w``). ``counts`` nᵢ, ``sigma_rel_se`` sᵢ, ``numerical_chi2_per_sample``
    (εᵢ/σᵢ)²."""
    w = np.asarray(weights, dtype=float)
    n = np.asarray(counts, dtype=float)
    s = np.asarray(sigma_rel_se, dtype=float)
    spread = float(np.sqrt(np.sum(w * ((2 * n * s) ** 2 + 2 * n))))
    return z * spread + float(np.sum(w * n * np.asarray(numerical_chi2_per_sample)))

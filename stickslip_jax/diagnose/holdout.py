"""Leave one regime out: does a refit predict recordings it was not fitted to?

A refit is judged in-sample by ΔBIC. That it also predicts recordings left out of the
fit is a separate check: for every regime (scanning, stepping forward, stepping
backward, sine, step), fit the model to the other regimes' recordings and measure its
whitened RSS on the regime left out; the sum over regimes is the held-out cost. An
entry passes when its held-out cost is at most the baseline's (the model it extends,
checked the same way on the same recordings).

The refits on all but one regime are linearised at the full optimum: one Gauss-Newton
step from it, ``Δθ = argmin |r₋g + J₋g·Δθ|²`` with the Jacobian ``J`` the solver
computed there anyway, and the held-out residual predicted as ``r_g + J_g·Δθ``. That is
the standard first-order leave-out (as for the PRESS statistic of linear regression):
exact for a linear model, and it costs a least-squares solve per regime instead of a
nonlinear refit. A regime without which some parameter is no longer determined (the
Jacobian of the other regimes loses rank: an entry whose signature lives in that regime
alone) cannot be predicted from the others at all; it is left out of the check, for
both models (:func:`predicts_as_well` compares the regimes both were checked on).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..identify.solve import triangle_of

RCOND = 1e-10
"""Relative singular-value cut-off of the leave-out solves (columns normalised)."""


def held_out_cost(residual: np.ndarray, jacobian: np.ndarray, regimes: Sequence[str],
                  ) -> dict[str, float]:
    """Per regime, the whitened RSS of the recordings of that regime predicted by the
    linearised fit to every other regime (module docstring).

    ``residual`` (B·T,) and ``jacobian`` (B·T, P) are the whitened residual and its
    Jacobian at the full fit, rows recording-major (padding rows 0); ``regimes`` the
    regime of each of the B recordings. A regime that holds every recording has no
    other to be fitted to, and one without which the Jacobian loses rank cannot be
    predicted (module docstring): both are left out of the result.
    """
    r = np.asarray(residual, dtype=float)
    jac = np.asarray(jacobian, dtype=float)
    labels = np.asarray(regimes)
    rows_per = r.size // len(labels)
    row_regime = np.repeat(labels, rows_per)
    norms = np.linalg.norm(jac, axis=0)
    jn = jac / np.where(norms > 0, norms, 1.0)
    names = list(dict.fromkeys(labels.tolist()))
    # Each regime's rows factorised once, J_h = Q_h·R_h and c_h = Q_hᵀr_h: the least
    # squares over every regime but g is then that over the stacked (R_h, c_h) of the
    # others (the same singular values and minimum-norm solution: the Q_h are
    # orthonormal), a few P-row blocks instead of the N rows once per regime; all of
    # them stacked have J's singular values, so J's rank too.
    blocks = {g: triangle_of(jn[row_regime == g], r[row_regime == g]) for g in names}
    sv = np.linalg.svd(np.concatenate([blocks[g][0] for g in names]), compute_uv=False)
    full_rank = int(np.count_nonzero(sv > RCOND * sv.max())) if sv.size else 0
    out: dict[str, float] = {}
    for g in names:
        held = row_regime == g
        if held.all():
            continue
        tri = np.concatenate([blocks[h][0] for h in names if h != g])
        c = np.concatenate([blocks[h][1] for h in names if h != g])
        step, _, rank, _ = np.linalg.lstsq(tri, -c, rcond=RCOND)
        if rank < full_rank:
            continue
        predicted = r[held] + jn[held] @ step
        out[g] = float(predicted @ predicted)
    return out


def predicts_as_well(entry: dict[str, float], baseline: dict[str, float]) -> bool:
    """The entry's held-out cost summed over the regimes both were checked on is at most
    the baseline's (True when there is nothing to compare)."""
    common = [g for g in entry if g in baseline]
    if not common:
        return True
    return sum(entry[g] for g in common) <= sum(baseline[g] for g in common)

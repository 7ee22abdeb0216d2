"""The hysteresis's shape, refined in the baseline when the data need it alone.

The baseline's Prandtl-Ishlinskii operator places its play thresholds on a fixed grid
(:func:`~stickslip_jax.model.hysteresis.default_thresholds`); a real piezo's loop has
its own (a few operators at thresholds of their own, or a continuous density). A loop
whose kinks fall between the grid's thresholds leaves a residual the grid cannot take
up, small but, under low noise, beyond the tolerance: the baseline is then not wrong
in its physics, only too coarse in its hysteresis, and no catalogue entry should be
named for it.

The refinement inserts a threshold midway between each pair of neighbours (weights
zero there: the refined model starts at the same trace), and polishes the baseline
with every weight free. The refined baseline is kept only when it is within the noise
tolerance: the hysteresis's shape then accounts for all that was left, and the
diagnosis has nothing to name. Otherwise the coarse baseline stays, so that the
refinement cannot take up part of an effect the entries are there to name (its work is
counted on the baseline's account).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..model.actuator import Actuator
from ..model.hysteresis import PrandtlIshlinskii


def refined_thresholds(thresholds) -> np.ndarray:
    """``thresholds`` [V] (ascending) with a threshold inserted midway between each pair
    of neighbours: ``2n − 1`` of them, the old ones at the even places."""
    r = np.asarray(thresholds, dtype=float)
    out = np.empty(2 * r.size - 1)
    out[0::2] = r
    out[1::2] = 0.5 * (r[:-1] + r[1:])
    return out


def with_refined_hysteresis(act: Actuator) -> Actuator:
    """``act`` with its PI grid refined (:func:`refined_thresholds`), the new operators'
    weights zero: the same trace, more freedom in the loop's shape. Raises ValueError
    for a hysteresis that is not a Prandtl-Ishlinskii operator."""
    pi = act.hysteresis
    if not isinstance(pi, PrandtlIshlinskii):
        raise ValueError(f"the hysteresis shape is refined on a Prandtl-Ishlinskii "
                         f"operator, not {type(pi).__name__}")
    weights = np.zeros(2 * pi.weights.shape[0] - 1)
    weights[0::2] = np.asarray(pi.weights)
    fine = PrandtlIshlinskii(jnp.asarray(refined_thresholds(pi.thresholds)),
                             jnp.asarray(weights))
    return eqx.tree_at(lambda a: a.hysteresis, act, fine)

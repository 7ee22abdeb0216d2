"""Prandtl-Ishlinskii hysteresis: a weighted sum of play (backlash) operators."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .base import AbstractHysteresis


def default_thresholds(n: int, u_max: float, *, power: float = 1.3) -> np.ndarray:
    """Non-uniform play thresholds ``r_i`` [V], ascending, with ``r_0 = 0``.

    Thresholds crowd near zero (``r_i ∝ i^power``) where the loop bends most, and the
    largest stays below ``u_max`` so every operator is exercised by a 0..u_max drive.
    """
    i = np.arange(n, dtype=float)
    return u_max * (i / n) ** power


class PrandtlIshlinskii(AbstractHysteresis):
    """``Γ[U](t) = Σ_i w_i · p_i(t)``, ``p_i = max(U − r_i, min(U + r_i, p_i⁻))``.

    Attributes
    ----------
    thresholds: play thresholds r_i [V], ascending, r_0 = 0 gives the linear part
        (static: the structure of the model, not fitted by gradient).
    weights: weights w_i [m/V]. The loop is monotone when every partial sum of the
        weights is positive (checked by :meth:`is_monotone`, kept by the fitter).
    """

    thresholds: Float[Array, " n"]
    weights: Float[Array, " n"]

    def __init__(self, thresholds, weights):
        thresholds = jnp.asarray(thresholds, dtype=float)
        weights = jnp.asarray(weights, dtype=float)
        if thresholds.ndim != 1 or thresholds.shape != weights.shape:
            raise ValueError(
                f"pi_thresholds and pi_weights must be 1-D lists of the same length, "
                f"got shapes {thresholds.shape} and {weights.shape}"
            )
        self.thresholds = thresholds
        self.weights = weights

    @property
    def n_memory(self) -> int:
        return self.thresholds.shape[0]

    def initial_memory(self, u0):
        return jnp.clip(0.0, u0 - self.thresholds, u0 + self.thresholds)

    def output(self, memory, u):
        played = jnp.clip(memory, u - self.thresholds, u + self.thresholds)
        return jnp.dot(self.weights, played)

    def update(self, memory, u):
        return jnp.clip(memory, u - self.thresholds, u + self.thresholds)

    def along(self, voltage):
        """Output Γ at every sample of ``voltage`` [V], from rest at the first sample
        (each sample commits the memory; no dynamics) [units of the weights x V]."""
        u = jnp.asarray(voltage, dtype=float)

        def step(memory, uk):
            memory = self.update(memory, uk)
            return memory, self.output(memory, uk)

        return jax.lax.scan(step, self.initial_memory(u[0]), u)[1]

    def is_monotone(self) -> bool:
        """True when every partial sum of the weights is positive (loop is monotone)."""
        return bool(np.all(np.cumsum(np.asarray(self.weights)) > 0))

    def static_gain(self):
        """Initial-loading slope at 0 V, ``w_0`` summed over open plays [m/V]."""
        return jnp.sum(self.weights)

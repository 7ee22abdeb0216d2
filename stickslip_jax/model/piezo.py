"""The piezo element (PE): a damped mass-spring driven by its free stroke (Lu eq. 1-2)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class PiezoElement(eqx.Module):
    """Second-order piezo element ``Mp·ẍ1 + Dp·ẋ1 + Kp·x1 = Kp·Γ − Kact2·N − Ff``.

    Attributes
    ----------
    Mp: equivalent mass of the piezo element [kg].
    Dp: damping [N·s/m].
    Kp: stiffness [N/m].
    Kact2: preload coefficient [-] (the paper's 1200 cannot be read in SI; default 0).
    N: normal preload [N]; ``Kact2·N`` is a constant force [N] that only shifts the
       static equilibrium.
    """

    Mp: Float[Array, ""]
    Dp: Float[Array, ""]
    Kp: Float[Array, ""]
    Kact2: Float[Array, ""]
    N: Float[Array, ""]

    def __init__(self, Mp, Dp, Kp, Kact2=0.0, N=0.0):
        self.Mp = jnp.asarray(Mp, dtype=float)
        self.Dp = jnp.asarray(Dp, dtype=float)
        self.Kp = jnp.asarray(Kp, dtype=float)
        self.Kact2 = jnp.asarray(Kact2, dtype=float)
        self.N = jnp.asarray(N, dtype=float)

    @property
    def preload_force(self):
        """Constant force ``Kact2·N`` [N] opposing the stroke."""
        return self.Kact2 * self.N

    def push(self, x1, v1, stroke):
        """The force [N] the stack puts on its base beyond the constant preload:
        ``Kp·(Γ − x1) − Dp·ẋ1 − Kact2·N`` (= ``Mp·ẍ1 + Ff``: the contact force and the
        reaction of the stack's accelerating mass)."""
        return self.Kp * (stroke - x1) - self.Dp * v1 - self.preload_force

    def acceleration(self, x1, v1, stroke, friction_force, extra_force=0.0):
        """ẍ1 [m/s²] from deformation [m], rate [m/s], free stroke [m], forces [N]."""
        rhs = self.push(x1, v1, stroke) - friction_force
        return (rhs + extra_force) * (1.0 / self.Mp)

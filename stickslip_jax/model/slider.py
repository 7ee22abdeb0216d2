"""The slider (runner), pushed by friction and external loads (Lu eq. 3; Nguyen eq. 5)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class Slider(eqx.Module):
    """``Ms·ẍ2 + Ds·ẋ2 = Ff + F_ext − k_load·x2``.

    Attributes
    ----------
    Ms: slider mass [kg].
    Ds: viscous damping of the guide [N·s/m].
    F_ext: constant external force along +x [N] (gravity on a vertical axis, a load).
    k_load: load-spring stiffness acting from x2 = 0 [N/m] (force generation).
    """

    Ms: Float[Array, ""]
    Ds: Float[Array, ""]
    F_ext: Float[Array, ""]
    k_load: Float[Array, ""]

    def __init__(self, Ms, Ds, F_ext=0.0, k_load=0.0):
        self.Ms = jnp.asarray(Ms, dtype=float)
        self.Ds = jnp.asarray(Ds, dtype=float)
        self.F_ext = jnp.asarray(F_ext, dtype=float)
        self.k_load = jnp.asarray(k_load, dtype=float)

    @staticmethod
    def gravity(Ms, Ds, *, g: float = 9.80665, upward_is_positive: bool = True, k_load=0.0):
        """A slider on a vertical axis: ``F_ext = −Ms·g`` when +x points up [N]."""
        sign = -1.0 if upward_is_positive else 1.0
        return Slider(Ms, Ds, F_ext=sign * jnp.asarray(Ms) * g, k_load=k_load)

    def external_force(self, x2):
        """External force on the slider at position ``x2`` [m], in N."""
        return self.F_ext - self.k_load * x2

    def acceleration(self, x2, v2, friction_force, extra_force=0.0):
        """ẍ2 [m/s²] from position [m], velocity [m/s] and forces [N]."""
        rhs = friction_force + self.external_force(x2) - self.Ds * v2 + extra_force
        return rhs * (1.0 / self.Ms)

"""Nguyen 2012 eq. 1-4: a ruby hemisphere on two piezo columns, tilting to drive the contact.

Each of Nguyen's six actuators is a hemisphere (radius ``R``, mass ``m_a``, inertia
``I_a`` about its centre of gravity, which lies ``a`` below the sphere centre) glued on
two piezo columns ``±r`` from its axis, with column stiffness ``C`` and damping ``D``
(equal columns). The columns get skew-symmetric strokes ``y_l = −Γ/2``, ``y_r = +Γ/2``
(Γ [m]: the differential stroke, the PI output); the hemisphere heaves by ``y`` and
tilts by ``θ``; its top, the contact point, moves tangentially by ``x_c = R·sin θ``::

    m_a·ÿ  = F_yr + F_yl − F_n − F_ga                                         (eq. 1)
    I_a·θ̈ = (F_yr − F_yl)·r + (F_yr + F_yl − F_n)·a·sin θ − F_f·(R − a·cos θ)   (eq. 2)
    F_yl = (y_l − y + r·sin θ)·C + (ẏ_l − ẏ + r·cos θ·θ̇)·D                    (eq. 3)
    F_yr = (y_r − y − r·sin θ)·C + (ẏ_r − ẏ − r·cos θ·θ̇)·D                    (eq. 4)

(the source text of eq. 3-4 is garbled; "r0" is read as r·θ, the column top's
vertical displacement under the tilt, here r·sin θ.) ``F_n`` is the normal preload
and ``F_ga`` the hemisphere's weight.

For small tilts, symmetric columns and the heave at its static value, eq. 2 in the
contact coordinate ``x1 = R·θ`` is exactly the paper's piezo element
``Mp·ẍ1 + Dp·ẋ1 + Kp·x1 = Kp·Γ_eq − F_f`` with (:meth:`TiltingHemisphere.equivalent`)::

    Mp = I_a / (R·(R − a)),   Kp = (2r²·C − F_ga·a) / (R·(R − a)),
    Dp = 2r²·D / (R·(R − a)),  Γ_eq = g·Γ with g = r·C·R / (2r²·C − F_ga·a) ≈ R/(2r),

plus a feed-through ``(r·D/(R − a))·Γ̇`` that the contract's element (absolute damping)
does not have; it vanishes with the column damping and is left out. So the tilting
actuator is used as a contact model by :func:`with_hemisphere`, which installs this
element and scales the PI weights by g (the lever R/(2r)); :func:`hemisphere_rates`
integrates the full nonlinear eq. 1-4 to check where the reduction holds.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .piezo import PiezoElement


class TiltingHemisphere(eqx.Module):
    """Geometry and columns of one hemisphere actuator (Nguyen eq. 1-4), SI units.

    Attributes
    ----------
    m_a: hemisphere mass [kg]; I_a: its inertia about the centre of gravity [kg·m²];
    R: hemisphere radius [m]; a: centre of gravity below the sphere centre [m];
    r: column distance from the axis [m]; C: column stiffness [N/m]; D: column
    damping [N·s/m]; F_n: normal preload on the contact [N]; F_ga: weight [N].
    """

    m_a: Float[Array, ""]
    I_a: Float[Array, ""]
    R: Float[Array, ""]
    a: Float[Array, ""]
    r: Float[Array, ""]
    C: Float[Array, ""]
    D: Float[Array, ""]
    F_n: Float[Array, ""]
    F_ga: Float[Array, ""]

    def __init__(self, *, m_a, I_a, R, a, r, C, D=0.0, F_n=0.0, F_ga=0.0):
        f = lambda x: jnp.asarray(x, dtype=float)  # noqa: E731
        self.m_a, self.I_a, self.R, self.a, self.r = f(m_a), f(I_a), f(R), f(a), f(r)
        self.C, self.D, self.F_n, self.F_ga = f(C), f(D), f(F_n), f(F_ga)

    def lever(self):
        """Static tip displacement per unit differential stroke, g [-] (≈ R/(2r))."""
        return self.r * self.C * self.R / (2 * self.r**2 * self.C - self.F_ga * self.a)

    def equivalent(self) -> tuple[PiezoElement, Float[Array, ""]]:
        """The small-tilt piezo element in the contact coordinate and the lever g."""
        arm = self.R * (self.R - self.a)
        piezo = PiezoElement(self.I_a / arm, 2 * self.r**2 * self.D / arm,
                             (2 * self.r**2 * self.C - self.F_ga * self.a) / arm)
        return piezo, self.lever()

    def rest_heave(self):
        """Heave y [m] at rest, where the columns carry F_n + F_ga."""
        return -(self.F_n + self.F_ga) / (2 * self.C)


def with_hemisphere(actuator, hemisphere: TiltingHemisphere):
    """The actuator driven through a tilting hemisphere: its piezo element becomes the
    hemisphere's small-tilt equivalent and its free stroke is scaled by the lever (the
    PI output is read as the columns' differential stroke)."""
    piezo, g = hemisphere.equivalent()
    piezo = eqx.tree_at(lambda p: (p.Kact2, p.N), piezo, (actuator.piezo.Kact2, actuator.piezo.N))
    act = eqx.tree_at(lambda a: a.piezo, actuator, piezo)
    return eqx.tree_at(lambda a: a.hysteresis.weights, act, actuator.hysteresis.weights * g)


def hemisphere_rates(h: TiltingHemisphere, state, gamma, gamma_dot, friction_force=0.0):
    """Right-hand side of the full eq. 1-4 (NumPy): state ``(y, ẏ, θ, θ̇)`` [m, m/s, rad,
    rad/s], differential stroke Γ [m] and its rate [m/s], friction force F_f [N]."""
    y, yd, th, thd = state
    p = {k: float(getattr(h, k)) for k in ("m_a", "I_a", "R", "a", "r", "C", "D", "F_n",
                                           "F_ga")}
    yl, yr, yld, yrd = -gamma / 2, gamma / 2, -gamma_dot / 2, gamma_dot / 2
    s, c = np.sin(th), np.cos(th)
    f_l = (yl - y + p["r"] * s) * p["C"] + (yld - yd + p["r"] * c * thd) * p["D"]
    f_r = (yr - y - p["r"] * s) * p["C"] + (yrd - yd - p["r"] * c * thd) * p["D"]
    ydd = (f_r + f_l - p["F_n"] - p["F_ga"]) / p["m_a"]
    thdd = ((f_r - f_l) * p["r"] + (f_r + f_l - p["F_n"]) * p["a"] * s
            - friction_force * (p["R"] - p["a"] * c)) / p["I_a"]
    return np.array([yd, ydd, thd, thdd])

"""Friction laws between the piezo tip and the slider.

Non-smooth functions and how they are handled (so that fitting keeps useful
derivatives):

- ``sgn(ẋ)`` in ``z_ss``: never evaluated as such. With ``z_ss = sgn(ẋ)·|z_ss|`` the
  elasto-plastic rate ``ż = ẋ·(1 − α·z/z_ss)`` equals ``ẋ − α·|ẋ|·z/|z_ss|`` wherever
  ``α ≠ 0`` (α is non-zero only when ``ẋ`` and ``z`` share a sign). That form is
  continuous in ``ẋ`` (Lipschitz), so no sign function enters the integrator and the
  vector field has no jump for the Runge-Kutta stages to straddle.
- The α switch: the contract's exact piecewise form. Its sine transition is C¹ at
  both ends (slope 0 at ``z_ba`` and at ``|z_ss|``), so the derivative with respect to
  ``z``, ``z_ba`` and ``zba_ratio`` is continuous except at the sign test, where α
  itself is 0 on both sides of ``z = 0``. The branches are ``jnp.where`` selections of
  finite expressions (the division by ``|z_ss| − z_ba`` is guarded for ratio 1), so
  no NaN leaks into gradients.
- Saturation ``|z| ≤ |z_ss|`` after each sub-step: a ``clip``. Its derivative is the
  identity inside and ``±d|z_ss|`` on the bound, which is the exact derivative of the
  discrete map; it carries the sensitivity of the slip phase to ``z_ba``.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .base import AbstractFriction, DriveContext
from .registry import LawParameter, ParameterError, register_friction_law

DEFAULT_ZBA_RATIO = 0.667
"""The paper's ``z_ba/|z_ss|`` [-] (Lu et al. 2015 §IV-B.3): the default of every
elasto-plastic law here (``zba_ratio``, CEIM's ``f_ba``)."""


def _f(x):
    return jnp.asarray(x, dtype=float)


_POSITIVE = {"lower": 0.0, "lower_open": True}
_NON_NEGATIVE = {"lower": 0.0}

ELASTOPLASTIC_PARAMETERS = (
    LawParameter("rho0", "N/m", "contact stiffness", required=True, **_POSITIVE,
                 step="dynamics", mass_scaled=True, stiffness=True, with_normal_force=True),
    LawParameter("rho1", "N·s/m", "contact micro-damping", default=0.0, **_NON_NEGATIVE,
                 step="dynamics", on_request=True, mass_scaled=True, with_normal_force=True),
    LawParameter("rho2", "N·s/m", "viscous friction", default=0.0, **_NON_NEGATIVE,
                 mass_scaled=True, with_normal_force=True),
    LawParameter("z_ba", "m", "break-away displacement, both directions",
                 alias_for=("z_ba_forward", "z_ba_backward"), **_POSITIVE),
    LawParameter("z_ba_forward", "m", "break-away displacement, forward drive (and sine, step)",
                 required=True, **_POSITIVE, step="friction", direction="forward"),
    LawParameter("z_ba_backward", "m", "break-away displacement, backward drive",
                 required=True, **_POSITIVE, step="friction", direction="backward"),
    LawParameter("zba_ratio", "-", "z_ba/|z_ss|", default=DEFAULT_ZBA_RATIO,
                 lower=0.0, lower_open=True, upper=1.0, step="friction", on_request=True),
    LawParameter("stribeck_ratio", "-", "f_max/f_c (Stribeck steady state when > 1)",
                 default=1.0, lower=1.0),
    LawParameter("v_s", "m/s", "Stribeck velocity (needed when stribeck_ratio > 1)",
                 **_POSITIVE),
)
"""The ``"elastoplastic"`` file form, shared by every law of the family: the paper's
law, its Stribeck generalisation (``stribeck_ratio`` > 1 selects it) and the variants
that read z_ba elsewhere (they are written as the paper's law)."""


def transition_alpha(abs_z, z_ba, zss_mag):
    """Lu eq. 8 for same-sign motion: 0 up to ``z_ba``, sine ramp, 1 from ``|z_ss|``.

    ``abs_z``, ``z_ba``, ``zss_mag`` in m. When ``|z_ss| = z_ba`` (ratio 1) the ramp
    collapses into a step at ``z_ba``.

    Written as ``sin²(π·s/2)`` of the clipped ramp coordinate
    ``s = clip((|z| − z_ba)/(|z_ss| − z_ba), 0, 1)``, which equals the contract's
    ``½·sin(π·(|z| − (|z_ss| + z_ba)/2)/(|z_ss| − z_ba)) + ½`` on the ramp and is
    exactly 0 and 1 outside it: one clip instead of a chain of selections, and a
    reciprocal of the width that is loop-invariant (hoisted out of the integrator).
    """
    width = zss_mag - z_ba
    ramp_exists = width > 0
    inv_width = 1.0 / jnp.where(ramp_exists, width, 1.0)
    s = jnp.clip((abs_z - z_ba) * inv_width, 0.0, 1.0)
    smooth = jnp.sin(0.5 * jnp.pi * s) ** 2
    return jnp.where(ramp_exists, smooth, jnp.where(abs_z > z_ba, 1.0, 0.0))


class AbstractElastoPlastic(AbstractFriction):
    """Elasto-plastic friction (Dupont et al. 2002) with a direction-aware ``z_ss``.

    ``Ff = ρ0·z + ρ1·ż + ρ2·ẋ``, ``ż = ẋ·(1 − α(z, ẋ)·z/z_ss(ẋ))`` with
    ``z_ss(ẋ) = sgn(ẋ)·|z_ss(ẋ)|`` (Lu §III-C: the sign switch). Subclasses give the
    magnitude ``|z_ss(ẋ)|`` [m].

    Attributes
    ----------
    rho0: contact stiffness [N/m].
    rho1: micro-damping [N·s/m] (paper: 0).
    rho2: viscous friction coefficient [N·s/m] (paper: neglected).
    z_ba_forward, z_ba_backward: break-away displacement for forward / backward drive
        [m]; recordings without a direction (step, sine) use the forward value.
    zba_ratio: ``z_ba/|z_ss|`` in (0, 1] [-] (paper: :data:`DEFAULT_ZBA_RATIO`).
    """

    parameters = ELASTOPLASTIC_PARAMETERS

    rho0: eqx.AbstractVar[Float[Array, ""]]
    rho1: eqx.AbstractVar[Float[Array, ""]]
    rho2: eqx.AbstractVar[Float[Array, ""]]
    z_ba_forward: eqx.AbstractVar[Float[Array, ""]]
    z_ba_backward: eqx.AbstractVar[Float[Array, ""]]
    zba_ratio: eqx.AbstractVar[Float[Array, ""]]

    @classmethod
    def from_params(cls, values):
        """The ``"elastoplastic"`` file form: the paper's law, or
        :class:`StribeckElastoPlastic` when ``stribeck_ratio`` > 1 (then ``v_s`` is
        needed). Every class of the family reads the same form into those two."""
        rest = {"zba_ratio": values["zba_ratio"], "rho1": values["rho1"],
                "rho2": values["rho2"]}
        args = (values["rho0"], values["z_ba_forward"], values["z_ba_backward"])
        if values["stribeck_ratio"] > 1.0:
            if "v_s" not in values:
                raise ParameterError("stribeck_ratio > 1 needs v_s.",
                                     fix="add the Stribeck velocity v_s [m/s].")
            return StribeckElastoPlastic(*args, stribeck_ratio=values["stribeck_ratio"],
                                         v_s=values["v_s"], **rest)
        return ElastoPlastic(*args, **rest)

    def z_ba(self, drive: DriveContext):
        """Break-away displacement for the drive's direction [m]."""
        return self.z_ba_forward + drive.backward * (self.z_ba_backward - self.z_ba_forward)

    @abc.abstractmethod
    def zss_magnitude(self, xdot, drive: DriveContext):
        """Steady-state elastic strain magnitude ``|z_ss(ẋ)|`` [m]."""

    def z_rate(self, z, xdot, drive):
        zss = self.zss_magnitude(xdot, drive)
        same_sign = xdot * z > 0
        alpha = jnp.where(same_sign, transition_alpha(jnp.abs(z), self.z_ba(drive), zss), 0.0)
        return xdot - alpha * jnp.abs(xdot) * z * (1.0 / zss)

    def force(self, z, zdot, xdot, drive):
        return self.rho0 * z + self.rho1 * zdot + self.rho2 * xdot

    def project(self, z, xdot, drive):
        zss = self.zss_magnitude(xdot, drive)
        return jnp.clip(z, -zss, zss)

    def z_at_rest(self, force, drive):
        return force / self.rho0

    def stiffness(self, drive):
        return self.rho0

    def strain_switches(self, drive):
        # α is 0 up to z_ba and C¹ there (second derivative jumps; a step at ratio 1).
        # |z_ss| is approached, never reached, in continuous time: no event there.
        return (self.z_ba(drive),)

    def velocity_kink(self, z, drive):
        # ∂ż/∂ẋ is 1 on the side where ẋ and z differ in sign (α = 0) and 1 − α·|z|/|z_ss|
        # on the other: the jump is α·|z|/|z_ss|, zero in the elastic range |z| ≤ z_ba.
        zss = self.zss_magnitude(0.0, drive)
        return transition_alpha(jnp.abs(z), self.z_ba(drive), zss) * jnp.abs(z) / zss

    def coulomb_force(self, drive: DriveContext):
        """Kinetic (Coulomb) friction level ``f_c = ρ0·z_ba/zba_ratio`` [N]."""
        return self.rho0 * self.z_ba(drive) / self.zba_ratio


@register_friction_law("elastoplastic")
class ElastoPlastic(AbstractElastoPlastic):
    """The paper's law (Lu eq. 16): constant ``f_ss = f_c``, so ``|z_ss| = z_ba/ratio``."""

    rho0: Float[Array, ""]
    rho1: Float[Array, ""]
    rho2: Float[Array, ""]
    z_ba_forward: Float[Array, ""]
    z_ba_backward: Float[Array, ""]
    zba_ratio: Float[Array, ""]

    def __init__(self, rho0, z_ba_forward, z_ba_backward=None, *, zba_ratio=DEFAULT_ZBA_RATIO,
                 rho1=0.0, rho2=0.0):
        self.rho0 = _f(rho0)
        self.rho1 = _f(rho1)
        self.rho2 = _f(rho2)
        self.z_ba_forward = _f(z_ba_forward)
        self.z_ba_backward = _f(z_ba_forward if z_ba_backward is None else z_ba_backward)
        self.zba_ratio = _f(zba_ratio)

    def zss_magnitude(self, xdot, drive):
        return self.z_ba(drive) / self.zba_ratio


class StribeckElastoPlastic(AbstractElastoPlastic):
    """Dupont's general law with the Stribeck steady state (Lu eq. 14).

    ``f_ss(ẋ) = (f_max − f_c)/(1 + (ẋ/v_s)²) + f_c`` with ``f_c = ρ0·z_ba/ratio`` and
    ``f_max = stribeck_ratio·f_c``; ``|z_ss(ẋ)| = f_ss(ẋ)/ρ0 ≥ z_ba/ratio``.

    Extra attributes: ``stribeck_ratio`` ≥ 1 [-], ``v_s`` Stribeck velocity [m/s].
    """

    rho0: Float[Array, ""]
    rho1: Float[Array, ""]
    rho2: Float[Array, ""]
    z_ba_forward: Float[Array, ""]
    z_ba_backward: Float[Array, ""]
    zba_ratio: Float[Array, ""]
    stribeck_ratio: Float[Array, ""]
    v_s: Float[Array, ""]

    def __init__(self, rho0, z_ba_forward, z_ba_backward=None, *, stribeck_ratio, v_s,
                 zba_ratio=DEFAULT_ZBA_RATIO, rho1=0.0, rho2=0.0):
        self.rho0 = _f(rho0)
        self.rho1 = _f(rho1)
        self.rho2 = _f(rho2)
        self.z_ba_forward = _f(z_ba_forward)
        self.z_ba_backward = _f(z_ba_forward if z_ba_backward is None else z_ba_backward)
        self.zba_ratio = _f(zba_ratio)
        self.stribeck_ratio = _f(stribeck_ratio)
        self.v_s = _f(v_s)

    def zss_magnitude(self, xdot, drive):
        base = self.z_ba(drive) / self.zba_ratio
        return base * (1.0 + (self.stribeck_ratio - 1.0) / (1.0 + (xdot / self.v_s) ** 2))


@register_friction_law("lugre")
class LuGre(AbstractFriction):
    """LuGre friction (Canudas de Wit 1995; Nguyen eq. 8-10).

    ``ż = ẋ − σ0·|ẋ|·z/g(ẋ)``, ``g(ẋ) = F_c + (F_s − F_c)·exp(−(ẋ/v_s)²)``,
    ``Ff = σ0·z + σ1·ż + σ2·ẋ``. Its bristle deflection is self-bounded (no
    saturation) and it has no pure-elastic region, hence no 0-amplitude effect.

    Attributes: sigma0 [N/m], sigma1 [N·s/m], sigma2 [N·s/m], F_c Coulomb level [N],
    F_s static level [N], v_s Stribeck velocity [m/s]. The identification does not fit
    it (no parameter is flagged for its steps); a file names every parameter.
    """

    parameters = (
        LawParameter("sigma0", "N/m", "LuGre bristle stiffness", required=True, **_POSITIVE,
                     mass_scaled=True, stiffness=True),
        LawParameter("sigma1", "N·s/m", "LuGre bristle damping", required=True,
                     **_NON_NEGATIVE, mass_scaled=True),
        LawParameter("sigma2", "N·s/m", "LuGre viscous friction", required=True,
                     **_NON_NEGATIVE, mass_scaled=True),
        LawParameter("F_c", "N", "LuGre Coulomb level", required=True, **_POSITIVE,
                     mass_scaled=True),
        LawParameter("F_s", "N", "LuGre static level (≥ F_c)", required=True, **_POSITIVE,
                     mass_scaled=True),
        LawParameter("v_s", "m/s", "Stribeck velocity", required=True, **_POSITIVE),
    )

    sigma0: Float[Array, ""]
    sigma1: Float[Array, ""]
    sigma2: Float[Array, ""]
    F_c: Float[Array, ""]
    F_s: Float[Array, ""]
    v_s: Float[Array, ""]

    def __init__(self, sigma0, sigma1, sigma2, F_c, F_s, v_s):
        self.sigma0 = _f(sigma0)
        self.sigma1 = _f(sigma1)
        self.sigma2 = _f(sigma2)
        self.F_c = _f(F_c)
        self.F_s = _f(F_s)
        self.v_s = _f(v_s)

    @classmethod
    def from_params(cls, values):
        if values["F_s"] < values["F_c"]:
            raise ParameterError("LuGre needs F_s ≥ F_c.",
                                 fix="the static level is at least the Coulomb level.")
        return cls(**values)

    def _g(self, xdot):
        return self.F_c + (self.F_s - self.F_c) * jnp.exp(-((xdot / self.v_s) ** 2))

    def z_rate(self, z, xdot, drive):
        return xdot - self.sigma0 * jnp.abs(xdot) * z / self._g(xdot)

    def force(self, z, zdot, xdot, drive):
        return self.sigma0 * z + self.sigma1 * zdot + self.sigma2 * xdot

    def project(self, z, xdot, drive):
        return z

    def z_at_rest(self, force, drive):
        return force / self.sigma0

    def stiffness(self, drive):
        return self.sigma0

    def coulomb_force(self, drive):
        return self.F_c

    def strain_switches(self, drive):
        return ()

    def velocity_kink(self, z, drive):
        # ż = ẋ − σ0·|ẋ|·z/g(ẋ): ∂ż/∂ẋ = 1 ∓ σ0·z/g(0) on either side of ẋ = 0.
        return 2.0 * self.sigma0 * jnp.abs(z) / self._g(0.0)


class ConstantZssElastoPlastic(AbstractElastoPlastic):
    """The pre-Lu elasto-plastic law with a constant positive ``z_ss`` (counter-example).

    Lu et al. 2015 §III-C: many earlier uses of Dupont's model keep the steady-state
    strain a positive constant, ``z_ss = +|z_ss|`` whatever the sign of ``ẋ``:

        ż = ẋ·(1 − α(z, ẋ)·z/z_ss),    z_ss = +z_ba/zba_ratio  (constant, > 0)

    with ``α`` from :func:`transition_alpha` where ``sgn(ẋ) = sgn(z)`` (Lu eq. 7-8)
    and 0 elsewhere, and the same saturation ``|z| ≤ |z_ss|`` after each sub-step.
    For ``ẋ > 0`` it is the Lu law. For ``ẋ < 0`` in the mixed regime
    (``z_ba < |z| < |z_ss|``, ``z < 0``) the factor ``C = 1 − α·z/z_ss`` exceeds 1
    (Lu eq. 9), so ``ż = C·ẋ`` outruns ``ẋ`` and the plastic rate
    ``ẇ = ẋ − ż = (1 − C)·ẋ`` has the sign opposite to the motion (Lu eq. 10-12):
    "elastic super-relaxation" in a one-directional motion, which the paper rules
    out. It exists only to reproduce that proof (``tests/test_paper_claims.py``);
    never use it to model an actuator.

    Attributes: as :class:`ElastoPlastic` (rho0 [N/m], rho1, rho2 [N·s/m],
    z_ba_forward, z_ba_backward [m], zba_ratio [-]).
    """

    rho0: Float[Array, ""]
    rho1: Float[Array, ""]
    rho2: Float[Array, ""]
    z_ba_forward: Float[Array, ""]
    z_ba_backward: Float[Array, ""]
    zba_ratio: Float[Array, ""]

    def __init__(self, rho0, z_ba_forward, z_ba_backward=None, *, zba_ratio=DEFAULT_ZBA_RATIO,
                 rho1=0.0, rho2=0.0):
        self.rho0 = _f(rho0)
        self.rho1 = _f(rho1)
        self.rho2 = _f(rho2)
        self.z_ba_forward = _f(z_ba_forward)
        self.z_ba_backward = _f(z_ba_forward if z_ba_backward is None else z_ba_backward)
        self.zba_ratio = _f(zba_ratio)

    def zss_magnitude(self, xdot, drive):
        return self.z_ba(drive) / self.zba_ratio

    def z_rate(self, z, xdot, drive):
        zss = self.zss_magnitude(xdot, drive)  # used as the signed z_ss: always > 0
        same_sign = xdot * z > 0
        alpha = jnp.where(same_sign, transition_alpha(jnp.abs(z), self.z_ba(drive), zss), 0.0)
        return xdot * (1.0 - alpha * z / zss)

"""CEIM: the elasto-plastic law with preload-dependent parameters (Nguyen 2012 eq. 14-19).

Nguyen et al. make the break-away strain and the tangential contact stiffness affine
functions of the normal preload ``F`` [N] and of an equivalent Young's modulus
``E* = o·ln(E) + p`` of the material pair::

    z_ba = (a·E* + b)·F + c·E* + d          (eq. 14)     |z_ss| = z_ba / f_ba   (15)
    σ0   = (a_s·E* + b_s)·F + c_s·E* + d_s   (eq. 19)
    ż    = ẋ − α(z, ẋ)·|ẋ|·σ0·z / (μ·F)      (eq. 17)     Ff = σ0·z + σ1·ż       (18)

The coefficients are empirical and material-specific; the paper prints none. This
class stores the four affine coefficients that result for one material
(``zba_slope = a·E* + b`` [m/N], ``zba_0 = c·E* + d`` [m], ``sigma0_slope`` [N/m per
N], ``sigma0_0`` [N/m]); :meth:`CEIMElastoPlastic.from_material` builds them from
the paper's a..d, a_s..d_s, o, p and E. The Coulomb level is ``μ·F`` (one friction
coefficient for static and kinetic, as the authors recommend), so the plastic
steady state is ``z_p = μ·F/σ0``.

Non-smooth parts, as in :mod:`stickslip_jax.model.friction`: α is the contract's C¹
sine ramp between z_ba and |z_ss| (applied only when z and ẋ share a sign); after
each sub-step |z| is clipped at ``max(|z_ss|, z_p)``: at |z_ss| as docs/model.md asks of
the elasto-plastic family, but never below the plastic steady state, so that the
contact can always carry its Coulomb force μ·F.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .base import AbstractFriction, DriveContext
from .friction import DEFAULT_ZBA_RATIO, transition_alpha
from .registry import LawParameter, ParameterError, register_friction_law


def _f(x):
    return jnp.asarray(x, dtype=float)


_NON_NEGATIVE = {"lower": 0.0}


@register_friction_law("ceim")
class CEIMElastoPlastic(AbstractFriction):
    """Preload-dependent elasto-plastic contact (see the module docstring).

    Attributes
    ----------
    preload: normal force F on the contact [N] (> 0).
    zba_slope: d z_ba / dF = a·E* + b [m/N].
    zba_0: z_ba at zero preload = c·E* + d [m].
    sigma0_slope: d σ0 / dF = a_s·E* + b_s [N/m per N].
    sigma0_0: σ0 at zero preload = c_s·E* + d_s [N/m].
    f_ba: z_ba/|z_ss| in (0, 1] [-] (eq. 15).
    mu: friction coefficient, Coulomb level μ·F [-].
    sigma1: micro-damping [N·s/m] (eq. 18).

    In a parameter file the preload is ``N`` (which also sets the piezo element's
    preload term); the identification does not fit this law.
    """

    parameters = (
        LawParameter("N", "N", "normal preload on the contact", required=True,
                     attribute="preload", lower=0.0, lower_open=True,
                     with_normal_force=True),
        LawParameter("zba_slope", "m/N", "CEIM: d z_ba / d preload = a·E* + b (Nguyen eq. 14)",
                     required=True, **_NON_NEGATIVE),
        LawParameter("zba_0", "m", "CEIM: z_ba at zero preload = c·E* + d", required=True,
                     **_NON_NEGATIVE),
        LawParameter("sigma0_slope", "N/m per N",
                     "CEIM: d sigma0 / d preload = a_s·E* + b_s (eq. 19)", required=True,
                     **_NON_NEGATIVE, mass_scaled=True, stiffness=True),
        LawParameter("sigma0_0", "N/m", "CEIM: sigma0 at zero preload = c_s·E* + d_s",
                     required=True, **_NON_NEGATIVE, mass_scaled=True, stiffness=True),
        LawParameter("mu", "-", "CEIM: friction coefficient, Coulomb level mu·N",
                     required=True, **_NON_NEGATIVE, mass_scaled=True),
        LawParameter("f_ba", "-", "CEIM: z_ba/|z_ss| (eq. 15)",
                     default=DEFAULT_ZBA_RATIO, lower=0.0, lower_open=True, upper=1.0),
        LawParameter("sigma1", "N·s/m", "CEIM: contact micro-damping (eq. 18)", default=0.0,
                     **_NON_NEGATIVE, mass_scaled=True, with_normal_force=True),
    )

    preload: Float[Array, ""]
    zba_slope: Float[Array, ""]
    zba_0: Float[Array, ""]
    sigma0_slope: Float[Array, ""]
    sigma0_0: Float[Array, ""]
    f_ba: Float[Array, ""]
    mu: Float[Array, ""]
    sigma1: Float[Array, ""]

    def __init__(self, preload, *, zba_slope, zba_0, sigma0_slope, sigma0_0,
                 f_ba=DEFAULT_ZBA_RATIO, mu, sigma1=0.0):
        self.preload = _f(preload)
        self.zba_slope = _f(zba_slope)
        self.zba_0 = _f(zba_0)
        self.sigma0_slope = _f(sigma0_slope)
        self.sigma0_0 = _f(sigma0_0)
        self.f_ba = _f(f_ba)
        self.mu = _f(mu)
        self.sigma1 = _f(sigma1)

    @staticmethod
    def from_material(preload, *, a, b, c, d, a_s, b_s, c_s, d_s, o, p, E,
                      f_ba=DEFAULT_ZBA_RATIO, mu, sigma1=0.0) -> CEIMElastoPlastic:
        """From the paper's empirical coefficients: ``E* = o·ln(E) + p`` (eq. 16)."""
        e_star = o * jnp.log(_f(E)) + p
        return CEIMElastoPlastic(preload, zba_slope=a * e_star + b, zba_0=c * e_star + d,
                                 sigma0_slope=a_s * e_star + b_s, sigma0_0=c_s * e_star + d_s,
                                 f_ba=f_ba, mu=mu, sigma1=sigma1)

    @staticmethod
    def matching(rho0, z_ba, *, zba_ratio=DEFAULT_ZBA_RATIO, preload=1.0, zba_share=0.5,
                 sigma0_share=0.5) -> CEIMElastoPlastic:
        """A CEIM contact equal to the elasto-plastic law (ρ0, z_ba, ratio) at ``preload``.

        ``zba_share`` and ``sigma0_share`` are the parts of z_ba and σ0 that grow with
        the preload (the rest is the zero-preload intercept); μ makes the Coulomb level
        μ·F equal ρ0·z_ba/ratio at that preload.
        """
        rho0, z_ba, preload = _f(rho0), _f(z_ba), _f(preload)
        return CEIMElastoPlastic(
            preload, zba_slope=zba_share * z_ba / preload, zba_0=(1 - zba_share) * z_ba,
            sigma0_slope=sigma0_share * rho0 / preload, sigma0_0=(1 - sigma0_share) * rho0,
            f_ba=zba_ratio, mu=rho0 * z_ba / zba_ratio / preload)

    @staticmethod
    def matching_law(law: AbstractFriction, *, preload=1.0, zba_share=0.5,
                     sigma0_share=0.5) -> CEIMElastoPlastic:
        """A CEIM contact equal to another friction law at ``preload`` [N] in what CEIM
        has: its small-motion stiffness, its break-away strain (the first of its strain
        switches) and its Coulomb level, for a forward drive (:meth:`matching`). For the
        elasto-plastic law that is the law itself (to rounding). ``ValueError`` for a
        law without an elastic range (no strain switch: LuGre)."""
        drive = DriveContext.make()
        switches = law.strain_switches(drive)
        if not switches:
            raise ValueError(f"a {type(law).__name__} contact has no break-away strain (no "
                             f"elastic range) for a CEIM contact to match")
        k, z_ba, fc = law.stiffness(drive), switches[0], law.coulomb_force(drive)
        ratio = float(k * z_ba / fc)
        if not 0.0 < ratio <= 1.0:
            raise ValueError(f"the {type(law).__name__} contact's break-away force "
                             f"stiffness·z_ba is {ratio:g} of its Coulomb level; a CEIM "
                             f"contact needs (0, 1]")
        return CEIMElastoPlastic.matching(k, z_ba, zba_ratio=ratio, preload=preload,
                                          zba_share=zba_share, sigma0_share=sigma0_share)

    @classmethod
    def from_params(cls, values):
        preload = values["N"]
        if values["mu"] <= 0 or values["zba_slope"] * preload + values["zba_0"] <= 0 or \
                values["sigma0_slope"] * preload + values["sigma0_0"] <= 0:
            raise ParameterError("CEIM needs mu > 0 and a positive z_ba and sigma0 at the "
                                 "preload N.",
                                 fix="check zba_slope/zba_0, sigma0_slope/sigma0_0 and N.")
        return cls(preload, **{k: v for k, v in values.items() if k != "N"})

    def with_preload(self, preload) -> CEIMElastoPlastic:
        """The same material under another normal force [N]."""
        return eqx.tree_at(lambda f: f.preload, self, _f(preload))

    # ---- eq. 14-19 ----------------------------------------------------------------
    def z_ba(self, drive: DriveContext | None = None):
        """Break-away strain at this preload [m] (eq. 14)."""
        return self.zba_slope * self.preload + self.zba_0

    def zss_magnitude(self, xdot=None, drive: DriveContext | None = None):
        """|z_ss| = z_ba/f_ba [m] (eq. 15)."""
        return self.z_ba(drive) / self.f_ba

    def sigma0(self):
        """Tangential contact stiffness at this preload [N/m] (eq. 19)."""
        return self.sigma0_slope * self.preload + self.sigma0_0

    def coulomb_force(self, drive: DriveContext | None = None):
        """Coulomb level μ·F [N]."""
        return self.mu * self.preload

    def plastic_strain(self):
        """Plastic steady state z_p = μ·F/σ0 [m]."""
        return self.coulomb_force() / self.sigma0()

    def z_rate(self, z, xdot, drive):
        same_sign = xdot * z > 0
        alpha = jnp.where(same_sign, transition_alpha(jnp.abs(z), self.z_ba(drive),
                                                      self.zss_magnitude(xdot, drive)), 0.0)
        return xdot - alpha * jnp.abs(xdot) * z / self.plastic_strain()

    def force(self, z, zdot, xdot, drive):
        return self.sigma0() * z + self.sigma1 * zdot

    def project(self, z, xdot, drive):
        bound = jnp.maximum(self.zss_magnitude(xdot, drive), self.plastic_strain())
        return jnp.clip(z, -bound, bound)

    def z_at_rest(self, force, drive):
        return force / self.sigma0()

    def stiffness(self, drive):
        return self.sigma0()

    def strain_switches(self, drive):
        return (self.z_ba(drive),)

    def velocity_kink(self, z, drive):
        # As the elasto-plastic law, with the plastic strain μ·F/σ0 in the denominator.
        alpha = transition_alpha(jnp.abs(z), self.z_ba(drive), self.zss_magnitude(0.0, drive))
        return alpha * jnp.abs(z) / self.plastic_strain()

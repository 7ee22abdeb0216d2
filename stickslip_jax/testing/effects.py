"""Effect components that only the test-data generators use (not part of the model).

Each is one final class implementing an abstract interface of
:mod:`stickslip_jax.model.base`, in the slot where the effect acts, written in a
functional form that the diagnosis catalogue does *not* fit (the random-set generator,
:mod:`.random_sets`, hides them in recordings to check that the diagnosis generalises).
None is registered anywhere: parameter files and the identification never see them.

- :class:`VariantElastoPlastic` (friction): the elasto-plastic law with an exponential
  or Gaussian Stribeck curve (the catalogue's is Lorentzian), a saturating contact
  damping or viscous force, or a viscous force on the slip rate only;
- :class:`CascadeInput` (input stage): two stages in series (a two-pole amplifier
  behind a first-order filter: a third-order drive);
- :class:`SaturatingRateStroke` (extension): a rate-dependent stroke lag that
  saturates (tanh) in the voltage lag;
- :class:`ReactionMode` (extension): a base resonance excited by the piezo stack's
  reaction force (the contact force plus the stack's inertia), not by the contact
  force alone;
- :class:`CoulombDrag` (extension): a velocity-sign force on the slider (a cable, a
  second bearing), in no catalogue entry;
- :class:`SensorLowPass` (output map): a first-order low-pass of the sensor (the
  catalogue's sensor entry is a pure delay).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..model.base import (
    AbstractExtension,
    AbstractInputStage,
    AbstractOutputMap,
    ExtensionTerms,
)
from ..model.friction import AbstractElastoPlastic

STRIBECK_SHAPES = ("lorentzian", "exponential", "gaussian")
DAMPING_SHAPES = ("linear", "saturating")
VISCOUS_SHAPES = ("linear", "saturating", "slip_only")


def _f(x):
    return jnp.asarray(x, dtype=float)


class VariantElastoPlastic(AbstractElastoPlastic):
    """Elasto-plastic friction with other velocity laws than the catalogue's.

    ``|z_ss(ẋ)| = (z_ba/ratio)·(1 + (stribeck_ratio − 1)·s(ẋ/v_s))`` with
    ``s(v) = 1/(1 + v²)`` (``lorentzian``, the catalogue's), ``exp(−|v|)``
    (``exponential``) or ``exp(−v²)`` (``gaussian``);
    ``Ff = ρ0·z + D(ż) + V(ẋ, ż)`` with the contact damping ``D`` linear, ``ρ1·ż``, or
    ``saturating``, ``ρ1·v_damp·tanh(ż/v_damp)`` (the damping force cannot exceed
    ``ρ1·v_damp``), and the viscous force ``V`` linear, ``ρ2·ẋ``, ``saturating``,
    ``ρ2·v_visc·tanh(ẋ/v_visc)``, or ``slip_only``, ``ρ2·(ẋ − ż)`` (on the plastic
    slip rate: no viscous force while the contact sticks).

    Attributes: as :class:`~stickslip_jax.model.friction.ElastoPlastic`, plus
    ``stribeck_ratio`` ≥ 1 [-], ``v_s`` [m/s], ``v_damp`` [m/s], ``v_visc`` [m/s], and
    the static shapes ``stribeck_shape``, ``damping_shape``, ``viscous_shape``.
    """

    rho0: Float[Array, ""]
    rho1: Float[Array, ""]
    rho2: Float[Array, ""]
    z_ba_forward: Float[Array, ""]
    z_ba_backward: Float[Array, ""]
    zba_ratio: Float[Array, ""]
    stribeck_ratio: Float[Array, ""]
    v_s: Float[Array, ""]
    v_damp: Float[Array, ""]
    v_visc: Float[Array, ""]
    stribeck_shape: str = eqx.field(static=True)
    damping_shape: str = eqx.field(static=True)
    viscous_shape: str = eqx.field(static=True)

    def __init__(self, rho0, z_ba_forward, z_ba_backward, *, zba_ratio, rho1=0.0, rho2=0.0,
                 stribeck_ratio=1.0, v_s=1e-3, v_damp=1e-3, v_visc=1e-3,
                 stribeck_shape="lorentzian", damping_shape="linear", viscous_shape="linear"):
        if (stribeck_shape not in STRIBECK_SHAPES or damping_shape not in DAMPING_SHAPES
                or viscous_shape not in VISCOUS_SHAPES):
            raise ValueError(f"unknown shape: {stribeck_shape!r}, {damping_shape!r}, "
                             f"{viscous_shape!r}")
        self.rho0, self.rho1, self.rho2 = _f(rho0), _f(rho1), _f(rho2)
        self.z_ba_forward, self.z_ba_backward = _f(z_ba_forward), _f(z_ba_backward)
        self.zba_ratio = _f(zba_ratio)
        self.stribeck_ratio, self.v_s = _f(stribeck_ratio), _f(v_s)
        self.v_damp, self.v_visc = _f(v_damp), _f(v_visc)
        self.stribeck_shape = stribeck_shape
        self.damping_shape = damping_shape
        self.viscous_shape = viscous_shape

    @staticmethod
    def like(friction, **changes) -> VariantElastoPlastic:
        """This law with the elasto-plastic values of ``friction`` and ``changes``."""
        kw = dict(zba_ratio=friction.zba_ratio, rho1=friction.rho1, rho2=friction.rho2)
        kw.update(changes)
        return VariantElastoPlastic(friction.rho0, friction.z_ba_forward,
                                    friction.z_ba_backward, **kw)

    def zss_magnitude(self, xdot, drive):
        v = xdot / self.v_s
        if self.stribeck_shape == "lorentzian":
            s = 1.0 / (1.0 + v**2)
        elif self.stribeck_shape == "exponential":
            s = jnp.exp(-jnp.abs(v))
        else:
            s = jnp.exp(-(v**2))
        return self.z_ba(drive) / self.zba_ratio * (1.0 + (self.stribeck_ratio - 1.0) * s)

    def force(self, z, zdot, xdot, drive):
        if self.damping_shape == "linear":
            damping = self.rho1 * zdot
        else:
            damping = self.rho1 * self.v_damp * jnp.tanh(zdot / self.v_damp)
        if self.viscous_shape == "linear":
            viscous = self.rho2 * xdot
        elif self.viscous_shape == "saturating":
            viscous = self.rho2 * self.v_visc * jnp.tanh(xdot / self.v_visc)
        else:
            viscous = self.rho2 * (xdot - zdot)
        return self.rho0 * z + damping + viscous


class CascadeInput(AbstractInputStage):
    """Two input stages in series: ``second`` is driven by the voltage ``first`` puts
    out (e.g. a two-pole amplifier behind a first-order filter: a third-order drive).

    Attributes: ``first``, ``second`` (input stages).
    """

    first: AbstractInputStage
    second: AbstractInputStage

    @property
    def n_states(self) -> int:
        return self.first.n_states + self.second.n_states

    def _split(self, state):
        n = self.first.n_states
        return state[:n], state[n:]

    def initial_state(self, u0):
        s1 = jnp.atleast_1d(self.first.initial_state(u0))
        s2 = jnp.atleast_1d(self.second.initial_state(self.first.voltage(s1, u0)))
        return jnp.concatenate([s1, s2])

    def rate(self, state, u_command):
        s1, s2 = self._split(state)
        v1 = self.first.voltage(s1, u_command)
        return jnp.concatenate([jnp.atleast_1d(self.first.rate(s1, u_command)),
                                jnp.atleast_1d(self.second.rate(s2, v1))])

    def voltage(self, state, u_command):
        s1, s2 = self._split(state)
        return self.second.voltage(s2, self.first.voltage(s1, u_command))


class SaturatingRateStroke(AbstractExtension):
    """Rate-dependent hysteresis that saturates: the stroke lags by
    ``gain·u_sat·tanh((u − s)/u_sat)`` where ``s`` follows the voltage with time constant
    ``τ``. For slow drives (``|u − s| = τ·|u̇| ≪ u_sat``) the catalogue's first-order
    lag ``gain·(u − s)``; for fast ones the lag stops growing with the rate, at
    ``gain·u_sat``.

    Attributes: ``gain`` [m/V], ``tau`` [s], ``u_sat`` [V].
    """

    gain: Float[Array, ""]
    tau: Float[Array, ""]
    u_sat: Float[Array, ""]

    def __init__(self, gain, tau, u_sat):
        self.gain, self.tau, self.u_sat = _f(gain), _f(tau), _f(u_sat)

    @property
    def n_states(self) -> int:
        return 1

    def initial_state(self, u0):
        return jnp.atleast_1d(_f(u0))

    def rate(self, state, core, drive):
        return (core.u - state) / self.tau

    def terms(self, state, core, drive):
        lag = self.u_sat * jnp.tanh((core.u - state[0]) / self.u_sat)
        return ExtensionTerms(stroke=-self.gain * lag)


class ReactionMode(AbstractExtension):
    """A base resonance excited by the force the piezo stack puts on its base,
    ``F_b = Kp·(Γ − x1) − Dp·ẋ1`` (= the contact force plus the stack's inertia
    ``Mp·ẍ1``): ``ẍ_b = ω²(compliance·F_b − x_b) − 2ζω·ẋ_b``; the sensor reads
    ``q + x_b``. The catalogue's mode is excited by the contact force alone; this one
    also rings at every drive edge, where the stack accelerates.

    Attributes: ``frequency`` [Hz], ``damping`` ζ [-], ``compliance`` [m/N] (signed),
    ``kp`` [N/m] and ``dp`` [N·s/m] (the stack's, copied from the actuator).
    """

    frequency: Float[Array, ""]
    damping: Float[Array, ""]
    compliance: Float[Array, ""]
    kp: Float[Array, ""]
    dp: Float[Array, ""]

    def __init__(self, frequency, damping, compliance, kp, dp):
        self.frequency, self.damping, self.compliance = _f(frequency), _f(damping), \
            _f(compliance)
        self.kp, self.dp = _f(kp), _f(dp)

    @property
    def n_states(self) -> int:
        return 2

    def initial_state(self, u0):
        # At rest F_b = −Kact2·N (0 here, as in the generator's truths).
        return jnp.zeros(2) + 0.0 * _f(u0)

    def rate(self, state, core, drive):
        w = 2 * jnp.pi * self.frequency
        f_base = self.kp * (core.stroke - core.x1) - self.dp * core.v1
        acc = w**2 * (self.compliance * f_base - state[0]) - 2 * self.damping * w * state[1]
        return jnp.stack([state[1], acc])

    def terms(self, state, core, drive):
        return ExtensionTerms(output=state[0])


class CoulombDrag(AbstractExtension):
    """A drag on the slider of constant magnitude against its velocity,
    ``F = −amplitude·tanh(v2/v_smooth)`` (a cable, a second bearing). No catalogue
    entry has it: the load entry is one constant force for every recording.

    Attributes: ``amplitude`` [N], ``v_smooth`` [m/s] (the tanh's smoothing).
    """

    amplitude: Float[Array, ""]
    v_smooth: Float[Array, ""]

    def __init__(self, amplitude, v_smooth=1e-4):
        self.amplitude, self.v_smooth = _f(amplitude), _f(v_smooth)

    @property
    def n_states(self) -> int:
        return 0

    def initial_state(self, u0):
        return jnp.zeros((0,)) + 0.0 * _f(u0)

    def rate(self, state, core, drive):
        return jnp.zeros((0,))

    def terms(self, state, core, drive):
        return ExtensionTerms(force_slider=-self.amplitude * jnp.tanh(core.v2 / self.v_smooth))


class SensorLowPass(AbstractOutputMap):
    """A sensor with a first-order low-pass, ``τ·ẏ = q − y`` (``y = q`` at the first
    sample), ``q`` taken linear between samples: exact on that interpolation. On a
    ramp it lags by ``τ`` like a delay of ``τ``; at an edge it smooths, where a delay
    shifts. Attribute: ``tau`` [s]."""

    tau: Float[Array, ""]

    def __init__(self, tau):
        self.tau = _f(tau)

    def __call__(self, t, q):
        h = t[1] - t[0]
        a = jnp.exp(-h / self.tau)
        b = self.tau / h * (1.0 - a)  # exact first-order-hold weights

        def step(y, qq):
            q0, q1 = qq
            y1 = a * y + (1.0 - b) * q1 + (b - a) * q0
            return y1, y1

        _, ys = jax.lax.scan(step, q[0], (q[:-1], q[1:]))
        return jnp.concatenate([q[:1], ys])

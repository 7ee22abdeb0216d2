"""Extra physics for the composition's slots: input stages, extensions, output maps.

Each class is one effect that the paper's model leaves out, in the slot where it
acts (see :class:`~stickslip_jax.model.actuator.Actuator`). They are the model side
of the diagnosis catalogue (:mod:`stickslip_jax.diagnose.catalogue`) and of the
concealed-effect generator (:mod:`stickslip_jax.testing.concealed`); every one
reduces exactly to the baseline model at its "zero" setting, so that its first-order
signature is a derivative at zero.

Input stages (voltage reaching the piezo):
    :class:`LowPassInput` (first order), :class:`SecondOrderInput` (two poles),
    :class:`SlewLimitedInput` (slew-rate limit), :class:`ClippedSlewInput` (hard limit),
    :class:`ShapedSlewInput` (a slew limit with a fitted corner),
    :class:`ParallelInputs` (stages side by side).
Extensions (own states and additive terms):
    :class:`Creep` (first-order creep of the stroke), :class:`RateDependentStroke`
    (stroke lag proportional to the voltage rate), :class:`RateLagForm` (that lag,
    linear or saturating in the voltage lag), :class:`CreepSpectrum` (creep as a
    Prony series on a fixed grid of time constants), :class:`StructuralMode` (a mount
    resonance seen by the sensor), :class:`SaturatingViscosity` (friction against the
    sliding velocity on a grid of saturation speeds),
    :class:`PositionRipple` (a force periodic in slider position, no catalogue entry:
    used to test the honest "unexplained"),
    :class:`LearnedForce` (the data-driven correction: sparse regression over a
    library of state features).
Output maps (what the sensor makes of q):
    :class:`SensorOutput` (delay, linear drift and settling terms, a periodic error
    of the fringe and its harmonics), :class:`ExponentialDrift`,
    :class:`PeriodicSensorError` (one sine of the fringe: the test generators' form),
    :class:`ChainedOutput`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .base import (
    AbstractExtension,
    AbstractInputStage,
    AbstractOutputMap,
    CoreState,
    DriveContext,
    ExtensionTerms,
)
from .slew_exact import advance_slew_limited


def _f(x):
    return jnp.asarray(x, dtype=float)


# ---- input stages -------------------------------------------------------------------
class LowPassInput(AbstractInputStage):
    """Drive amplifier with a first-order low-pass: ``τ·ṡ = u − s``.

    The piezo sees ``u + mix·(s − u)``: ``mix = 1`` is the plain low-pass, ``mix = 0``
    the pass-through (the zero setting whose derivative is the signature).

    Attributes: ``tau`` time constant [s] (bandwidth 1/(2π·τ) Hz), ``mix`` [-].
    """

    tau: Float[Array, ""]
    mix: Float[Array, ""]

    def __init__(self, tau, mix=1.0):
        self.tau = _f(tau)
        self.mix = _f(mix)

    @property
    def n_states(self) -> int:
        return 1

    def initial_state(self, u0):
        return jnp.atleast_1d(_f(u0))

    def rate(self, state, u_command):
        return (u_command - state) / self.tau

    def voltage(self, state, u_command):
        return u_command + self.mix * (state[0] - u_command)

    def advance(self, state, u_start, u_end, h):
        # Under u = u_start + r·t the solution is s = u − r·τ + (s0 − u_start + r·τ)·e^(−t/τ).
        lag = (u_end - u_start) / h * self.tau
        return u_end - lag + (state - u_start + lag) * jnp.exp(-h / self.tau)


class SecondOrderInput(AbstractInputStage):
    """Drive amplifier with a two-pole low-pass: ``s̈ = ω²(u − s) − 2ζω·ṡ``.

    Under-damped (ζ < 0.707) it overshoots the command's fast edges, as an amplifier
    driving a capacitive load through a cable often does.

    Attributes: ``frequency`` corner [Hz], ``damping`` ζ [-] (0.707: Butterworth).
    """

    frequency: Float[Array, ""]
    damping: Float[Array, ""]

    def __init__(self, frequency, damping=0.707):
        self.frequency = _f(frequency)
        self.damping = _f(damping)

    @property
    def n_states(self) -> int:
        return 2

    def initial_state(self, u0):
        return jnp.stack([_f(u0), jnp.zeros_like(_f(u0))])

    def rate(self, state, u_command):
        w = 2 * jnp.pi * self.frequency
        acc = w**2 * (u_command - state[0]) - 2 * self.damping * w * state[1]
        return jnp.stack([state[1], acc])

    def voltage(self, state, u_command):
        return state[0]


class SlewLimitedInput(AbstractInputStage):
    """Drive amplifier with a slew-rate limit: ``ṡ = S·tanh((u − s)/(S·τ))``.

    Small differences follow the command with time constant ``τ``; large ones at the
    slew rate ``S`` at most (the tanh is the smooth saturation, so the stage stays
    differentiable). The piezo sees ``u + mix·(s − u)``: ``mix = 1`` the amplifier,
    ``mix = 0`` the pass-through (the zero setting whose derivative is the signature).

    Attributes: ``slew`` S [V/s], ``tau`` [s], ``mix`` [-].
    """

    slew: Float[Array, ""]
    tau: Float[Array, ""]
    mix: Float[Array, ""]

    def __init__(self, slew, tau, mix=1.0):
        self.slew = _f(slew)
        self.tau = _f(tau)
        self.mix = _f(mix)

    @property
    def n_states(self) -> int:
        return 1

    def initial_state(self, u0):
        return jnp.atleast_1d(_f(u0))

    def rate(self, state, u_command):
        return self.slew * jnp.tanh((u_command - state) / (self.slew * self.tau))

    def voltage(self, state, u_command):
        return u_command + self.mix * (state[0] - u_command)

    def advance(self, state, u_start, u_end, h):
        # Exact under a linear command (slew_exact): a sub-µs τ, where a fit may take
        # it, costs no more than a slow one.
        return advance_slew_limited(state, u_start, u_end, h, self.slew, self.tau)


class ClippedSlewInput(SlewLimitedInput):
    """Slew-limited amplifier with a hard limit: ``ṡ = clip((u − s)/τ, −S, S)``.

    The linear small-signal response up to the slew rate, then exactly ``S``: the
    corner is not smooth (its derivative in ``S`` jumps), so this form generates data
    (a current-limited amplifier) rather than being fitted; the catalogue fits the
    tanh form of :class:`SlewLimitedInput`. Attributes as there.
    """

    def rate(self, state, u_command):
        return jnp.clip((u_command - state) / self.tau, -self.slew, self.slew)

    # Not the tanh form's exact step: RK4 steps of the clipped rate (it makes data).
    advance = AbstractInputStage.advance


def shaped_saturation(x, sharpness):
    """``sign(x)·tanh(|x|^p)^(1/p)`` for ``p = sharpness`` [-]: slope 1 at 0 and
    saturation at ±1 for every ``p > 0``; ``p = 1`` is ``tanh x``, ``p → ∞`` the hard
    clip ``clip(x, −1, 1)``, ``p < 1`` softer corners than tanh.

    Written as ``x·exp(g(L)/p)`` with ``L = p·ln|x|`` and ``g(L) = ln tanh(e^L) − L``
    (``ln(tanh y / y)`` at ``y = |x|^p``), each branch where it neither overflows nor
    cancels: ``g ≈ −e^(2L)/3`` far below the corner, ``g = −L`` (``tanh y = 1`` to
    rounding) far above it. ``x = 0`` takes the lower branch with its derivatives, so
    the slope at rest is 1 and the derivative in ``p`` there is 0 (not ``0·(−∞)``).
    """
    ax = jnp.abs(x)
    positive = ax > 0
    log_ax = jnp.log(jnp.where(positive, ax, 1.0))
    big_l = jnp.where(positive, sharpness * log_ax, -800.0)
    low, high = -20.0, 4.0
    below = jnp.minimum(big_l, low)
    middle = jnp.clip(big_l, low, high)
    g = jnp.where(big_l < low, -jnp.exp(2 * below) / 3,
                  jnp.where(big_l > high, -big_l,
                            jnp.log(jnp.tanh(jnp.exp(middle))) - middle))
    return x * jnp.exp(g / sharpness)


class ShapedSlewInput(SlewLimitedInput):
    """Drive amplifier with a slew-rate limit whose corner the data decide:
    ``ṡ = S·σ_p((u − s)/(S·τ))`` with :func:`shaped_saturation` ``σ_p``.

    The slew-limit class: small differences follow the command with time constant
    ``τ`` for every ``p``, large ones at ``S`` at most; ``p = 1`` is
    :class:`SlewLimitedInput`'s tanh, a large ``p`` a current-limited amplifier's hard
    clip (:class:`ClippedSlewInput`), so a refit can start at the tanh form's optimum
    and move the corner continuously. No closed-form step: the drive path takes RK4
    steps of its rate (:mod:`stickslip_jax.drive_path`).

    Attributes: ``slew`` S [V/s], ``tau`` [s], ``sharpness`` p [-], ``mix`` [-].
    """

    sharpness: Float[Array, ""]

    def __init__(self, slew, tau, sharpness=1.0, mix=1.0):
        super().__init__(slew, tau, mix)
        self.sharpness = _f(sharpness)

    def rate(self, state, u_command):
        x = (u_command - state) / (self.slew * self.tau)
        return self.slew * shaped_saturation(x, self.sharpness)

    advance = AbstractInputStage.advance


class ParallelInputs(AbstractInputStage):
    """Several input stages side by side: the piezo sees the command plus the sum of
    each stage's departure from it, ``u + Σᵢ (vᵢ − u)``. With every stage at ``mix = 0``
    it is the pass-through; the diagnosis puts its drive probes (a low-pass and a slew
    limit) in the one input slot this way. Attribute: ``stages`` (a tuple)."""

    stages: tuple

    @property
    def n_states(self) -> int:
        return sum(st.n_states for st in self.stages)

    def _split(self, state):
        out, start = [], 0
        for st in self.stages:
            out.append(state[start:start + st.n_states])
            start += st.n_states
        return out

    def initial_state(self, u0):
        return jnp.concatenate([jnp.atleast_1d(st.initial_state(u0)) for st in self.stages])

    def rate(self, state, u_command):
        return jnp.concatenate([jnp.atleast_1d(st.rate(s, u_command))
                                for st, s in zip(self.stages, self._split(state), strict=True)])

    def voltage(self, state, u_command):
        return u_command + sum(st.voltage(s, u_command) - u_command
                               for st, s in zip(self.stages, self._split(state), strict=True))

    @property
    def advances_in_closed_form(self) -> bool:
        return all(st.n_states == 0 or st.advances_in_closed_form for st in self.stages)

    def advance(self, state, u_start, u_end, h):
        # Each stage sees the command only, so each advances on its own.
        if not self.advances_in_closed_form:
            return None
        return jnp.concatenate([jnp.atleast_1d(st.advance(s, u_start, u_end, h))
                                for st, s in zip(self.stages, self._split(state), strict=True)
                                if st.n_states > 0])


# ---- extensions ---------------------------------------------------------------------
class _FirstOrder(AbstractExtension):
    """A first-order state per element of ``gain`` and ``tau`` (scalars, or vectors of
    one length: a bank whose strokes add, one extension for several time constants,
    which is what the score test installs, :func:`~stickslip_jax.diagnose.scores.
    install_probes`; a program's size grows with its extensions, not with a bank's
    length)."""

    gain: Float[Array, "*k"]
    tau: Float[Array, "*k"]

    def __init__(self, gain, tau):
        self.gain, self.tau = _f(gain), _f(tau)
        if self.gain.ndim > 1 or self.gain.shape != self.tau.shape:
            raise ValueError(f"gain and tau must be scalars or vectors of one length, "
                             f"got shapes {self.gain.shape} and {self.tau.shape}")

    @classmethod
    def bank(cls, members):
        """One extension of the class holding ``members`` (scalar ones) side by side."""
        return cls(jnp.stack([m.gain for m in members]), jnp.stack([m.tau for m in members]))

    @property
    def n_states(self) -> int:
        return max(1, self.gain.size)


class Creep(_FirstOrder):
    """First-order creep of the piezo stroke: ``τ·ċ = gain·u − c``, stroke += ``c``.

    After a voltage change the stroke keeps moving by ``gain·Δu`` with time constant
    ``τ``. At rest ``c = gain·u``. Attributes: ``gain`` [m/V], ``tau`` [s] (vectors: a
    bank, :class:`_FirstOrder`).
    """

    def initial_state(self, u0):
        return jnp.atleast_1d(self.gain * _f(u0))

    def rate(self, state, core: CoreState, drive: DriveContext):
        return (self.gain * core.u - state) / self.tau

    def terms(self, state, core, drive):
        return ExtensionTerms(stroke=jnp.sum(state))


class CreepSpectrum(AbstractExtension):
    """Creep as a Prony series: first-order creep terms ``τ_i·ċ_i = g_i·u − c_i`` on a
    fixed grid of time constants, stroke += ``Σ c_i``; with non-negative weights
    ``g_i`` it is any creep whose step response rises monotonically (a logarithmic
    or fractional law, several modes), the weights being its relaxation spectrum.

    The weights are a tuple of scalars, so that a fit can free each one
    (``eqx.tree_at`` addresses tuple members, not a vector's elements); the time
    constants are the fixed grid. At rest ``c_i = g_i·u``.

    Attributes: ``gains`` g_i [m/V], ``taus`` τ_i [s].
    """

    gains: tuple
    taus: Float[Array, " k"]

    def __init__(self, gains, taus):
        self.taus = _f(taus)
        self.gains = tuple(_f(g) for g in gains)
        if self.taus.ndim != 1 or len(self.gains) != self.taus.size:
            raise ValueError(f"CreepSpectrum needs one gain per time constant, got "
                             f"{len(self.gains)} gains and taus of shape {self.taus.shape}")

    @property
    def n_states(self) -> int:
        return len(self.gains)

    def _weights(self):
        return jnp.stack(self.gains)

    def initial_state(self, u0):
        return self._weights() * _f(u0)

    def rate(self, state, core: CoreState, drive: DriveContext):
        return (self._weights() * core.u - state) / self.taus

    def terms(self, state, core, drive):
        return ExtensionTerms(stroke=jnp.sum(state))


class RateDependentStroke(_FirstOrder):
    """Rate-dependent hysteresis, first order: the stroke lags by ``gain·(u − s)``
    where ``s`` follows the voltage with time constant ``τ``, i.e. by
    ``gain·τ·u̇`` for slow changes, saturating for fast ones (the Hammerstein form of
    a rate-dependent Prandtl-Ishlinskii loop: the loop widens with the drive rate).

    Attributes: ``gain`` [m/V] (> 0 widens the loop), ``tau`` [s] (vectors: a bank,
    :class:`_FirstOrder`).
    """

    def initial_state(self, u0):
        return jnp.broadcast_to(_f(u0), (self.n_states,))

    def rate(self, state, core, drive):
        return (core.u - state) / self.tau

    def terms(self, state, core, drive):
        return ExtensionTerms(stroke=-jnp.sum(self.gain * (core.u - state)))


class RateLagForm(AbstractExtension):
    """Rate-dependent hysteresis as a class: the voltage lag ``d = u − s`` of a first-order
    follower ``τ·ṡ = u − s`` shapes the stroke's lag as ``gain·d + Σ g_k·V_k·tanh(d/V_k)``,
    a linear term beside saturating ones on a fixed grid of voltages: the first-order
    lag of :class:`RateDependentStroke` (the linear term alone), a lag that stops
    growing with the rate beyond some volts of lag (one saturating term), or a curve
    between them. One state, ``s``; at rest ``s = u``.

    The saturating gains are a tuple of scalars, so that a fit can free each one; the
    voltages are the fixed grid.

    Attributes: ``gain`` [m/V], ``tau`` [s], ``sat_gains`` g_k [m/V], ``sat_volts`` V_k
    [V].
    """

    gain: Float[Array, ""]
    tau: Float[Array, ""]
    sat_gains: tuple
    sat_volts: Float[Array, " k"]

    def __init__(self, gain, tau, sat_gains=(), sat_volts=()):
        self.gain, self.tau = _f(gain), _f(tau)
        self.sat_gains = tuple(_f(g) for g in sat_gains)
        self.sat_volts = jnp.asarray(sat_volts, dtype=float).reshape(-1)
        if len(self.sat_gains) != self.sat_volts.size:
            raise ValueError(f"RateLagForm needs one saturating gain per voltage, got "
                             f"{len(self.sat_gains)} and {self.sat_volts.size}")

    @property
    def n_states(self) -> int:
        return 1

    def initial_state(self, u0):
        return jnp.atleast_1d(_f(u0))

    def rate(self, state, core, drive):
        return (core.u - state) / self.tau

    def lag(self, d):
        """The stroke's lag [m] at voltage lags ``d`` [V]."""
        out = self.gain * d
        for k, g in enumerate(self.sat_gains):
            v = self.sat_volts[k]
            out = out + g * v * jnp.tanh(d / v)
        return out

    def terms(self, state, core, drive):
        return ExtensionTerms(stroke=-self.lag(core.u - state[0]))


class StructuralMode(AbstractExtension):
    """A resonance of the mount, guide or base that the sensor sees.

    The mount moves by ``x_b`` with ``ẍ_b = ω²(compliance·Ff + stack_compliance·F_s −
    x_b) − 2ζω·ẋ_b``: excited by the contact force Ff [N] (at the slider's contact)
    and by the force F_s [N] the stack puts on its base (:meth:`~stickslip_jax.model.
    piezo.PiezoElement.push`: the contact force and the reaction of the stack's
    accelerating mass, which rings the base at every drive edge); statically
    ``x_b = compliance·Ff + stack_compliance·F_s``; the sensor reads ``q + x_b``.

    Attributes: ``frequency`` [Hz], ``damping`` ζ [-], ``compliance`` and
    ``stack_compliance`` [m/N] (signed: the sensor may see the mount move either way;
    the second 0 by default).
    """

    frequency: Float[Array, ""]
    damping: Float[Array, ""]
    compliance: Float[Array, ""]
    stack_compliance: Float[Array, ""]

    def __init__(self, frequency, damping, compliance, stack_compliance=0.0):
        self.frequency = _f(frequency)
        self.damping = _f(damping)
        self.compliance = _f(compliance)
        self.stack_compliance = _f(stack_compliance)

    @property
    def n_states(self) -> int:
        return 2

    def initial_state(self, u0):
        return jnp.zeros(2) + 0.0 * _f(u0)

    def rate(self, state, core, drive):
        w = 2 * jnp.pi * self.frequency
        load = self.compliance * core.ff + self.stack_compliance * core.push
        acc = w**2 * (load - state[0]) - 2 * self.damping * w * state[1]
        return jnp.stack([state[1], acc])

    def terms(self, state, core, drive):
        return ExtensionTerms(output=state[0])


class _ForceOnly(AbstractExtension):
    """An extension without states of its own (only additive terms)."""

    @property
    def n_states(self) -> int:
        return 0

    def initial_state(self, u0):
        return jnp.zeros((0,)) + 0.0 * _f(u0)

    def rate(self, state, core, drive):
        return jnp.zeros((0,))


class PositionRipple(_ForceOnly):
    """A force on the slider periodic in its position: ``F = amplitude·sin(2π·x2/λ)``
    (a waviness of the guide, cogging). In no catalogue; used to test that the
    diagnosis says "unexplained" rather than a wrong name.

    Attributes: ``amplitude`` [N], ``wavelength`` λ [m].
    """

    amplitude: Float[Array, ""]
    wavelength: Float[Array, ""]

    def __init__(self, amplitude, wavelength):
        self.amplitude = _f(amplitude)
        self.wavelength = _f(wavelength)

    def terms(self, state, core, drive):
        return ExtensionTerms(force_slider=self.amplitude
                              * jnp.sin(2 * jnp.pi * core.x2 / self.wavelength))


class SaturatingViscosity(_ForceOnly):
    """Friction against the sliding velocity that saturates, on a fixed grid of speeds:
    ``F = Σ_k c_k·v_k·tanh(ẋ/v_k)`` [N] added to the contact's friction force (ẋ = v1 −
    v2, the sign of the law's ``rho2·ẋ``). Each term is a viscous force of slope
    ``c_k`` at rest that levels off at ``c_k·v_k`` above ``v_k``; with non-negative
    ``c_k`` beside the law's linear ``rho2`` the sum is any odd friction that rises
    with the speed and bends over (linear viscous, saturating, a drag nearly constant
    above a small speed). Smooth: no switch, no kink at ẋ = 0.

    The slopes are a tuple, so that a fit can free each one (``eqx.tree_at``
    addresses tuple members, not a vector's elements): scalars, or one vector for a
    bank of probes (:meth:`bank`; the score test's strengths are its elements); the
    speeds are the fixed grid, one per slope. Attributes: ``gains`` c_k [N·s/m],
    ``speeds`` v_k [m/s].
    """

    gains: tuple
    speeds: Float[Array, " k"]

    def __init__(self, gains, speeds):
        self.speeds = jnp.atleast_1d(_f(speeds))
        self.gains = tuple(_f(g) for g in gains)
        if (self.speeds.ndim != 1 or any(g.ndim > 1 for g in self.gains)
                or sum(g.size for g in self.gains) != self.speeds.size):
            raise ValueError(f"SaturatingViscosity needs one gain per speed, got gains of "
                             f"shapes {[g.shape for g in self.gains]} and speeds of shape "
                             f"{self.speeds.shape}")

    @classmethod
    def bank(cls, members):
        """One extension holding ``members`` (one slope each) side by side, their slopes
        one vector (the score test's bank of probes)."""
        return cls((jnp.stack([m.gains[0] for m in members]),),
                   jnp.concatenate([m.speeds for m in members]))

    def slopes(self):
        """The slopes c_k [N·s/m] as one vector, in the order of ``speeds``."""
        return jnp.concatenate([jnp.atleast_1d(g) for g in self.gains])

    def force(self, xdot):
        """The force [N] at sliding velocity ``xdot`` [m/s] (any shape)."""
        xdot = jnp.asarray(xdot)
        lead = (1,) * xdot.ndim  # the grid on a last axis of its own (no rank promotion)
        speeds = self.speeds.reshape(lead + (-1,))
        levels = (self.slopes() * self.speeds).reshape(lead + (-1,))
        return jnp.sum(levels * jnp.tanh(xdot[..., None] / speeds), axis=-1)

    def terms(self, state, core, drive):
        return ExtensionTerms(friction=self.force(core.v1 - core.v2))


def first_slope(ext: SaturatingViscosity):
    """The first member of ``ext``'s slopes (a bank's vector): what a probe frees."""
    return ext.gains[0]


LEARNED_FEATURES = ("x2", "v2", "xdot", "tanh_xdot", "u", "x1_minus_stroke")
"""Library of the learned force correction, each scaled to O(1) by :class:`LearnedForce`."""


class LearnedForce(_ForceOnly):
    """Data-driven force on the slider: ``F = Σ_k c_k·φ_k(state)`` [N].

    The library (:data:`LEARNED_FEATURES`, each divided by its ``scales`` entry to be
    O(1)): slider position x2 [m], slider velocity v2 [m/s], relative velocity
    ẋ = v1 − v2 [m/s], ``tanh(ẋ/scale)`` (a smoothed Coulomb term), piezo voltage u
    [V], piezo compression x1 − Γ [m]. Coefficients ``coef`` [N]; fitted by sparse
    regression (fit, drop the small ones, refit), the universal-differential-equation
    fallback of the diagnosis. ``active`` (1 or 0 per feature, default all 1) switches
    features off: an array, not part of the static structure, so that the sparse refit
    runs the compiled program of the full fit.
    """

    coef: Float[Array, " k"]
    active: Float[Array, " k"]
    scales: tuple[float, ...] = eqx.field(static=True)

    def __init__(self, coef, scales, active=None):
        self.coef = _f(coef)
        self.scales = tuple(float(s) for s in scales)
        self.active = _f(jnp.ones(len(self.scales)) if active is None else active)

    def features(self, core: CoreState):
        """The scaled library at the current state, shape (k,)."""
        s = self.scales
        xdot = core.v1 - core.v2
        return jnp.stack([core.x2 / s[0], core.v2 / s[1], xdot / s[2], jnp.tanh(xdot / s[3]),
                          core.u / s[4], (core.x1 - core.stroke) / s[5]])

    def terms(self, state, core, drive):
        return ExtensionTerms(force_slider=jnp.dot(self.coef * self.active,
                                                   self.features(core)))


# ---- output maps --------------------------------------------------------------------
def delayed(t, q, delay):
    """``q(t − delay)`` by linear interpolation between samples (uniform ``t`` [s]);
    before the trace starts the first value holds. Differentiable in ``delay`` [s]
    (from 0: the derivative is the backward difference)."""
    dt = t[1] - t[0]
    shift = jnp.maximum(delay, 0.0) / dt
    whole = jnp.floor(shift)
    frac = shift - whole
    idx = jnp.arange(q.shape[0]) - whole.astype(int)
    a = q[jnp.clip(idx, 0, q.shape[0] - 1)]
    b = q[jnp.clip(idx - 1, 0, q.shape[0] - 1)]
    return (1.0 - frac) * a + frac * b


HENE_FRINGE_M = 316.4e-9
"""The displacement of one fringe of a HeNe laser (λ = 632.8 nm) in a single-pass
Michelson interferometer, λ/2 [m]: the period of its first-order periodic error (a
double-pass plane-mirror interferometer's fringe, λ/4, is its second harmonic)."""


class SensorOutput(AbstractOutputMap):
    """Interferometer with a delay, a drift and a periodic error:
    ``p + drift·t + Σ a_i·(1 − exp(−t/T_i)) + Σ_k (c_k·cos(2πk·p/P) + s_k·sin(2πk·p/P))``
    with ``p = q(t − delay)``. The drift is a linear term beside settling terms on a
    fixed grid of time constants (none by default): with amplitudes of either sign, a
    thermal drift that settles (one exponential, several, or a curve between them) as
    well as a steady one; ``t`` is each recording's own time from its first sample.
    The periodic error (none by default) is the interferometer's nonlinearity (mixing
    of its polarisations or frequencies): periodic in the position it reads, of period
    ``P`` (:data:`HENE_FRINGE_M`) and its harmonics, whatever its shape within the
    period. Its phase is that of ``p = 0`` where every recording starts at one point
    of the fringe (the simulated protocols); a real set's recordings each start at
    another, ``o_r`` [m] further along it (``fringe_offsets``, one per recording of
    the dataset, read by :meth:`read`): the error of recording r is the series at
    ``p + o_r``. Only the offsets' differences show (the coefficients take up a shift
    of them all), so a fit holds one of them.

    The amplitudes and coefficients are tuples of scalars, so that a fit can free each
    one (``eqx.tree_at`` addresses tuple members); the time constants and the period
    are fixed.

    Attributes: ``delay`` [s] (≥ 0), ``drift`` [m/s], ``settling`` a_i [m],
    ``settle_times`` T_i [s], ``periodic`` ``(c_1, s_1, c_2, s_2, ...)`` [m],
    ``period`` P [m], ``fringe_offsets`` ``(o_1, ..., o_R)`` [m] (none by default).
    """

    delay: Float[Array, ""]
    drift: Float[Array, ""]
    settling: tuple
    settle_times: Float[Array, " k"]
    periodic: tuple
    period: Float[Array, ""]
    fringe_offsets: tuple

    def __init__(self, delay=0.0, drift=0.0, settling=(), settle_times=(), periodic=(),
                 period=HENE_FRINGE_M, fringe_offsets=()):
        self.delay = _f(delay)
        self.drift = _f(drift)
        self.settling = tuple(_f(a) for a in settling)
        self.settle_times = jnp.asarray(settle_times, dtype=float).reshape(-1)
        self.periodic = tuple(_f(c) for c in periodic)
        self.period = _f(period)
        self.fringe_offsets = tuple(_f(o) for o in fringe_offsets)
        if len(self.settling) != self.settle_times.size:
            raise ValueError(f"SensorOutput needs one settling amplitude per time constant, "
                             f"got {len(self.settling)} and {self.settle_times.size}")
        if len(self.periodic) % 2:
            raise ValueError(f"SensorOutput's periodic error needs a cosine and a sine "
                             f"coefficient per harmonic, got {len(self.periodic)} values")

    def drift_at(self, t):
        """The drift [m] at times ``t`` [s] from the recording's start."""
        out = self.drift * t
        for i, a in enumerate(self.settling):
            out = out + a * (1.0 - jnp.exp(-t / self.settle_times[i]))
        return out

    def periodic_error(self, p):
        """The periodic error [m] at read positions ``p`` [m] (0 without harmonics)."""
        # One array where a caller set the vector quantity with ``eqx.tree_at`` rather
        # than element by element (:func:`~stickslip_jax.identify.parameters.set_quantity`).
        coef = jnp.reshape(jnp.asarray(self.periodic), (-1, 2))
        lead = (1,) * jnp.ndim(p)  # harmonics on a last axis of their own
        k = jnp.arange(1, coef.shape[0] + 1, dtype=float).reshape(lead + (-1,))
        phase = (2.0 * jnp.pi / self.period) * p[..., None] * k
        return jnp.sum(coef[:, 0].reshape(k.shape) * jnp.cos(phase)
                       + coef[:, 1].reshape(k.shape) * jnp.sin(phase), axis=-1)

    def __call__(self, t, q):
        return self._reading(t, q, None)

    def read(self, t, q, recording=None):
        """The reading of the dataset's recording ``recording`` (its index; None: a
        trace of no dataset, read at offset 0): the periodic error at its own
        ``fringe_offsets`` entry."""
        if recording is None or not _count(self.fringe_offsets):
            return self._reading(t, q, None)
        offsets = jnp.reshape(jnp.asarray(self.fringe_offsets), -1)
        return self._reading(t, q, offsets[recording])

    def recordings(self) -> int:
        return _count(self.fringe_offsets)

    def _reading(self, t, q, offset):
        p = delayed(t, q, self.delay)
        out = p + self.drift_at(t)
        if _count(self.periodic):  # none: the sum of before, to the last bit
            out = out + self.periodic_error(p if offset is None else p + offset)
        return out


def _count(values) -> int:
    """Elements of a tuple of scalars, or of the one array a caller set in its place
    (``eqx.tree_at`` of a whole vector quantity)."""
    return len(values) if isinstance(values, tuple) else int(jnp.size(values))


class ExponentialDrift(AbstractOutputMap):
    """Thermal drift settling exponentially: ``q + amplitude·(1 − exp(−t/time))``.

    Attributes: ``amplitude`` [m], ``time`` [s].
    """

    amplitude: Float[Array, ""]
    time: Float[Array, ""]

    def __init__(self, amplitude, time):
        self.amplitude = _f(amplitude)
        self.time = _f(time)

    def __call__(self, t, q):
        return q + self.amplitude * (1.0 - jnp.exp(-t / self.time))


class PeriodicSensorError(AbstractOutputMap):
    """Periodic nonlinearity of a displacement interferometer (mixing of the two
    polarisations): ``q + amplitude·sin(2π·(q + offset)/period)``. The test
    generators' form of it, kept apart from :class:`SensorOutput`'s so that the data it
    makes are not the fitted model's own.

    Attributes: ``amplitude`` [m], ``period`` [m] (λ/2 = 316.4 nm for a HeNe laser
    in a single-pass Michelson), ``offset`` [m]: where along the fringe the
    recording starts (0 by default).
    """

    amplitude: Float[Array, ""]
    period: Float[Array, ""]
    offset: Float[Array, ""]

    def __init__(self, amplitude, period=316.4e-9, offset=0.0):
        self.amplitude = _f(amplitude)
        self.period = _f(period)
        self.offset = _f(offset)

    def __call__(self, t, q):
        return q + self.amplitude * jnp.sin(2.0 * jnp.pi * (q + self.offset) / self.period)


class ChainedOutput(AbstractOutputMap):
    """Output maps applied one after the other (first in the tuple first)."""

    maps: tuple[AbstractOutputMap, ...]

    def __call__(self, t, q):
        for m in self.maps:
            q = m(t, q)
        return q

    def read(self, t, q, recording=None):
        for m in self.maps:
            q = m.read(t, q, recording)
        return q

    def recordings(self) -> int:
        return max((m.recordings() for m in self.maps), default=0)

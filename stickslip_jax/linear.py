"""Linearised stick dynamics: modes, antiresonance and frequency response.

While the contact sticks (``|z| ≤ z_ba``, so ``α = 0`` and ``ż = ẋ``) the model of
docs/model.md is a linear two-degree-of-freedom chain driven by the free stroke Γ [m]:

    Mp·ẍ1 + Dp·ẋ1 + Kp·x1 + kc·(x1 − x2) + cc·(ẋ1 − ẋ2) = Kp·Γ
    Ms·ẍ2 + Ds·ẋ2 + k_load·x2 − kc·(x1 − x2) − cc·(ẋ1 − ẋ2) = 0

with the contact stiffness ``kc = friction.stiffness(drive)`` [N/m] (ρ0 for the
elasto-plastic laws, σ0 for LuGre) and the contact damping ``cc = dFf/dẋ`` [N·s/m]
at rest (ρ1 + ρ2, or σ1 + σ2), both taken from the friction law itself. The
piezo is the driven oscillator (fixed to ground through Kp), the slider the
undriven one (tied to ground only through the guide damper Ds and the optional load
spring ``k_load``). Constant forces (``Kact2·N``, ``F_ext``) shift the equilibrium
and do not enter. Input stages, extensions and output maps are not part of this
linearisation.

In the Laplace domain, with ``P1 = Mp·s² + (Dp + cc)·s + Kp + kc``,
``P2 = Ms·s² + (Ds + cc)·s + k_load + kc`` and ``C = cc·s + kc``:

    X1/Γ = Kp·P2/Δ,    X2/Γ = Kp·C/Δ,    Q/Γ = (X1 + X2)/Γ = Kp·(P2 + C)/Δ,
    Δ = P1·P2 − C²

The resonances are the roots of Δ (two modes), and the antiresonance of the output
``q = x1 + x2`` is the root pair of ``P2 + C = Ms·s² + (Ds + 2·cc)·s + k_load + 2·kc``,
undamped at ``sqrt((2·kc + k_load)/Ms)/(2π)``. With ``k_load = 0`` the static gain
of ``q/Γ`` is 2: in stick the slider follows the piezo tip, so ``x1 = x2 = Γ``.

For the paper's printed table (Lu 2015 §IV-B.1, read in SI) this gives modes at
about 564 Hz and 17.5 kHz undamped (523 Hz and 16.7 kHz damped) and a q
antiresonance at about 849 Hz, not the printed spectrum's 595 Hz, 1633 Hz and
725 Hz. :func:`spectrum_consistency` shows that no positive undamped chain of this
form has the printed spectrum at all: the q antiresonance must lie strictly
between ``√2·f1`` and ``√2·f2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .model.actuator import Actuator
from .model.base import DriveContext
from .program_store import stored_jit

__all__ = [
    "SpectrumConsistency",
    "StickChain",
    "StickModes",
    "frequency_response",
    "spectrum_consistency",
    "stick_chain",
    "stick_modes",
]

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class StickChain:
    """Coefficients of the linear stick chain (SI units).

    Attributes
    ----------
    Mp, Dp, Kp: piezo mass [kg], damping [N·s/m], stiffness [N/m].
    Ms, Ds: slider mass [kg] and guide damping [N·s/m].
    k_load: load spring on the slider [N/m].
    kc: contact stiffness [N/m] (``friction.stiffness(drive)``).
    cc: contact damping [N·s/m] (``dFf/dẋ`` at rest, ``ż = ẋ``).
    """

    Mp: float
    Dp: float
    Kp: float
    Ms: float
    Ds: float
    k_load: float
    kc: float
    cc: float

    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(M, D, K, B)`` of ``M·ẍ + D·ẋ + K·x = B·Γ`` for ``x = (x1, x2)`` [m].

        M [kg], D [N·s/m], K [N/m] are 2×2; B [N/m] is the stroke input vector.
        """
        m = np.diag([self.Mp, self.Ms])
        d = np.array([[self.Dp + self.cc, -self.cc], [-self.cc, self.Ds + self.cc]])
        k = np.array([[self.Kp + self.kc, -self.kc], [-self.kc, self.k_load + self.kc]])
        b = np.array([self.Kp, 0.0])
        return m, d, k, b

    def response(self, f_Hz, output: str = "q") -> np.ndarray:
        """:func:`frequency_response` of this chain in numpy (no JAX operation to
        compile: a figure's one number) [m/m], at ``f_Hz`` [Hz], any shape."""
        s = 1j * TWO_PI * np.asarray(f_Hz, dtype=float)
        return _chain_response(self.Mp, self.Dp, self.Kp, self.Ms, self.Ds, self.k_load,
                               self.kc, self.cc, s, output)

    def state_matrix(self) -> np.ndarray:
        """4×4 matrix ``A`` of ``d/dt (x1, x2, v1, v2) = A·(x1, x2, v1, v2)`` [1/s, 1/s²]."""
        m, d, k, _ = self.matrices()
        minv = np.linalg.inv(m)
        return np.block([[np.zeros((2, 2)), np.eye(2)], [-minv @ k, -minv @ d]])


@dataclass(frozen=True)
class StickModes:
    """Modes and q-antiresonance of the linear stick chain.

    Attributes
    ----------
    undamped_Hz: natural frequencies of the undamped chain (D = 0), ascending [Hz].
    natural_Hz: ``|λ|/(2π)`` of the damped chain's pole pairs, ascending [Hz].
    damped_Hz: ``|Im λ|/(2π)`` of the same pole pairs (0 for an overdamped pair) [Hz].
    damping_ratio: ``−Re λ/|λ|`` of each pair [-].
    antiresonance_undamped_Hz: zero of ``q/Γ`` without damping,
        ``sqrt((2·kc + k_load)/Ms)/(2π)`` [Hz].
    antiresonance_damped_Hz: ``|Im s|/(2π)`` of the damped zero pair (0 if real) [Hz].
    antiresonance_damping_ratio: damping ratio of the zero pair [-].
    """

    undamped_Hz: np.ndarray
    natural_Hz: np.ndarray
    damped_Hz: np.ndarray
    damping_ratio: np.ndarray
    antiresonance_undamped_Hz: float
    antiresonance_damped_Hz: float
    antiresonance_damping_ratio: float


def _contact_damping(friction, drive: DriveContext):
    """``dFf/dẋ`` [N·s/m] at ``z = 0``, ``ẋ = 0`` with ``ż = z_rate(0, ẋ)`` (stick)."""

    def ff(v):
        z = jnp.zeros_like(v)
        return friction.force(z, friction.z_rate(z, v, drive), v, drive)

    _, slope = jax.jvp(ff, (jnp.asarray(0.0, dtype=float),), (jnp.asarray(1.0, dtype=float),))
    return slope


@stored_jit
def _contact(friction, drive: DriveContext):
    # One compiled program: operation by operation, the law's functions each compiled
    # their own (0.8 s on the first call, issue #28).
    return friction.stiffness(drive), _contact_damping(friction, drive)


def stick_chain(actuator: Actuator, drive: DriveContext | None = None) -> StickChain:
    """The linear stick chain of ``actuator`` for ``drive`` (default: forward)."""
    if drive is None:
        drive = DriveContext.make()
    p, s, fr = actuator.piezo, actuator.slider, actuator.friction
    kc, cc = _contact(fr, drive)
    return StickChain(
        Mp=float(p.Mp), Dp=float(p.Dp), Kp=float(p.Kp),
        Ms=float(s.Ms), Ds=float(s.Ds), k_load=float(s.k_load),
        kc=float(kc), cc=float(cc),
    )


def _pair_modes(eigenvalues: np.ndarray) -> list[tuple[float, float, float]]:
    """Group eigenvalues into (natural ω, damped ω, ζ) pairs [rad/s, rad/s, -]."""
    lam = np.asarray(eigenvalues, dtype=complex)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(lam))))
    complex_up = [x for x in lam if x.imag > tol]
    real = np.sort([x.real for x in lam if abs(x.imag) <= tol])
    modes = [(abs(x), x.imag, -x.real / abs(x)) for x in complex_up]
    for a, b in zip(real[0::2], real[1::2], strict=True):
        wn = math.sqrt(a * b) if a * b > 0 else 0.0
        modes.append((wn, 0.0, -(a + b) / (2 * wn) if wn > 0 else math.inf))
    return sorted(modes)


def stick_modes(actuator: Actuator, drive: DriveContext | None = None) -> StickModes:
    """Resonances and the q-antiresonance of the stick dynamics [Hz].

    See :class:`StickModes`. The undamped values ignore Dp, Ds and the contact
    damping; the damped ones come from the eigenvalues of the full linear chain.
    """
    ch = stick_chain(actuator, drive)
    m, _, k, _ = ch.matrices()
    w2 = np.sort(np.linalg.eigvals(np.linalg.solve(m, k)).real)
    undamped = np.sqrt(w2) / TWO_PI
    modes = _pair_modes(np.linalg.eigvals(ch.state_matrix()))
    natural = np.array([x[0] for x in modes]) / TWO_PI
    damped = np.array([x[1] for x in modes]) / TWO_PI
    zeta = np.array([x[2] for x in modes])
    # Zero pair of q/Γ: Ms·s² + (Ds + 2·cc)·s + (k_load + 2·kc).
    k0 = ch.k_load + 2.0 * ch.kc
    c0 = ch.Ds + 2.0 * ch.cc
    wa = math.sqrt(k0 / ch.Ms)
    zeta_a = c0 / (2.0 * math.sqrt(k0 * ch.Ms))
    wa_d = wa * math.sqrt(1.0 - zeta_a**2) if zeta_a < 1.0 else 0.0
    return StickModes(
        undamped_Hz=undamped,
        natural_Hz=natural,
        damped_Hz=damped,
        damping_ratio=zeta,
        antiresonance_undamped_Hz=wa / TWO_PI,
        antiresonance_damped_Hz=wa_d / TWO_PI,
        antiresonance_damping_ratio=zeta_a,
    )


def frequency_response(actuator: Actuator, f_Hz, drive: DriveContext | None = None, *,
                       output: str = "q"):
    """Complex stick transfer function from free stroke Γ [m] to the output [m].

    Parameters
    ----------
    actuator:
        The actuator (its piezo, slider and friction stiffness are used).
    f_Hz:
        Frequencies [Hz], any shape.
    drive:
        Drive context for drive-dependent contact stiffness (default: forward).
    output:
        ``"q"`` (``x1 + x2``, the measured output, the default), ``"x1"`` or ``"x2"``.

    Returns
    -------
    Complex array [m/m] of the shape of ``f_Hz``: ``Q(i·2πf)/Γ(i·2πf)``. Evaluated
    with ``jax.numpy`` on the actuator's own parameters, so it is differentiable with
    respect to them (e.g. to fit a measured spectrum).
    """
    if drive is None:
        drive = DriveContext.make()
    p, sl, fr = actuator.piezo, actuator.slider, actuator.friction
    kc = fr.stiffness(drive)
    cc = _contact_damping(fr, drive)
    s = 1j * TWO_PI * jnp.asarray(f_Hz, dtype=float)
    return _chain_response(p.Mp, p.Dp, p.Kp, sl.Ms, sl.Ds, sl.k_load, kc, cc, s, output)


def _chain_response(Mp, Dp, Kp, Ms, Ds, k_load, kc, cc, s, output: str):
    """``output``/Γ of the stick chain at Laplace variable ``s`` [rad/s]: plain
    arithmetic, so JAX and numpy operands alike (:func:`frequency_response`,
    :meth:`StickChain.response`)."""
    if output not in ("q", "x1", "x2"):
        raise ValueError(f"output must be 'q', 'x1' or 'x2', got {output!r}")
    p1 = Mp * s**2 + (Dp + cc) * s + Kp + kc
    p2 = Ms * s**2 + (Ds + cc) * s + k_load + kc
    c = cc * s + kc
    delta = p1 * p2 - c**2
    num = {"q": p2 + c, "x1": p2, "x2": c}[output]
    return Kp * num / delta


@dataclass(frozen=True)
class SpectrumConsistency:
    """What an undamped 2-DOF chain needs to have a given q spectrum.

    The chain of :mod:`stickslip_jax.linear` without dampers and load spring, per
    unit slider mass: unknowns ``Kp/Mp``, ``ρ0/Mp``, ``ρ0/Ms`` (and so ``Mp/Ms``,
    ``Kp/Ms``), all [1/s²] except the mass ratio [-]. With ``ω = 2πf``:

        ρ0/Ms = ωa²/2                       (zero of P2 + C)
        Kp/Mp = ω1²·ω2²/(ρ0/Ms) = 2·ω1²·ω2²/ωa²   (product of the roots of Δ)
        ρ0/Mp = ω1² + ω2² − Kp/Mp − ρ0/Ms         (sum of the roots of Δ)

    All are positive if and only if ``√2·f1 < fa < √2·f2``.

    Attributes
    ----------
    f1_Hz, f2_Hz, fa_Hz: the requested resonances and antiresonance [Hz].
    rho0_per_Ms, Kp_per_Mp, rho0_per_Mp, Kp_per_Ms: required ratios [N/(m·kg) = 1/s²].
    Mp_per_Ms: required mass ratio [-] (negative when impossible).
    fa_range_Hz: open interval of antiresonances that positive parameters allow [Hz].
    feasible: True when every required parameter is positive.
    message: the verdict in words, with numbers.
    """

    f1_Hz: float
    f2_Hz: float
    fa_Hz: float
    rho0_per_Ms: float
    Kp_per_Mp: float
    rho0_per_Mp: float
    Mp_per_Ms: float
    Kp_per_Ms: float
    fa_range_Hz: tuple[float, float]
    feasible: bool
    message: str


def spectrum_consistency(f1_Hz: float, f2_Hz: float, fa_Hz: float) -> SpectrumConsistency:
    """Solve for the undamped chain (per unit Ms) with resonances f1 < f2, q-zero fa.

    Parameters
    ----------
    f1_Hz, f2_Hz:
        The two resonances [Hz], ``0 < f1 < f2``.
    fa_Hz:
        The antiresonance of ``q = x1 + x2`` [Hz], > 0.

    Returns
    -------
    :class:`SpectrumConsistency`: the required ratios, whether they are all positive
    and a message. For the spectrum printed in Lu 2015 (595, 1633, 725 Hz) the
    required ``ρ0/Mp`` is negative (about −3.3e7 1/s²): ``fa`` would have to exceed
    ``√2·595 ≈ 841 Hz``. Damping moves these frequencies only at second order in the
    damping ratios; the result is about the undamped (or lightly damped) chain.
    """
    f1, f2, fa = float(f1_Hz), float(f2_Hz), float(fa_Hz)
    if not (0 < f1 < f2) or fa <= 0:
        raise ValueError(f"need 0 < f1 < f2 and fa > 0, got f1={f1}, f2={f2}, fa={fa}")
    w1, w2, wa = (TWO_PI * f1) ** 2, (TWO_PI * f2) ** 2, (TWO_PI * fa) ** 2
    rho0_per_ms = wa / 2.0
    kp_per_mp = w1 * w2 / rho0_per_ms
    rho0_per_mp = w1 + w2 - kp_per_mp - rho0_per_ms
    mp_per_ms = rho0_per_ms / rho0_per_mp
    kp_per_ms = kp_per_mp * mp_per_ms
    lo, hi = math.sqrt(2.0) * f1, math.sqrt(2.0) * f2
    feasible = rho0_per_ms > 0 and kp_per_mp > 0 and rho0_per_mp > 0
    if feasible:
        message = (
            f"feasible: Kp/Mp = {kp_per_mp:.4g} 1/s², rho0/Mp = {rho0_per_mp:.4g} 1/s², "
            f"rho0/Ms = {rho0_per_ms:.4g} 1/s², Mp/Ms = {mp_per_ms:.4g}"
        )
    else:
        message = (
            f"impossible: resonances {f1:g} Hz and {f2:g} Hz with a q antiresonance at "
            f"{fa:g} Hz need rho0/Mp = {rho0_per_mp:.4g} 1/s² (negative stiffness or "
            f"mass; Kp/Mp = {kp_per_mp:.4g}, rho0/Ms = {rho0_per_ms:.4g} 1/s²). "
            f"Positive parameters put the q antiresonance strictly between "
            f"{lo:.1f} Hz and {hi:.1f} Hz."
        )
    return SpectrumConsistency(
        f1_Hz=f1, f2_Hz=f2, fa_Hz=fa,
        rho0_per_Ms=rho0_per_ms, Kp_per_Mp=kp_per_mp, rho0_per_Mp=rho0_per_mp,
        Mp_per_Ms=mp_per_ms, Kp_per_Ms=kp_per_ms, fa_range_Hz=(lo, hi),
        feasible=bool(feasible), message=message,
    )

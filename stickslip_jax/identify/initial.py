"""Starting values from the data: PI thresholds over the recorded range, the stroke
gain from a slow sine (or the step), and the stiffnesses and dampings from the measured ringing."""

from __future__ import annotations

import equinox as eqx
import numpy as np

from ..io import Recording
from ..linear import stick_modes
from ..model.actuator import Actuator
from ..model.hysteresis import PrandtlIshlinskii, default_thresholds
from ..model.registry import held_parameters


def resample_pi(pi: PrandtlIshlinskii, thresholds: np.ndarray) -> PrandtlIshlinskii:
    """A PI with new ``thresholds`` [V] and the same initial-loading curve.

    The initial-loading curve ``Γ(U) = Σ w_i·max(U − r_i, 0)`` is piecewise linear
    with slope ``Σ_{r_i ≤ U} w_i``; the new weights keep the old slope on each new
    segment (exact when the thresholds coincide), so the loop stays monotone.
    """
    r_old = np.asarray(pi.thresholds)
    slope_old = np.cumsum(np.asarray(pi.weights))
    thresholds = np.asarray(thresholds, dtype=float)
    idx = np.searchsorted(r_old, thresholds, side="right") - 1
    slope_new = slope_old[np.clip(idx, 0, len(r_old) - 1)]
    return PrandtlIshlinskii(thresholds, np.diff(slope_new, prepend=0.0))


def pi_over_range(actuator: Actuator, recordings, n: int) -> Actuator:
    """Actuator whose PI has ``n`` non-uniform thresholds over the recorded voltages."""
    u_max = max(float(np.max(r.voltage_V)) for r in recordings)
    u_min = min(float(np.min(r.voltage_V)) for r in recordings)
    span = max(u_max - u_min, 1e-6)
    pi = resample_pi(actuator.hysteresis, default_thresholds(n, span))
    return eqx.tree_at(lambda a: a.hysteresis, actuator, pi)


def stroke_along(actuator: Actuator, voltage_V) -> np.ndarray:
    """Free stroke Γ [m] of the hysteresis at each sample of ``voltage_V`` [V], from rest
    at the first sample (the input stage is not applied)."""
    gamma = actuator.hysteresis.along(voltage_V)
    return np.asarray(gamma)


def scale_pi_quasistatic(actuator: Actuator, rec: Recording) -> tuple[Actuator, float]:
    """Scale the PI weights so that the model's quasi-static stroke matches ``rec``.

    For a slow drive (a sine well below the first resonance) the contact sticks and the
    slider follows the piezo with no force on it, so q = x1 + x2 = 2·Γ(U): the
    peak-to-peak of q is twice that of the free stroke. For a step the estimate is
    rougher (a fast edge makes the slider slip, so q rises by less than 2·ΔΓ). Returns
    the actuator and the factor applied [-] (clipped to [0.2, 5]; 1 when nothing moves).
    """
    gamma = stroke_along(actuator, rec.voltage_V)
    q_span = float(np.ptp(rec.position_m))
    g_span = float(np.ptp(gamma))
    if not (g_span > 0 and np.isfinite(q_span) and q_span > 0):
        return actuator, 1.0
    factor = float(np.clip(q_span / (2.0 * g_span), 0.2, 5.0))
    return eqx.tree_at(lambda a: a.hysteresis.weights, actuator,
                       actuator.hysteresis.weights * factor), factor


def measured_step_mode(step: Recording, *, band=(100.0, 6000.0), window_s: float = 0.01,
                       ) -> tuple[float, float] | None:
    """Damped frequency [Hz] and damping ratio [-] of the ringing after a step edge.

    Fits ``c + exp(−σt)·(a·cos ωt + b·sin ωt)`` to the ``window_s`` after the edge
    (the largest sample-to-sample jump) by a grid over frequency (log-spaced in
    ``band``) and damping ratio, with ``c, a, b`` solved linearly at each grid point.
    A time-domain fit is used rather than a spectral peak because white sensor noise
    dominates any differentiated spectrum at high frequency. None when the segment is
    too short or the best fit explains less than half of the segment's variance.
    """
    return ringing_on_grid(step, ringing_costs, band=band, window_s=window_s)


def ringing_costs(basis: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Least-squares cost of ``seg`` (L,) [m] on each of the bases ``basis`` (Z, L, 3),
    their coefficients solved linearly [m²]. Batched matrix products, not einsum, whose
    unoptimised loops took 0.75 of :func:`measured_step_mode`'s 0.85 s (issue #64); the
    grid point chosen is the same on every bundled step and 60 of random truths
    (benchmarks/experiments/step_mode_products.py)."""
    basis_t = basis.transpose(0, 2, 1)  # (Z, 3, L)
    coef = np.linalg.solve(basis_t @ basis + 1e-30 * np.eye(3), basis_t @ seg[:, None])
    return np.sum(((basis @ coef)[..., 0] - seg) ** 2, axis=1)


def ringing_on_grid(step: Recording, costs, *, band=(100.0, 6000.0),
                    window_s: float = 0.01) -> tuple[float, float] | None:
    """:func:`measured_step_mode` with ``costs(basis, seg)`` (:func:`ringing_costs`'s
    signature) the cost of each damping ratio at one frequency."""
    q = np.asarray(step.position_m, dtype=float)
    k0 = int(np.argmax(np.abs(np.diff(q)))) + 2  # after the first-order-hold ramp
    seg = q[k0:k0 + max(int(window_s / step.dt), 16)]
    if len(seg) < 16:
        return None
    seg = seg - seg.mean()
    t = np.arange(len(seg)) * step.dt
    zetas = np.linspace(0.02, 0.9, 45)
    best = (np.inf, np.nan, np.nan)
    for f in np.geomspace(band[0], min(band[1], 0.45 / step.dt), 500):
        w = 2 * np.pi * f
        decay = np.exp(-np.outer(zetas * w / np.sqrt(1 - zetas**2), t))  # (Z, L)
        basis = np.stack([np.ones_like(decay), decay * np.cos(w * t), decay * np.sin(w * t)],
                         axis=-1)  # (Z, L, 3)
        cost = costs(basis, seg)
        i = int(np.argmin(cost))
        if cost[i] < best[0]:
            best = (float(cost[i]), float(f), float(zetas[i]))
    if not best[0] < 0.5 * float(np.sum(seg**2)):
        return None
    return best[1], best[2]


def scale_to_step_mode(actuator: Actuator, f_damped: float, zeta: float, *,
                       iterations: int = 4) -> tuple[Actuator, float, float]:
    """Scale the stiffnesses (Kp and the friction law's contact stiffnesses, rho0 for
    the paper's law: its parameters flagged ``stiffness``) and dampings (Dp, Ds) so
    that the first mode of the linear stick chain has damped frequency ``f_damped``
    [Hz] and damping ratio ``zeta`` [-]. Masses stay (they carry the scale that
    position data cannot fix).

    Returns the actuator and the overall stiffness and damping factors applied. Each
    factor is clipped per iteration to [0.1, 10] so a poor estimate cannot run away.
    """
    k_total, d_total = 1.0, 1.0
    act = actuator
    contact = tuple(p.attr for p in held_parameters(actuator.friction) if p.stiffness)

    def stiffnesses(a):
        return (a.piezo.Kp, *(getattr(a.friction, attr) for attr in contact))

    for _ in range(iterations):
        m = stick_modes(act)
        f_model, z_model = float(m.damped_Hz[0]), float(m.damping_ratio[0])
        if not (f_model > 0 and z_model > 0 and np.isfinite(f_damped) and zeta > 0):
            break
        # Stiffness by ω², damping by √k (ζ unchanged), then damping by the ζ ratio.
        k = float(np.clip((f_damped / f_model) ** 2, 0.1, 10.0))
        d = float(np.clip(np.sqrt(k) * zeta / z_model, 0.1, 10.0))
        act = eqx.tree_at(lambda a: (*stiffnesses(a), a.piezo.Dp, a.slider.Ds), act,
                          (*(x * k for x in stiffnesses(act)), act.piezo.Dp * d,
                           act.slider.Ds * d))
        k_total *= k
        d_total *= d
    return act, k_total, d_total

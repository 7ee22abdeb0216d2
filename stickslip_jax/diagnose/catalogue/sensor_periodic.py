"""The interferometer's periodic error: the reading is off by an error periodic in the
position it reads, of the fringe's period and its harmonics, in whatever shape.

The class, not one form: the refit fits a cosine and a sine coefficient per harmonic of
the fringe (:class:`~stickslip_jax.model.extensions.SensorOutput`'s ``periodic``), so
that any shape of error within a period (a polarisation-mixing sine, its second-order
companion at half the period, a double-pass interferometer's fringe, which is the
single-pass one's second harmonic) and any phase are special cases. The score test
probes both coefficients of the first :data:`HARMONICS` harmonics as one vector
quantity (linear in them: the derivative at 0 is what it is anywhere); the refit starts
from the best probe's coefficient with the others at 0. A fitted error that leaves the
model beyond the noise gets one more harmonic as its refined form, up to
:data:`MAX_HARMONICS`.

The phase is that of the read position 0: each recording's first sample in the
simulated protocols, one phase for the set. In a real set every recording starts at
another point of the fringe. When the residual says so, the entry also starts a fit
with one fringe offset per recording (:class:`~stickslip_jax.model.extensions.
SensorOutput`'s ``fringe_offsets``, :func:`fringe_start`): the residual of each
recording regressed on the fringe's harmonics at the positions the model reads (a
constant and a cubic in time beside them), the recordings' coefficients rotated onto
one another, and the offsets offered where they lower the regression's BIC below that
of one phase for all (ln N per offset; the misfits scaled by the rotated fit's
overdispersion, so that another physics' misfit projected on the fringe is not taken
for phases). Then the score test's probes read each recording at its offset (with
one phase for all, the recordings' errors would cancel in the probes' columns), and
the sizing starts from whichever of the two starts costs least
(:func:`~stickslip_jax.diagnose.sizing.first_order_start`). The offsets are the
residual's where the model stands: after an accepted entry the next round's are the
residual's then (a periodic error's phases show once another effect's misfit is
gone).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import final

import equinox as eqx
import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.actuator import Actuator
from ...model.extensions import HENE_FRINGE_M
from ..form_band import draw_band
from .base import CatalogueEntry, Probe
from .slots import carry_output_map, with_sensor

HARMONICS = 2
"""Harmonics of the fringe probed and fitted at first: the first-order error (a
single-pass interferometer's polarisation mixing) and the second (its second-order
term, and a double-pass interferometer's first-order one, whose fringe is λ/4)."""

MAX_HARMONICS = 4
"""Harmonics a refined form reaches at most (one more per refinement)."""

PROBE_SCALE_M = 1e-9
"""θ = 1 of a probe: a coefficient of 1 nm (periodic errors of commercial
interferometers are 0.1-10 nm)."""


def coefficient_name(index: int) -> str:
    """The reported name of the ``index``-th coefficient (cosine then sine, by
    harmonic)."""
    harmonic, odd = divmod(index, 2)
    return f"periodic_{'sin' if odd else 'cos'}_{harmonic + 1}"


def with_periodic(act: Actuator, harmonics: int = HARMONICS) -> Actuator:
    """``act`` with a :class:`SensorOutput` whose periodic error has ``harmonics``
    harmonics (the fitted ones kept, new ones at 0), its other quantities as they
    were."""
    act = with_sensor(act)
    have = act.output_map.periodic
    if len(have) >= 2 * harmonics:
        return act
    return _with_coefficients(act, have + (0.0,) * (2 * harmonics - len(have)))


def _with_coefficients(act: Actuator, coefficients) -> Actuator:
    """``act`` (its output map a :class:`SensorOutput`) with the periodic error's
    ``coefficients``, its other quantities as they were."""
    return eqx.tree_at(lambda a: a.output_map, act,
                       dataclasses.replace(act.output_map, periodic=tuple(coefficients)))


def _coefficient(index: int):
    return lambda a: a.output_map.periodic[index]


def _offset(index: int):
    return lambda a: a.output_map.fringe_offsets[index]


def offset_name(recording: int) -> str:
    """The reported name of recording ``recording``'s fringe offset."""
    return f"fringe_offset_{recording}"


def _specs(count: int, scale: float, free_offsets=()) -> dict[str, ParameterSpec]:
    specs = {coefficient_name(i): ParameterSpec(_coefficient(i), "linear", scale, "m")
             for i in range(count)}
    # θ = 1 of an offset: one radian of the fringe.
    specs.update({offset_name(r): ParameterSpec(_offset(r), "linear",
                                                HENE_FRINGE_M / (2.0 * math.pi), "m")
                  for r in free_offsets})
    return specs


@dataclass(frozen=True)
class FringeStart:
    """Where a fit with one fringe offset per recording starts (:func:`fringe_start`):
    the periodic error's ``coefficients`` [m] at the offsets' origin, each recording's
    ``offsets`` [m], the recordings whose offsets a fit frees (``free``: those moving
    a fringe, but the ``reference``, whose offset it holds), and the regression's
    (quasi-likelihood) BIC gain over one phase for all (``bic_gain``, > 0 where it was
    offered)."""

    coefficients: tuple[float, ...]
    offsets: tuple[float, ...]
    free: tuple[int, ...]
    reference: int
    bic_gain: float


TIME_TREND_DEGREE = 3
"""Degree of the polynomial in time fitted beside the fringe's harmonics in each
recording's regression: what the residual holds of smooth misfit (creep, drift) is not
taken for a phase."""

ANGLE_GRID = 720
"""Angles tried per recording when rotating its fringe coefficients onto the others'
(a half degree apart; the best is refined by the fit)."""


def _moves_a_fringe(output: np.ndarray) -> bool:
    return output.size > 0 and float(np.ptp(output)) >= HENE_FRINGE_M


def fringe_reference(hints: dict) -> int | None:
    """The recording whose fringe offset a fit holds: of those moving a fringe, the one
    with the most samples per noise variance (what fixes the fringe's phase best; the
    positions and noise decide, not the residual, so successive fits agree). None
    without the hints or such a recording."""
    outputs, noise = hints.get("outputs_m"), hints.get("noise_m")
    if not outputs or not noise:
        return None
    weight = [q.size / s**2 if _moves_a_fringe(q) else -1.0
              for q, s in zip(outputs, noise, strict=True)]
    best = int(np.argmax(weight))
    return best if weight[best] > 0 else None


def _rotation(angle: np.ndarray, harmonics: int) -> np.ndarray:
    """Matrices (…, 2H, 2H) taking the coefficients ``(c_k, s_k)`` of an error read
    ``angle`` radians of the fringe later (``e(p + o)``, ``angle = 2πo/P``) from those
    at the origin: block k a rotation by ``k·angle``."""
    angle = np.asarray(angle, dtype=float)[..., None]
    k = np.arange(1, harmonics + 1)
    cos, sin = np.cos(k * angle), np.sin(k * angle)
    out = np.zeros(angle.shape[:-1] + (2 * harmonics, 2 * harmonics))
    for j in range(harmonics):
        out[..., 2 * j, 2 * j] = cos[..., j]
        out[..., 2 * j, 2 * j + 1] = sin[..., j]
        out[..., 2 * j + 1, 2 * j] = -sin[..., j]
        out[..., 2 * j + 1, 2 * j + 1] = cos[..., j]
    return out


def _fringe_regression(output: np.ndarray, residual: np.ndarray, sigma: float,
                       harmonics: int) -> tuple[np.ndarray, np.ndarray]:
    """``(w, info)``: one recording's residual [m] regressed on the fringe's harmonics
    at the positions ``output`` [m] (a constant and a polynomial in time beside them),
    its coefficients ``(c_k, s_k)`` [m] and their information matrix [1/m²]."""
    n = output.size
    theta = 2.0 * math.pi * output / HENE_FRINGE_M
    k = np.arange(1, harmonics + 1)
    fringe = np.stack([f(kk * theta) for kk in k for f in (np.cos, np.sin)], axis=1)
    trend = np.polynomial.legendre.legvander(np.linspace(-1.0, 1.0, n), TIME_TREND_DEGREE)
    basis, _ = np.linalg.qr(trend)
    f_perp = fringe - basis @ (basis.T @ fringe)
    y_perp = residual - basis @ (basis.T @ residual)
    w = np.linalg.lstsq(f_perp, y_perp, rcond=None)[0]
    return w, f_perp.T @ f_perp / sigma**2


def _aligned(ws, infos, angles, harmonics):
    """The coefficients and information matrices rotated back to the origin by each
    recording's ``angles``, their information-weighted mean and the misfit of the
    recordings to it (Σ (w − w̄)ᵀ I (w − w̄))."""
    rot = _rotation(angles, harmonics)
    back = np.einsum("rji,rj->ri", rot, ws)  # Rᵀ w
    info = np.einsum("rji,rjk,rkl->ril", rot, infos, rot)  # Rᵀ I R
    mean = np.linalg.solve(info.sum(axis=0), np.einsum("rij,rj->i", info, back))
    d = back - mean
    return mean, float(np.einsum("ri,rij,rj->", d, info, d))


def fringe_start(hints: dict, harmonics: int = HARMONICS) -> FringeStart | None:
    """A start with one fringe offset per recording, from ``hints`` (the located
    model's outputs, residuals and noise), where the residual asks for one: each
    recording moving a fringe regressed on the fringe's ``harmonics``
    (:func:`_fringe_regression`); each recording's coefficients rotated onto the
    reference's (:func:`fringe_reference`), then onto their mean, over a grid of
    :data:`ANGLE_GRID` angles. The offsets are offered when, by the BIC of the
    regression (ln N per offset, N the samples of all recordings; the misfits divided
    by the rotated fit's misfit per degree of freedom where that exceeds 1, as
    quasi-likelihood criteria do for overdispersed data), the rotated recordings fit
    one set of coefficients better than one phase for all does. None otherwise."""
    reference = fringe_reference(hints)
    if reference is None:
        return None
    outputs, residuals, noise = hints["outputs_m"], hints["residuals_m"], hints["noise_m"]
    used = [r for r, q in enumerate(outputs) if _moves_a_fringe(q)]
    if len(used) < 2:
        return None
    fits = [_fringe_regression(outputs[r], residuals[r], noise[r], harmonics) for r in used]
    ws = np.stack([w for w, _ in fits])
    infos = np.stack([i for _, i in fits])
    _, shared = _aligned(ws, infos, np.zeros(len(used)), harmonics)
    grid = np.linspace(0.0, 2.0 * math.pi, ANGLE_GRID, endpoint=False)
    rot = _rotation(grid, harmonics)  # (G, 2H, 2H)
    target = ws[used.index(reference)]
    angles = np.zeros(len(used))
    for _ in range(2):  # onto the reference, then onto the mean of the rotated ones
        for i in range(len(used)):
            # The angle at which recording i's coefficients, rotated back, sit nearest
            # the target in its own information metric.
            back = np.einsum("gji,j->gi", rot, ws[i])
            d = back - target
            angles[i] = grid[int(np.argmin(np.einsum("gi,ij,gj->g", d, infos[i], d)))]
        target, rotated = _aligned(ws, infos, angles, harmonics)
    # The BIC of m − 1 offsets more than one phase for all, the misfits scaled by the
    # rotated model's overdispersion (QBIC): what another physics' misfit projects on
    # the fringe's columns differs in amplitude from recording to recording, where an
    # interferometer's error has one; its rotated misfit then stays far above its
    # degrees of freedom, and the rotation's gain counts that much less.
    m, log_n = len(used), math.log(sum(q.size for q in outputs))
    dispersion = max(1.0, rotated / ((2 * harmonics - 1) * (m - 1)))
    gain = (shared - rotated) / dispersion - (m - 1) * log_n
    if not gain > 0:
        return None
    offsets = np.zeros(len(outputs))
    offsets[used] = angles * HENE_FRINGE_M / (2.0 * math.pi)
    return FringeStart(tuple(float(c) for c in target), tuple(float(o) for o in offsets),
                       tuple(r for r in used if r != reference), reference, float(gain))


def _with_offsets(act: Actuator, offsets) -> Actuator:
    """``act`` with a sensor reading the recordings at the fringe ``offsets`` [m], its
    other quantities as they were (with no periodic error, the readings unchanged)."""
    act = with_sensor(act)
    return eqx.tree_at(lambda a: a.output_map, act, dataclasses.replace(
        act.output_map, fringe_offsets=tuple(offsets)))


def with_fringe_offsets(act: Actuator, start: FringeStart) -> Actuator:
    """``act`` (its sensor's other quantities kept) with ``start``'s coefficients and
    offsets."""
    return _with_coefficients(_with_offsets(act, start.offsets), start.coefficients)


@final
class SensorPeriodicEntry(CatalogueEntry):
    """The :class:`~stickslip_jax.model.extensions.SensorOutput`'s periodic error:
    cosine and sine coefficients [m] of the fringe's harmonics (either sign); the refit
    frees them all."""

    name = "sensor_periodic"
    slot = "output_map"
    signature = ("residual periodic in the position read, of the laser's fringe "
                 f"({HENE_FRINGE_M * 1e9:.4g} nm) or its harmonics, in every regime alike")

    def needs(self, recordings):
        if not any(_moves_a_fringe(r.position_m) for r in recordings
                   if r.position_m is not None):
            return (f"indistinguishable: no recording moves one fringe "
                    f"({HENE_FRINGE_M * 1e9:.4g} nm); within a fringe a periodic error of "
                    f"the reading is a smooth bend of the stroke")
        return None

    def probes(self, act, hints):
        # One spec for all: the coefficients are one vector quantity of the score test.
        spec = ParameterSpec(lambda a: a.output_map.periodic, "linear", PROBE_SCALE_M, "m")
        # Where the residual asks for an offset per recording, the probes read each
        # recording at its own: one phase for all would see the recordings' errors
        # cancel one another.
        fringe = fringe_start(hints)
        install = with_periodic if fringe is None else (
            lambda a: with_periodic(_with_offsets(a, fringe.offsets)))
        return [Probe(f"periodic {coefficient_name(i).removeprefix('periodic_')}",
                      install, spec, 0, {"index": i, "fringe": fringe})
                for i in range(2 * HARMONICS)]

    def attach(self, act, strength, probe):
        start = [0.0] * (2 * HARMONICS)
        start[probe.setting["index"]] = strength
        new = _with_coefficients(with_sensor(act), start)
        return new, _specs(len(start), probe.strength_scale(strength))

    def attach_options(self, act, strength, probe):
        """The probe's coefficient at ``strength`` (one phase for the set), and, where
        the residual asked for them (:func:`fringe_start`), the offsets per recording
        with the coefficients their regression found."""
        options = [self.attach(act, strength, probe)]
        fringe = probe.setting.get("fringe")
        if fringe is not None:
            scale = float(np.max(np.abs(fringe.coefficients))) or PROBE_SCALE_M
            options.append((with_fringe_offsets(act, fringe),
                            _specs(len(fringe.coefficients), scale, fringe.free)))
        return options

    def refined_forms(self, act, hints):
        """One more harmonic (at 0: the fitted error itself), every coefficient
        freed, and the fringe offsets per recording where the model has them (all but
        the reference's, :func:`fringe_reference`); none once :data:`MAX_HARMONICS`
        are fitted."""
        have = len(getattr(act.output_map, "periodic", ())) // 2
        if not have or have >= MAX_HARMONICS:
            return []
        coef = np.abs(np.asarray(act.output_map.periodic, dtype=float))
        scale = float(coef.max()) if coef.max() > 0 else PROBE_SCALE_M
        free = ()  # without the hints, the offsets held where the fit left them
        if act.output_map.recordings() and hints.get("outputs_m"):
            reference = fringe_reference(hints)
            free = tuple(r for r, q in enumerate(hints["outputs_m"])
                         if _moves_a_fringe(q) and r != reference)
        return [(with_periodic(act, have + 1), _specs(2 * (have + 1), scale, free))]

    def carry(self, init, fitted):
        return carry_output_map(init, fitted)

    def implausible(self, params):
        slope = _max_slope(_coefficients(params))
        if slope >= 1.0:
            return (f"the error's slope reaches {slope:.3g} of the position's: the reading "
                    f"would run backwards within a fringe; not an interferometer's "
                    f"periodic error")
        return ""

    def describe(self, params):
        coef = _coefficients(params)
        if not coef.size:
            return ""
        amps = np.hypot(coef[:, 0], coef[:, 1])
        p = np.linspace(0.0, HENE_FRINGE_M, 400)
        curve = _error(coef, p)
        parts = ", ".join(f"{a * 1e9:.3g} nm at {HENE_FRINGE_M / (k + 1) * 1e9:.4g} nm"
                          for k, a in enumerate(amps))
        offsets = _fitted_starts(params).size
        where = (f"; each recording's start along the fringe fitted ({offsets} offsets)"
                 if offsets else "")
        return (f"interferometer periodic error: {parts}; "
                f"{np.ptp(curve) * 1e9:.3g} nm peak to peak over a fringe{where}")

    def plot_form(self, ax, params, draws=None):
        coef = _coefficients(params)
        if not coef.size:
            return False
        p = np.linspace(0.0, 2.0 * HENE_FRINGE_M, 400)
        draw_band(ax, p * 1e9, lambda q: _error(_coefficients(q), p), params, draws,
                  scale=1e9)
        ax.plot(p * 1e9, _error(coef, p) * 1e9, color="tab:blue", label="error found")
        ax.plot(p * 1e9, _error(coef[:1], p) * 1e9, color="0.5", ls="--", lw=0.8,
                label="first harmonic")
        starts = _fitted_starts(params)
        if starts.size:
            # Where each recording's first sample meets the fringe: the error read there.
            ax.plot(starts * 1e9, _error(coef, starts) * 1e9, "o", ms=3, color="tab:orange",
                    label=f"recordings' starts ({starts.size} fitted; the reference's held)")
        ax.set_xlabel("position read [nm]")
        ax.set_ylabel("reading error [nm]")
        ax.set_title(f"interferometer periodic error ({len(coef)} harmonics)", fontsize=9)
        ax.legend(fontsize=7)
        return True


def _coefficients(params: dict[str, float]) -> np.ndarray:
    """The refitted coefficients in ``params`` as rows ``(c_k, s_k)`` by harmonic."""
    count = sum(1 for k in params if k.startswith("periodic_"))
    return np.array([params.get(coefficient_name(i), 0.0)
                     for i in range(count - count % 2)]).reshape(-1, 2)


def _fitted_starts(params: dict[str, float]) -> np.ndarray:
    """The fitted fringe offsets in ``params``, each within one fringe [m]."""
    offsets = [v for k, v in params.items() if k.startswith("fringe_offset_")]
    return np.mod(np.asarray(offsets, dtype=float), HENE_FRINGE_M)


def _error(coef: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The periodic error [m] of rows ``coef`` at read positions ``p`` [m]."""
    k = np.arange(1, len(coef) + 1)
    phase = 2.0 * math.pi * p[:, None] * k / HENE_FRINGE_M
    return np.sum(coef[:, 0] * np.cos(phase) + coef[:, 1] * np.sin(phase), axis=1)


def _max_slope(coef: np.ndarray) -> float:
    """The error's largest slope [-] over a fringe (its derivative, on a grid of 2048
    points per fringe)."""
    if not coef.size:
        return 0.0
    k = np.arange(1, len(coef) + 1)
    phase = 2.0 * math.pi * np.linspace(0.0, HENE_FRINGE_M, 2049)[:, None] * k / HENE_FRINGE_M
    rate = 2.0 * math.pi * k / HENE_FRINGE_M
    return float(np.max(np.abs(np.sum(rate * (coef[:, 1] * np.cos(phase)
                                               - coef[:, 0] * np.sin(phase)), axis=1))))


__all__ = ["HARMONICS", "MAX_HARMONICS", "FringeStart", "SensorPeriodicEntry",
           "coefficient_name", "fringe_reference", "fringe_start", "offset_name",
           "with_fringe_offsets", "with_periodic"]

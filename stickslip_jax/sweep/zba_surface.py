"""The z_ba surface: break-away displacement over the drive workspace (Lu 2015, future
work), fitted from a grid of stepping recordings.

1. :func:`fit_zba_points`: z_ba of every recording, in one compiled batch of
   optimistix Levenberg-Marquardt solves (one parameter per recording, everything else
   fixed), with its standard error from the Jacobian at the optimum.
2. :func:`fit_zba_surface`: per direction, a quadratic in amplitude and log10
   frequency (both standardised) by weighted least squares on the points the data
   determine, with R², RMS and leave-one-out RMS; queries outside the fitted ranges
   are extrapolation and are flagged.
3. :class:`ZbaSurfaceElastoPlastic`: the paper's friction law with z_ba read from the
   surface at the drive of each simulation (``DriveContext`` amplitude, frequency,
   direction), so ``simulate`` and ``sweep`` use it unchanged.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..files import atomic_write_text, check_output_path
from ..model.base import DriveContext
from ..model.friction import AbstractElastoPlastic, ElastoPlastic
from ..simulate import (
    default_batching,
    drive_context,
    model_output,
    over_rows,
    pad_voltages,
    plan_steps,
    stack_drives,
)

N_TERMS = 6  # 1, a, l, a², a·l, l²
FORM = ("z_ba = c0 + c1*a + c2*l + c3*a^2 + c4*a*l + c5*l^2, a = (A - A0)/sA, "
        "l = (log10 f - l0)/sl, per direction")


def _basis(a, l):
    return jnp.stack([jnp.ones_like(a), a, l, a * a, a * l, l * l], axis=-1)


class ZbaSurface(eqx.Module):
    """z_ba(A, f, direction) [m]; row 0 forward, row 1 backward."""

    coefficients: Float[Array, "2 6"]  # [m]
    centre: Float[Array, "2 2"]  # (A0 [V], l0 [-]) per direction
    scale: Float[Array, "2 2"]  # (sA [V], sl [-]) per direction

    def __call__(self, amplitude, frequency, backward):
        row = jnp.asarray(backward, float)
        pick = lambda x: x[0] + row * (x[1] - x[0])  # noqa: E731 - same form for all three
        c, centre, scale = pick(self.coefficients), pick(self.centre), pick(self.scale)
        a = (amplitude - centre[0]) / scale[0]
        lf = (jnp.log10(jnp.maximum(frequency, 1e-9)) - centre[1]) / scale[1]
        return jnp.dot(_basis(a, lf), c)


class ZbaSurfaceElastoPlastic(AbstractElastoPlastic):
    """Lu 2015 friction (constant f_ss) with z_ba from a :class:`ZbaSurface` at the
    drive's amplitude, frequency and direction. ``z_ba_forward/backward`` are kept
    for drives without amplitude or frequency (step, sine, unknown)."""

    rho0: Float[Array, ""]
    rho1: Float[Array, ""]
    rho2: Float[Array, ""]
    z_ba_forward: Float[Array, ""]
    z_ba_backward: Float[Array, ""]
    zba_ratio: Float[Array, ""]
    surface: ZbaSurface

    @staticmethod
    def from_friction(friction: ElastoPlastic, surface: ZbaSurface) -> ZbaSurfaceElastoPlastic:
        f = friction
        return ZbaSurfaceElastoPlastic(f.rho0, f.rho1, f.rho2, f.z_ba_forward, f.z_ba_backward,
                                       f.zba_ratio, surface)

    def z_ba(self, drive: DriveContext):
        plain = self.z_ba_forward + drive.backward * (self.z_ba_backward - self.z_ba_forward)
        known = (drive.amplitude > 0) & (drive.frequency > 0)
        return jnp.where(known, self.surface(drive.amplitude, drive.frequency, drive.backward),
                         plain)

    def zss_magnitude(self, xdot, drive):
        return self.z_ba(drive) / self.zba_ratio


# ----------------------------------------------------------------------- points
@dataclass(frozen=True)
class ZbaPoints:
    """Per recording: drive, fitted ``z_ba_m`` [m], ``std_error_m`` [m], ``nrmse`` [-] (a
    percentage in the CSV, ``nrmse_percent``), ``converged`` and ``determined``
    (relative standard error below 2 %)."""

    names: list[str]
    amplitude_V: np.ndarray
    frequency_Hz: np.ndarray
    backward: np.ndarray
    z_ba_m: np.ndarray
    std_error_m: np.ndarray
    nrmse: np.ndarray
    converged: np.ndarray
    determined: np.ndarray

    def to_csv(self) -> str:
        rows = ["recording,amplitude_V,frequency_Hz,direction,z_ba_um,std_error_um,"
                "nrmse_percent,"
                "converged,determined"]
        for i, n in enumerate(self.names):
            rows.append(f"{n},{self.amplitude_V[i]:.10g},{self.frequency_Hz[i]:.10g},"
                        f"{'backward' if self.backward[i] else 'forward'},"
                        f"{self.z_ba_m[i] * 1e6:.8g},{self.std_error_m[i] * 1e6:.3g},"
                        f"{100 * self.nrmse[i]:.4g},{bool(self.converged[i])},"
                        f"{bool(self.determined[i])}")
        return "\n".join(rows) + "\n"


def fit_zba_points(actuator, recordings, *, stepping=None, max_steps: int = 40) -> ZbaPoints:
    """z_ba of each sawtooth recording in one batched LM solve (other parameters fixed).

    Residual per recording: simulated minus measured position with its mean removed
    (one offset per recording), over the peak-to-peak of the measurement.
    """
    recs = [r for r in recordings if r.drive.waveform == "sawtooth"]
    if not recs:
        raise ValueError("no sawtooth recordings: z_ba points need stepping recordings")
    volts, lengths = pad_voltages([r.voltage_V for r in recs])
    meas, _ = pad_voltages([r.position_m for r in recs])
    t_max = volts.shape[1]
    mask = (np.arange(t_max)[None, :] < lengths[:, None]).astype(float)
    scale = np.array([np.ptp(r.position_m) for r in recs])
    dts = np.array([r.dt for r in recs])
    drives = stack_drives([drive_context(r) for r in recs])
    z_start = jax.vmap(actuator.friction.z_ba)(drives)
    plan = plan_steps(actuator, dts, stepping=stepping, samples=int(volts.size))

    def residual(theta, args):
        v, q, m, s, dt, d, z0 = args
        zb = z0 * jnp.exp(theta[0])
        act = eqx.tree_at(lambda a: (a.friction.z_ba_forward, a.friction.z_ba_backward),
                          actuator, (zb, zb))
        diff = (model_output(act, v, dt, d, plan) - q) * m
        diff = diff - m * jnp.sum(diff) / jnp.sum(m)
        return diff / s

    # Imported here: optimistix takes about 0.2 s to import, which every command (the
    # package imports this module) would otherwise pay.
    import optimistix as optx

    solver = optx.LevenbergMarquardt(rtol=1e-7, atol=1e-9)

    def solve_one(args):
        sol = optx.least_squares(residual, solver, jnp.zeros(1), args=args,
                                 max_steps=max_steps, throw=False)
        r = residual(sol.value, args)
        jac = jax.jacfwd(residual)(sol.value, args)[:, 0]
        return sol.value[0], sol.result == optx.RESULTS.successful, r, jac

    args = (jnp.asarray(volts), jnp.asarray(meas), jnp.asarray(mask), jnp.asarray(scale),
            jnp.asarray(dts), drives, z_start)
    # One solve per recording, side by side (vmap) or one after the other (map, the CPU
    # default: a vmapped simulation pays every refined interval of every row).
    batching = default_batching()
    theta, ok, r, jac = jax.jit(
        lambda a: over_rows(lambda *row: solve_one(row), a, batching))(args)
    theta, ok, r, jac = (np.asarray(x) for x in (theta, ok, r, jac))
    z = np.asarray(z_start) * np.exp(theta)
    n = lengths.astype(float)
    sigma2 = np.sum(r**2, axis=1) / np.maximum(n - 2, 1)  # offset and z_ba fitted
    # dr/dθ = z·dr/dz_ba, so se(z_ba) = z·se(θ).
    se = z * np.sqrt(sigma2 / np.maximum(np.sum(jac**2, axis=1), 1e-300))
    nrmse = np.sqrt(np.sum(r**2, axis=1) / n)
    return ZbaPoints([r.name for r in recs],
                     np.array([r.drive.amplitude_V for r in recs], float),
                     np.array([r.drive.frequency_Hz for r in recs], float),
                     np.array([bool(r.drive.is_backward) for r in recs]),
                     z, se, nrmse, ok.astype(bool), ok.astype(bool) & (se < 0.02 * z))


# ---------------------------------------------------------------------- surface
@dataclass(frozen=True)
class SurfaceFit:
    """The fitted :class:`ZbaSurface` and, per direction, its goodness of fit."""

    surface: ZbaSurface
    stats: dict

    def to_json(self) -> str:
        s = self.surface
        out = {"form": FORM, "unit": "m", "directions": {}}
        for row, name in enumerate(("forward", "backward")):
            out["directions"][name] = {
                "coefficients": np.asarray(s.coefficients[row]).tolist(),
                "A0_V": float(s.centre[row, 0]), "sA_V": float(s.scale[row, 0]),
                "l0": float(s.centre[row, 1]), "sl": float(s.scale[row, 1]),
                **self.stats.get(name, {}),
            }
        return json.dumps(out, indent=1) + "\n"

    def save(self, path, *, force: bool = False) -> Path:
        path = Path(path)
        check_output_path(path, force=force)
        atomic_write_text(path, self.to_json())
        return path


def load_zba_surface(path) -> ZbaSurface:
    """Read a surface written by :meth:`SurfaceFit.save`."""
    d = json.loads(Path(path).read_text())["directions"]
    rows = [d["forward"], d["backward"]]
    return ZbaSurface(jnp.asarray([r["coefficients"] for r in rows], float),
                      jnp.asarray([[r["A0_V"], r["l0"]] for r in rows], float),
                      jnp.asarray([[r["sA_V"], r["sl"]] for r in rows], float))


def _design(amplitude, frequency, centre, scale):
    a = (np.asarray(amplitude) - centre[0]) / scale[0]
    lf = (np.log10(np.asarray(frequency)) - centre[1]) / scale[1]
    return np.asarray(_basis(jnp.asarray(a), jnp.asarray(lf)))


MIN_POINTS = 3
"""Fewest determined points a direction needs for a surface: the smallest form fitted,
a line in amplitude or in log10 frequency (2 terms), plus one residual degree of
freedom, so that R² and the leave-one-out error measure something. The full quadratic
(6 terms) needs 7 points at 3 or more amplitudes and 3 or more frequencies."""


def surface_terms(amplitude, frequency) -> np.ndarray:
    """Which of the 6 terms of :data:`FORM` points at these drives (``amplitude`` [V],
    ``frequency`` [Hz]) support: a term needs as many distinct amplitudes (frequencies)
    as its degree in a (l) plus one, and the fit keeps at least one residual degree of
    freedom (higher terms dropped first)."""
    amp, freq = np.asarray(amplitude, float), np.asarray(frequency, float)
    n, n_a, n_f = amp.size, np.unique(amp).size, np.unique(freq).size
    use = np.array([True, n_a >= 2, n_f >= 2, n_a >= 3, n_a >= 2 and n_f >= 2, n_f >= 3])
    if n <= use.sum():
        use[3:] = False
    while n <= use.sum() and use.sum() > 1:
        use[np.flatnonzero(use)[-1]] = False
    return use


def surface_shortfall(amplitude, frequency) -> str | None:
    """Why points at these drives [V], [Hz] cannot carry a surface, or None when they
    can (at least :data:`MIN_POINTS`, at two or more drives)."""
    n = np.asarray(amplitude).size
    need = (f"a surface needs at least {MIN_POINTS} determined points at 2 or more "
            f"amplitudes or frequencies (the full quadratic: {N_TERMS + 1} points at 3 "
            f"amplitudes x 3 frequencies)")
    if n < MIN_POINTS:
        return f"{n} determined point(s); {need}"
    if surface_terms(amplitude, frequency).sum() < 2:
        return f"all {n} determined points are at one drive; {need}"
    return None


NEGATIVE_R2 = ("R² < 0: the surface predicts these points worse than their mean does. "
               "The fit weights each point by 1/standard error², so the most precise "
               "points dominate and the others are missed; judge it by the leave-one-out "
               "RMS, and add points or use a narrower drive range")


def fit_zba_surface(points: ZbaPoints) -> SurfaceFit:
    """Per direction, the quadratic of :data:`FORM` through the determined points,
    weighted by 1/standard error². Terms the points cannot support (fewer distinct
    amplitudes or frequencies than the term's degree needs, or no residual degree of
    freedom left) are dropped (:func:`surface_terms`); a direction with fewer than
    :data:`MIN_POINTS` points, or with all of them at one drive, gets no surface
    (``supported`` False and a ``note`` saying what it needs)."""
    coefs = np.zeros((2, N_TERMS))
    centre = np.zeros((2, 2))
    scale = np.ones((2, 2))
    stats = {}
    for row, name in enumerate(("forward", "backward")):
        sel = (points.backward == bool(row)) & points.determined
        amp, freq = points.amplitude_V[sel], points.frequency_Hz[sel]
        short = surface_shortfall(amp, freq)
        if short is not None:
            stats[name] = {"points": int(sel.sum()), "supported": False, "note": short}
            continue
        z, se = points.z_ba_m[sel], points.std_error_m[sel]
        lf = np.log10(freq)
        centre[row] = [amp.mean(), lf.mean()]
        scale[row] = [max(amp.std(), 1e-9), max(lf.std(), 1e-9)]
        x = _design(amp, freq, centre[row], scale[row])
        use = surface_terms(amp, freq)
        w = 1.0 / np.maximum(se, 1e-15)
        c, *_ = np.linalg.lstsq(x[:, use] * w[:, None], z * w, rcond=None)
        coefs[row, use] = c
        pred = x[:, use] @ c
        resid = z - pred
        # Leave-one-out residuals of a linear fit: r_i / (1 − h_ii).
        xw = x[:, use] * w[:, None]
        hat = np.einsum("ij,ji->i", xw, np.linalg.pinv(xw))
        loo = resid / np.maximum(1 - hat, 1e-9)
        stats[name] = {
            "points": int(sel.sum()), "terms": int(use.sum()),
            "amplitude_range_V": [float(amp.min()), float(amp.max())],
            "frequency_range_Hz": [float(freq.min()), float(freq.max())],
            "rms_rel": float(np.sqrt(np.mean((resid / z) ** 2))),
            "loo_rms_rel": float(np.sqrt(np.mean((loo / z) ** 2))),
            "r2": float(1 - np.sum(resid**2) / max(np.sum((z - z.mean()) ** 2), 1e-300)),
            "max_abs_rel": float(np.max(np.abs(resid / z))),
            "excluded_undetermined": int(np.sum((points.backward == bool(row))
                                                & ~points.determined)),
            "supported": True,
        }
        if stats[name]["r2"] < 0:
            stats[name]["r2_note"] = NEGATIVE_R2
    return SurfaceFit(ZbaSurface(jnp.asarray(coefs), jnp.asarray(centre), jnp.asarray(scale)),
                      stats)


def surface_supports(fit: SurfaceFit, amplitude, frequency, backward) -> bool:
    """True when (amplitude, frequency) lies inside the fitted ranges of its direction."""
    st = fit.stats.get("backward" if backward else "forward", {})
    if not st.get("supported"):
        return False
    (a0, a1), (f0, f1) = st["amplitude_range_V"], st["frequency_range_Hz"]
    return a0 <= amplitude <= a1 and f0 <= frequency <= f1


def support_interval(amplitude, frequency, at_frequency: float) -> tuple[float, float] | None:
    """Amplitudes [V] at ``at_frequency`` [Hz] that lie in the convex hull of the points
    (``amplitude`` [V], log10 ``frequency`` [Hz]): where a surface fitted to those
    points interpolates rather than extrapolates. ``(lo, hi)``, or None when the
    frequency misses the hull. Points on one line (one frequency, or one amplitude)
    make a degenerate hull: the segment they span."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.unique(np.column_stack([np.asarray(amplitude, float),
                                     np.log10(np.asarray(frequency, float))]), axis=0)
    lq = float(np.log10(at_frequency))
    tol = 1e-9
    if pts.shape[0] == 0:
        return None
    try:
        eqs = ConvexHull(pts).equations  # rows (n_a, n_l, c): n·x + c ≤ 0 inside
    except (QhullError, ValueError):
        # A point or a segment: the part of it at this frequency.
        l_lo, l_hi = pts[:, 1].min(), pts[:, 1].max()
        if not l_lo - tol <= lq <= l_hi + tol:
            return None
        if l_hi - l_lo <= tol:
            return float(pts[:, 0].min()), float(pts[:, 0].max())
        i, j = np.argmin(pts[:, 1]), np.argmax(pts[:, 1])
        w = (lq - pts[i, 1]) / (pts[j, 1] - pts[i, 1])
        a = float(pts[i, 0] + w * (pts[j, 0] - pts[i, 0]))
        return a, a
    lo, hi = -np.inf, np.inf
    for n_a, n_l, c in eqs:
        rhs = -(c + n_l * lq)
        if abs(n_a) <= tol:
            if rhs < -tol:
                return None
        elif n_a > 0:
            hi = min(hi, rhs / n_a)
        else:
            lo = max(lo, rhs / n_a)
    return (float(lo), float(hi)) if lo <= hi + tol else None


def plot_zba_surface(points: ZbaPoints, fit: SurfaceFit, path=None):
    """z_ba against amplitude, one panel (and y axis, plain µm with no offset) per
    direction, one colour per frequency: fitted points (markers with ±2 standard
    errors; x: not determined) and the surface (lines), drawn only where it is
    supported: at each frequency, over the amplitudes inside the convex hull of that
    direction's determined points (:func:`support_interval`).

    A direction whose determined points are consistent with one constant (χ² of the
    points about their 1/SE²-weighted mean within the 95 % quantile of χ²(n − 1)) is
    flat within its uncertainty: its panel says so, with ``z_ba = X ± Y µm`` (the
    weighted mean and its standard error, scaled by √(χ²/(n − 1)) when that exceeds
    1), and draws that constant with its ±2 SE band instead of the surface, whose
    shape would then be noise drawn as structure."""
    from scipy.stats import chi2

    from ..plots import colormap, subplots

    def flat_level(z, se):
        """(mean, its SE, χ², dof) [m] when ``z`` ± ``se`` [m] are consistent with a
        constant, else None."""
        if z.size < 2 or not np.all(np.isfinite(se) & (se > 0)):
            return None
        w = 1.0 / se**2
        mean = float(np.sum(w * z) / np.sum(w))
        c2, dof = float(np.sum(((z - mean) / se) ** 2)), z.size - 1
        if c2 > chi2.ppf(0.95, dof):
            return None
        return mean, float(np.sqrt(1.0 / np.sum(w)) * max(1.0, np.sqrt(c2 / dof))), c2, dof

    def plus_minus(x_um, y_um):
        digits = max(0, 1 - int(np.floor(np.log10(y_um)))) if y_um > 0 else 4
        return f"{x_um:.{digits}f} ± {y_um:.{digits}f} µm"

    fig, axes = subplots(1, 2, figsize=(11, 4.6))
    freqs = np.unique(points.frequency_Hz)
    colours = colormap("viridis")(np.linspace(0, 0.85, max(freqs.size, 1)))
    for ax, back in zip(axes, (False, True), strict=True):
        name = "backward" if back else "forward"
        used = (points.backward == back) & points.determined
        st = fit.stats.get(name, {})
        flat = (flat_level(points.z_ba_m[used], points.std_error_m[used])
                if st.get("supported") else None)
        spread = []  # the surface's values over its support [µm]
        for colour, f in zip(colours, freqs, strict=True):
            sel = (points.frequency_Hz == f) & (points.backward == back)
            if np.any(sel):
                ax.errorbar(points.amplitude_V[sel], points.z_ba_m[sel] * 1e6,
                            yerr=2 * points.std_error_m[sel] * 1e6, fmt="o", color=colour,
                            ms=4, label=f"{f:g} Hz (±2 SE)")
                bad = sel & ~points.determined
                if np.any(bad):
                    ax.plot(points.amplitude_V[bad], points.z_ba_m[bad] * 1e6, "x",
                            color="red", label="not determined")
            span = (support_interval(points.amplitude_V[used], points.frequency_Hz[used], f)
                    if st.get("supported") else None)
            if span is not None and span[1] > span[0]:
                a = np.linspace(span[0], span[1], 60)
                z = np.asarray(jax.vmap(lambda amp, f=f, b=back: fit.surface(amp, f, float(b)))(
                    jnp.asarray(a))) * 1e6
                spread.extend(z.tolist())
                if flat is None:
                    ax.plot(a, z, "-", color=colour, lw=1,
                            label=None if spread[:-a.size] else "surface (its frequency's colour)")
        if flat is not None:
            mean_um, se_um, c2, dof = flat[0] * 1e6, flat[1] * 1e6, flat[2], flat[3]
            ax.axhspan(mean_um - 2 * se_um, mean_um + 2 * se_um, color="0.6", alpha=0.3,
                       lw=0, label="±2 SE of the constant")
            ax.axhline(mean_um, color="k", ls="--", lw=1,
                       label="constant (weighted mean of the points)")
            span_nm = (f"; surface varies {1e3 * np.ptp(spread):.2g} nm: noise, not drawn"
                       if spread else "")
            ax.set_title(f"{name}: flat within uncertainty\nz_ba = "
                         f"{plus_minus(mean_um, se_um)}\n(χ² = {c2:.3g} for {dof} dof about "
                         f"it{span_nm})", fontsize=8)
        elif st.get("supported"):
            ax.set_title(f"{name}: surface RMS {100 * st['rms_rel']:.2g} %, leave-one-out "
                         f"{100 * st['loo_rms_rel']:.2g} %", fontsize=9)
        else:
            ax.set_title(f"{name}: no surface", fontsize=9)
        ax.ticklabel_format(axis="y", style="plain", useOffset=False)
        ax.set_xlabel("amplitude [V]")
        ax.set_ylabel(f"z_ba, {name} drive [µm]")
        ax.grid(alpha=0.25)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="best", framealpha=0.85)
    fig.suptitle("z_ba per recording (markers, ±2 SE) and the surface (lines, only within "
                 "the points' convex hull)", fontsize=10)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=130)
    return fig


def with_zba_surface(actuator, surface: ZbaSurface):
    """``actuator`` with its elasto-plastic friction reading z_ba from ``surface``."""
    f = actuator.friction
    if not isinstance(f, ElastoPlastic | ZbaSurfaceElastoPlastic):
        raise ValueError("a z_ba surface applies to the paper's elasto-plastic law only; "
                         f"the parameters use {type(f).__name__}")
    if isinstance(f, ZbaSurfaceElastoPlastic):
        return eqx.tree_at(lambda a: a.friction.surface, actuator, surface)
    return eqx.tree_at(lambda a: a.friction, actuator,
                       ZbaSurfaceElastoPlastic.from_friction(f, surface))

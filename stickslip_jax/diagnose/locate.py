"""Where simulation and recordings differ: by regime, in time, in frequency, vs noise.

For each recording the residual ``e = measured − simulated`` (best constant offset
removed) is compared with the sensor noise estimated from the recording itself
(:func:`stickslip_jax.noise.noise_sigma`: period-to-period repeatability, or third
differences), and tested for structure:

- ``chi2``: mean of (e/σ)², 1 for pure noise;
- whiteness: Ljung-Box Q over lags 1..20 of e, χ²(20) under white noise;
- correlation with the drive: Pearson correlation of e with the voltage and with its
  rate, as z-scores (√n·r, standard normal under independence);
- in time, by phase of the period: the share of the residual's excess energy in the
  ``edge`` (the abrupt voltage change ±2 samples), the ``ringing`` after it (1 ms),
  the ``ramp`` (the rest), and the ``drift`` (the part of e below a quarter of the
  drive frequency, or below 20 Hz for steps);
- in frequency: the residual PSD over 1/3-octave bands against the white noise level
  σ²·dt, and the band with the largest excess; peaks shared by several recordings are
  hints for an unmodelled resonance (a periodic drive's harmonics counted only by how
  far each stands above its neighbours: :func:`harmonic_prominence`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..identify.report import classify_regime
from ..identify.residuals import periodogram_psd
from ..noise import noise_sigma
from ..significance import SIGNIFICANCE_Z

LJUNG_BOX_LAGS = 20
STRUCTURE_CHI2 = 1.10
"""A recording is flagged when its mean (e/σ)² exceeds this (σ is estimated to a few
per cent) or its residual fails the whiteness test at p < 1e-3."""


@dataclass
class RecordingResidual:
    """Residual statistics of one recording (see the module docstring)."""

    recording: str
    regime: str
    amplitude_V: float
    frequency_Hz: float
    nrmse: float
    noise_m: float
    rms_residual_m: float
    chi2: float
    ljung_box_p: float
    z_voltage: float
    z_rate: float
    phase_share: dict
    peak_window_s: tuple[float, float]
    band_Hz: tuple[float, float]
    band_excess: float
    flagged: bool

    def as_dict(self) -> dict:
        d = asdict(self)
        d["peak_window_s"] = list(self.peak_window_s)
        d["band_Hz"] = list(self.band_Hz)
        return d


def residual_of(rec, q_sim) -> np.ndarray:
    """``measured − simulated`` [m] with the best constant offset removed."""
    e = np.asarray(rec.position_m, dtype=float) - np.asarray(q_sim[: rec.n], dtype=float)
    return e - e.mean()


def ljung_box(e: np.ndarray, lags: int = LJUNG_BOX_LAGS) -> tuple[float, float]:
    """Ljung-Box statistic over ``lags`` and its χ² p-value (small: not white)."""
    x = e - e.mean()
    n = x.size
    denom = float(np.dot(x, x)) or 1.0
    rho = np.array([np.dot(x[k:], x[:-k]) / denom for k in range(1, lags + 1)])
    q = n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, lags + 1)))
    # χ²'s survival function from scipy.special, which scipy.stats.chi2.sf evaluates
    # (the same bits): scipy.stats takes 0.5-0.7 s more to import, in every diagnosis.
    # Imported here, so that commands without a diagnosis do not import it.
    from scipy.special import chdtrc

    return float(q), float(chdtrc(lags, q))


def _z_corr(e, x) -> float:
    x = x - x.mean()
    if np.allclose(x, 0):
        return 0.0
    r = np.dot(e - e.mean(), x) / (np.linalg.norm(e - e.mean()) * np.linalg.norm(x) + 1e-300)
    return float(r * np.sqrt(e.size))


def phase_segments(rec) -> np.ndarray:
    """Label of each sample: 0 ramp, 1 edge, 2 ringing (see the module docstring)."""
    u = np.asarray(rec.voltage_V, dtype=float)
    labels = np.zeros(rec.n, dtype=int)
    du = np.abs(np.diff(u))
    if du.size == 0:
        return labels
    typical = np.median(du) + 1e-12
    edges = np.flatnonzero(du > max(10 * typical, 0.2 * np.ptp(u))) + 1
    ring = int(round(1e-3 * rec.sample_rate_Hz))
    if rec.drive.frequency_Hz:
        ring = min(ring, int(rec.sample_rate_Hz / rec.drive.frequency_Hz / 3))
    for k in edges:
        labels[k + 3: k + 3 + ring] = np.where(labels[k + 3: k + 3 + ring] == 1, 1, 2)
        labels[max(k - 1, 0): k + 3] = 1
    return labels


def _drift_share(e, t) -> float:
    """Share of the residual's energy in a cubic trend over the whole trace."""
    x = (t - t[0]) / max(t[-1] - t[0], 1e-300) * 2 - 1
    trend = np.polynomial.polynomial.polyval(x, np.polynomial.polynomial.polyfit(x, e, 3))
    return float(np.sum(trend**2) / (np.sum(e**2) + 1e-300))


def third_octave_bands(f_lo: float, f_hi: float) -> np.ndarray:
    """Edges [Hz] of 1/3-octave bands covering ``f_lo``..``f_hi``."""
    n = int(np.ceil(3 * np.log2(f_hi / f_lo)))
    return f_lo * 2 ** (np.arange(n + 1) / 3)


def band_excess(e, dt, sigma) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual PSD over noise level per 1/3-octave band: ``(lo, hi, ratio)`` arrays."""
    f, psd = periodogram_psd(e, dt, np)
    edges = third_octave_bands(max(f[1], 10.0), 0.5 / dt)
    level = sigma**2 * dt
    lo, hi, ratio = [], [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        sel = (f >= a) & (f < b)
        if np.any(sel):
            lo.append(a)
            hi.append(b)
            ratio.append(float(np.mean(psd[sel]) / level))
    return np.array(lo), np.array(hi), np.array(ratio)


def analyse_recording(rec, q_sim, sigma: float | None = None) -> RecordingResidual:
    """Statistics of one recording's residual (``sigma`` [m]: noise, estimated if None)."""
    e = residual_of(rec, q_sim)
    sigma = float(sigma if sigma is not None else noise_sigma(rec))
    dt = rec.dt
    chi2 = float(np.mean(e**2) / sigma**2)
    _, p_lb = ljung_box(e)
    u = np.asarray(rec.voltage_V, dtype=float)
    z_u = _z_corr(e, u)
    z_du = _z_corr(e, np.gradient(u))
    labels = phase_segments(rec)
    excess = np.maximum(e**2 - sigma**2, 0.0)
    total = excess.sum() + 1e-300
    share = {name: float(excess[labels == k].sum() / total)
             for k, name in enumerate(("ramp", "edge", "ringing"))}
    share["drift"] = _drift_share(e, rec.time_s)
    # Window (a tenth of the trace) holding the most excess energy.
    w = max(rec.n // 10, 1)
    run = np.convolve(excess, np.ones(w), mode="valid")
    k = int(np.argmax(run))
    window = (float(rec.time_s[k]), float(rec.time_s[min(k + w - 1, rec.n - 1)]))
    lo, hi, ratio = band_excess(e, dt, sigma)
    j = int(np.argmax(ratio)) if ratio.size else 0
    band = (float(lo[j]), float(hi[j])) if ratio.size else (0.0, 0.0)
    nrmse = float(np.sqrt(np.mean(e**2)) / (np.ptp(rec.position_m) or 1.0))
    flagged = bool(chi2 > STRUCTURE_CHI2 or p_lb < 1e-3)
    return RecordingResidual(
        rec.name, classify_regime(rec), float(rec.drive.amplitude_V or 0.0),
        float(rec.drive.frequency_Hz or 0.0), nrmse, sigma, float(np.sqrt(np.mean(e**2))),
        chi2, p_lb, z_u, z_du, share, window, band,
        float(ratio[j]) if ratio.size else 0.0, flagged)


def mismatch_entries(analyses: list[RecordingResidual]) -> list[dict]:
    """The ``mismatch`` list of ``diagnosis.json``: one entry per flagged recording,
    worst first: ``{recording, regime, time_s, band_Hz, statistic}``."""
    out = []
    for a in sorted(analyses, key=lambda a: -a.chi2):
        if not a.flagged:
            continue
        phase = max(a.phase_share, key=a.phase_share.get)
        out.append({
            "recording": a.recording, "regime": a.regime,
            "time_s": list(a.peak_window_s), "band_Hz": list(a.band_Hz),
            "statistic": {"chi2_per_sample": a.chi2, "ljung_box_p": a.ljung_box_p,
                          "z_voltage": a.z_voltage, "z_voltage_rate": a.z_rate,
                          "band_psd_over_noise": a.band_excess, "dominant_phase": phase,
                          "phase_share": a.phase_share},
        })
    return out



PEAK_MIN_LEVEL = 5.0
"""The default least mean level of the residual PSD over its noise level (1 for white
noise) at a residual peak (:func:`residual_peaks`): a factor 5, which an average of
the 17 recordings' periodograms of pure noise (each bin χ²(2)/2: mean 1, standard
deviation 1) reaches at some 16 of its standard errors above its mean."""

PEAK_OCTAVES = 0.5
"""Half an octave: how far apart two residual peaks must be (:func:`residual_peaks`),
and how far either side of a drive harmonic its envelope's harmonics lie
(:func:`harmonic_prominence`); narrower than a decade so that the envelope's own slope
changes little within it."""


def harmonic_bins(f: np.ndarray, drive_Hz: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """The orders ``k`` (1, 2, ... up to the last frequency of ``f``) of a periodic
    drive's harmonics ``k·drive_Hz`` [Hz] and, for each, the indices of the bins of the
    evenly spaced ``f`` [Hz] within one bin of it: a harmonic of a recording of whole
    periods falls on a bin, and one bin either side holds the Hann window's leakage.
    Each harmonic below the last frequency has at least its nearest bin."""
    df = f[1] - f[0]
    orders = np.arange(1, int(f[-1] // drive_Hz) + 1)
    return orders, [np.flatnonzero(np.abs(f - k * drive_Hz) <= 1.01 * df) for k in orders]


def harmonic_prominence(f: np.ndarray, level: np.ndarray, drive_Hz: float | None, *,
                        noise_z: float = SIGNIFICANCE_Z,
                        octaves: float = PEAK_OCTAVES) -> np.ndarray:
    """``level`` (a residual PSD over its noise level, 1 for white noise, at the
    frequencies ``f`` [Hz] of one recording) with each harmonic ``k·drive_Hz`` of a
    periodic drive (the bins within one bin of it) counted only by its prominence over
    the harmonics around it: ``1 + max(level − L − z·sqrt(2L), 0)``. ``L``, the
    envelope, is the geometric mean of the median peak of the harmonics below it and of
    those above it, each side within ``octaves`` (:data:`PEAK_OCTAVES`); ``z·sqrt(2L)``
    is the noise's scatter of a harmonic at that level: ``z = noise_z`` standard
    deviations of it (``sqrt(2E)`` in noise units at an envelope ``E``, the cross term
    of a harmonic with the noise), the diagnosis's
    :attr:`~.policy.Policy.significance_z`.
    Where a side has no harmonic, the noise level 1. ``drive_Hz`` None or 0 (a step,
    no periodic drive): ``level`` unchanged.

    Whatever the model gets wrong of a periodic response (a friction level, a stroke,
    a damping: the period's shape) shows at the drive's harmonics, most at the lowest
    ones, with an envelope that falls smoothly with the order; such peaks say nothing of
    a resonance, and taken for one they start a mode's probe at the drive frequency (a
    saturating viscous force, 8x the noise, put the largest residual peaks at the
    500 Hz drive's first two harmonics, and a mode fitted there took half of the
    excess). A resonance raises the harmonics near it above the envelope on both sides:
    that excess is kept. A smooth (power-law) envelope is its own geometric mean of
    either side, so it leaves little; a harmonic with no neighbour on one side within
    half an octave (a fast drive's first three) cannot be told from the envelope's
    edge and counts as noise. The harmonics of a recording of whole periods fall on
    its bins (:func:`harmonic_bins`)."""
    out = np.array(level, dtype=float)
    if not drive_Hz or f.size < 2:
        return out
    orders, bins = harmonic_bins(f, drive_Hz)
    peak = np.array([level[b].max() for b in bins])  # (each holds its nearest bin)
    span = 2.0**octaves
    for k, b in zip(orders, bins, strict=True):
        below = peak[(orders < k) & (orders >= k / span)]
        above = peak[(orders > k) & (orders <= k * span)]
        if below.size and above.size:
            envelope = np.sqrt(np.median(below) * np.median(above))
            # The noise moves a harmonic of level E by about sqrt(2E) (its cross term
            # with the harmonic): only what stands above that counts.
            spread = noise_z * np.sqrt(2.0 * envelope)
            out[b] = 1.0 + np.maximum(level[b] - envelope - spread, 0.0)
        else:
            out[b] = 1.0
    return out


def level_on_grid(f: np.ndarray, level: np.ndarray, drive_Hz: float | None,
                  grid: np.ndarray) -> np.ndarray:
    """``level`` (at the frequencies ``f`` [Hz] of one recording) on the increasing
    ``grid`` [Hz]: interpolated, except in the grid's cells (edges at the geometric
    midpoints) that hold a harmonic ``k·drive_Hz`` of a periodic drive, where it is the
    largest level over the bins within one bin of those harmonics.

    A harmonic of a recording of whole periods is one to three bins wide: sampled by
    interpolation at a grid point beside it, it would count by its leakage or not at
    all, so a resonance that lifts a 50 Hz drive's harmonics would show in every
    recording's spectrum and on no grid point (with 17 recordings, a mode 0.67x the
    noise in the data: a grid mean of 5.75 raw, 2-4 once counted by prominence, below
    the threshold). Binned, each harmonic counts once, in its cell. ``drive_Hz`` None
    or 0: interpolated everywhere. A spectrum of fewer than two frequencies (no
    level above 0 Hz): 0 everywhere."""
    if f.size < 2:
        return np.zeros(grid.size)
    out = np.interp(grid, f[1:], level[1:], left=0.0, right=0.0)
    if not drive_Hz:
        return out
    edges = np.sqrt(grid[1:] * grid[:-1])
    half_cell = np.sqrt(grid[1] / grid[0])
    binned = np.full(grid.size, -np.inf)
    for k, bins in zip(*harmonic_bins(f, drive_Hz), strict=True):
        fk = k * drive_Hz
        if not grid[0] / half_cell <= fk <= grid[-1] * half_cell:
            continue
        cell = int(np.searchsorted(edges, fk))
        binned[cell] = max(binned[cell], level[bins].max())
    return np.where(np.isfinite(binned), binned, out)


def residual_peaks(recs, q_sims, sigmas, *, band=(300.0, 10_000.0), n_peaks: int = 2,
                   noise_z: float = SIGNIFICANCE_Z, min_level: float = PEAK_MIN_LEVEL,
                   octaves: float = PEAK_OCTAVES):
    """Frequencies [Hz] where the residual PSDs, averaged over recordings in units of
    their noise level, peak inside ``band``: candidates for an unmodelled resonance.
    Peaks are at least ``min_level`` over the noise and ``octaves`` apart. A periodic
    drive's harmonics count by their prominence over the neighbouring harmonics
    (:func:`harmonic_prominence`, ``noise_z``), each in the grid cell that holds it
    (:func:`level_on_grid`)."""
    grid = np.geomspace(band[0], band[1], 160)
    total = np.zeros_like(grid)
    for rec, q, s in zip(recs, q_sims, sigmas, strict=True):
        f, psd = periodogram_psd(residual_of(rec, q), rec.dt, np)
        periodic = rec.drive.frequency_Hz if rec.drive.waveform != "step" else None
        level = harmonic_prominence(f, psd / (s**2 * rec.dt), periodic, noise_z=noise_z,
                                    octaves=octaves)
        total += level_on_grid(f, level, periodic, grid)
    total /= max(len(recs), 1)
    peaks = []
    for i in np.argsort(-total):
        if total[i] < min_level or len(peaks) >= n_peaks:
            break
        if i in (0, grid.size - 1) or total[i] < max(total[i - 1], total[i + 1]):
            continue
        if all(abs(np.log2(grid[i] / p)) > octaves for p in peaks):
            peaks.append(float(grid[i]))
    return peaks

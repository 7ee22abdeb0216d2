"""Figures of an identification: overlays, spectra, hysteresis loop, step lengths.

Each function takes measured recordings and the matching simulated outputs [m] and
writes one image (or returns the figure when ``path`` is None).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import colormap, legend_on_labelled, save_figure, subplots
from .dataset import mean_step_length
from .initial import stroke_along
from .residuals import _psd


def _finish(fig, path):
    return save_figure(fig, path) if path is not None else fig


def display_psd(x, dt: float, *, band=(20.0, 12_500.0), period_samples: float | None = None,
                per_octave: int = 12):
    """A PSD [m²/Hz] to look at, averaged over log-spaced bands.

    ``x`` [m] sampled every ``dt`` [s]. A periodic drive (``period_samples`` given, ≥ 2)
    gets a Welch estimate (``scipy.signal.welch``: Hann window, half-overlapping
    segments of a whole number of periods, about half the trace each, linear trend of
    each removed), so that the harmonics fall on bins. A transient (a step response)
    gets one Hann periodogram of the whole trace, as the identification's spectral
    term does (segments would cut the transient and the window would hide it).
    Then the mean over bands of 1/``per_octave`` octave within ``band`` [Hz]: a
    periodic drive's comb of harmonics fills the upper decades of a log-frequency axis
    solid, and its band means show the envelope instead (power per band over the band
    width, so a white floor keeps its level). Bands holding no bin are left out.
    Returns ``(band centres [Hz], PSD [m²/Hz])``.
    """
    x = np.asarray(x, dtype=float)
    if period_samples is not None and period_samples >= 2 and x.size >= 2 * period_samples:
        from scipy.signal import welch

        periods = max(int((x.size // 2) // period_samples), 1)
        seg = int(round(periods * period_samples))
        f, psd = welch(x, fs=1.0 / dt, window="hann", nperseg=seg, noverlap=seg // 2,
                       detrend="linear")
    else:
        f, psd = _psd(x, dt, np)
    n_bands = int(np.ceil(per_octave * np.log2(band[1] / band[0])))
    edges = np.geomspace(band[0], band[1], n_bands + 1)
    centres, levels = [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (f >= lo) & (f < hi)
        if np.any(sel):
            centres.append(np.sqrt(lo * hi))
            levels.append(float(np.mean(psd[sel])))
    return np.array(centres), np.array(levels)


def plot_psd_overlay(recs, q_sims, *, title: str, path: str | Path | None = None,
                     band=(20.0, 12_500.0)):
    """Measured vs simulated PSD [m²/Hz] of each recording, one panel per recording
    (:func:`display_psd`: Welch average for periodic drives, 1/12-octave bands)."""
    fig, axes = subplots(1, len(recs), figsize=(5.2 * len(recs), 3.6), squeeze=False)
    for ax, rec, q in zip(axes[0], recs, q_sims, strict=True):
        f0 = rec.drive.frequency_Hz if rec.drive.waveform in ("sawtooth", "sine") else None
        per = rec.sample_rate_Hz / f0 if f0 else None
        f, p_m = display_psd(rec.position_m, rec.dt, band=band, period_samples=per)
        _, p_s = display_psd(np.asarray(q), rec.dt, band=band, period_samples=per)
        ax.loglog(f, p_m, color="0.55", lw=2.6, alpha=0.8, label="measured")
        ax.loglog(f, p_s, color="tab:blue", lw=0.9, ls=(0, (4, 2)), label="simulated")
        ax.set_xlabel("frequency [Hz]")
        ax.set_title(rec.name, fontsize=9)
        ax.grid(True, which="both", alpha=0.25)
    axes[0][0].set_ylabel("PSD of q [m²/Hz]")
    axes[0][0].legend(fontsize=8)
    how = "Welch average, " if any(r.drive.waveform in ("sawtooth", "sine") for r in recs) else ""
    fig.suptitle(f"{title}; {how}mean over 1/12-octave bands", fontsize=10)
    fig.tight_layout()
    return _finish(fig, path)


def plot_hysteresis_loop(actuator, rec, q_sim, *, path: str | Path | None = None):
    """Hysteresis of a slow drive: measured and simulated q/2 against U, with the
    model's free stroke Γ(U) (in stick, q = 2·Γ)."""
    u = np.asarray(rec.voltage_V)
    gamma = stroke_along(actuator, u)
    fig, ax = subplots(figsize=(5.2, 4.2))
    half_m = np.asarray(rec.position_m) / 2
    half_s = np.asarray(q_sim) / 2
    shift = np.mean(half_s - half_m)  # the interferometer zero is arbitrary
    ax.plot(u, (half_m + shift) * 1e6, color="0.55", lw=2.6, alpha=0.8, label="measured q/2")
    ax.plot(u, half_s * 1e6, color="tab:blue", lw=0.9, ls=(0, (4, 2)), label="simulated q/2")
    ax.plot(u, gamma * 1e6, color="tab:orange", lw=0.9, label="model Γ(U) (PI)")
    ax.set_xlabel("U [V]")
    ax.set_ylabel("displacement [µm]")
    ax.set_title(f"hysteresis loop: {rec.name}", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.25)
    return _finish(fig, path)


def plot_step_lengths(recs, q_sims, *, path: str | Path | None = None):
    """Step length per period against amplitude, forward and backward, measured
    (markers) and simulated (lines), one colour per frequency."""
    fig, axes = subplots(1, 2, figsize=(9.5, 3.8), sharey=False)
    saw = [(r, q) for r, q in zip(recs, q_sims, strict=True) if r.drive.waveform == "sawtooth"]
    freqs = sorted({r.drive.frequency_Hz for r, _ in saw})
    colours = colormap("viridis")(np.linspace(0.0, 0.85, max(len(freqs), 1)))
    for ax, backward in zip(axes, (False, True), strict=True):
        for colour, f in zip(colours, freqs, strict=True):
            sel = sorted([(r.drive.amplitude_V, mean_step_length(r, r.position_m),
                           mean_step_length(r, q)) for r, q in saw
                          if r.drive.frequency_Hz == f and r.drive.is_backward == backward])
            if not sel:
                continue
            a, meas, sim = (np.array(x) for x in zip(*sel, strict=True))
            ax.plot(a, meas * 1e9, "o", color=colour, label=f"{f:g} Hz measured")
            ax.plot(a, sim * 1e9, "-", color=colour, label=f"{f:g} Hz simulated")
        ax.set_title("backward" if backward else "forward", fontsize=10)
        ax.set_xlabel("amplitude [V]")
        ax.grid(alpha=0.25)
    axes[0].set_ylabel("step per period [nm] (+x)")
    axes[1].set_ylabel("step per period [nm] (negative: towards −x)")
    legend_on_labelled(axes, fontsize=7, ncol=1)   # a forward-only set has no backward panel
    fig.tight_layout()
    return _finish(fig, path)

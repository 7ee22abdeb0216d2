"""Figures of an identification: overlays, spectra, hysteresis loop, step lengths.

Each function takes measured recordings and the matching simulated outputs [m] and
writes one image (or returns the figure when ``path`` is None).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import colormap, save_figure, subplots
from .dataset import period_ends, step_lengths
from .initial import stroke_along
from .residuals import log_psd


def _finish(fig, path):
    return save_figure(fig, path) if path is not None else fig


def plot_psd_overlay(recs, q_sims, *, title: str, path: str | Path | None = None,
                     band=(20.0, 12_500.0)):
    """Measured vs simulated PSD [m²/Hz] of each recording, one panel per recording."""
    fig, axes = subplots(1, len(recs), figsize=(5.2 * len(recs), 3.6), squeeze=False)
    for ax, rec, q in zip(axes[0], recs, q_sims, strict=True):
        f, lp_m = log_psd(rec.position_m, rec.dt, band=band, xp=np)
        _, lp_s = log_psd(q, rec.dt, band=band, xp=np)
        ax.loglog(f, 10**lp_m, color="k", lw=0.8, label="measured")
        ax.loglog(f, 10**lp_s, color="tab:blue", lw=0.9, label="simulated")
        ax.set_xlabel("frequency [Hz]")
        ax.set_title(rec.name, fontsize=9)
        ax.grid(True, which="both", alpha=0.25)
    axes[0][0].set_ylabel("PSD of q [m²/Hz]")
    axes[0][0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
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
    ax.plot(u, (half_m + shift) * 1e6, color="k", lw=0.8, label="measured q/2")
    ax.plot(u, half_s * 1e6, color="tab:blue", lw=0.9, ls="--", label="simulated q/2")
    ax.plot(u, gamma * 1e6, color="tab:orange", lw=0.9, label="model Γ(U) (PI)")
    ax.set_xlabel("U [V]")
    ax.set_ylabel("displacement [µm]")
    ax.set_title(f"hysteresis loop: {rec.name}", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.25)
    return _finish(fig, path)


def mean_step_length(rec, q) -> float:
    """Mean phase-locked step per sawtooth period [m] (period end to period end, the
    start-up period left out); NaN when the recording has fewer than two whole
    periods."""
    steps = step_lengths(q, period_ends(rec))
    return float(np.mean(steps)) if steps.size else float("nan")


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
    axes[0].set_ylabel("step per period [nm]")
    axes[1].legend(fontsize=7, ncol=1)
    fig.tight_layout()
    return _finish(fig, path)

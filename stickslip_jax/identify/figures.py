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
from .residuals import periodogram_psd


def _finish(fig, path):
    return save_figure(fig, path) if path is not None else fig


def welch_psd(x, dt: float, seg: int) -> tuple[np.ndarray, np.ndarray]:
    """Welch's one-sided PSD of ``x`` sampled every ``dt`` [s]: segments of ``seg``
    samples overlapping by half (``seg // 2``), the least-squares line removed from
    each, a periodic Hann window, the periodograms averaged and scaled to a density
    [units²/Hz] (``scipy.signal.welch``'s defaults with ``window="hann"``,
    ``detrend="linear"``, to rounding; written here because importing scipy.signal
    costs about 0.7 s, a twentieth of an identification). Returns
    ``(frequencies [Hz], PSD)``."""
    x = np.asarray(x, dtype=float)
    step = seg - seg // 2
    starts = np.arange(0, x.size - seg + 1, step)
    segments = x[starts[:, None] + np.arange(seg)]
    t = np.arange(seg) - (seg - 1) / 2.0   # centred: the line's two terms decouple
    slope = segments @ t / (t @ t)
    segments = segments - segments.mean(axis=1, keepdims=True) - slope[:, None] * t
    window = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(seg) / seg)
    power = np.abs(np.fft.rfft(segments * window, axis=1)) ** 2
    psd = power.mean(axis=0) * dt / np.sum(window**2)
    psd[1:seg // 2 + (seg % 2)] *= 2.0   # one-sided: every bin but DC and an even Nyquist
    return np.fft.rfftfreq(seg, dt), psd


def display_psd(x, dt: float, *, band=(20.0, 12_500.0), period_samples: float | None = None,
                per_octave: int = 12):
    """A PSD [m²/Hz] to look at, averaged over log-spaced bands.

    ``x`` [m] sampled every ``dt`` [s]. A periodic drive (``period_samples`` given, ≥ 2)
    gets a Welch estimate (:func:`welch_psd`: Hann window, half-overlapping
    segments of a whole number of periods, about half the trace each, linear trend of
    each removed), so that the harmonics fall on bins. A transient (a step response)
    gets one Hann periodogram of the whole trace, as the identification's spectral
    term does (segments would cut the transient and the window would hide it), made
    one-sided like Welch's (twice :func:`~.residuals.periodogram_psd`'s level), so that white
    noise of std σ sits at ``2σ²·dt`` in both.
    Then the mean over bands of 1/``per_octave`` octave within ``band`` [Hz]: a
    periodic drive's comb of harmonics fills the upper decades of a log-frequency axis
    solid, and its band means show the envelope instead (power per band over the band
    width, so a white floor keeps its level). Bands holding no bin are left out.
    Returns ``(band centres [Hz], PSD [m²/Hz])``.
    """
    x = np.asarray(x, dtype=float)
    if period_samples is not None and period_samples >= 2 and x.size >= 2 * period_samples:
        periods = max(int((x.size // 2) // period_samples), 1)
        seg = int(round(periods * period_samples))
        f, psd = welch_psd(x, dt, seg)
    else:
        f, psd = periodogram_psd(x, dt, np)
        psd = 2.0 * psd  # one-sided, as Welch's (DC and Nyquist lie outside any band)
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
                     band=(20.0, 12_500.0), noise_m=None):
    """Measured vs simulated one-sided PSD [m²/Hz] of each recording, one panel per
    recording (:func:`display_psd`: Welch average for periodic drives, 1/12-octave
    bands), with each recording's sensor-noise floor: white noise of std σ sampled at
    fs has the one-sided level 2σ²/fs. ``noise_m``: σ [m] per recording; None
    estimates it from each recording (:func:`stickslip_jax.noise.noise_sigma`). Below
    the floor the measured PSD is noise, and the simulated one (noise-free) may go on
    falling there without any disagreement."""
    from ..noise import noise_sigma

    if noise_m is None:
        noise_m = [noise_sigma(r) for r in recs]
    fig, axes = subplots(1, len(recs), figsize=(5.4 * len(recs), 3.8), squeeze=False)
    for ax, rec, q, sigma in zip(axes[0], recs, q_sims, noise_m, strict=True):
        f0 = rec.drive.frequency_Hz if rec.drive.waveform in ("sawtooth", "sine") else None
        per = rec.sample_rate_Hz / f0 if f0 else None
        f, p_m = display_psd(rec.position_m, rec.dt, band=band, period_samples=per)
        _, p_s = display_psd(np.asarray(q), rec.dt, band=band, period_samples=per)
        ax.loglog(f, p_m, color="0.55", lw=2.6, alpha=0.8, label="measured")
        ax.loglog(f, p_s, color="tab:blue", lw=0.9, ls=(0, (4, 2)), label="simulated")
        if sigma is not None and np.isfinite(sigma) and sigma > 0:
            ax.axhline(2.0 * float(sigma) ** 2 * rec.dt, color="tab:red", lw=0.9, ls=":",
                       label=f"noise floor 2σ²/fs (σ = {float(sigma) * 1e9:.3g} nm)")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("one-sided PSD of q [m²/Hz]")
        ax.set_title(rec.name, fontsize=9)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=7, loc="best", framealpha=0.85)
    how = "Welch average, " if any(r.drive.waveform in ("sawtooth", "sine") for r in recs) else ""
    fig.suptitle(f"{title}; {how}mean over 1/12-octave bands", fontsize=10)
    fig.tight_layout()
    return _finish(fig, path)


def plot_hysteresis_loop(actuator, rec, q_sim, *, path: str | Path | None = None):
    """Hysteresis of a slow drive: measured and simulated q/2 against U, with the
    model's free stroke Γ(U) (in stick, q = 2·Γ).

    While the slider sticks it moves with the piezo, so q = x1 + x2 = 2·x1, and at a
    slow drive x1 follows Γ: q/2 is the measured hysteresis output. Γ(U) is the
    rate-independent Prandtl-Ishlinskii stroke, but the piezo (Mp, Dp, Kp, carrying
    the slider) lags it, so the measured loop against U is wider than Γ's. To compare
    like with like the figure also draws Γ through the model's stick dynamics at the
    drive frequency (:func:`stickslip_jax.linear.frequency_response`: gain |H|/2 and
    time lag τ = −arg H/ω), Γ(t − τ)·|H|/2, and says how wide each loop is."""
    return draw_hysteresis_loop(rec, q_sim, *hysteresis_loop_model(actuator, rec), path=path)


def hysteresis_loop_model(actuator, rec) -> tuple[np.ndarray, complex | None]:
    """What :func:`plot_hysteresis_loop` needs of the model: Γ at each sample of ``rec``
    [m] and the stick chain's response H at its drive frequency [m/m] (None without one:
    a drive other than a sine or sawtooth). Evaluated apart from the drawing, so that
    :func:`draw_hysteresis_loop` takes plain data (a figure helper can draw it)."""
    gamma = stroke_along(actuator, np.asarray(rec.voltage_V))
    f0 = rec.drive.frequency_Hz if rec.drive.waveform in ("sine", "sawtooth") else None
    if not f0:
        return gamma, None
    from ..linear import stick_chain

    return gamma, complex(stick_chain(actuator).response(float(f0)))


def draw_hysteresis_loop(rec, q_sim, gamma, h: complex | None, *,
                         path: str | Path | None = None):
    """:func:`plot_hysteresis_loop` from the model's Γ and H
    (:func:`hysteresis_loop_model`)."""
    u = np.asarray(rec.voltage_V)
    fig, ax = subplots(figsize=(6.4, 5.2))
    half_m = np.asarray(rec.position_m) / 2
    half_s = np.asarray(q_sim) / 2
    shift = np.mean(half_s - half_m)  # the interferometer zero is arbitrary
    ax.plot(u, (half_m + shift) * 1e6, color="0.55", lw=2.6, alpha=0.8,
            label="measured q/2 (q = 2Γ while the slider sticks)")
    ax.plot(u, half_s * 1e6, color="tab:blue", lw=0.9, ls=(0, (4, 2)), label="simulated q/2")
    ax.plot(u, gamma * 1e6, color="tab:orange", lw=0.9,
            label="model Γ(U): PI stroke, rate-independent")
    f0 = rec.drive.frequency_Hz
    note = ("Γ(U) has no dynamics; the measured q/2 also carries\nthe piezo's lag behind "
            "Γ, which widens its loop")
    if h is not None:
        tau = -np.angle(h) / (2 * np.pi * f0)
        t = np.asarray(rec.time_s)
        lagged = np.interp(t - tau, t, gamma) * abs(h) / 2
        ax.plot(u, lagged * 1e6, color="k", lw=0.8, ls=":",
                label=f"Γ through the stick dynamics: Γ(t − τ)·|H|/2, τ = {tau * 1e6:.3g} µs")
        widths = [_loop_width(u, y) for y in (half_m, gamma, lagged)]
        if all(np.isfinite(widths)):
            note = (f"Γ(U) has no dynamics: at {f0:g} Hz the piezo lags it by "
                    f"τ = {tau * 1e6:.3g} µs ({np.degrees(-np.angle(h)):.2g}°),\nwhich "
                    f"widens the loop: width at mid-voltage {widths[0] * 1e9:.3g} nm "
                    f"measured,\n{widths[1] * 1e9:.3g} nm Γ(U), {widths[2] * 1e9:.3g} nm "
                    f"Γ through the stick dynamics")
    ax.text(0.98, 0.02, note, transform=ax.transAxes, ha="right", va="bottom", fontsize=7,
            bbox=dict(boxstyle="round", fc="w", ec="0.7", alpha=0.9))
    ax.set_xlabel("U [V]")
    ax.set_ylabel("q/2 (the hysteresis output) and free stroke Γ [µm]")
    ax.set_title(f"hysteresis loop: {rec.name}", fontsize=10)
    ax.legend(fontsize=7, loc="upper left", framealpha=0.85)
    ax.grid(alpha=0.25)
    return _finish(fig, path)


def _loop_width(u, y) -> float:
    """Vertical opening of the last full loop of ``y`` against ``u`` at mid-voltage
    [units of y] (falling branch minus rising branch, over the last third of the
    trace), NaN where the trace does not pass mid-voltage both ways there."""
    n = len(u)
    uu, yy = np.asarray(u)[2 * n // 3:], np.asarray(y)[2 * n // 3:]
    mid = 0.5 * (np.min(u) + np.max(u))
    du = np.gradient(uu)
    out = []
    for branch in (du > 0, du < 0):
        ub, yb = uu[branch], yy[branch]
        if ub.size < 2 or not ub.min() <= mid <= ub.max():
            return float("nan")
        order = np.argsort(ub)
        out.append(np.interp(mid, ub[order], yb[order]))
    return float(out[1] - out[0])


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

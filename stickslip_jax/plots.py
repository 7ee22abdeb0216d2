"""Figures the tools write (matplotlib figures outside pyplot: no screen needed, and the
backend of a notebook or script that imports this package is left alone)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .files import atomic_writer


def subplots(*args, figsize=None, **kwargs):
    """A new ``(figure, axes)`` pair that lives outside pyplot's global state.

    Same arguments as ``pyplot.subplots``. Nothing is shown and no backend is
    selected, so writing figures from a notebook or a script never changes its
    backend; save with :func:`save_figure` or ``display(fig)`` in a notebook.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*args, **kwargs)


def legend_on_labelled(axes, **kwargs):
    """A legend on the first of ``axes`` (tried in reverse order, so the last panel is
    preferred) that holds labelled lines; none when no panel does (matplotlib would warn
    "No artists with labels found")."""
    for ax in reversed(list(axes)):
        if ax.get_legend_handles_labels()[0]:
            return ax.legend(**kwargs)
    return None


LINE_STYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "D", "v", "P")


def curve_style(i: int) -> dict:
    """Line style, marker and marker size of the ``i``-th of several curves on one
    axes, all different from their neighbours' (hollow markers, shrinking), so that a
    curve drawn over another that it equals leaves the one beneath visible."""
    return {"ls": LINE_STYLES[i % len(LINE_STYLES)], "marker": MARKERS[i % len(MARKERS)],
            "ms": max(6.5 - 1.2 * (i % 4), 2.5), "mfc": "none", "mew": 0.9}


def coincident_labels(names, curves, *, rel: float = 0.01, unit: str = "",
                      scale: float = 1.0) -> list[str]:
    """For each curve (rows of ``curves``, all on one grid), a note naming the first
    earlier curve it coincides with: largest difference within ``rel`` of the largest
    |value| of all curves; ``""`` where it coincides with none. The difference is
    written in ``unit`` after multiplying by ``scale``."""
    c = np.asarray(curves, dtype=float)
    finite = np.abs(c[np.isfinite(c)])
    tol = rel * (float(finite.max()) if finite.size else 0.0)
    out = []
    for i in range(len(c)):
        note = ""
        for j in range(i):
            diff = float(np.nanmax(np.abs(c[i] - c[j]))) if c.shape[1] else 0.0
            if diff <= tol:
                note = f" (= {names[j]} within {diff * scale:.2g}{unit})"
                break
        out.append(note)
    return out


def colormap(name: str):
    """A named matplotlib colormap."""
    import matplotlib

    return matplotlib.colormaps[name]


SAVE_PAD_INCHES = 0.1
"""White margin around a saved figure's artists [in] (matplotlib's default)."""

SAVE_DPI = 130
"""Resolution of a saved raster figure [dots per inch]."""


def save_figure(fig, path: str | Path) -> Path:
    """Write a figure atomically (format from the file extension) and return the path.

    Cropped to what it draws, with a :data:`SAVE_PAD_INCHES` margin, as
    ``bbox_inches="tight"`` crops it. A PNG is rendered once and cropped to its ink:
    the rows and columns holding any pixel that differs from the figure's face colour.
    "tight" lays every tick and label out once more to measure the artists' extents
    before it renders (an overlay of 2500 samples: 0.45 s by the extents, 0.25 s by the
    ink). Ink that reaches the canvas's edge may run beyond it, so such a figure, and
    every vector format, is cropped by its artists' extents instead."""
    path = Path(path)
    fmt = path.suffix.lstrip(".") or "png"
    if fmt == "png":
        image = _ink_cropped_render(fig)
        if image is not None:
            import matplotlib.image

            with atomic_writer(path, "wb") as fh:
                matplotlib.image.imsave(fh, image, format="png", dpi=SAVE_DPI)
            return path
    crop = fig.get_tightbbox().padded(SAVE_PAD_INCHES)
    with atomic_writer(path, "wb") as fh:
        fig.savefig(fh, format=fmt, dpi=SAVE_DPI, bbox_inches=crop)
    return path


def _ink_cropped_render(fig) -> np.ndarray | None:
    """``fig`` rendered at :data:`SAVE_DPI` (RGBA, uint8) and cropped to its ink plus the
    margin; None when ink touches the canvas's edge (it may have been cut off there) or
    the face colour is not opaque (then "ink" has no clear meaning)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    face = np.asarray(fig.get_facecolor(), dtype=float)
    if face[3] < 1.0:
        return None
    dpi = fig.dpi
    try:
        fig.set_dpi(SAVE_DPI)
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        rgba = np.array(canvas.buffer_rgba())
    finally:
        fig.set_dpi(dpi)
    ink = np.any(rgba != np.round(face * 255).astype(np.uint8), axis=2)
    rows, cols = np.flatnonzero(ink.any(axis=1)), np.flatnonzero(ink.any(axis=0))
    if rows.size == 0:
        return None
    h, w = ink.shape
    if rows[0] == 0 or cols[0] == 0 or rows[-1] == h - 1 or cols[-1] == w - 1:
        return None
    pad = int(round(SAVE_PAD_INCHES * SAVE_DPI))
    return rgba[max(rows[0] - pad, 0):rows[-1] + pad + 1,
                max(cols[0] - pad, 0):cols[-1] + pad + 1]


def plot_trace(time_s, voltage_V, q_sim_m, *, q_meas_m=None, noise_m=None,
               meas_label: str = "measured", title: str = "", path=None):
    """Voltage and output against time; with a measured output, also the residual.

    ``time_s`` [s], ``voltage_V`` [V], ``q_sim_m`` and ``q_meas_m`` [m] (plotted in µm).
    The measured trace is drawn first, wide and light, and the simulated one on top,
    thin and dashed, so both stay visible where they agree (alone, the simulated trace
    is drawn solid). Every panel has a legend inside its axes naming each trace (the
    residual panel gets head room above its trace for it). With ``q_meas_m`` a third
    panel shows ``q_sim − q_meas`` [nm] less its mean (the best constant offset of
    docs/model.md "Fit quality") with the ±1σ band of the sensor noise: ``noise_m``
    [m] when given (e.g. ``stickslip_jax.noise.noise_sigma`` of the recording), 0 for
    no band (a noiseless reference), None to estimate σ from the measured trace's
    third differences. ``meas_label`` names the compared trace in the legend.
    Returns the figure, or writes it to ``path`` and returns the path.
    """
    from .noise import sigma_from_differences

    t_ms = np.asarray(time_s) * 1e3
    q_sim = np.asarray(q_sim_m, dtype=float)
    if q_meas_m is None:
        fig, (ax_u, ax_q) = subplots(2, 1, sharex=True, figsize=(8, 5),
                                     gridspec_kw={"height_ratios": [1, 2]})
    else:
        fig, (ax_u, ax_q, ax_r) = subplots(3, 1, sharex=True, figsize=(8, 6.6),
                                           gridspec_kw={"height_ratios": [1, 2, 1.4]})
    ax_u.plot(t_ms, voltage_V, color="tab:gray", lw=0.8, label="drive voltage U")
    ax_u.set_ylabel("U [V]")
    lo, hi = ax_u.get_ylim()
    ax_u.set_ylim(lo, hi + 0.45 * (hi - lo))  # head room: a drive at its top leaves none
    ax_u.legend(loc="upper right", fontsize=7, framealpha=0.85)
    if q_meas_m is not None:
        q_meas = np.asarray(q_meas_m, dtype=float)
        ax_q.plot(t_ms, q_meas * 1e6, color="0.55", lw=2.6, alpha=0.8, zorder=1,
                  solid_capstyle="butt", label=meas_label)
    ax_q.plot(t_ms, q_sim * 1e6, color="tab:blue", lw=0.9, zorder=3,
              ls="-" if q_meas_m is None else (0, (4, 2)), label="simulated q")
    ax_q.set_ylabel("q = x1 + x2 [µm]")
    ax_q.legend(loc="best", fontsize=8, framealpha=0.85)
    if q_meas_m is None:
        ax_q.set_xlabel("time [ms]")
    else:
        resid = q_sim - q_meas
        resid = resid - resid.mean()
        sigma = sigma_from_differences(q_meas) if noise_m is None else float(noise_m)
        if sigma > 0:
            how = "estimated from the trace" if noise_m is None else "noise floor"
            ax_r.axhspan(-sigma * 1e9, sigma * 1e9, color="tab:orange", alpha=0.25, lw=0,
                         zorder=1, label=f"±1σ sensor noise, σ = {sigma * 1e9:.3g} nm ({how})")
        rms = float(np.sqrt(np.mean(resid**2)))
        ax_r.plot(t_ms, resid * 1e9, color="tab:blue", lw=0.6, zorder=2,
                  label=f"simulated − {meas_label.split(' (')[0]}, offset removed "
                        f"(RMS {rms * 1e9:.3g} nm)")
        ax_r.axhline(0.0, color="k", lw=0.5, zorder=1)
        ax_r.set_ylabel("residual [nm]")
        ax_r.set_xlabel("time [ms]")
        # The legend inside the axes, over head room added above the trace (outside,
        # a long label ran off the figure's edge).
        lo, hi = ax_r.get_ylim()
        ax_r.set_ylim(lo, hi + 0.75 * (hi - lo))
        ax_r.legend(loc="upper left", ncol=1, fontsize=7, framealpha=0.85)
    if title:
        ax_u.set_title(title, fontsize=10)
    fig.align_ylabels()
    return save_figure(fig, path) if path is not None else fig

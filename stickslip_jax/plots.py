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


def colormap(name: str):
    """A named matplotlib colormap."""
    import matplotlib

    return matplotlib.colormaps[name]


def save_figure(fig, path: str | Path) -> Path:
    """Write a figure atomically (format from the file extension) and close it."""
    path = Path(path)
    fmt = path.suffix.lstrip(".") or "png"
    with atomic_writer(path, "wb") as fh:
        fig.savefig(fh, format=fmt, dpi=130, bbox_inches="tight")
    return path


def plot_trace(time_s, voltage_V, q_sim_m, *, q_meas_m=None, title: str = "", path=None):
    """Voltage and output against time; measured output overlaid when given.

    ``time_s`` [s], ``voltage_V`` [V], ``q_sim_m`` and ``q_meas_m`` [m] (plotted in µm).
    Returns the figure, or writes it to ``path`` and returns the path.
    """
    t_ms = np.asarray(time_s) * 1e3
    fig, (ax_u, ax_q) = subplots(2, 1, sharex=True, figsize=(8, 5),
                                     gridspec_kw={"height_ratios": [1, 2]})
    ax_u.plot(t_ms, voltage_V, color="tab:gray", lw=0.8)
    ax_u.set_ylabel("U [V]")
    if q_meas_m is not None:
        ax_q.plot(t_ms, np.asarray(q_meas_m) * 1e6, color="k", lw=0.8, label="measured")
    ax_q.plot(t_ms, np.asarray(q_sim_m) * 1e6, color="tab:blue", lw=0.9, label="simulated")
    ax_q.set_xlabel("time [ms]")
    ax_q.set_ylabel("q = x1 + x2 [µm]")
    if q_meas_m is not None:
        ax_q.legend(loc="best", fontsize=8)
    if title:
        ax_u.set_title(title, fontsize=10)
    fig.align_ylabels()
    return save_figure(fig, path) if path is not None else fig

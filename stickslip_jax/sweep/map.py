"""Velocity map: steady-state velocity and step over an amplitude × frequency ×
direction grid, as a table (CSV) and a heat map."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..files import atomic_write_text, check_output_path
from ..model.actuator import Actuator
from ..signals import DEFAULT_SAMPLE_RATE_HZ
from .engine import SweepRun, run_grid
from .grid import DriveGrid
from .velocity import PointVelocity, steady_velocity

CSV_COLUMNS = ("amplitude_V", "frequency_Hz", "direction", "velocity_um_s", "step_nm",
               "regime")


@dataclass(frozen=True)
class VelocityMap:
    """One :class:`PointVelocity` per grid point, with the grid and how it ran."""

    grid: DriveGrid
    points: list[PointVelocity]
    periods: int
    settle: int
    sample_rate_Hz: float
    run: SweepRun

    @property
    def velocity_m_s(self) -> np.ndarray:
        return np.array([p.velocity_m_s for p in self.points])

    @property
    def step_m(self) -> np.ndarray:
        return np.array([p.step_m for p in self.points])

    def to_csv(self) -> str:
        lines = [",".join(CSV_COLUMNS)]
        for a, f, d, p in zip(self.grid.amplitude_V, self.grid.frequency_Hz,
                              self.grid.direction_names(), self.points, strict=True):
            lines.append(f"{a:.10g},{f:.10g},{d},{p.velocity_m_s * 1e6:.8g},"
                         f"{p.step_m * 1e9:.8g},{p.regime}")
        return "\n".join(lines) + "\n"

    def save_csv(self, path, *, force: bool = False) -> Path:
        path = Path(path)
        check_output_path(path, force=force)
        atomic_write_text(path, self.to_csv())
        return path

    def plot(self, path=None):
        """Heat map of velocity [µm/s] over amplitude and frequency, one panel per
        direction; scanning points hatched. Returns the figure.

        The colour scale is symmetric-logarithmic (linear within ±``linthresh``, a few
        µm/s, logarithmic beyond), so rows of a few tens of µm/s stay readable next to
        rows of hundreds: velocity grows with frequency, and a linear scale to the
        largest washes the low-frequency rows out."""
        from matplotlib.colors import SymLogNorm
        from matplotlib.patches import Patch, Rectangle
        from matplotlib.patheffects import withStroke

        from ..plots import subplots

        dirs = sorted(set(self.grid.backward.tolist()))
        amps = np.unique(self.grid.amplitude_V)
        freqs = np.unique(self.grid.frequency_Hz)
        fig, axes = subplots(1, len(dirs), figsize=(5.6 * len(dirs), 4.4), squeeze=False)
        v = self.velocity_m_s * 1e6
        finite = np.abs(v[np.isfinite(v)])
        vmax = float(finite.max()) if finite.size and finite.max() > 0 else 1.0
        linthresh = min(2.0, vmax / 10)
        norm = SymLogNorm(linthresh=linthresh, linscale=0.5, vmin=-vmax, vmax=vmax, base=10)
        for ax, back in zip(axes[0], dirs, strict=True):
            img = np.full((freqs.size, amps.size), np.nan)
            scan = np.zeros_like(img, dtype=bool)
            for i in np.flatnonzero(self.grid.backward == back):
                r = int(np.searchsorted(freqs, self.grid.frequency_Hz[i]))
                c = int(np.searchsorted(amps, self.grid.amplitude_V[i]))
                img[r, c] = v[i]
                scan[r, c] = self.points[i].regime == "scanning"
            mesh = ax.pcolormesh(np.arange(amps.size + 1), np.arange(freqs.size + 1), img,
                                 cmap="RdBu_r", norm=norm, edgecolors="w", linewidth=0.4)
            for r, c in zip(*np.nonzero(scan), strict=True):
                # Hatched in black over the cell's own colour: scanning stays visible
                # whatever the velocity (pre-sliding drift gives scanning cells some).
                ax.add_patch(Rectangle((c, r), 1, 1, fill=False, hatch="////",
                                       edgecolor="k", lw=0.0, alpha=0.45))
            if amps.size <= 16 and freqs.size <= 12:  # the value in each cell [µm/s]
                for r, c in zip(*np.nonzero(np.isfinite(img)), strict=True):
                    x = img[r, c]
                    txt = "0" if abs(x) < 0.05 else f"{x:.1f}" if abs(x) < 10 else f"{x:.0f}"
                    red, green, blue, _ = mesh.cmap(norm(x))
                    dark = 0.299 * red + 0.587 * green + 0.114 * blue < 0.55
                    halo = [withStroke(linewidth=1.5, foreground="w")] if scan[r, c] else []
                    ax.text(c + 0.5, r + 0.5, txt, ha="center", va="center", fontsize=5.5,
                            color="w" if dark else "k", path_effects=halo)  # halo: hatch
            ax.set_xticks(np.arange(amps.size) + 0.5, [f"{a:.3g}" for a in amps], fontsize=7,
                          rotation=45 if amps.size > 8 else 0)
            ax.set_yticks(np.arange(freqs.size) + 0.5, [f"{f:.4g}" for f in freqs], fontsize=7)
            ax.set_xlabel("amplitude [V]")
            ax.set_ylabel("frequency [Hz]")
            ax.set_title("backward" if back else "forward", fontsize=10)
            decades = [10.0**k for k in range(int(np.ceil(np.log10(5 * linthresh))),
                                              int(np.floor(np.log10(vmax))) + 1)]
            bar = fig.colorbar(mesh, ax=ax, ticks=[-d for d in decades[::-1]] + [0.0]
                               + decades, format="%g")
            bar.set_label(f"steady-state velocity [µm/s]\n(symmetric log scale, linear "
                          f"within ±{linthresh:.2g} µm/s)", fontsize=8)
            bar.ax.tick_params(labelsize=7)
        if np.any([p.regime == "scanning" for p in self.points]):
            fig.legend(handles=[Patch(facecolor="white", edgecolor="k", hatch="////",
                                      label="scanning: no net step, the slider follows "
                                            "the piezo back and forth")],
                       loc="lower center", fontsize=8, frameon=False)
        fig.suptitle(f"velocity map: phase-locked over periods {self.settle + 1}-"
                     f"{self.periods}", fontsize=10)
        fig.tight_layout(rect=(0, 0.06, 1, 1))
        if path is not None:
            fig.savefig(path, dpi=130)
        return fig


def velocity_map(actuator: Actuator, grid: DriveGrid, *, periods: int = 10, settle: int = 2,
                 sample_rate_Hz: float = DEFAULT_SAMPLE_RATE_HZ, chunk: int | None = None,
                 segment: int = 250, stepping=None,
                 progress: Callable[[int, int], None] | None = None) -> VelocityMap:
    """Simulate the grid (:func:`run_grid`) and measure each point's steady-state
    velocity phase-locked over periods ``settle+1 .. periods``."""

    def reduce(i, q):
        return steady_velocity(q, float(grid.frequency_Hz[i]), sample_rate_Hz, periods, settle)

    points, run = run_grid(actuator, grid, periods=periods, sample_rate_Hz=sample_rate_Hz,
                           chunk=chunk, segment=segment, stepping=stepping, reduce=reduce,
                           progress=progress)
    return VelocityMap(grid, points, periods, settle, sample_rate_Hz, run)

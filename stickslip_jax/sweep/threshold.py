"""Step length against amplitude and the 0-amplitude threshold (Nguyen 2012, Fig. 5).

Below a threshold amplitude the contact never leaves its elastic region: the slider
follows the piezo back and forth and makes no net step. The threshold is read from a
step-vs-amplitude curve as the smallest amplitude at which the phase-locked step per
period reaches ``min_step`` (linear interpolation between grid amplitudes).
"""

from __future__ import annotations

import numpy as np

from ..model.actuator import Actuator
from .grid import DriveGrid
from .map import velocity_map


def step_vs_amplitude(actuator: Actuator, amplitudes, frequency_Hz: float, *,
                      direction: str = "forward", periods: int = 6, settle: int = 2
                      ) -> np.ndarray:
    """Steady step per period [m] at each amplitude [V] (one batched sweep)."""
    grid = DriveGrid.make(np.asarray(amplitudes, float), [frequency_Hz], direction)
    return velocity_map(actuator, grid, periods=periods, settle=settle).step_m


def zero_amplitude_threshold(amplitudes, steps, *, min_step: float = 1e-9) -> float:
    """Smallest amplitude [V] where |step| reaches ``min_step`` [m]; NaN if never
    reached, the first amplitude if already reached there."""
    a = np.asarray(amplitudes, float)
    s = np.abs(np.asarray(steps, float))
    order = np.argsort(a)
    a, s = a[order], s[order]
    above = np.flatnonzero(s >= min_step)
    if above.size == 0:
        return float("nan")
    k = int(above[0])
    if k == 0:
        return float(a[0])
    return float(a[k - 1] + (min_step - s[k - 1]) * (a[k] - a[k - 1]) / (s[k] - s[k - 1]))


def ratio_study(actuator: Actuator, ratios, amplitudes, frequency_Hz: float, *,
                direction: str = "forward", min_step: float = 2e-9, periods: int = 6
                ) -> dict[float, tuple[np.ndarray, float]]:
    """Step-vs-amplitude curve [m] and 0-amplitude threshold [V] for each z_ba/z_ss
    ratio (z_ba kept), as in Nguyen 2012 Fig. 5. Requires an elasto-plastic law."""
    import equinox as eqx
    import jax.numpy as jnp

    if not hasattr(actuator.friction, "zba_ratio"):
        raise ValueError("the ratio study needs an elasto-plastic friction law")
    out = {}
    for r in ratios:
        act = eqx.tree_at(lambda a: a.friction.zba_ratio, actuator, jnp.asarray(float(r)))
        steps = step_vs_amplitude(act, amplitudes, frequency_Hz, direction=direction,
                                  periods=periods)
        out[float(r)] = (steps, zero_amplitude_threshold(amplitudes, steps, min_step=min_step))
    return out


def plot_ratio_study(amplitudes, study: dict, *, frequency_Hz: float, path=None,
                     extra: dict | None = None):
    """Step per period [nm] against amplitude [V], one line per ratio with its
    threshold marked; ``extra`` adds labelled curves (e.g. LuGre). Returns the figure."""
    from ..plots import coincident_labels, colormap, curve_style, subplots

    fig, ax = subplots(figsize=(6.4, 4.2))
    colours = colormap("plasma")(np.linspace(0, 0.85, max(len(study), 1)))
    names = [f"z_ba/z_ss = {ratio:g}" for ratio in study] + list(extra or {})
    curves = [np.asarray(steps) for steps, _ in study.values()] + [
        np.asarray(steps) for steps in (extra or {}).values()]
    same = coincident_labels(names, curves, unit=" nm", scale=1e9)
    for i, (colour, (steps, thr)) in enumerate(zip(colours, study.values(), strict=True)):
        ax.plot(amplitudes, np.asarray(steps) * 1e9, color=colour, lw=1.3, **curve_style(i),
                label=names[i] + same[i] + (f": 0-amplitude {thr:.1f} V" if np.isfinite(thr)
                                            else ": no step in this range"))
        if np.isfinite(thr):
            ax.axvline(thr, color=colour, lw=0.8, ls=":")
    for k, steps in enumerate((extra or {}).values(), start=len(study)):
        ax.plot(amplitudes, np.asarray(steps) * 1e9, color="k", lw=1,
                **{**curve_style(k), "ls": "--"}, label=names[k] + same[k])
    ax.set_xlabel("amplitude [V]")
    ax.set_ylabel("step per period [nm]")
    ax.set_title(f"step length vs amplitude at {frequency_Hz:g} Hz (Nguyen 2012 Fig. 5)",
                 fontsize=10)
    ax.grid(alpha=0.25)
    ax.legend(fontsize=7)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=130)
    return fig

"""Seed 2 (Nguyen 2012) as studies: preload dependence (CEIM), the spread of normal
forces over a multi-contact runner, and stick-slip force generation.

- :func:`preload_study`: step per period against amplitude, and the 0-amplitude
  threshold, at several preloads of a CEIM contact (step length falls as the preload
  rises: z_ba and the contact stiffness grow with it, Nguyen eq. 14-19).
- :func:`spread_study`: the same for several splits of one preload over K contacts
  (:func:`~stickslip_jax.model.contacts.multi_contact`).
- :func:`force_vs_amplitude`: the runner pushes a load spring (``k_load``; a stiff
  one is a blocked runner); the force it generates is the settled period mean of
  ``k_load·x2`` over that of a contact that never slips. The elasto-plastic model
  predicts a dead zone (no force below the 0-amplitude threshold, Nguyen §4, Fig. 9);
  LuGre has none.

Each study is one batched simulation per setting (vmap over amplitudes).
"""

from __future__ import annotations

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..model.actuator import Actuator
from ..model.base import DriveContext
from ..model.ceim import CEIMElastoPlastic
from ..model.contacts import multi_contact
from ..signals import DEFAULT_SAMPLE_RATE_HZ
from ..simulate import simulate_states
from .threshold import step_vs_amplitude, zero_amplitude_threshold


@dataclass(frozen=True)
class StepCurves:
    """Step per period [m] against amplitude [V] for each setting, with thresholds.

    ``settings``: the varied quantity (preload [N], or a label per spread);
    ``steps_m``: (settings, amplitudes); ``thresholds_V``: 0-amplitude threshold per
    setting (NaN where no amplitude of the grid slips).
    """

    label: str
    settings: list
    amplitudes_V: np.ndarray
    steps_m: np.ndarray
    thresholds_V: np.ndarray
    frequency_Hz: float

    def to_dict(self) -> dict:
        return {"varied": self.label, "frequency_Hz": self.frequency_Hz,
                "amplitudes_V": self.amplitudes_V.tolist(),
                "curves": [{"setting": s if isinstance(s, str) else float(s),
                            "step_nm": (self.steps_m[i] * 1e9).tolist(),
                            "threshold_V": None if not np.isfinite(self.thresholds_V[i])
                            else float(self.thresholds_V[i])}
                           for i, s in enumerate(self.settings)]}

    def plot(self, path=None, *, title: str = ""):
        """Step per period [nm] against amplitude, one line per setting. Returns the
        figure (written to ``path`` when given)."""
        from ..plots import coincident_labels, colormap, curve_style, save_figure, subplots

        fig, ax = subplots(figsize=(6.4, 4.2))
        colours = colormap("viridis")(np.linspace(0, 0.85, max(len(self.settings), 1)))
        names = [_setting_name(self.label, s) for s in self.settings]
        same = coincident_labels(names, self.steps_m, unit=" nm", scale=1e9)
        for i, (name, c) in enumerate(zip(names, colours, strict=True)):
            thr = self.thresholds_V[i]
            ax.plot(self.amplitudes_V, self.steps_m[i] * 1e9, color=c, lw=1.3,
                    **curve_style(i),
                    label=name + same[i] + (f": 0-amplitude {thr:.1f} V" if np.isfinite(thr)
                                            else ": no step in this range"))
            if np.isfinite(thr):
                ax.axvline(thr, color=c, lw=0.7, ls=":")
        ax.set_xlabel("amplitude [V]")
        ax.set_ylabel("step per period [nm]")
        ax.set_title(title or f"step length at {self.frequency_Hz:g} Hz", fontsize=10)
        ax.grid(alpha=0.25)
        ax.legend(fontsize=7)
        fig.tight_layout()
        if path is not None:
            save_figure(fig, path)
        return fig


def _setting_name(label: str, setting) -> str:
    """A setting as the legend says it: a label (a spread's name) as is, a value with
    the unit of a ``"name [unit]"`` label after it (``preload 0.5 N``)."""
    if isinstance(setting, str):
        return setting
    name, _, unit = label.partition(" [")
    return f"{name} {setting:g} {unit.rstrip(']')}".rstrip()


def _require_ceim(actuator: Actuator) -> CEIMElastoPlastic:
    if not isinstance(actuator.friction, CEIMElastoPlastic):
        raise ValueError("this study needs a CEIM contact (friction 'ceim'); build one with "
                         "CEIMElastoPlastic.matching(rho0, z_ba, preload=...)")
    return actuator.friction


def _curves(label, settings, actuators, amplitudes, frequency_Hz, direction, min_step,
            periods) -> StepCurves:
    amplitudes = np.asarray(amplitudes, float)
    steps = np.array([step_vs_amplitude(a, amplitudes, frequency_Hz, direction=direction,
                                        periods=periods) for a in actuators])
    thr = np.array([zero_amplitude_threshold(amplitudes, s, min_step=min_step) for s in steps])
    return StepCurves(label, list(settings), amplitudes, steps, thr, float(frequency_Hz))


def preload_study(actuator: Actuator, preloads, amplitudes, frequency_Hz: float, *,
                  direction: str = "forward", min_step: float = 2e-9,
                  periods: int = 6) -> StepCurves:
    """Step curves and 0-amplitude thresholds at each preload [N] of a CEIM contact."""
    ceim = _require_ceim(actuator)
    acts = [eqx.tree_at(lambda a: a.friction, actuator, ceim.with_preload(float(p)))
            for p in preloads]
    return _curves("preload [N]", [float(p) for p in preloads], acts, amplitudes,
                   frequency_Hz, direction, min_step, periods)


def spread_study(actuator: Actuator, spreads: dict, amplitudes, frequency_Hz: float, *,
                 direction: str = "forward", min_step: float = 2e-9,
                 periods: int = 6) -> StepCurves:
    """Step curves and thresholds for several normal-force splits ``{label: shares}``
    of the actuator's contact (see :func:`~stickslip_jax.model.contacts.multi_contact`)."""
    acts = [multi_contact(actuator, shares) for shares in spreads.values()]
    return _curves("contacts", list(spreads), acts, amplitudes, frequency_Hz, direction,
                   min_step, periods)


@dataclass(frozen=True)
class ForceCurve:
    """Generated force [N] against amplitude [V] against a load spring ``k_load`` [N/m].

    ``force_N``: generated force averaged over the last ``average`` periods;
    ``history_N``: (amplitudes, periods) force of every period (to check it settled);
    ``coulomb_N``: the contact's Coulomb level (the ceiling of a blocked runner).
    """

    amplitudes_V: np.ndarray
    force_N: np.ndarray
    history_N: np.ndarray
    k_load: float
    frequency_Hz: float
    coulomb_N: float

    def dead_zone_V(self, *, fraction: float = 0.02) -> float:
        """Largest amplitude [V] below which the force stays under ``fraction`` of
        the largest force of the curve (NaN if none)."""
        f = np.abs(self.force_N)
        return zero_amplitude_threshold(self.amplitudes_V, f, min_step=fraction * f.max())

    def to_dict(self) -> dict:
        return {"k_load_N_m": self.k_load, "frequency_Hz": self.frequency_Hz,
                "coulomb_N": self.coulomb_N, "amplitudes_V": self.amplitudes_V.tolist(),
                "force_N": self.force_N.tolist(), "dead_zone_V": self.dead_zone_V()}


def _elastic_twin(actuator: Actuator) -> Actuator:
    """The actuator with its contact replaced by a linear spring of the same small-motion
    stiffness that never slips (break-away strain 1 m)."""
    from ..model.friction import ElastoPlastic

    k = actuator.friction.stiffness(DriveContext.make())
    return eqx.tree_at(lambda a: (a.friction, a.extensions), actuator,
                       (ElastoPlastic(k, 1.0), ()))


def force_vs_amplitude(actuator: Actuator, amplitudes, frequency_Hz: float, *,
                       k_load: float, periods: int = 40, average: int = 5,
                       direction: str = "forward",
                       sample_rate_Hz: float = DEFAULT_SAMPLE_RATE_HZ,
                       stepping=None) -> ForceCurve:
    """Force generated against a load spring ``k_load`` [N/m] by a sawtooth of each
    amplitude [V] (one vmapped simulation over amplitudes per model).

    The spring force ``k_load·x2`` also swings with the stroke while the contact
    sticks; what stick-slip *generates* is the shift of its period mean over that of
    the same drive on a contact that never slips (a linear spring of the contact's
    stiffness). So the force is exactly 0 while the drive only scans. Each period's
    value is the mean over that period; ``force_N`` averages the last ``average``.
    """
    if k_load <= 0:
        raise ValueError(f"k_load must be positive, got {k_load!r}")
    amplitudes = np.asarray(amplitudes, float)
    loaded = eqx.tree_at(lambda a: a.slider.k_load, actuator, jnp.asarray(float(k_load)))
    per = int(round(sample_rate_Hz / frequency_Hz))
    n = periods * per + 1
    phase = np.mod(np.arange(n) * frequency_Hz / sample_rate_Hz, 1.0)
    backward = direction == "backward"
    ramps = amplitudes[:, None] * phase[None, :]
    volts = jnp.asarray(amplitudes[:, None] - ramps if backward else ramps)
    dt = 1.0 / sample_rate_Hz

    def period_means(act):
        def slider_position(u, amplitude):
            drive = DriveContext.make(backward=backward, amplitude=amplitude,
                                      frequency=frequency_Hz)
            return simulate_states(act, u, dt=dt, drive=drive, stepping=stepping).x2

        x2 = np.asarray(jax.vmap(slider_position)(volts, jnp.asarray(amplitudes)))
        return x2[:, 1 : periods * per + 1].reshape(len(amplitudes), periods, per).mean(-1)

    history = k_load * (period_means(loaded) - period_means(_elastic_twin(loaded)))
    force = history[:, -average:].mean(axis=1)
    fc = float(actuator.friction.coulomb_force(DriveContext.make(backward=backward)))
    return ForceCurve(amplitudes, force, history, float(k_load), float(frequency_Hz), fc)


def plot_force_curves(curves: dict, path=None):
    """Generated force [N] against amplitude for several models ``{label: ForceCurve}``,
    and the build-up period by period at one amplitude [V] for all of them: the
    largest amplitude every curve has, so the models are compared at the same drive.
    Returns the figure."""
    from ..plots import save_figure, subplots

    common = set.intersection(*(set(np.round(c.amplitudes_V, 9)) for c in curves.values()))
    if not common:
        raise ValueError("the force curves share no amplitude to compare the build-up at")
    a_cmp = max(common)
    fig, axes = subplots(1, 2, figsize=(11, 3.8))
    for label, c in curves.items():
        dz = c.dead_zone_V()
        axes[0].plot(c.amplitudes_V, c.force_N * 1e3, "-o", ms=3,
                     label=f"{label}" + (f" (dead zone to {dz:.1f} V)" if np.isfinite(dz)
                                         and dz > c.amplitudes_V.min() else ""))
        i = int(np.flatnonzero(np.round(c.amplitudes_V, 9) == a_cmp)[0])
        axes[1].plot(np.arange(1, c.history_N.shape[1] + 1), c.history_N[i] * 1e3,
                     label=label)
    first = next(iter(curves.values()))
    if np.isfinite(first.coulomb_N):
        axes[0].axhline(first.coulomb_N * 1e3, color="grey", ls="--", lw=0.8,
                        label="Coulomb level")
    axes[0].set_xlabel("amplitude [V]")
    axes[0].set_ylabel("generated force [mN]")
    axes[0].set_title(f"force against a {first.k_load:g} N/m load spring, "
                      f"{first.frequency_Hz:g} Hz (Nguyen Fig. 9)", fontsize=10)
    axes[0].legend(fontsize=7)
    axes[1].set_xlabel("period")
    axes[1].set_ylabel("generated force, period mean [mN]")
    axes[1].set_title(f"build-up at {a_cmp:g} V, the largest amplitude", fontsize=10)
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig

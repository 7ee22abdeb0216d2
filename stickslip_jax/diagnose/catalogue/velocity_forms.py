"""Friction against a velocity as a class: the flexible form of the viscous-friction
entry, kept apart from it for the damping entries that take the same form.

The refit frees the friction law's linear coefficient (rho2) beside saturating terms
on a fixed grid of speeds (:class:`~stickslip_jax.model.extensions.
SaturatingViscosity`, non-negative slopes), so that a linear, a saturating or a nearly
constant drag are all special cases of one entry. The score test probes the linear
coefficient and a saturating term at each of the grid's speeds inside the range the
velocity spans in stepping (a force that levels off there projects poorly on the
linear one's signature); the refit starts from the best probe's slope at its speed.

Contact damping (rho1, against the bristles' rate ż) is not one of them yet: the same
terms in ż were tried, and a refit that grows them stiffens the model beyond the plan
of sub-steps made at its start (benchmarks/README.md, "Friction against the sliding
velocity as a class").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...identify.parameters import ParameterSpec
from ...model.actuator import Actuator
from ...model.extensions import SaturatingViscosity, first_slope
from ..form_band import draw_band
from .base import Probe
from .slots import damping_attach, damping_probes, ext

START_SHARE = 0.01
"""Each slope but the probe's starts at this share of the first-order strength: inside
the softplus's curve, where the fit can raise it or let it fall to 0."""


USED_SHARE = 1e-3
"""The report says a saturating slope only above this share of the largest: below it
the fit drove it to its bound, 0 (the refit's own count of what it spent is
:func:`~stickslip_jax.diagnose.refit.counted_parameters`'s)."""


@dataclass(frozen=True)
class VelocityForm:
    """One entry's friction against the sliding velocity: the law's linear
    ``coefficient`` and :class:`SaturatingViscosity` at ``speeds`` [m/s], probed at
    ``probe_speeds``; ``prefix`` names its slopes in reports, ``velocity`` the
    velocity in words (figures)."""

    coefficient: str
    speeds: tuple[float, ...]
    probe_speeds: tuple[float, ...]
    prefix: str
    velocity: str

    def slope_name(self, speed: float) -> str:
        """The reported name of the saturating term at ``speed`` [m/s]."""
        return f"{self.prefix}_slope_{speed * 1e3:g}mm/s"

    def slopes(self, params: dict[str, float]) -> np.ndarray:
        """The terms' slopes [N·s/m] in grid order, from refitted ``params``."""
        return np.array([params.get(self.slope_name(v), 0.0) for v in self.speeds])

    def force_curve(self, params: dict[str, float], speeds) -> np.ndarray:
        """The friction [N] at velocities ``speeds`` [m/s] of the linear coefficient
        and the terms (the whole coefficient: the baseline's share of it is not known
        here; the profile's is 0)."""
        speeds = np.asarray(speeds, dtype=float)[..., None]
        grid = np.asarray(self.speeds)
        return params.get(self.coefficient, 0.0) * speeds[..., 0] + np.sum(
            self.slopes(params) * grid * np.tanh(speeds / grid), axis=-1)

    def probes(self) -> list[Probe]:
        """The linear coefficient's probe, then one saturating term per probe speed
        (θ = 1 is a slope of 1 N·s/m, as the coefficient's)."""
        return damping_probes(self.coefficient) + [
            Probe(f"{self.prefix} saturating at {v * 1e3:g} mm/s", None,
                  ParameterSpec(None, "linear", 1.0, "N·s/m"), +1, {"speed": v},
                  SaturatingViscosity((0.0,), (v,)), first_slope)
            for v in self.probe_speeds]

    def attach(self, act: Actuator, strength: float,
               probe: Probe) -> tuple[Actuator, dict[str, ParameterSpec]]:
        """``act`` with the coefficient and the terms, every one freed: from the
        coefficient's probe the coefficient takes ``strength``, from a saturating one
        the grid's term nearest its speed does and the coefficient starts a little
        above the baseline's (:func:`~.slots.damping_attach`)."""
        speed = probe.setting.get("speed")
        new, specs = damping_attach(act, strength if speed is None else 0.0,
                                    self.coefficient)
        scale = max(strength, 0.05)
        slopes = [START_SHARE * scale] * len(self.speeds)
        if speed is not None:
            slopes[int(np.argmin(np.abs(np.log(np.asarray(self.speeds) / speed))))] = scale
        new = new.with_extension(SaturatingViscosity(slopes, self.speeds))
        g = ext(SaturatingViscosity)
        return new, specs | {self.slope_name(v): ParameterSpec(
            lambda a, i=i: g(a).gains[i], "nonneg", scale, "N·s/m")
            for i, v in enumerate(self.speeds)}

    def describe(self, params: dict[str, float], what: str) -> str:
        """``what`` (the entry's words) and the form found, from refitted ``params``."""
        at = np.asarray(self.probe_speeds)
        force = self.force_curve(params, at)
        fitted = self.slopes(params)
        # A slope the fit drove to its bound (orders below the largest) is left out.
        slopes = [f"{c:.3g} to {v * 1e3:g} mm/s"
                  for c, v in zip(fitted, self.speeds, strict=True)
                  if c > USED_SHARE * fitted.max()]
        return (f"{what}: {self.coefficient} {params.get(self.coefficient, 0.0):.3g} N·s/m"
                + (" and saturating slopes " + ", ".join(slopes) if slopes else "")
                + "; force at " + ", ".join(f"{v * 1e3:g} mm/s {f * 1e3:.3g} mN"
                                            for v, f in zip(at, force, strict=True)))

    def plot(self, ax, params: dict[str, float], what: str, draws=None) -> bool:
        """The force found against the velocity, with its 95 % band (``draws``:
        :func:`~..form_band.draw_band`), beside the coefficient alone."""
        v = np.linspace(0.0, 2.0 * self.speeds[-1] / 3.0, 200)
        draw_band(ax, v * 1e3, lambda p: self.force_curve(p, v), params, draws, scale=1e3)
        ax.plot(v * 1e3, self.force_curve(params, v) * 1e3, color="tab:blue")
        ax.plot(v * 1e3, params.get(self.coefficient, 0.0) * v * 1e3, color="0.5", ls="--",
                lw=0.8, label=f"{self.coefficient} alone")
        ax.set_xlabel(f"{self.velocity} [mm/s]")
        ax.set_ylabel("friction added [mN]")
        slopes = self.slopes(params)
        used = int(np.sum(slopes > USED_SHARE * slopes.max())) if slopes.max() > 0 else 0
        ax.set_title(f"{what} ({used} saturating terms)", fontsize=9)
        ax.legend(fontsize=7)
        return True

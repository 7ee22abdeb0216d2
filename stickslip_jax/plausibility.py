"""Plausibility of an actuator's parameters: what a stick-slip piezo actuator can have.

A parameter file holds SI values, and the commonest mistake in one is a unit slip: a
stiffness written in N/µm and read as N/m (10⁶ too soft), a mass in g read as kg (10³
too heavy), a length in µm read as m. The file's own bounds (positive masses, ...)
cannot see these; the model then simulates, silently, an actuator that cannot exist.
:func:`implausible_parameters` compares each value with the range such actuators span
and, where the value lies outside, names the unit slip that would bring it back in.

The ranges are generous on purpose (several decades each), so that only a slip trips
them, never an unusual but real actuator; they are not tuned to any fixture. Where
they come from (orders of magnitude; the default profile, Lu et al. 2015's SmarAct
SLC-1720 read in SI, lies well inside each: Mp 2.5e-4 kg, Kp 2.6e6 N/m, Ms 0.025 kg):

- ``Mp`` [kg], the piezo element's moving mass, 1e-9..1: from a microgram-scale thin
  film or MEMS element to the effective mass (a third of the body) of the largest
  multilayer stacks (56 mm across, 0.1 m long: about 2 kg of PZT at 7.8 g/cm³).
- ``Kp`` [N/m], 1e2..1e9: piezo benders at about 1e2..1e4 N/m, thin shear plates at
  0.01..10 N/µm, multilayer stacks' data sheets at about 1..1000 N/µm.
- ``Ms`` [kg], the slider (runner) with its load, 1e-9..10: MEMS sliders to a stage
  carrying a payload of kilograms.
- ``Dp``, ``Ds`` and the friction law's dampings [N·s/m], 1e-6..1e7 (0 allowed: the
  undamped idealisation): the critical damping 2·√(K·M) over the stiffness and mass
  ranges above spans about 6e-4..2e5 N·s/m; damping ratios of 1e-2..50 widen it.
- ``pi_weights`` [m/V], their sum (the stroke per volt once every play has turned),
  1e-11..1e-5: a single shear plate moves about 0.5 nm/V (PZT's d15 ≈ 0.5..0.7 nm/V), long
  stacks about 0.1..1 µm/V (tens of µm at 100-150 V).
- ``pi_thresholds`` [V], the highest, 1e-3..1e4: piezo drives run at 10..1000 V.
- The friction law's parameters, by their unit in the law's own records
  (:attr:`~stickslip_jax.model.base.AbstractFriction.parameters`, so a new law is
  covered without a change here): a contact stiffness [N/m] (``rho0``, LuGre's
  ``sigma0``) 1e2..1e10: Mindlin's tangential stiffness 8·G*·a of contacts 1 µm..1 mm
  wide in polymer to steel (G* ≈ 3e8..3e10 Pa) is about 2e3..2e8 N/m, LuGre's classic
  σ0 is 1e5 N/m (Canudas de Wit et al. 1995); a break-away or pre-sliding displacement
  [m] (``z_ba``) 1e-10..1e-4: sub-nanometre for atomic-scale contacts to the µm of
  engineering contacts (Al-Bender and Swevers 2008) and tens of µm for soft ones; a
  force [N] (Coulomb levels, a preload) 1e-6..1e4; a velocity [m/s] (Stribeck)
  1e-8..10, around the 1e-4..1e-2 m/s usually reported (Armstrong-Hélouvry et al.
  1994). Dimensionless ratios and per-newton slopes are not judged.

Input stages, extensions and output maps carry their own units and are not judged.
:func:`check_actuator_plausible` is what the command line calls: one ``warning:`` line
per finding, and a :class:`~stickslip_jax.model.registry.ParameterError` (exit 2)
naming the parameter when the simulator cannot run the model at all.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .model.registry import ParameterError

__all__ = ["Finding", "PlausibleRange", "check_actuator_plausible",
           "implausible_parameters"]


@dataclass(frozen=True)
class PlausibleRange:
    """Where a parameter of a stick-slip piezo actuator can lie [its unit], and what
    lies at each end (for messages: "above the stiffest piezo stacks")."""

    low: float
    high: float
    lowest: str
    highest: str


# The ranges [SI]; the module docstring says where each comes from.
MP = PlausibleRange(1e-9, 1.0, "the lightest piezo elements", "the heaviest piezo stacks")
KP = PlausibleRange(1e2, 1e9, "the softest piezo benders", "the stiffest piezo stacks")
MS = PlausibleRange(1e-9, 10.0, "the lightest micro-sliders",
                    "the heaviest sliders with a payload")
DAMPING = PlausibleRange(1e-6, 1e7, "any damping worth modelling",
                         "any damping of a piezo drive")
STROKE = PlausibleRange(1e-11, 1e-5, "a single shear plate's stroke per volt",
                        "the longest stacks' stroke per volt")
THRESHOLD = PlausibleRange(1e-3, 1e4, "any drive's voltage scale",
                           "any piezo drive's voltage")
LAW_RANGES = {
    "N/m": PlausibleRange(1e2, 1e10, "the softest friction contacts",
                          "the stiffest friction contacts"),
    "N·s/m": DAMPING,
    "m": PlausibleRange(1e-10, 1e-4, "the shortest pre-sliding displacements",
                        "the longest pre-sliding displacements"),
    "N": PlausibleRange(1e-6, 1e4, "the smallest forces of such a drive",
                        "the largest forces of such a drive"),
    "m/s": PlausibleRange(1e-8, 10.0, "the slowest Stribeck velocities",
                          "the fastest Stribeck velocities"),
}
"""Ranges of a friction law's parameters by their SI unit (see the module docstring)."""

OTHER_UNITS = {
    "kg": {"g": 1e-3, "mg": 1e-6, "µg": 1e-9},
    "N/m": {"N/mm": 1e3, "N/µm": 1e6},
    "N·s/m": {"N·s/mm": 1e3, "N·s/µm": 1e6},
    "m": {"mm": 1e-3, "µm": 1e-6, "nm": 1e-9},
    "m/V": {"µm/V": 1e-6, "nm/V": 1e-9},
    "V": {"mV": 1e-3, "kV": 1e3},
    "N": {"mN": 1e-3, "kN": 1e3},
    "m/s": {"mm/s": 1e-3, "µm/s": 1e-6},
}
"""The units a value of each SI unit is commonly written in, with their size [SI]: the
candidates for a unit slip."""

TIME_SCALE_UNITS = ("kg", "N/m", "N·s/m")
"""Units of the parameters that set the model's rates (masses, stiffnesses, dampings)."""


@dataclass(frozen=True)
class Finding:
    """One parameter outside what a stick-slip piezo actuator can have.

    Attributes
    ----------
    name: the parameter's name in a parameter file.
    value: its value [unit] (for ``pi_weights`` their sum, for ``pi_thresholds`` the
        highest; ``label`` says so).
    unit: its SI unit.
    plausible: the range it should lie in.
    slips: the likely unit slips, each a phrase with its factor, e.g. "a value in
        N/µm (×1e-6) read as N/m"; empty when no common slip brings it back in range.
    label: how the message names it ('' for ``name``).
    """

    name: str
    value: float
    unit: str
    plausible: PlausibleRange
    slips: tuple[str, ...] = ()
    label: str = ""

    @property
    def above(self) -> bool:
        return self.value > self.plausible.high

    @property
    def ratio(self) -> float:
        """How far outside the range [-]: value/high above it, low/value below (> 1)."""
        p = self.plausible
        return self.value / p.high if self.above else p.low / self.value

    @property
    def speeds_up(self) -> bool:
        """Whether the slip makes the model faster than any actuator (a stiffness or
        damping too high, a mass too low): the findings that can stop the simulator."""
        if self.unit not in TIME_SCALE_UNITS:
            return False
        return self.above != (self.unit == "kg")

    @property
    def facts(self) -> str:
        """The value against its range, e.g. "Kp 2.62e+12 N/m is 2,620x above the
        stiffest piezo stacks (plausible: 100..1e9 N/m)"."""
        p = self.plausible
        side, what = ("above", p.highest) if self.above else ("below", p.lowest)
        return (f"{self.label or self.name} {self.value:.3g} {self.unit} is "
                f"{_times(self.ratio)}x {side} {what} (plausible: {_num(p.low)}.."
                f"{_num(p.high)} {self.unit})")

    @property
    def question(self) -> str:
        """The likely slip as a question, e.g. "a value in N/µm (×1e-6) read as N/m?"."""
        return (" or ".join(self.slips) if self.slips else "a unit slip") + "?"

    def __str__(self) -> str:
        return f"{self.facts}: {self.question}"


def _times(ratio: float) -> str:
    if ratio < 10:
        return f"{ratio:.2g}"
    return f"{ratio:,.0f}" if ratio < 1e5 else f"{ratio:.1e}"


def _num(x: float) -> str:
    """A range's end: a power of ten outside 0.01..1000 as 1eN, else plain."""
    exp = math.log10(x)
    if exp == round(exp) and not -2 <= exp <= 3:
        return f"1e{round(exp)}"
    return f"{x:g}"


def _power(factor: float) -> str:
    return f"1e{round(math.log10(factor))}"


def likely_slips(value: float, unit: str, plausible: PlausibleRange) -> tuple[str, ...]:
    """The common unit slips that would bring ``value`` [unit] back into ``plausible``
    (at most two, mildest first), as phrases: a number written in another unit and read
    as SI ("a value in g (×1e3) read as kg"), or an SI value converted again as if it
    were in another unit ("a value in N/m converted again as if from N/µm (×1e6)")."""
    candidates = []  # (|log10 factor|, read as SI?, "unit (×factor)")
    for other, size in OTHER_UNITS.get(unit, {}).items():
        # factor: the value read over the value meant
        for factor, read in ((1 / size, True), (size, False)):
            if (factor > 1) == (value > plausible.high) and (
                    plausible.low <= value / factor <= plausible.high):
                candidates.append((abs(math.log10(factor)), read,
                                   f"{other} (×{_power(factor)})"))
    mildest = sorted(candidates)[:2]
    read = " or ".join(w for _, r, w in mildest if r)
    converted = " or ".join(w for _, r, w in mildest if not r)
    return tuple(([f"a value in {read} read as {unit}"] if read else [])
                 + ([f"a value in {unit} converted again as if from {converted}"]
                    if converted else []))


def _scalar(value) -> float | None:
    """A parameter's value as a float, or None for a batch of values (not judged)."""
    arr = np.asarray(value, dtype=float)
    return float(arr.reshape(-1)[0]) if arr.size == 1 else None


def _law_entries(friction) -> list[tuple[str, float, str]]:
    """(file name, value, unit) of the friction law's parameters, read through the
    law's own records (an alias such as ``z_ba`` stands for its targets when they
    agree, else the targets are judged one by one)."""
    try:
        values = friction.to_params()
        records = {p.name: p for p in friction.parameters}
    except (AttributeError, TypeError, ValueError):  # not a registered law's form
        return []
    for p in records.values():  # (written files hold the targets, not the alias)
        targets = [values.get(t) for t in p.alias_for]
        if targets and None not in targets and len(set(targets)) == 1:
            for name in p.alias_for:
                values.pop(name)
            values[p.name] = targets[0]
    return [(n, v, records[n].unit) for n, v in values.items() if n in records]


def _entries(actuator) -> list[tuple[str, object, str, PlausibleRange, str]]:
    """(name, value, unit, range, label) of every parameter judged."""
    piezo, slider, hysteresis = actuator.piezo, actuator.slider, actuator.hysteresis
    out = [("Mp", piezo.Mp, "kg", MP, ""), ("Kp", piezo.Kp, "N/m", KP, ""),
           ("Dp", piezo.Dp, "N·s/m", DAMPING, ""), ("Ms", slider.Ms, "kg", MS, ""),
           ("Ds", slider.Ds, "N·s/m", DAMPING, "")]
    weights = getattr(hysteresis, "weights", None)
    if weights is not None:
        out.append(("pi_weights", np.sum(np.asarray(weights)), "m/V", STROKE,
                    "pi_weights (sum)"))
    thresholds = getattr(hysteresis, "thresholds", None)
    if thresholds is not None and np.size(thresholds):
        out.append(("pi_thresholds", np.max(np.asarray(thresholds)), "V", THRESHOLD,
                    "pi_thresholds (highest)"))
    for name, value, unit in _law_entries(actuator.friction):
        if unit in LAW_RANGES:
            out.append((name, value, unit, LAW_RANGES[unit], ""))
    return out


def implausible_parameters(actuator) -> list[Finding]:
    """The parameters of ``actuator`` outside what a stick-slip piezo actuator can
    have (the module docstring gives the ranges and their sources), each with the
    likely unit slip. Values ≤ 0 (an idealisation such as no damping, or a sign the
    file's own bounds judge) and batched values are not judged. Numpy only: no
    simulation, no compilation."""
    found = []
    for name, raw, unit, plausible, label in _entries(actuator):
        value = _scalar(raw)
        if value is None or not value > 0 or plausible.low <= value <= plausible.high:
            continue
        found.append(Finding(name, value, unit, plausible,
                             likely_slips(value, unit, plausible), label))
    return found


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)  # sys.stderr at call time (test runners)


def _stepping_refusal(actuator, stepping, dt, samples):
    """The :class:`~stickslip_jax.stepping.SteppingError` the simulator would raise
    for this actuator (the model's time scale; with ``dt`` [s] and ``samples``, the
    whole call's sub-steps too), or None. Plans steps only: no simulation."""
    from .stepping import DEFAULT_STEPPING, SteppingError

    stepping = DEFAULT_STEPPING if stepping is None else stepping
    try:
        if dt is None:
            stepping.longest_step(actuator)
        else:
            stepping.plan(actuator, dt, samples=samples)
    except SteppingError as err:
        return err
    return None


def _mode_hz(actuator) -> float:
    """The model's fastest mechanical mode [Hz] (inf where it is not finite)."""
    from .stepping import mechanical_rate

    try:
        rate = mechanical_rate(actuator)
    except Exception:  # noqa: BLE001 - a report must not fail where the model does
        return math.inf
    return rate / (2 * math.pi) if math.isfinite(rate) else math.inf


def _why_not(mode_hz: float, samples: int | None) -> str:
    """Why the simulator cannot step a model whose fastest mode is ``mode_hz`` [Hz]."""
    from .stepping import MAX_PLAUSIBLE_MODE_HZ

    if not math.isfinite(mode_hz):
        return "the model's linearisation at rest is then not finite"
    if mode_hz > MAX_PLAUSIBLE_MODE_HZ:
        return (f"the model's fastest mode is then {mode_hz / 1e6:.3g} MHz, beyond the "
                f"{MAX_PLAUSIBLE_MODE_HZ / 1e6:g} MHz the simulator steps on its own")
    count = f"{samples:,}" if samples else "these"
    return (f"the model's fastest mode is then {mode_hz / 1e3:.3g} kHz, and {count} "
            "samples at its step pass the simulator's limit of sub-steps")


def _culprit(findings: list[Finding], refusal, actuator) -> tuple[Finding | None, float]:
    """The finding that explains the simulator's ``refusal`` (None: none does), with
    the model's fastest mode [Hz]: a slip that speeds the model up, and only when the
    model's own time scale is what the simulator refuses (not, say, a job's size)."""
    from .stepping import TYPICAL_MODE_HZ

    if refusal is None:
        return None, math.nan
    mode_hz = _mode_hz(actuator)
    if not mode_hz > TYPICAL_MODE_HZ:  # an ordinary model: the refusal is not its slip
        return None, mode_hz
    fast = [f for f in findings if f.speeds_up]
    return (max(fast, key=lambda f: f.ratio) if fast else None), mode_hz


def check_actuator_plausible(actuator, source=None, *, stepping=None, dt=None,
                             samples: int | None = None,
                             warn: Callable[[str], None] | None = None) -> list[Finding]:
    """Report the implausible parameters of ``actuator`` (read from ``source``, a
    parameter file, named in the messages): one ``warning: ...`` line each through
    ``warn`` (default: stderr), and a :class:`ParameterError` (exit 2 on the command
    line) where the simulator cannot run the model at all and a slip that speeds the
    model up (a stiffness or damping too high, a mass too low) explains it; that
    finding is then the error, not a warning.

    ``stepping``: the :class:`~stickslip_jax.stepping.Stepping` the command will use
    (default: the default stepping; an explicit ``max_step`` lets any mode through);
    ``dt`` [s] and ``samples``: the call's sample interval and count, to include the
    limit on all sub-steps. A refusal no finding explains is raised as the simulator's
    own :class:`~stickslip_jax.stepping.SteppingError`. Returns the findings.
    """
    warn = _stderr if warn is None else warn
    where = f"{source}: " if source is not None else ""
    findings = implausible_parameters(actuator)
    # Plausible values need no planning here: the command plans its steps anyway.
    refusal = _stepping_refusal(actuator, stepping, dt, samples) if findings else None
    culprit, mode_hz = _culprit(findings, refusal, actuator)
    for finding in findings:
        if finding is not culprit:
            warn(f"warning: {where}{finding}")
    if culprit is not None:
        raise ParameterError(f"{culprit.facts}, and {_why_not(mode_hz, samples)}: "
                             f"{culprit.question}",
                             source=None if source is None else str(source),
                             fix=f"write {culprit.name} in {culprit.unit}.")
    if refusal is not None:
        raise refusal
    return findings

"""What a set of recordings can determine, decided before any fitting.

Lu 2015's protocol gives each kind of recording one job (§IV-B):

- a **step response** determines the dynamics: the ringing after the edge sets the
  first resonance and its damping, hence Mp, Dp, Kp, Ds, rho0 (up to the common mass
  factor; one of them is held);
- a **sine** determines the Prandtl-Ishlinskii weights: the slopes of its loop;
- **sawtooth** drives determine the friction break-away of their direction
  (``z_ba_forward`` / ``z_ba_backward``) through the slip at each abrupt edge.

A recording of the right kind may still be too short, too coarsely sampled or too
quiet to show what it is for. :func:`assess` applies the rules below to each
recording, for the parameter groups of the identification steps asked for, and
says per undetermined group which parameters, why, and which recording would
determine them. Every threshold is stated in the model's own time scales (the first
resonance of the starting parameters, the drive period, the play thresholds), not in
numbers of a particular data set.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..io import Recording
from ..linear import stick_modes
from ..model.actuator import Actuator
from ..model.hysteresis import default_thresholds
from ..noise import noise_sigma, sigma_from_differences
from .dataset import period_ends, step_lengths
from .parameters import law_fittable
from .step_names import dynamics_names, friction_names

RING_PERIODS = 3.0
"""Periods of the first resonance a step response must hold after its edge [-]: a
damped oscillation's frequency and decay rate are two numbers, and they separate only
when more than one swing is seen; three also shows how fast the ringing dies."""

REST_PERIODS = 1.0
"""Periods of the first resonance of rest before a step edge that a recommended step
recording holds [-] (the level and the noise before the edge; not a rule)."""

SAMPLES_PER_MODE_PERIOD = 8.0
"""Samples per period of the first resonance [-] that a step response or a sawtooth
needs: the ringing's peak and trough each need a few samples, and a sawtooth's
one-sample flyback must be fast against the resonance to make the slider slip."""

MIN_DRIVE_PERIODS = 2.0
"""Whole drive periods a sine or a sawtooth must hold [-]: the first period starts
from rest (a sine traces the PI's initial loading curve, not its loop; a sawtooth
starts unstrained), so the second is the first one that repeats; a phase-locked step
length needs two period ends."""

SLOW_DRIVE = 10.0
"""A recommended sine or sawtooth frequency is at most the first resonance over this
[-]: the sine's loop is then quasi-static, and a sawtooth edge's ringing has died out
well before the next edge."""

MIN_SNR = 10.0
"""The output's peak-to-peak must exceed this many noise standard deviations [-]; a
trace buried in the sensor noise determines nothing."""


@dataclass(frozen=True)
class Undetermined:
    """One group of parameters that the recordings cannot determine.

    ``names`` the parameters; ``steps`` the identification steps that fit them;
    ``reason`` why the data cannot (names the recordings and what they lack);
    ``record`` the recording that would determine them; ``blocking`` False only for a
    drive direction that was not recorded at all while the other was: the user drives
    one way, the parameter is not fitted and keeps its start value.
    """

    names: tuple[str, ...]
    steps: tuple[str, ...]
    reason: str
    record: str
    blocking: bool = True

    def line(self) -> str:
        """``reason: names undetermined; record ...`` in one line."""
        what = "undetermined" if self.blocking else "not fitted (kept at the start value)"
        return f"{self.reason}: {', '.join(self.names)} {what}; {self.record}"

    def as_dict(self) -> dict:
        return {"names": list(self.names), "steps": list(self.steps), "reason": self.reason,
                "record": self.record, "blocking": self.blocking}


@dataclass(frozen=True)
class Assessment:
    """Result of :func:`assess`.

    ``groups`` the undetermined groups; ``steps`` the steps asked for;
    ``first_mode_Hz`` the damped first resonance of the starting parameters [Hz], the
    time scale behind the step and sampling rules; ``problems`` recording name → why
    it cannot serve its purpose (recordings that can are absent).
    """

    groups: tuple[Undetermined, ...]
    steps: tuple[str, ...]
    first_mode_Hz: float
    problems: dict[str, str] = field(default_factory=dict)

    @property
    def blocking(self) -> tuple[Undetermined, ...]:
        """The groups that stop the identification."""
        return tuple(g for g in self.groups if g.blocking)

    @property
    def names(self) -> tuple[str, ...]:
        """Every parameter name of every group."""
        return tuple(n for g in self.groups for n in g.names)

    @property
    def determinable_steps(self) -> tuple[str, ...]:
        """The steps asked for whose parameters the data all determine (``joint``
        needs every group)."""
        bad = {s for g in self.blocking for s in g.steps}
        return tuple(s for s in self.steps if s not in bad)

    def statement(self) -> str:
        """Several lines: what cannot be determined, why, which recording would
        determine it, and which of the steps asked for the data do determine."""
        lines = [f"these recordings cannot determine the parameters that the steps asked for "
                 f"({', '.join(self.steps)}) fit; nothing was fitted:"]
        for g in self.blocking:
            lines += [f"- {g.reason}: {', '.join(g.names)} undetermined;",
                      f"  {g.record[:1].upper()}{g.record[1:]}."]
        ok = self.determinable_steps
        lines.append("these recordings determine the steps: " + ", ".join(ok)
                     + f" (fit only those: --steps {','.join(ok)})" if ok else
                     "these recordings determine none of the steps asked for.")
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {"steps": list(self.steps), "first_mode_Hz": self.first_mode_Hz,
                "groups": [g.as_dict() for g in self.groups], "problems": dict(self.problems)}


# ---------------------------------------------------------------- the model's scales


def first_mode(actuator: Actuator) -> float:
    """Damped frequency [Hz] of the first mode of the starting parameters' stick chain:
    the ringing a step response shows (:func:`~stickslip_jax.linear.stick_modes`); its
    natural frequency when it is overdamped (then it does not ring)."""
    modes = stick_modes(actuator)
    f = float(modes.damped_Hz[0])
    return f if f > 0 else float(modes.natural_Hz[0])


def min_sample_rate(f1_Hz: float) -> float:
    """Lowest sample rate [Hz] at which a step response or a sawtooth shows the first
    resonance ``f1_Hz`` [Hz] (:data:`SAMPLES_PER_MODE_PERIOD` samples per period)."""
    return SAMPLES_PER_MODE_PERIOD * f1_Hz


def slow_frequency(f1_Hz: float) -> float:
    """A round drive frequency [Hz] (1, 2 or 5 times a power of ten) at most
    ``f1_Hz/SLOW_DRIVE``: quasi-static for the first resonance ``f1_Hz`` [Hz]."""
    top = f1_Hz / SLOW_DRIVE
    decade = 10.0 ** math.floor(math.log10(top))
    return max(m * decade for m in (1.0, 2.0, 5.0) if m * decade <= top)


def _ms(t_s: float) -> str:
    return f"{math.ceil(t_s * 1e4) / 10:g} ms"  # rounded up to 0.1 ms: a minimum


def _khz(f_Hz: float) -> str:
    return f"{math.ceil(f_Hz / 100) / 10:g} kHz"


# ------------------------------------------------------------------ per recording


def quiet_problem(rec: Recording) -> str | None:
    """Why ``rec``'s output is too small to tell anything, or None.

    The output must move: its peak-to-peak above :data:`MIN_SNR` noise standard
    deviations, the noise estimated from the recording itself
    (:func:`~stickslip_jax.noise.noise_sigma`)."""
    q = np.asarray(rec.position_m, dtype=float)
    span = float(np.ptp(q))
    if q.size < 8:
        return f"{rec.name}: {q.size} samples, too few to tell the output from its noise"
    try:
        sigma = noise_sigma(rec)
    except (TypeError, ValueError):  # a periodic drive whose frequency is unknown
        sigma = sigma_from_differences(q)
    if not span > 0:
        return f"{rec.name}: the output does not move"
    if span < MIN_SNR * sigma:
        return (f"{rec.name}: the output moves {span * 1e9:.3g} nm peak to peak, under "
                f"{MIN_SNR:g} times its noise ({sigma * 1e9:.3g} nm)")
    return None


def step_problem(rec: Recording, f1_Hz: float) -> str | None:
    """Why the step response ``rec`` cannot determine the dynamics, or None.

    Rules, with the first resonance ``f1_Hz`` [Hz] of the starting parameters:

    - the edge must be in the recording (a voltage jump of at least half the voltage's
      range): a simulation starts at rest under the first voltage, so a recording all
      before the edge (or all after it) shows a constant level, which holds no
      dynamics;
    - at least :data:`RING_PERIODS` periods of ``f1_Hz`` after the edge: the ringing's
      frequency and decay are what determine the masses, dampings and stiffnesses;
    - at least :func:`min_sample_rate` samples per second, so that the ringing is
      resolved and the one-sample edge is abrupt for it;
    - an output above the noise (:func:`quiet_problem`).
    """
    u = np.asarray(rec.voltage_V, dtype=float)
    duration = rec.n * rec.dt
    span = float(np.ptp(u))
    if span == 0.0:
        where = ("ends before the step edge" if abs(u[0]) < abs(rec.drive.amplitude_V or 1.0)
                 / 2 else "starts after the step edge")
        return (f"{rec.name}: the voltage stays at {u[0]:g} V over its {rec.n} samples "
                f"({_ms(duration)}): the recording {where}")
    k = int(np.argmax(np.abs(np.diff(u))))
    if abs(u[k + 1] - u[k]) < 0.5 * span:
        return f"{rec.name}: the voltage has no step edge (no jump of half its range)"
    after = (rec.n - 1 - k) * rec.dt
    need = RING_PERIODS / f1_Hz
    if after < need:
        return (f"{rec.name}: {_ms(after)} after the edge, less than {RING_PERIODS:g} "
                f"periods of the first resonance ({_ms(need)})")
    if rec.sample_rate_Hz < min_sample_rate(f1_Hz):
        return (f"{rec.name}: sampled at {_khz(rec.sample_rate_Hz)}, under "
                f"{SAMPLES_PER_MODE_PERIOD:g} samples per period of the first resonance "
                f"({_khz(min_sample_rate(f1_Hz))})")
    return quiet_problem(rec)


def _periods(rec: Recording) -> float:
    f = rec.drive.frequency_Hz
    return rec.n * rec.dt * f if f else 0.0


def _periods_problem(rec: Recording) -> str | None:
    f = rec.drive.frequency_Hz
    if not f or not f > 0:
        return f"{rec.name}: the drive frequency is unknown (give frequency_Hz)"
    # Half a sample of slack: a duration is rounded to whole samples.
    if _periods(rec) + 0.5 * rec.dt * f < MIN_DRIVE_PERIODS:
        return (f"{rec.name}: {_periods(rec):.4g} period(s) of its {f:g} Hz drive, fewer "
                f"than {MIN_DRIVE_PERIODS:g} ({_ms(MIN_DRIVE_PERIODS / f)})")
    return None


def sine_problem(rec: Recording, thresholds: np.ndarray) -> str | None:
    """Why the sine ``rec`` cannot determine the PI weights, or None.

    Rules: at least :data:`MIN_DRIVE_PERIODS` periods (the first rise from rest traces
    the initial loading curve; the loop repeats from the second period on); every two
    consecutive play thresholds ``r_i < r_{i+1}`` [V] that the loop engages (after a
    reversal play i moves once the voltage has travelled ``2·r_i``, within the
    peak-to-peak ``A``) engage at least one sample period apart: a weight changes the
    loop's slope at its own engagement point, and two kinks between the same two
    samples are one kink to the data; an output above the noise.
    """
    problem = _periods_problem(rec)
    if problem:
        return problem
    # The drive's own amplitude: the samples' peak-to-peak depends on where they fall.
    a = abs(float(rec.drive.amplitude_V or np.ptp(rec.voltage_V)))
    f = float(rec.drive.frequency_Hz)
    travel = 2.0 * np.asarray(thresholds, dtype=float)
    travel = travel[travel < a]
    if travel.size >= 2 and a > 0:
        # Time after a reversal of (A/2)(1 - cos 2πft) at which the voltage has travelled s.
        t = np.arccos(np.clip(1.0 - 2.0 * travel / a, -1.0, 1.0)) / (2 * np.pi * f)
        gap = float(np.min(np.diff(t)))
        if gap < rec.dt:
            return (f"{rec.name}: sampled at {_khz(rec.sample_rate_Hz)}, but two play "
                    f"thresholds engage {gap * 1e6:.3g} µs apart on its loop: their "
                    f"weights cannot be told apart (record at ≥ {_khz(1 / gap)} or fit "
                    f"fewer play operators, --n-pi)")
    return quiet_problem(rec)


def sawtooth_problem(rec: Recording, f1_Hz: float) -> str | None:
    """Why the sawtooth ``rec`` cannot determine its direction's break-away, or None.

    Rules: at least :data:`MIN_DRIVE_PERIODS` periods; at least
    :func:`min_sample_rate` (the flyback, one sample long, must be abrupt against the
    first resonance to make the slider slip); an output above the noise; and the
    slider must slip: break-away is where the contact starts to slide, so a drive
    under which it never slides (scanning) bounds z_ba only from below. Slipping shows
    as a mean phase-locked advance per period (:func:`~.dataset.step_lengths`) above
    :data:`MIN_SNR` noise standard deviations (a period-end sample pair carries
    √2·σ; without noise, above rounding).
    """
    problem = _periods_problem(rec)
    if problem:
        return problem
    if rec.sample_rate_Hz < min_sample_rate(f1_Hz):
        return (f"{rec.name}: sampled at {_khz(rec.sample_rate_Hz)}, under "
                f"{SAMPLES_PER_MODE_PERIOD:g} samples per period of the first resonance "
                f"({_khz(min_sample_rate(f1_Hz))})")
    problem = quiet_problem(rec)
    if problem:
        return problem
    q = np.asarray(rec.position_m, dtype=float)
    steps = step_lengths(q, period_ends(rec))
    if not steps.size:
        return (f"{rec.name}: fewer than {MIN_DRIVE_PERIODS:g} whole periods of its "
                f"{rec.drive.frequency_Hz:g} Hz drive end in the recording")
    advance = abs(float(np.mean(steps)))
    sigma = noise_sigma(rec)
    if not advance > max(MIN_SNR * sigma, 1e-9 * float(np.ptp(q))):
        return (f"{rec.name}: the slider does not slip under this {rec.drive.amplitude_V:g} "
                f"V drive (it advances {advance * 1e9:.2g} nm per period, within "
                f"{MIN_SNR:g} times the {sigma * 1e9:.2g} nm noise), which bounds the "
                f"break-away only from below")
    return None


# ----------------------------------------------------------------------- assessment


def _is(waveform: str):
    return lambda r: r.drive.waveform == waveform


def assess(recordings: Sequence[Recording], actuator: Actuator, *,
           steps: Sequence[str] = ("dynamics", "hysteresis", "friction", "joint"),
           fix=(), also_fit: Sequence[str] = (), n_pi: int = 35) -> Assessment:
    """Decide, before fitting, which parameters of the ``steps`` asked for the
    recordings cannot determine (rules: :func:`step_problem`, :func:`sine_problem`,
    :func:`sawtooth_problem`).

    ``actuator`` the starting parameters (their first resonance sets the time scales;
    their law says which parameters each step fits); ``fix`` names held (not judged);
    ``also_fit`` the law's on-request parameters asked for; ``n_pi`` play operators,
    spread over the recorded voltage range as the identification spreads them.
    Groups: the dynamics (``dynamics``, ``joint``) need a step response, the PI
    weights (``hysteresis``, ``joint``) a sine, each direction's break-away
    (``friction``, ``joint``) a sawtooth of that direction that steps; the law's other
    friction-step parameters any stepping sawtooth.
    """

    steps = tuple(steps)
    recordings = [r for r in recordings if r.position_m is not None]
    f1 = first_mode(actuator)
    fs_min = min_sample_rate(f1)
    slow = slow_frequency(f1)
    volts = [float(np.max(np.abs(r.voltage_V))) for r in recordings]
    a_rec = max([v for v in volts if v > 0], default=40.0)  # Lu records at 40 V
    u_all = np.concatenate([np.asarray(r.voltage_V) for r in recordings]) if recordings \
        else np.zeros(1)
    thresholds = default_thresholds(n_pi, max(float(np.ptp(u_all)), 1e-6))
    problems: dict[str, str] = {}

    def usable(keep, rule):
        recs = [r for r in recordings if keep(r)]
        good = []
        for r in recs:
            p = rule(r)
            if p is None:
                good.append(r)
            else:
                problems[r.name] = p
        return recs, good

    def why(kind, recs):
        if not recs:
            return f"no {kind}"
        return f"no usable {kind} ({'; '.join(problems[r.name] for r in recs)})"

    groups: list[Undetermined] = []

    def in_steps(*names):
        return tuple(s for s in ("dynamics", "hysteresis", "friction", "joint")
                     if s in names and s in steps)

    # Dynamics: the step responses.
    dyn_steps = in_steps("dynamics", "joint")
    dyn = dynamics_names(actuator, fix=fix, also_fit=also_fit)
    if dyn_steps and dyn:
        recs, good = usable(_is("step"), lambda r: step_problem(r, f1))
        if not good:
            amp = next((r.drive.amplitude_V for r in recs if r.drive.amplitude_V), a_rec)
            rest, ring = REST_PERIODS / f1, RING_PERIODS / f1
            groups.append(Undetermined(
                tuple(dyn), dyn_steps, why("step response", recs),
                f"record a {abs(amp):g} V step of at least {_ms(rest + ring)} at "
                f"≥ {_khz(fs_min)} ({_ms(rest)} at rest, the edge, then {RING_PERIODS:g} "
                f"periods of the first resonance, {f1:.0f} Hz by the starting parameters)"))

    # Hysteresis: the sines.
    hys_steps = in_steps("hysteresis", "joint")
    if hys_steps:
        recs, good = usable(_is("sine"), lambda r: sine_problem(r, thresholds))
        if not good:
            groups.append(Undetermined(
                ("pi_weights",), hys_steps, why("sine", recs),
                f"record a {a_rec:g} V, {slow:g} Hz sine of at least "
                f"{MIN_DRIVE_PERIODS:g} periods ({_ms(MIN_DRIVE_PERIODS / slow)}) at "
                f"≥ {_khz(fs_min)}"))

    # Friction: the sawtooths, per direction.
    fr_steps = in_steps("friction", "joint")
    fr = friction_names(actuator, fix=fix, also_fit=also_fit)
    if fr_steps and fr:
        saws = [r for r in recordings if r.drive.waveform == "sawtooth"]
        record = (f"of at least {MIN_DRIVE_PERIODS:g} periods ({_ms(MIN_DRIVE_PERIODS / slow)} "
                  f"at {slow:g} Hz) at ≥ {_khz(fs_min)}, at an amplitude the slider "
                  f"steps under (Lu: 40 and 60 V)")
        direction = {p.name: p.direction for p in law_fittable(actuator)}
        any_good = []
        if not saws:
            groups.append(Undetermined(tuple(fr), fr_steps, "no sawtooth",
                                       f"record a forward and a backward sawtooth, each {record}"))
        for way in ("forward", "backward") if saws else ():
            names = tuple(n for n in fr if direction.get(n) == way)
            backward = way == "backward"
            recs, good = usable(lambda r, b=backward: r in saws and r.drive.is_backward == b,
                                lambda r: sawtooth_problem(r, f1))
            any_good += good
            if names and not good:
                # One direction never driven while the other was: the user drives one
                # way; its break-away stays at the start and nothing else needs it.
                one_way = backward and not recs and bool(saws)
                groups.append(Undetermined(
                    names, fr_steps, why(f"{way} sawtooth", recs),
                    f"record a {way} sawtooth {record}", blocking=not one_way))
        rest = tuple(n for n in fr if not direction.get(n))
        if saws and rest and not any_good:
            groups.append(Undetermined(rest, fr_steps, why("stepping sawtooth", saws),
                                       f"record a sawtooth {record}"))
    return Assessment(tuple(groups), steps, f1, problems)

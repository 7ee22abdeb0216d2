"""Drive inference: recognise the waveform, amplitude, frequency and direction of a
sampled drive voltage by fitting the drive definitions of docs/model.md ("Drives and
recordings") to it.

:func:`infer_drive` fills the metadata a recording leaves out
(:func:`stickslip_jax.io.load_recording` calls it). It lives here rather than in
:mod:`stickslip_jax.signals` because the signal generators build
:class:`~stickslip_jax.io.Recording` objects (signals imports io) while io needs the
inference when it reads a file: in signals it would close an import cycle. This
module is a leaf: pure numpy, no JAX, no other module of the package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DIRECTIONS", "WAVEFORMS", "DriveInfo", "infer_drive"]

WAVEFORMS = ("sawtooth", "sine", "step", "other")
DIRECTIONS = ("forward", "backward")


# ----------------------------------------------------------------------- drive info


@dataclass(frozen=True)
class DriveInfo:
    """What drives a recording.

    Attributes
    ----------
    waveform:
        ``"sawtooth"``, ``"sine"``, ``"step"`` or ``"other"``.
    amplitude_V:
        Amplitude ``A`` [V] as docs/model.md defines it per waveform (sawtooth: the size
        of the ramp, not the peak sample; sine: the peak of ``(A/2)(1 − cos)``; step:
        the level after the step), or None when unknown.
    frequency_Hz:
        Frequency [Hz] (sawtooth, sine), or None.
    direction:
        ``"forward"``, ``"backward"`` or None.
    inferred:
        True when at least one field was inferred from the voltage rather than read
        from the metadata.
    """

    waveform: str
    amplitude_V: float | None = None
    frequency_Hz: float | None = None
    direction: str | None = None
    inferred: bool = False

    def __post_init__(self) -> None:
        if self.waveform not in WAVEFORMS:
            raise ValueError(f"waveform must be one of {WAVEFORMS}, got {self.waveform!r}")
        if self.direction is not None and self.direction not in DIRECTIONS:
            raise ValueError(f"direction must be one of {DIRECTIONS}, got {self.direction!r}")

    @property
    def is_backward(self) -> bool:
        """True only for a backward sawtooth (the drive that selects ``z_ba_backward``).

        A sine or a step has no slow/abrupt asymmetry, so it counts as forward whatever
        the metadata's ``direction`` says; so does an unknown waveform.
        """
        return self.waveform == "sawtooth" and self.direction == "backward"



# ------------------------------------------------------------------ drive inference


def infer_drive(time_s: np.ndarray, voltage_V: np.ndarray, *, rtol: float = 1e-3) -> DriveInfo:
    """Recognise the drive from the sampled voltage (docs/model.md "Drives and recordings").

    Parameters
    ----------
    time_s:
        Uniform sample times [s].
    voltage_V:
        Drive voltage [V].
    rtol:
        A waveform is recognised when its least-squares model fits the samples within
        ``rtol`` times the voltage's peak-to-peak range, RMS (and within 10 times that
        at every sample), so that a little measurement noise is tolerated.

    Returns
    -------
    DriveInfo
        ``inferred=True``. Recognised, in this order:

        - step: 0 up to one jump, then a constant ``A`` (amplitude = ``A``, signed; no
          frequency or direction). A constant non-zero voltage counts as a step at or
          before the first sample.
        - sawtooth: linear ramps broken by one-sample edges against the ramp. The model
          ``U_k = a·t_k + b·m_k + c`` (``m_k`` = edges so far) is fitted by least squares;
          ``A = |b|`` is the edge height plus one ramp step (the forward peak sample is
          only ``A·(1 − f/fs)``) and ``f = |a|/A``. Needs one edge, so about one period
          or more; works for any, non-integer, number of periods.
        - sine: ``c0 + c1·cos ωt + c2·sin ωt``; ``ω`` starts from the exact three-term
          recurrence ``U_{k+1} + U_{k−1} = 2 cos(ω dt)·U_k + const`` and is refined by
          Gauss-Newton. ``A = 2·hypot(c1, c2)`` (negative when the offset ``c0`` is),
          ``f = ω/2π``. Needs half a period or more.
        - anything else: ``"other"``, with no amplitude or frequency.

        A constant offset is tolerated for sawtooth and sine. Direction: sawtooth only
        (forward for a rising ramp, backward for a falling one).
    """
    t = np.asarray(time_s, dtype=np.float64)
    u = np.asarray(voltage_V, dtype=np.float64)
    if t.ndim != 1 or t.shape != u.shape:
        raise ValueError(f"time_s and voltage_V must be 1-D of equal length, got "
                         f"{t.shape} and {u.shape}")
    other = DriveInfo("other", inferred=True)
    if u.size < 4 or not (np.all(np.isfinite(u)) and np.all(np.isfinite(t))):
        return other
    span = float(u.max() - u.min())
    scale = float(np.max(np.abs(u)))
    if span <= 1e-12 * scale or span == 0.0:
        if scale == 0.0:
            return other  # no drive at all
        return DriveInfo("step", float(np.median(u)), inferred=True)
    tol = rtol * span
    for attempt in (_try_step, _try_sawtooth, _try_sine):
        info = attempt(t, u, span, tol)
        if info is not None:
            return info
    return other


def _fits(residual: np.ndarray, tol: float) -> bool:
    """A model fits when its residual is within ``tol`` RMS and ``10·tol`` everywhere [V].

    RMS rather than maximum so that measurement noise of a few tol does not hide the
    waveform; the bound on the maximum still rejects a model that misses whole samples
    (a misplaced edge, a second step).
    """
    if residual.size == 0:
        return True
    rms = math.sqrt(float(np.mean(residual * residual)))
    return rms <= tol and float(np.max(np.abs(residual))) <= 10.0 * tol


def _try_step(t: np.ndarray, u: np.ndarray, span: float, tol: float) -> DriveInfo | None:
    jumps = np.flatnonzero(np.abs(np.diff(u)) > 0.5 * span)
    if jumps.size != 1:
        return None
    before, after = u[: jumps[0] + 1], u[jumps[0] + 1:]
    level = float(np.median(after))
    if not (_fits(before, tol) and _fits(after - level, tol)):
        return None
    return DriveInfo("step", level, inferred=True)


def _try_sawtooth(t: np.ndarray, u: np.ndarray, span: float, tol: float) -> DriveInfo | None:
    d = np.diff(u)
    ramp = float(np.median(d))
    if ramp == 0.0:
        return None
    edges = np.flatnonzero((np.sign(d) == -np.sign(ramp)) & (np.abs(d) > 0.5 * span))
    if edges.size == 0:
        return None
    # m_k: edges before sample k, so U_k = a·t_k + b·m_k + c holds exactly for
    # U_k = A·frac(f·t_k) (a = A·f, b = −A) whatever the phase or number of periods.
    m = np.zeros(u.size)
    m[edges + 1] = 1.0
    m = np.cumsum(m)
    dt = float(np.median(np.diff(t)))
    k = (t - t[0]) / dt  # sample index: keeps the columns of similar size
    design = np.column_stack([k, m, np.ones(u.size)])
    coef, *_ = np.linalg.lstsq(design, u, rcond=None)
    if not _fits(u - design @ coef, tol):
        return None
    slope, jump = coef[0] / dt, coef[1]  # [V/s], [V]
    if slope * jump >= 0:
        return None  # edges must go against the ramp
    amplitude = abs(float(jump))
    frequency = abs(float(slope)) / amplitude
    if not frequency * dt < 0.5:
        return None
    direction = "forward" if slope > 0 else "backward"
    return DriveInfo("sawtooth", amplitude, frequency, direction, inferred=True)


def _sine_frequency_guess(u: np.ndarray, dt: float) -> float | None:
    """Angular frequency [rad/s] of a sampled sinusoid plus offset, or None.

    ``U_{k+L} + U_{k−L} = 2 cos(ωL·dt)·U_k + const`` holds exactly for any lag ``L``;
    its least-squares slope gives ``ω`` whatever the number of periods. The lag is
    doubled from 1 until ``ωL·dt`` passes 0.8 rad: near ``cos = 1`` (a slow sine at
    lag 1) the arccos would amplify the noise, and stopping below π avoids aliasing.
    """
    lag = 1
    while True:
        x = u[lag:-lag]
        design = np.column_stack([x, np.ones(x.size)])
        (p, _), *_ = np.linalg.lstsq(design, u[2 * lag:] + u[: -2 * lag], rcond=None)
        half = float(p) / 2.0
        if half < 0.7 or u.size - 4 * lag < 8:
            break
        lag *= 2
    if not -1.0 < half < 1.0:
        return None
    return math.acos(half) / (lag * dt)


def _try_sine(t: np.ndarray, u: np.ndarray, span: float, tol: float) -> DriveInfo | None:
    if u.size < 8:
        return None
    dt = float(np.median(np.diff(t)))
    omega = _sine_frequency_guess(u, dt)
    if omega is None:
        return None
    tau = t - t[0]
    coef = None
    for iteration in range(30):
        c, s = np.cos(omega * tau), np.sin(omega * tau)
        basis = np.column_stack([np.ones(u.size), c, s])
        coef, *_ = np.linalg.lstsq(basis, u, rcond=None)
        resid = u - basis @ coef
        if iteration >= 6 and not _fits(resid, 10.0 * tol):
            return None  # Gauss-Newton converges in a few steps on a sine: this is none
        # Gauss-Newton step in ω with the linear coefficients free (scaled by ω so
        # the column has the size of the others).
        dcol = (tau * omega) * (-coef[1] * s + coef[2] * c)
        step, *_ = np.linalg.lstsq(np.column_stack([basis, dcol]), resid, rcond=None)
        omega *= 1.0 + step[3]
        if abs(step[3]) < 1e-14:
            break
    c, s = np.cos(omega * tau), np.sin(omega * tau)
    basis = np.column_stack([np.ones(u.size), c, s])
    coef, *_ = np.linalg.lstsq(basis, u, rcond=None)
    if not _fits(u - basis @ coef, tol):
        return None
    frequency = float(omega) / (2.0 * math.pi)
    if not (frequency > 0 and frequency * dt < 0.5 and frequency * (tau[-1] + dt) >= 0.5):
        return None
    amplitude = 2.0 * math.hypot(coef[1], coef[2])
    if coef[0] < 0:
        amplitude = -amplitude
    return DriveInfo("sine", amplitude, frequency, inferred=True)

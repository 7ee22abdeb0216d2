"""Drive-voltage generators, exactly as docs/model.md ("Drives and recordings") defines them.

All generators sample at ``t_k = k/fs``, ``k = 0 .. round(duration_s·fs) − 1``, and
return ``(t, U)``: time [s] and voltage [V], float64 arrays.

- sawtooth, forward:  ``U_k = A·frac(f·t_k)`` (slow rise from 0, one-sample drop);
  backward: ``U_k = A − A·frac(f·t_k)`` (slow fall from A, one-sample rise);
- sine:  ``U_k = (A/2)·(1 − cos 2πf·t_k)`` (from 0 to A);
- step:  ``U_k = A`` for ``t_k ≥ t0``, 0 before.

``frac(f·t_k)`` is computed as ``mod(k·f, fs)/fs`` rather than from ``f·(k/fs)``: for
integer ``f`` and ``fs`` the product ``k·f`` and the remainder are exact, so the
abrupt edges land on exactly the samples the definition puts them on (``f·t_k`` in
floating point can come out as 0.999999… just before an edge and move it one sample).
"""

from __future__ import annotations

import math

import numpy as np

from stickslip_jax.drive_inference import DIRECTIONS, WAVEFORMS
from stickslip_jax.io import Recording, format_meta_number

__all__ = ["make_recording", "sawtooth", "sine", "step"]

DEFAULT_SAMPLE_RATE_HZ = 25_000.0


def _check_positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return value


def _sample_indices(duration_s: float, sample_rate_Hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample numbers ``k`` (float64, exact integers) and times ``t_k = k/fs`` [s]."""
    duration_s = _check_positive("duration_s", duration_s)
    fs = _check_positive("sample_rate_Hz", sample_rate_Hz)
    n = round(duration_s * fs)
    if n < 1:
        raise ValueError(
            f"duration_s={duration_s!r} at sample_rate_Hz={fs!r} gives no sample; "
            "use a longer duration"
        )
    k = np.arange(n, dtype=np.float64)
    return k, k / fs


def _frac_ft(k: np.ndarray, frequency_Hz: float, sample_rate_Hz: float) -> np.ndarray:
    """``frac(f·t_k)`` for ``t_k = k/fs``, in [0, 1) [-]."""
    # np.mod of two floats is exact (fmod), so only k·f can round, and it does not
    # for integer f and k·f < 2**53.
    return np.mod(k * frequency_Hz, sample_rate_Hz) / sample_rate_Hz


def _check_amplitude(amplitude_V: float) -> float:
    amplitude_V = float(amplitude_V)
    if not math.isfinite(amplitude_V):
        raise ValueError(f"amplitude_V must be finite, got {amplitude_V!r}")
    return amplitude_V


def sawtooth(
    amplitude_V: float,
    frequency_Hz: float,
    *,
    direction: str = "forward",
    duration_s: float,
    sample_rate_Hz: float = DEFAULT_SAMPLE_RATE_HZ,
) -> tuple[np.ndarray, np.ndarray]:
    """Sawtooth drive (docs/model.md): forward ``A·frac(f·t)``, backward ``A − A·frac(f·t)``.

    Parameters
    ----------
    amplitude_V:
        Amplitude ``A`` [V]. The forward peak sample is ``A·(1 − f/fs)``.
    frequency_Hz:
        Frequency ``f`` [Hz], > 0.
    direction:
        ``"forward"`` (slow rise, abrupt drop; slider moves towards +x) or
        ``"backward"`` (slow fall, abrupt rise; towards −x).
    duration_s:
        Duration [s]; ``round(duration_s·fs)`` samples.
    sample_rate_Hz:
        Sample rate ``fs`` [Hz] (default 25 kHz).

    Returns
    -------
    t, U:
        Time [s] and voltage [V], float64 arrays.
    """
    amplitude_V = _check_amplitude(amplitude_V)
    frequency_Hz = _check_positive("frequency_Hz", frequency_Hz)
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}, got {direction!r}")
    k, t = _sample_indices(duration_s, sample_rate_Hz)
    ramp = amplitude_V * _frac_ft(k, frequency_Hz, float(sample_rate_Hz))
    voltage = ramp if direction == "forward" else amplitude_V - ramp
    return t, voltage


def sine(
    amplitude_V: float,
    frequency_Hz: float,
    *,
    duration_s: float,
    sample_rate_Hz: float = DEFAULT_SAMPLE_RATE_HZ,
) -> tuple[np.ndarray, np.ndarray]:
    """Raised-cosine drive ``U = (A/2)·(1 − cos 2πf·t)``, from 0 to ``A`` (docs/model.md).

    Parameters
    ----------
    amplitude_V:
        Peak voltage ``A`` [V].
    frequency_Hz:
        Frequency ``f`` [Hz], > 0.
    duration_s:
        Duration [s]; ``round(duration_s·fs)`` samples.
    sample_rate_Hz:
        Sample rate ``fs`` [Hz] (default 25 kHz).

    Returns
    -------
    t, U:
        Time [s] and voltage [V], float64 arrays.
    """
    amplitude_V = _check_amplitude(amplitude_V)
    frequency_Hz = _check_positive("frequency_Hz", frequency_Hz)
    k, t = _sample_indices(duration_s, sample_rate_Hz)
    # The phase is reduced to one period before the cosine: cos of a large argument
    # loses digits on long recordings.
    phase = 2.0 * np.pi * _frac_ft(k, frequency_Hz, float(sample_rate_Hz))
    return t, 0.5 * amplitude_V * (1.0 - np.cos(phase))


def step(
    amplitude_V: float,
    *,
    t0_s: float = 2e-3,
    duration_s: float,
    sample_rate_Hz: float = DEFAULT_SAMPLE_RATE_HZ,
) -> tuple[np.ndarray, np.ndarray]:
    """Step drive: ``U = A`` from ``t0`` on, 0 before (docs/model.md).

    Parameters
    ----------
    amplitude_V:
        Step height ``A`` [V].
    t0_s:
        Step time ``t0`` [s], ≥ 0 (default 2 ms). The first sample at or after it is
        the first at ``A``.
    duration_s:
        Duration [s]; ``round(duration_s·fs)`` samples.
    sample_rate_Hz:
        Sample rate ``fs`` [Hz] (default 25 kHz).

    Returns
    -------
    t, U:
        Time [s] and voltage [V], float64 arrays.
    """
    amplitude_V = _check_amplitude(amplitude_V)
    t0_s = float(t0_s)
    if not (math.isfinite(t0_s) and t0_s >= 0):
        raise ValueError(f"t0_s must be a finite number >= 0, got {t0_s!r}")
    k, t = _sample_indices(duration_s, sample_rate_Hz)
    # First sample index at or after t0, decided on k rather than on t_k = k/fs so
    # that t0 = 2 ms at 25 kHz (t0·fs = 50.000000000000007) starts at k = 50.
    k0 = math.ceil(round(t0_s * float(sample_rate_Hz), 9))
    return t, np.where(k >= k0, amplitude_V, 0.0)


def make_recording(
    t: np.ndarray,
    U: np.ndarray,
    *,
    waveform: str,
    amplitude_V: float,
    frequency_Hz: float | None = None,
    direction: str | None = None,
    name: str,
) -> Recording:
    """Wrap a generated drive into a :class:`~stickslip_jax.io.Recording` (no output yet).

    Parameters
    ----------
    t, U:
        Time [s] and voltage [V], e.g. from :func:`sawtooth`.
    waveform:
        One of ``sawtooth``, ``sine``, ``step``, ``other``.
    amplitude_V:
        Amplitude [V].
    frequency_Hz:
        Frequency [Hz] (sawtooth and sine).
    direction:
        ``forward`` or ``backward`` (sawtooth).
    name:
        Recording name (used for output file names and plots).

    Returns
    -------
    Recording
        ``position`` and ``sensor_V`` are None; metadata holds ``waveform``,
        ``amplitude_V``, ``frequency_Hz`` and ``direction`` where given, and
        ``sample_rate_Hz`` from the time column. Use
        :meth:`~stickslip_jax.io.Recording.with_position_m` to attach a simulated output.
    """
    if waveform not in WAVEFORMS:
        raise ValueError(f"waveform must be one of {WAVEFORMS}, got {waveform!r}")
    if direction is not None and direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS} or None, got {direction!r}")
    t = np.asarray(t, dtype=np.float64)
    meta = {"waveform": waveform, "amplitude_V": format_meta_number(amplitude_V)}
    if frequency_Hz is not None:
        meta["frequency_Hz"] = format_meta_number(_check_positive("frequency_Hz", frequency_Hz))
    if direction is not None:
        meta["direction"] = direction
    if t.size >= 2 and t[-1] > t[0]:
        # From the whole span rather than one interval, and to 12 significant digits:
        # single intervals of k/fs carry rounding noise (1/dt = 24999.9999998 Hz), and
        # the load check allows 1e-6 relative anyway.
        rate = (t.size - 1) / float(t[-1] - t[0])
        meta["sample_rate_Hz"] = format_meta_number(float(f"{rate:.12g}"))
    return Recording(
        time_s=t,
        voltage_V=np.asarray(U, dtype=np.float64),
        position=None,
        position_unit=None,
        sensor_V=None,
        meta=meta,
        source=None,
        name=name,
    )

"""Residual vectors for least squares: time traces, step-response PSD, step lengths.

Every term is scaled so that a recording's contribution is comparable with its
NRMSE (docs/model.md "Fit quality"): the sum of squares of the time-domain term over a
set is Σ_recordings NRMSE², with the best constant offset of each recording removed
analytically (the interferometer's zero is arbitrary).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..noise import noise_sigma
from ..simulate import checked_batching, model_output, over_rows, plan_steps
from ..stepping import Stepping, StepPlan
from .dataset import Dataset, check_readable
from .parameters import ParameterMap
from .sensitivities import RecordingPrograms


def default_batching() -> str:
    """``"map"`` on CPU, ``"vmap"`` on accelerators (see :func:`simulate_dataset`)."""
    return "map" if jax.default_backend() == "cpu" else "vmap"


def dataset_plan(actuator, data: Dataset,
                 stepping: Stepping | StepPlan | None = None) -> StepPlan:
    """The :class:`StepPlan` for simulating ``data`` with ``actuator`` (concrete values:
    call it outside ``jit``)."""
    return plan_steps(actuator, data.dt, stepping=stepping,
                      samples=int(np.prod(data.voltages.shape)))


def numerical_error(actuator, data: Dataset, plan: StepPlan, q: np.ndarray | None = None,
                    *, programs=None) -> np.ndarray:
    """A-posteriori numerical error of ``simulate_dataset`` at ``plan``, per recording:
    RMS over its real samples, offset removed [m].

    Step doubling: the set again with twice the coarse sub-steps; for the fourth-order
    scheme the coarser trace's error is 16/15 of their difference. ``q``: the outputs at
    ``plan`` when already computed (one simulation saved). ``programs``: the
    :class:`~.sensitivities.RecordingPrograms` of ``data`` to simulate with (on a CPU
    one is made here: one compiled recording at a time, not one loop per length bucket;
    on accelerators :func:`simulate_dataset` batches the recordings).
    """
    if programs is None and default_batching() == "map":
        programs = RecordingPrograms(data)
    if programs is None:
        if q is None:
            q = simulate_dataset(actuator, data, plan=plan)
        q2 = simulate_dataset(actuator, data, plan=plan.doubled())
    else:
        if q is None:
            q = programs.simulate(actuator, plan)
        q2 = programs.simulate(actuator, plan.doubled())
    mask = np.asarray(data.mask)
    diff = offset_removed(np.asarray(q) - np.asarray(q2), mask, xp=np)
    n = mask.sum(axis=1)
    return np.sqrt(np.sum(diff * diff, axis=1) / n) * 16.0 / 15.0


def simulate_dataset(actuator, data: Dataset, *, plan: StepPlan | None = None,
                     batching: str | None = None):
    """Model output q [m] for every (padded) recording of ``data``, shape (B, T).

    ``plan``: the internal steps (:func:`dataset_plan`; default: planned here, which
    needs concrete parameter values, so pass one when calling under ``jit``).

    Each length bucket of ``data`` is one scan over its own padded length; the
    outputs are padded (last value repeated) to the common length and put back in
    recording order. Within a bucket the recordings go through ``jax.vmap``
    (``batching="vmap"``, for accelerators) or one after the other through
    ``jax.lax.map`` (``"map"``, the CPU default): on CPU a forward-mode Jacobian with a
    batch of recordings *and* a batch of tangents runs ~4x slower than the same
    Jacobian taken recording by recording (measured with XLA's default loops: 17
    fixture recordings, 42 parameters, 5.7 s vs 1.4 s), while the plain forward costs
    the same either way; with native loops (:func:`~stickslip_jax.fast_cpu_loops`)
    mapping is also the faster forward (17 copies of a 1 s trace: 0.79 s mapped, 1.33 s
    vmapped), as in :func:`~stickslip_jax.simulate.default_batching`.
    """
    batching = checked_batching(batching or default_batching())
    plan = dataset_plan(actuator, data) if plan is None else plan
    check_readable(actuator, data)

    def one(u, dt, drive, recording):
        q = model_output(actuator, u, dt, drive, plan)
        return actuator.output_map.read(dt * jnp.arange(u.shape[0]), q, recording)

    total = data.voltages.shape[1]
    buckets = data.buckets or ((tuple(range(len(data))), total),)
    parts, order = [], []
    for idx, length in buckets:
        sel = np.asarray(idx)
        drives = jax.tree_util.tree_map(lambda x, s=sel: x[s], data.drives)
        args = (jnp.asarray(data.voltages[sel, :length]), jnp.asarray(data.dt[sel]), drives,
                jnp.asarray(sel, dtype=jnp.int32))
        q = over_rows(one, args, batching)
        parts.append(jnp.pad(q, ((0, 0), (0, total - length)), mode="edge"))
        order += list(idx)
    q = jnp.concatenate(parts, axis=0)
    return q if order == sorted(order) else q[np.argsort(order)]


def offset_removed(diff, mask, *, xp=jnp):
    """``diff`` minus its masked mean along the last axis (best constant offset)."""
    n = xp.sum(mask, axis=-1, keepdims=True)
    return (diff - xp.sum(diff * mask, axis=-1, keepdims=True) / n) * mask


def nrmse_per_recording(q_sim, data: Dataset) -> np.ndarray:
    """NRMSE of each recording (offset removed), as a numpy array [-]."""
    mask = np.asarray(data.mask)
    r = offset_removed(np.asarray(q_sim) - np.asarray(data.measured), mask, xp=np)
    n = np.sum(mask, axis=-1)
    return np.sqrt(np.sum(r**2, axis=-1) / n) / np.asarray(data.scale)


def recording_noise(data: Dataset) -> tuple[float, ...]:
    """Each recording's sensor noise level [m], estimated without a model
    (:func:`~stickslip_jax.noise.noise_sigma`), floored at 1e-6 of the largest so that
    a noise-free recording does not take all the weight."""
    sigma = np.array([noise_sigma(r) for r in data.recordings], dtype=float)
    top = float(np.max(sigma, initial=0.0))
    if not top > 0:
        raise ValueError("no recording shows any noise: a whitened residual needs a "
                         "noise level")
    return tuple(float(s) for s in np.maximum(sigma, 1e-6 * top))


def periodogram_psd(x, dt, xp):
    """Periodogram PSD [m²/Hz] (Hann window, normalised so that white noise of
    variance σ² has the level σ²·dt) at the rfft frequencies [Hz], after removing the
    line through the ends, so the ends meet and the window does not leak a jump."""
    x = xp.asarray(x)
    n = x.shape[-1]
    t = xp.arange(n)
    slope = (x[..., -1] - x[..., 0]) / (n - 1)
    x = x - x[..., :1] - slope[..., None] * t
    win = np.hanning(n)
    spec = xp.fft.rfft(x * xp.asarray(win)) * dt
    return np.fft.rfftfreq(n, dt), (xp.abs(spec) ** 2) / (dt * float(np.sum(win**2)))


def log_psd(x, dt, *, band=(50.0, 5000.0), xp=jnp):
    """Log power spectral density (Hann window) of a trace in a band.

    Returns ``(frequencies [Hz], log10 PSD [m²/Hz])`` for the bins inside ``band``.
    ``xp`` is ``jax.numpy`` (traceable) or ``numpy`` (for measured data).
    """
    f, psd = periodogram_psd(x, dt, xp)
    keep = np.flatnonzero((f >= band[0]) & (f <= band[1]))
    return f[keep], xp.log10(psd[..., keep] + 1e-40)


def band_matrix(n: int, dt: float, *, band=(50.0, 5000.0), n_bands: int = 30):
    """Averaging matrix (bands × rfft bins) over log-spaced bands, and band centres [Hz].

    A periodogram bin of white noise scatters by a factor of ~3 in power; averaging
    the bins of each band (1/5 octave for the default) before the log makes the
    log-PSD a smooth, low-variance shape to fit. Bands without a bin are dropped.
    """
    f = np.fft.rfftfreq(n, dt)
    edges = np.geomspace(band[0], band[1], n_bands + 1)
    rows, centres = [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (f >= lo) & (f < hi)
        if np.any(sel):
            rows.append(sel / sel.sum())
            centres.append(np.sqrt(lo * hi))
    return np.array(rows), np.array(centres)


def band_log_psd(x, dt, bands, *, floor=0.0, xp=jnp):
    """log10 of the band-averaged PSD [m²/Hz] (``bands`` from :func:`band_matrix`) plus
    ``floor`` [m²/Hz], the measurement noise added to a noiseless simulation."""
    _, psd = periodogram_psd(x, dt, xp)
    return xp.log10(xp.asarray(bands) @ psd + floor + 1e-40)


def noise_floor_psd(x, dt) -> float:
    """White-noise PSD level [m²/Hz] of a measured trace: the mean of its upper
    half-band (above Nyquist/2), where the actuator's response has died out. (The
    mean, not the median: periodogram bins are exponentially distributed, and their
    median is ln 2 ≈ 0.69 of the level.)"""
    f, psd = periodogram_psd(x, dt, np)
    return float(np.mean(psd[f >= 0.25 / dt]))


DEFAULT_W_PSD = 0.01
"""Weight of the step-response log-PSD term. Band-averaged log10 PSDs of a noisy
trace scatter by ~0.1 per band, so at the optimum the term costs ~1e-2·w²; with
w = 0.01 it guides the resonances from far away without outweighing the time-domain
term (NRMSE² ~ 1e-6 at a 1 nm noise floor) near the optimum."""


class TraceResiduals(eqx.Module):
    """``θ ↦`` residual vector over a dataset (used as ``fn(y, args)`` by optimistix).

    Terms: time-domain (always; weight ``w_time``), band-averaged log-PSD of the step
    responses (``w_psd``, see :data:`DEFAULT_W_PSD`; the measured noise floor is added
    to the simulated PSD so that the high-frequency bands compare like with like), and
    per-period step lengths of the sawtooth recordings (``w_steps``). With
    ``in_metres`` the vector is only the offset-removed sample residuals [m] (padding
    zeroed), whose noise is the sensor's white noise. With ``whiten`` it is the same
    divided by each recording's noise level ``noise_m`` [m] (model-free estimates,
    :func:`~stickslip_jax.noise.noise_sigma`): the maximum-likelihood residual under
    white Gaussian noise, the one whose Jacobian gives the covariance
    (:mod:`.uncertainty`). The NRMSE-scaled default weights a recording by
    1/(stroke²·samples), not by its noise, so its minimiser is a different, less
    efficient estimator whose spread σ²(JᵀJ)⁻¹ understates: on the identification
    fixtures that put Mp, Dp and Kp three of those standard errors from the truth.
    """

    pmap: ParameterMap
    data: Dataset = eqx.field(static=True)
    w_time: float = eqx.field(static=True, default=1.0)
    w_psd: float = eqx.field(static=True, default=0.0)
    w_steps: float = eqx.field(static=True, default=0.0)
    in_metres: bool = eqx.field(static=True, default=False)
    plan: StepPlan | None = eqx.field(static=True, default=None)
    whiten: bool = eqx.field(static=True, default=False)
    noise_m: tuple[float, ...] | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if self.plan is None:
            raise ValueError("TraceResiduals needs a StepPlan: build it with "
                             "TraceResiduals.make (plans from the start actuator)")
        if self.whiten and (self.noise_m is None or len(self.noise_m) != len(self.data)
                            or not all(s > 0 for s in self.noise_m)):
            raise ValueError("a whitened residual needs a positive noise level per "
                             "recording (noise_m)")

    @classmethod
    def make(cls, pmap: ParameterMap, data: Dataset, *,
             stepping: Stepping | StepPlan | None = None, **options) -> TraceResiduals:
        """The residual of ``data`` around ``pmap`` (``options``: the weights,
        ``in_metres`` or ``whiten``), its internal steps planned from ``pmap.start``;
        with ``whiten`` and no ``noise_m`` the noise is estimated from each recording."""
        if options.get("whiten") and options.get("noise_m") is None:
            options["noise_m"] = recording_noise(data)
        return cls(pmap, data, plan=dataset_plan(pmap.start, data, stepping), **options)

    def simulate(self, theta):
        return simulate_dataset(self.pmap.actuator(theta), self.data, plan=self.plan)

    def __call__(self, theta, args=None):
        return self.from_output(self.simulate(theta))

    def from_output(self, q, *, xp=jnp):
        """The residual vector for simulated outputs ``q`` (B, T) [m]; ``xp`` is
        ``jax.numpy`` (traceable) or ``numpy`` (for concrete outputs)."""
        d = self.data
        diff = offset_removed(q - xp.asarray(d.measured), xp.asarray(d.mask), xp=xp)
        parts = [self._time_part(diff, xp).reshape(-1)]
        if self.in_metres or self.whiten:
            return parts[0]
        if self.w_psd > 0:
            parts += self._psd_terms(q, xp)
        if self.w_steps > 0:
            parts += self._step_terms(q, xp)
        return xp.concatenate(parts)

    def jacobian_from_outputs(self, q, dq) -> tuple[np.ndarray, np.ndarray]:
        """``(residual (N,), ∂residual/∂θ (N, k))`` from simulated outputs ``q`` (B, T)
        [m] and their derivatives ``dq`` (B, T, k) [m per unit of θ], in numpy: the
        chain rule through :meth:`from_output` (the time and step-length terms are
        linear in q; the log-PSD term's derivative is written out in
        :func:`psd_and_tangents`)."""
        d = self.data
        q = np.asarray(q, dtype=float)
        dq = np.asarray(dq, dtype=float)
        b, t, k = dq.shape
        # The offset removal runs along the samples: the k columns go in front of them.
        ddiff = offset_removed(np.moveaxis(dq, 2, 1), np.asarray(d.mask)[:, None, :], xp=np)
        parts = [np.moveaxis(self._time_part(ddiff, np), 1, 2).reshape(b * t, k)]
        if not (self.in_metres or self.whiten):
            if self.w_psd > 0:
                parts += self._psd_terms(q, np, dq)
            if self.w_steps > 0:
                parts += self._step_terms(dq, np, tangent=True)
        return np.asarray(self.from_output(q, xp=np)), np.concatenate(parts)

    def _time_part(self, diff, xp):
        """The time-domain rows for offset-removed differences ``diff`` (B, …, T) [m]
        (the residual's, or their derivatives along leading axes after B)."""
        d = self.data
        shape = (-1,) + (1,) * (diff.ndim - 1)
        if self.in_metres:  # raw sample residuals [m]
            return diff
        if self.whiten:  # in units of each recording's noise: maximum likelihood
            return diff / xp.asarray(self.noise_m).reshape(shape)
        n = xp.sum(xp.asarray(d.mask), axis=-1).reshape(shape)
        return self.w_time * diff / (xp.asarray(d.scale).reshape(shape) * xp.sqrt(n))

    def _time_rows(self, x):
        """The time-domain rows of a residual-shaped array ``x`` (vector or Jacobian),
        as (B, T, ...) per recording and sample."""
        b, t = self.data.measured.shape
        return np.asarray(x)[: b * t].reshape((b, t) + np.shape(x)[1:])

    def nrmse_from_residual(self, r) -> np.ndarray:
        """Per-recording NRMSE [-] from a residual vector of this function (its time
        part is ``w_time``·NRMSE-scaled, so no simulation is needed)."""
        if self.in_metres:
            raise ValueError("nrmse_from_residual needs the scaled residual, not in_metres")
        rows = self._time_rows(r)
        if self.whiten:
            rows = rows * np.asarray(self.noise_m)[:, None]
            return np.sqrt(np.sum(rows**2, axis=1) / np.sum(self.data.mask, axis=1)) \
                / np.asarray(self.data.scale)
        return np.sqrt(np.sum(rows**2, axis=1)) / self.w_time

    def in_metres_rows(self, x) -> np.ndarray:
        """What ``in_metres=True`` would give, from this function's residual vector or
        Jacobian ``x``: the time rows unscaled to metres, flattened as that vector."""
        d = self.data
        n = np.sum(d.mask, axis=-1)
        if self.in_metres:
            factor = np.ones(len(d))
        elif self.whiten:
            factor = np.asarray(self.noise_m)
        else:
            factor = np.asarray(d.scale) * np.sqrt(n) / self.w_time
        rows = self._time_rows(x)
        rows = rows * factor.reshape((-1,) + (1,) * (rows.ndim - 1))
        return rows.reshape((-1,) + rows.shape[2:])

    def _psd_terms(self, q, xp=jnp, dq=None):
        """The log-PSD rows of each step response; with ``dq`` (B, T, k) (numpy) their
        derivatives (rows, k) instead."""
        out = []
        for b, rec in enumerate(self.data.recordings):
            if rec.drive.waveform != "step":
                continue
            bands, _ = band_matrix(rec.n, rec.dt)
            floor = noise_floor_psd(rec.position_m, rec.dt)
            lp_meas = band_log_psd(rec.position_m, rec.dt, bands, xp=np)
            if dq is None:
                lp_sim = band_log_psd(q[b, : rec.n], rec.dt, bands, floor=floor, xp=xp)
                out.append(self.w_psd * (lp_sim - lp_meas) / np.sqrt(lp_meas.size))
                continue
            psd, dpsd = psd_and_tangents(q[b, : rec.n], dq[b, : rec.n].T, rec.dt)
            # d log10(bands·psd + floor) = bands·dpsd / ((bands·psd + floor)·ln 10)
            level = bands @ psd + floor + 1e-40
            dlp = (dpsd @ bands.T) / (level * np.log(10.0))
            out.append((self.w_psd * dlp / np.sqrt(lp_meas.size)).T)
        return out

    def _step_terms(self, q, xp=jnp, *, tangent: bool = False):
        """The step-length rows of each sawtooth; with ``tangent`` (``q`` then the
        derivatives (B, T, k)) their derivatives (rows, k)."""
        out = []
        for b, ends in enumerate(self.data.ends):
            if len(ends) < 2:
                continue
            meas = np.diff(self.data.recordings[b].position_m[ends])
            sim = xp.diff(q[b, ends], axis=0)
            if not tangent:
                sim = sim - meas
            out.append(self.w_steps * sim / (self.data.scale[b] * np.sqrt(len(meas))))
        return out


def psd_and_tangents(x, dx, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`periodogram_psd`'s periodogram of ``x`` (n,) [m²/Hz] and its derivatives along the
    rows of ``dx`` (k, n) [m²/Hz per unit of the tangent] (numpy): the detrending and
    the window are linear, so d|X|² = 2·Re(X̄·dX)·dt/Σwin² with X, dX the windowed
    spectra [m·s]."""
    x = np.asarray(x, dtype=float)
    dx = np.atleast_2d(np.asarray(dx, dtype=float))
    n = x.shape[-1]
    t = np.arange(n)
    win = np.hanning(n)

    def spectrum(y):
        slope = (y[..., -1] - y[..., 0]) / (n - 1)
        return np.fft.rfft((y - y[..., :1] - slope[..., None] * t) * win) * dt

    spec, dspec = spectrum(x), spectrum(dx)
    norm = dt * float(np.sum(win**2))
    return np.abs(spec) ** 2 / norm, 2.0 * np.real(np.conj(spec) * dspec) / norm

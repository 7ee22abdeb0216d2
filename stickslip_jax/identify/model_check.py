"""Does the fitted model describe the recordings? The verdict on a fit's residual.

A fit can converge to the least-squares optimum of a model that lacks something the
recordings hold. Its standard errors (:mod:`.uncertainty`) assume the residual is
white noise around a right model; they say nothing about the bias a missing effect
puts into every parameter. So every identification ends with a look at its residual,
recording by recording, against each recording's own noise level ``σ_i``
(:func:`~stickslip_jax.noise.noise_sigma`):

- **adequate**: the mean ``(e/σ)²`` is within the tolerance of the noise, overall and
  for every recording (:class:`~stickslip_jax.significance.Significance`: the noise
  estimate's own uncertainty and the simulator's numerical error at ``z`` standard
  errors). The standard errors are what holds.
- **mismatch**: detectably beyond the noise, but what the model misses is smaller than
  the noise itself (:data:`MODEL_ERROR_OVER_NOISE`). The fit is a result, but its
  standard errors assume a right model: the spread of each parameter over
  leave-one-regime-out fits (:mod:`.regime_spread`) is reported beside them.
  ``stickslip diagnose`` can name what is missing.
- **misspecified**: what the model misses is larger than the noise, overall or in a
  recording: the fit is shaped by the missing physics (or a wrong recording) more than
  by the data's noise. It is said so before its values, which come with their spreads.

What the verdicts and spreads are worth was measured on 24 development sets
(``benchmarks/bench_model_check.py``; benchmarks/README): the 8 null sets were all
adequate (their values within 2.3 standard errors of the truth); on the 13 sets beyond
the noise 20 of 91 piezo values lay within 2 standard errors of the truth and 42 within
2 spreads: the spread is the better measure, and still short of the bias where the
model misses much. A missing effect that the model's own parameters absorb (a viscous
force, a structural mode) can leave an adequate residual and values 24-35 standard
errors off: no residual test sees that; the diagnosis's score tests look for it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..noise import noise_sigma_relative_se
from ..significance import SIGNIFICANCE_Z, Significance
from .dataset import Dataset
from .residuals import offset_removed, recording_noise

MODEL_ERROR_OVER_NOISE = 1.0
"""A fit is misspecified when the residual's mean ``(e/σ)²`` exceeds 1 (the noise) by
more than this (and by more than the tolerance): the model's error variance is then
larger than the noise variance, i.e. the model's RMS error is larger than the sensor
noise. A convention, the point where a residual stops being mostly noise; it is not
tuned on any data set."""

VERDICTS = ("adequate", "mismatch", "misspecified")


@dataclass(frozen=True)
class ModelCheck:
    """The residual of a fit against the noise, per recording (module docstring)."""

    names: tuple[str, ...]
    """The recordings, in the data set's order."""
    chi2: np.ndarray
    """Mean ``(e/σ)²`` per recording (offset removed) [-]."""
    significance: Significance
    """Each recording's noise level, its uncertainty and the numerical floor."""

    @property
    def chi2_overall(self) -> float:
        """Mean ``(e/σ)²`` over every real sample [-]."""
        n = self.significance.counts
        return float(np.sum(n * self.chi2) / np.sum(n))

    @property
    def adequate(self) -> bool:
        """Within the tolerance of the noise, overall and for every recording."""
        sig = self.significance
        return sig.adequate(self.chi2_overall * sig.n_obs, self.chi2)

    @property
    def misspecified_recordings(self) -> tuple[str, ...]:
        """The recordings whose excess over the noise passes both their tolerance and
        :data:`MODEL_ERROR_OVER_NOISE`."""
        limit = np.maximum(self.significance.recording_tolerances(), MODEL_ERROR_OVER_NOISE)
        return tuple(n for n, c, lim in zip(self.names, self.chi2, limit, strict=True)
                     if c - 1.0 > lim)

    @property
    def misspecified(self) -> bool:
        """What the model misses is larger than the noise, overall or in a recording."""
        excess = self.chi2_overall - 1.0
        overall = excess > max(self.significance.tolerance, MODEL_ERROR_OVER_NOISE)
        return overall or bool(self.misspecified_recordings)

    @property
    def verdict(self) -> str:
        """One of :data:`VERDICTS`."""
        if self.misspecified:
            return "misspecified"
        return "adequate" if self.adequate else "mismatch"

    def model_error_nm(self) -> np.ndarray:
        """Per recording, the residual's RMS beyond its noise, ``σ·√max(χ² − 1, 0)``
        [nm]: what the model misses, in the recording's units."""
        return 1e9 * self.significance.sigmas * np.sqrt(np.maximum(self.chi2 - 1.0, 0.0))

    def statement(self) -> str:
        """One line: the verdict and the numbers behind it."""
        chi2 = self.chi2_overall
        sigma = self.significance.sigma_rms_m * 1e9
        beyond = sigma * np.sqrt(max(chi2 - 1.0, 0.0))
        head = (f"residual {beyond:.3g} nm RMS beyond a noise of {sigma:.3g} nm "
                f"(mean (e/σ)² {chi2:.3g}; the noise's tolerance 1 + "
                f"{self.significance.tolerance:.2g})")
        if self.verdict == "adequate":
            return f"the model describes these recordings to within their noise: {head}"
        if self.verdict == "mismatch":
            return (f"a mismatch smaller than the noise is detectable: {head}; the "
                    f"standard errors assume a right model (the spread over fits leaving "
                    f"one regime out does not), and `stickslip diagnose` can name what the "
                    f"model leaves out")
        worst = self.misspecified_recordings
        where = ""
        if worst:
            errors = dict(zip(self.names, self.model_error_nm(), strict=True))
            shown = ", ".join(f"{n} ({errors[n]:.3g} nm)" for n in worst[:4])
            where = (f"; beyond the noise in {len(worst)} of {len(self.names)} "
                     f"recording(s): {shown}{', ...' if len(worst) > 4 else ''}")
        return f"the model does not describe these recordings: {head}{where}"

    def as_dict(self) -> dict:
        """For fit.json."""
        return {"verdict": self.verdict, "chi2": self.chi2_overall,
                "tolerance_chi2": self.significance.tolerance,
                "model_error_over_noise": MODEL_ERROR_OVER_NOISE,
                "misspecified_recordings": list(self.misspecified_recordings),
                "statement": self.statement(),
                "per_recording": {n: {"chi2": float(c), "model_error_nm": float(e),
                                      "tolerance_chi2": float(t)}
                                  for n, c, e, t in zip(
                                      self.names, self.chi2, self.model_error_nm(),
                                      self.significance.recording_tolerances(), strict=True)}}


def check_model(data: Dataset, q_sim, numerical_m, *, z: float = SIGNIFICANCE_Z,
                sigmas=None) -> ModelCheck:
    """The :class:`ModelCheck` of the outputs ``q_sim`` [m] (one row per recording of
    ``data``, as simulated) against the recordings. ``numerical_m`` the simulator's
    error per recording [m RMS] (None: 0); ``sigmas`` each recording's noise [m]
    (default :func:`~.residuals.recording_noise`, the fit's own weights)."""
    mask = np.asarray(data.mask)
    resid = offset_removed(np.asarray(q_sim)[:, :mask.shape[1]] - np.asarray(data.measured),
                           mask, xp=np)
    counts = mask.sum(axis=1)
    sig = np.asarray(recording_noise(data) if sigmas is None else sigmas, dtype=float)
    chi2 = np.sum((resid / sig[:, None]) ** 2, axis=1) / counts
    rel_se = np.array([noise_sigma_relative_se(r) for r in data.recordings])
    numerical = (np.zeros(len(counts)) if numerical_m is None
                 else np.asarray(numerical_m, dtype=float))
    return ModelCheck(tuple(r.name for r in data.recordings), chi2,
                      Significance(counts, sig, rel_se, numerical, z))

"""Practical significance: when a residual is at the noise level as far as the data can
tell, and when what an entry removes is material.

With ~10⁵ samples any systematic difference, however small, is statistically
significant; a real recording always differs from any model by something. What the
data can tell apart from the noise is bounded by how well the noise level itself is
known, and by the simulator's own numerical error:

- each recording's σ is estimated from the recording (:func:`~stickslip_jax.noise.
  noise_sigma`) with a relative standard error ``s_i``
  (:func:`~stickslip_jax.noise.noise_sigma_relative_se`). The mean ``(e/σ)²`` of pure
  noise over ``N = Σ n_i`` samples is then ``1`` with a standard error
  ``SE = √(Σ (2 n_i s_i)² + 2N) / N`` (a relative error δ of σ̂ moves ``(σ/σ̂)²`` by
  ``−2δ``; ``2N`` is the χ² sampling variance);
- the simulator's error ``ε_i`` [m RMS] at the baseline (step doubling) is a bias
  any entry could absorb: ``Σ n_i (ε_i/σ_i)² / N`` in the same units.

The **tolerance** ``τ = z·SE + numerical`` (``z``: :data:`SIGNIFICANCE_Z`, or the
diagnosis's :attr:`~stickslip_jax.diagnose.policy.Policy.significance_z`). A residual
is *adequate* when its mean ``(e/σ)²`` is at most ``1 + τ`` overall and, for every
recording, at most ``1 + z_B·SE_i + numerical_i`` (``z_B`` the same one-sided level
shared over the ``B`` recordings, Bonferroni: a strong residual confined to one
recording is not diluted by the others). An entry's
refit is *material* when the drop of the mean ``(e/σ)²`` it buys exceeds ``τ``: more
than the uncertainty of the noise level and the numerical floor could produce. Both
are stated in nm RMS (``√(Δ(e/σ)²)`` times the samples' RMS σ) and as a share of the
noise variance.
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

SIGNIFICANCE_Z = 3.0
"""The default one-sided normal quantile of the tests: a residual of pure noise is
called inadequate about once in 740 (see
:attr:`~stickslip_jax.diagnose.policy.Policy.significance_z`)."""


@dataclass(frozen=True)
class Significance:
    """The tolerance of a data set (module docstring) and the tests that use it."""

    counts: np.ndarray
    """Real samples per recording ``n_i``."""
    sigmas: np.ndarray
    """Noise level per recording [m]."""
    sigma_rel_se: np.ndarray
    """Relative standard error of each σ [-]."""
    numerical_m: np.ndarray
    """The simulator's error per recording at the baseline, RMS [m]."""
    z: float
    """One-sided normal quantile of the tests."""

    @property
    def n_obs(self) -> int:
        return int(np.sum(self.counts))

    @property
    def chi2_se(self) -> float:
        """Standard error of the mean ``(e/σ)²`` of pure noise, given the σ estimates."""
        n, s = self.counts, self.sigma_rel_se
        return float(np.sqrt(np.sum((2 * n * s) ** 2) + 2 * self.n_obs) / self.n_obs)

    @property
    def numerical_chi2(self) -> float:
        """The simulator's error in mean ``(e/σ)²`` units."""
        return float(np.sum(self.counts * (self.numerical_m / self.sigmas) ** 2)
                     / self.n_obs)

    @property
    def tolerance(self) -> float:
        """``τ``: the excess of mean ``(e/σ)²`` over 1 that the data cannot tell from
        noise."""
        return self.z * self.chi2_se + self.numerical_chi2

    @property
    def tolerance_rss(self) -> float:
        """``τ·N``: the tolerance as a whitened RSS (what a refit must remove to be
        material, what a residual may exceed ``N`` by and still be at the noise)."""
        return self.tolerance * self.n_obs

    def recording_tolerances(self) -> np.ndarray:
        """Per recording, the same test at the Bonferroni level over the recordings."""
        n, s = self.counts, self.sigma_rel_se
        p = NormalDist().cdf(-self.z) / len(n)
        z_b = -NormalDist().inv_cdf(p)
        se = np.sqrt((2 * s) ** 2 + 2 / n)
        return z_b * se + (self.numerical_m / self.sigmas) ** 2

    @property
    def sigma_rms_m(self) -> float:
        """RMS noise level over the samples [m]: converts mean ``(e/σ)²`` to nm."""
        return float(np.sqrt(np.sum(self.counts * self.sigmas**2) / self.n_obs))

    def adequate(self, rss: float, per_recording: np.ndarray | None = None) -> bool:
        """The whitened RSS ``rss`` (and, when given, each recording's mean
        ``(e/σ)²``, ``per_recording``) is within the tolerance of the noise."""
        if not rss / self.n_obs <= 1 + self.tolerance:
            return False
        if per_recording is None:
            return True
        return bool(np.all(np.asarray(per_recording) <= 1 + self.recording_tolerances()))

    def material(self, rss_before: float, rss_after: float) -> bool:
        """The drop from ``rss_before`` to ``rss_after`` (whitened RSS) exceeds the
        tolerance: more than the noise level's uncertainty and the numerical floor."""
        return bool((rss_before - rss_after) / self.n_obs > self.tolerance)

    def nm(self, rss_part: float) -> float:
        """A whitened sum of squares as an RMS over the samples [nm]."""
        return float(np.sqrt(max(rss_part, 0.0) / self.n_obs) * self.sigma_rms_m * 1e9)

    def record(self) -> dict:
        """For diagnosis.json."""
        return {"z": self.z, "tolerance_chi2": self.tolerance,
                "tolerance_nm": self.nm(self.tolerance_rss),
                "noise_estimate_se_chi2": self.chi2_se,
                "numerical_chi2": self.numerical_chi2,
                "sigma_relative_se": [float(s) for s in self.sigma_rel_se],
                "numerical_error_nm": [float(e * 1e9) for e in self.numerical_m]}


def per_recording_chi2(r_whitened, counts: np.ndarray) -> np.ndarray:
    """Mean ``(e/σ)²`` per recording from a whitened residual vector (padding 0)."""
    rows = np.asarray(r_whitened).reshape(len(counts), -1)
    return np.sum(rows**2, axis=1) / counts

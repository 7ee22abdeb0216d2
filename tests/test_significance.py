"""Practical significance: the noise estimate's standard error and the tolerance built
on it hold on generated noise (no diagnosis, no fixture set)."""

import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.noise import noise_sigma, noise_sigma_relative_se
from stickslip_jax.significance import Significance, per_recording_chi2

FS = 25_000.0


def _recording(n: int, q: np.ndarray, waveform: str) -> ss.Recording:
    t = np.arange(n) / FS
    if waveform == "sawtooth":  # 100 Hz: 250 samples per period, period differences
        return ss.make_recording(t, np.zeros_like(t), waveform="sawtooth", amplitude_V=40.0,
                                 frequency_Hz=100.0, direction="forward",
                                 name="saw").with_position_m(q)
    return ss.make_recording(t, np.zeros_like(t), waveform="step", amplitude_V=0.0,
                             name="step").with_position_m(q)  # third differences


@pytest.mark.parametrize("waveform", ["sawtooth", "step"])
def test_the_noise_estimate_states_its_own_spread(waveform):
    rng = np.random.default_rng(3)
    n, sigma = 1500, 1e-9
    t = np.arange(n) / FS
    smooth = 2e-6 * np.sin(2 * np.pi * 100.0 * t)  # periodic at the drive's period
    est, se = [], []
    for _ in range(300):
        rec = _recording(n, smooth + sigma * rng.standard_normal(n), waveform)
        est.append(noise_sigma(rec) / sigma)
        se.append(noise_sigma_relative_se(rec))
    spread, stated = np.std(est), np.mean(se)
    # Stated within -20 % / +60 % of the spread seen over the draws (it may err on the
    # safe side: the block estimate is itself noisy and the larger of two is taken).
    assert 0.8 * spread < stated < 1.6 * spread, (spread, stated)
    assert abs(np.mean(est) - 1) < 0.03


def _null_set(rng, sizes, sigma_m):
    """A whitened residual that is noise alone, with σ estimated from each recording."""
    recs = [_recording(n, s * rng.standard_normal(n), w)
            for n, s, w in zip(sizes, sigma_m, ["sawtooth", "step"] * len(sizes),
                               strict=False)]
    sig_hat = np.array([noise_sigma(r) for r in recs])
    rel_se = np.array([noise_sigma_relative_se(r) for r in recs])
    width = max(sizes)
    white = np.zeros((len(recs), width))
    for i, r in enumerate(recs):
        white[i, :r.n] = r.position_m / sig_hat[i]  # the model is exact: e = noise
    counts = np.array(sizes, dtype=float)
    return Significance(counts, sig_hat, rel_se, np.zeros(len(recs)), 3.0), white


def test_noise_alone_is_adequate_and_the_tolerance_matches_its_spread():
    rng = np.random.default_rng(5)
    sizes = [2500, 1250, 500, 2500, 1250, 500, 1500, 1250]
    sigma_m = np.exp(rng.uniform(np.log(0.5e-9), np.log(2e-9), len(sizes)))
    chi2, inadequate, se = [], 0, []
    for _ in range(200):
        sig, white = _null_set(rng, sizes, sigma_m)
        rss = float(np.sum(white**2))
        chi2.append(rss / sig.n_obs)
        se.append(sig.chi2_se)
        inadequate += not sig.adequate(rss, per_recording_chi2(white, sig.counts))
    # The stated standard error of mean (e/σ)² is the spread over the draws (to 30 %),
    # and at z = 3 (one-sided ~0.1 % overall, Bonferroni per recording) noise alone is
    # almost never called inadequate.
    assert 0.7 < np.mean(se) / np.std(chi2) < 1.3, (np.mean(se), np.std(chi2))
    assert inadequate <= 4


def test_a_residual_above_the_tolerance_is_not_adequate_and_its_removal_is_material():
    rng = np.random.default_rng(9)
    sizes = [2500, 1250, 500, 2500, 1250, 500, 1500, 1250]
    sig, white = _null_set(rng, sizes, np.full(len(sizes), 1e-9))
    tol = sig.tolerance
    assert 0.01 < tol < 0.2
    # A systematic residual spread over every recording, 1.5 tolerances of variance.
    n_obs = sig.n_obs
    mask = np.arange(white.shape[1])[None, :] < np.array(sizes)[:, None]
    bias = np.sqrt(1.5 * tol) * np.sin(np.arange(white.shape[1]) / 7.0)[None, :] * np.sqrt(2)
    rss_null = float(np.sum(white**2))
    rss_bias = float(np.sum((white + bias * mask) ** 2))
    assert sig.adequate(rss_null) and not sig.adequate(rss_bias)
    # Removing it is material; removing a tenth of a tolerance is not.
    assert sig.material(rss_bias, rss_null)
    assert not sig.material(rss_null + 0.1 * tol * n_obs, rss_null)
    # In nm: √(τ) of the RMS noise level (1 nm here).
    assert sig.nm(tol * n_obs) == pytest.approx(np.sqrt(tol) * sig.sigma_rms_m * 1e9)


def test_a_strong_residual_in_one_recording_is_not_diluted_by_the_others():
    rng = np.random.default_rng(13)
    sizes = [2500] * 12 + [500]
    sig, white = _null_set(rng, sizes, np.full(len(sizes), 1e-9))
    # The short recording gets a residual of 1.2 σ RMS: the total stays within the
    # tolerance, the recording does not.
    white[-1, :500] += 1.2 * np.sign(np.sin(np.arange(500) / 5.0))
    per = per_recording_chi2(white, sig.counts)
    rss = float(np.sum(white**2))
    assert rss / sig.n_obs <= 1 + sig.tolerance
    assert not sig.adequate(rss, per)
    assert sig.adequate(rss)


def test_the_simulator_error_widens_the_tolerance():
    sig = Significance(np.array([1000.0, 1000.0]), np.array([1e-9, 2e-9]),
                       np.array([0.05, 0.05]), np.array([0.0, 0.0]), 3.0)
    noisy = Significance(sig.counts, sig.sigmas, sig.sigma_rel_se,
                         np.array([0.3e-9, 0.6e-9]), 3.0)
    assert noisy.numerical_chi2 == pytest.approx(0.09)
    assert noisy.tolerance == pytest.approx(sig.tolerance + 0.09)
    assert sig.chi2_se == pytest.approx(np.sqrt(2 * (2 * 1000 * 0.05) ** 2 + 4000) / 2000)

"""Residual localisation: noise vs structure, in time and in frequency."""

import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.locate import (
    analyse_recording,
    ljung_box,
    mismatch_entries,
    phase_segments,
    residual_peaks,
)
from stickslip_jax.synthetic import DriveSpec


@pytest.fixture(scope="module")
def stepping():
    """A 40 V, 500 Hz stepping trace with 1 nm noise, and its noiseless simulation."""
    rec = DriveSpec("sawtooth", 40.0, 500.0, "forward", 0.02).recording()
    q = np.asarray(ss.simulate(ss.lu2015_slc1720(), jnp.asarray(rec.voltage_V), dt=rec.dt))
    noisy = q + 1e-9 * np.random.default_rng(4).standard_normal(q.shape)
    return rec.with_position_m(noisy), q


def test_pure_noise_is_not_flagged(stepping):
    rec, q = stepping
    a = analyse_recording(rec, q)
    assert 0.8 < a.chi2 < 1.25
    assert a.ljung_box_p > 1e-3
    assert abs(a.z_voltage) < 4 and abs(a.z_rate) < 4
    assert not a.flagged
    assert mismatch_entries([a]) == []


def test_a_resonance_is_located_in_frequency(stepping):
    rec, q = stepping
    t = rec.time_s
    ring = 4e-9 * np.sin(2 * np.pi * 3000.0 * t)
    a = analyse_recording(rec, q + ring)
    assert a.flagged and a.chi2 > 3
    lo, hi = a.band_Hz
    assert lo <= 3000.0 <= hi
    (entry,) = mismatch_entries([a])
    assert entry["band_Hz"] == [lo, hi] and entry["regime"] == "stepping_forward"
    peaks = residual_peaks([rec], [q + ring], [a.noise_m])
    assert abs(np.log2(peaks[0] / 3000.0)) < 0.1


def test_drift_and_edges_are_located_in_time(stepping):
    rec, q = stepping
    t = rec.time_s
    drift = analyse_recording(rec, q - 2e-7 * t / t[-1])
    assert drift.phase_share["drift"] > 0.9
    # Offset removed, a ramp is worst at its two ends.
    assert drift.peak_window_s[0] < 0.05 * t[-1] or drift.peak_window_s[1] > 0.95 * t[-1]
    labels = phase_segments(rec)
    edge = np.where(labels == 1, 5e-9, 0.0)
    at_edges = analyse_recording(rec, q + edge)
    assert max(at_edges.phase_share, key=at_edges.phase_share.get) == "edge"
    # 10 periods, one edge each (the first sample is no edge): 4 samples per edge.
    assert (labels == 1).sum() == 4 * 9


def test_ljung_box_separates_white_from_coloured():
    rng = np.random.default_rng(0)
    white = rng.standard_normal(4000)
    coloured = np.convolve(white, np.ones(5) / 5, mode="same")
    assert ljung_box(white)[1] > 1e-3
    assert ljung_box(coloured)[1] < 1e-10

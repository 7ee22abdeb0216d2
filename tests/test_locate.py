"""Residual localisation: noise vs structure, in time and in frequency."""

import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.locate import (
    analyse_recording,
    harmonic_bins,
    harmonic_prominence,
    level_on_grid,
    ljung_box,
    mismatch_entries,
    phase_segments,
    residual_peaks,
)
from stickslip_jax.identify.residuals import periodogram_psd
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
    assert residual_peaks([rec], [q], [1e-9]) == []


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


def _periodic_mismatch(t, drive_Hz, amplitude, orders=24):
    """A mismatch of the periodic response: the drive's harmonics with an envelope
    falling as 1/k (a sawtooth's) up to the Nyquist frequency (12.5 kHz at 500 Hz),
    at random phases [m]."""
    phases = np.random.default_rng(7).uniform(0, 2 * np.pi, orders)
    return sum(amplitude / k * np.sin(2 * np.pi * k * drive_Hz * t + phases[k - 1])
               for k in range(1, orders + 1))


def test_drive_harmonics_are_no_resonance(stepping):
    """A periodic mismatch, largest at the 500 Hz drive's first harmonics, is no
    resonance; a ringing between the harmonics, and one that lifts a harmonic above its
    neighbours, are found beside it."""
    rec, q = stepping
    t = rec.time_s
    sigma = 1e-9
    mismatch = _periodic_mismatch(t, 500.0, 20e-9)
    # Counted as they are, the harmonics are the peaks (the fundamental first).
    f, psd = periodogram_psd(mismatch + (rec.position_m - q), rec.dt, np)
    level = psd / (sigma**2 * rec.dt)
    plain = harmonic_prominence(f, level, None)
    assert np.array_equal(plain, level)
    k1 = np.argmin(abs(f - 500.0))
    assert plain[k1] > 100
    counted = harmonic_prominence(f, level, 500.0)
    assert counted[k1] == 1.0  # the fundamental: never a peak
    assert np.all(counted[(f > 900) & (f < 4100)] < 5)  # a falling envelope: no peak
    assert residual_peaks([rec], [q - mismatch], [sigma]) == []
    # A ringing between the harmonics is found beside the mismatch.
    ring = 4e-9 * np.sin(2 * np.pi * 3250.0 * t)
    (peak,) = residual_peaks([rec], [q - mismatch - ring], [sigma])
    assert abs(np.log2(peak / 3250.0)) < 0.05
    # So is a resonance that lifts the 7th harmonic well above its neighbours.
    lifted = 12e-9 * np.sin(2 * np.pi * 3500.0 * t)
    (peak,) = residual_peaks([rec], [q - mismatch - lifted], [sigma])
    assert abs(np.log2(peak / 3500.0)) < 0.05


def test_a_weak_mode_at_a_slow_drives_harmonics_is_found_in_their_cells():
    """A weak resonance (3.9 kHz, ζ = 0.05) excited by a 50 Hz sawtooth raises only
    the drive's harmonics, 50 Hz apart on 10 Hz bins: sampled by interpolation on the
    peak grid (cells 87 Hz wide there) the grid points fall beside them; binned into
    the cells that hold them, they make the peak."""
    rec = DriveSpec("sawtooth", 40.0, 50.0, "forward", 0.1).recording()
    q = np.asarray(ss.simulate(ss.lu2015_slc1720(), jnp.asarray(rec.voltage_V), dt=rec.dt))
    rng = np.random.default_rng(3)
    noise = 1e-9 * rng.standard_normal(q.shape)
    t, phases = rec.time_s, rng.uniform(0, 2 * np.pi, 250)
    ratio = 50.0 * np.arange(1, 250) / 3900.0
    gain = 0.025e-9 / np.sqrt((1 - ratio**2) ** 2 + (0.1 * ratio) ** 2)  # [m]
    mode = sum(g * np.sin(2 * np.pi * 50.0 * k * t + phases[k])
               for k, g in enumerate(gain, start=1))
    assert np.std(mode) < 0.7e-9  # below the noise
    (peak,) = residual_peaks([rec.with_position_m(q + noise + mode)], [q], [1e-9])
    assert abs(np.log2(peak / 3900.0)) < 0.05
    # The cell of each harmonic holds the harmonic's bins' largest level; a cell with
    # no harmonic, and any cell without a periodic drive, the interpolated level.
    f = np.arange(0.0, 12_500.0, 10.0)
    level = np.ones_like(f)
    level[np.isin(f, [3850.0, 3900.0])] = 30.0
    grid = np.geomspace(300.0, 10_000.0, 160)
    binned = level_on_grid(f, level, 50.0, grid)
    cells = np.searchsorted(np.sqrt(grid[1:] * grid[:-1]), [3850.0, 3900.0])
    lifted = np.isin(np.arange(grid.size), cells)
    assert np.all(binned[lifted] == 30.0) and np.all(binned[~lifted] == 1.0)
    assert np.all(np.abs(np.log(grid[lifted] / 3875.0)) < 0.03)
    assert np.array_equal(level_on_grid(f, level, None, grid), np.interp(grid, f, level))
    assert np.array_equal(level_on_grid(f[:1], level[:1], 50.0, grid), np.zeros(grid.size))


def test_harmonic_bins_hold_each_harmonic_and_its_leakage_up_to_the_last_frequency():
    f = np.arange(0.0, 1000.5, 10.0)  # bins 10 Hz apart, to 1 kHz
    orders, bins = harmonic_bins(f, 50.0)
    assert np.array_equal(orders, np.arange(1, 21))
    assert np.array_equal(f[bins[0]], [40.0, 50.0, 60.0])
    assert np.array_equal(f[bins[-1]], [990.0, 1000.0])  # the last: no bin above
    orders, bins = harmonic_bins(f, 333.0)  # off the bins: the two within one bin
    assert np.array_equal(orders, [1, 2, 3])
    assert [f[b].tolist() for b in bins] == [[330.0, 340.0], [660.0, 670.0], [990.0, 1000.0]]


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


def test_ljung_box_p_value_is_the_chi2_tail():
    """The p-value is χ²'s survival function at the statistic: scipy.stats's to the bit
    (computed with scipy.special's, lighter to import), over white to strongly
    coloured residuals and other lag counts."""
    from scipy import stats

    rng = np.random.default_rng(3)
    white = rng.standard_normal(3000)
    for width in (1, 2, 3, 8):
        e = np.convolve(white, np.ones(width) / width, mode="same")
        for lags in (5, 20, 40):
            q, p = ljung_box(e, lags)
            assert p == float(stats.chi2.sf(q, lags))
            assert (p > 1e-3) if width == 1 else (p < 1e-6)

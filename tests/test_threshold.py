"""The 0-amplitude threshold of the elasto-plastic model (Nguyen 2012, Fig. 5) from
batched step-vs-amplitude sweeps."""

import equinox as eqx
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.sweep.threshold import step_vs_amplitude, zero_amplitude_threshold

AMPS = np.linspace(4.0, 40.0, 19)


def with_zba(act, factor):
    f = act.friction
    return eqx.tree_at(lambda a: (a.friction.z_ba_forward, a.friction.z_ba_backward), act,
                       (f.z_ba_forward * factor, f.z_ba_backward * factor))


def test_threshold_interpolation():
    assert zero_amplitude_threshold([10, 20, 30], [0, 0.5e-9, 1.5e-9]) == pytest.approx(25.0)
    assert np.isnan(zero_amplitude_threshold([10, 20], [0, 1e-10]))
    assert zero_amplitude_threshold([10, 20], [2e-9, 3e-9]) == 10.0


def test_zero_amplitude_threshold_moves_with_z_ba():
    act = ss.lu2015_slc1720()
    thresholds = []
    for factor in (0.7, 1.0, 1.4):
        steps = step_vs_amplitude(with_zba(act, factor), AMPS, 500.0)
        thresholds.append(zero_amplitude_threshold(AMPS, steps, min_step=2e-9))
        # Above the threshold the step grows with amplitude (Nguyen Fig. 5).
        above = AMPS > thresholds[-1] + 4
        assert np.all(np.diff(steps[above]) > 0)
    assert np.all(np.isfinite(thresholds))
    # A larger breakaway strain needs a larger drive before the contact slips.
    assert thresholds[0] < thresholds[1] < thresholds[2], thresholds
    assert thresholds[2] / thresholds[0] > 1.3, thresholds


def test_ratio_study_thresholds_fall_as_z_ss_approaches_z_ba(tmp_path):
    from stickslip_jax.sweep.threshold import plot_ratio_study, ratio_study

    amps = np.linspace(4.0, 60.0, 15)
    study = ratio_study(ss.lu2015_slc1720(), (0.4, 0.667, 0.95), amps, 500.0)
    thresholds = [study[r][1] for r in (0.4, 0.667, 0.95)]
    # Measured when written: 22.3, 20.2, 16.4 V; steps at 60 V: 338, 622, 804 nm.
    assert thresholds[0] > thresholds[1] > thresholds[2], thresholds
    assert study[0.4][0][-1] < study[0.667][0][-1] < study[0.95][0][-1]
    plot_ratio_study(amps, study, frequency_Hz=500.0, path=tmp_path / "fig5.png")
    assert (tmp_path / "fig5.png").stat().st_size > 10_000
    with pytest.raises(ValueError, match="elasto-plastic"):
        lugre = eqx.tree_at(lambda a: a.friction, ss.lu2015_slc1720(),
                            ss.LuGre(3.5e5, 1.0, 0.0, 0.2, 0.24, 1e-3))
        ratio_study(lugre, (0.5,), amps, 500.0)

"""Stepping or scanning: one definition (stickslip_jax.regime) that the velocity map,
the drive inversion, the identification and the diagnosis all read, and `drive`
exits non-zero when a printed drive does not give the velocity."""

import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
import stickslip_jax.sweep as sweep_pkg
from stickslip_jax.cli.main import app
from stickslip_jax.identify.dataset import classify_regime
from stickslip_jax.regime import STEPPING_FRACTION, drive_steps
from stickslip_jax.sweep.inverse import DriveChoice
from stickslip_jax.synthetic import DriveSpec, simulate_set


def test_the_threshold_is_a_twentieth_of_the_swing():
    assert STEPPING_FRACTION == 0.05
    assert drive_steps(133e-9, 1447e-9)       # 30 V, 50 Hz forward: 9 % of the swing
    assert drive_steps(-100e-9, 1035e-9)      # backward steps count by their size
    assert not drive_steps(3.6e-9, 466e-9)    # 30 V at 1 kHz: the piezo's own 0.8 %
    assert not drive_steps(float("nan"), 1e-6)


@pytest.fixture(scope="module")
def recordings():
    specs = [DriveSpec("sawtooth", a, 50.0, d, 0.12)
             for a, d in ((20.0, "forward"), (30.0, "forward"), (30.0, "backward"),
                          (60.0, "backward"))]
    return simulate_set(ss.lu2015_slc1720(), specs, noise_m=0.0)


def test_map_and_identification_call_a_drive_alike(recordings):
    grid = ss.DriveGrid(np.array([20.0, 30.0, 30.0, 60.0]), np.full(4, 50.0),
                        np.array([False, False, True, True]))
    vm = ss.velocity_map(ss.lu2015_slc1720(), grid, periods=6, settle=2)
    from_map = [p.regime for p in vm.points]
    from_recordings = [classify_regime(r).split("_")[0] for r in recordings]
    assert from_map == from_recordings == ["scanning", "stepping", "stepping", "stepping"]


def _choices(reached_500):
    return [DriveChoice(100.0, 48.1, -50e-6, -500e-9, "stepping", True),
            DriveChoice(500.0, 24.0, -30e-6, -60e-9, "scanning", reached_500)], []


@pytest.mark.parametrize("reached", [True, False])
def test_drive_exits_3_when_a_printed_drive_misses(monkeypatch, reached):
    monkeypatch.setattr(sweep_pkg, "drive_for_velocity",
                        lambda *a, **k: _choices(reached))
    res = CliRunner().invoke(app, ["drive", "--velocity", "-50um/s"])
    if reached:
        assert res.exit_code == 0, res.output
        assert "NOT REACHED" not in res.output
    else:
        assert res.exit_code == 3, res.output
        assert "NOT REACHED: scanning, not stepping (-40.0 % off)" in res.output
        assert "not reached at 500 Hz; the other rows stand" in res.output

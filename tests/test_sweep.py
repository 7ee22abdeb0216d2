"""Batched sweeps: equal to a per-point loop, independent of how they are batched,
the same on two devices as on one; the velocity map CLI."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
from stickslip_jax.cli.main import app
from stickslip_jax.sweep import (
    DriveGrid,
    auto_chunk,
    parse_values,
    samples_needed,
    steady_velocity,
    velocity_map,
)

FS = 25_000.0
PERIODS, SETTLE = 4, 1


@pytest.fixture(scope="module")
def small_grid():
    return DriveGrid.make([20.0, 45.0, 70.0], [100.0, 300.0, 700.0], "both")


@pytest.fixture(scope="module")
def small_map(small_grid):
    return velocity_map(ss.lu2015_slc1720(), small_grid, periods=PERIODS, settle=SETTLE,
                        segment=100)


def test_batched_sweep_equals_a_per_point_loop_of_simulate(small_grid, small_map):
    act = ss.lu2015_slc1720()
    for i in range(len(small_grid)):
        a, f = small_grid.amplitude_V[i], small_grid.frequency_Hz[i]
        back = bool(small_grid.backward[i])
        n = int(samples_needed(f, PERIODS, FS))
        _, u = ss.sawtooth(a, f, direction="backward" if back else "forward",
                           duration_s=n / FS)
        q = ss.simulate(act, u, dt=1 / FS,
                        drive=ss.DriveContext.make(backward=back, amplitude=a, frequency=f))
        ref = steady_velocity(np.asarray(q), f, FS, PERIODS, SETTLE)
        got = small_map.points[i]
        assert got.velocity_m_s == pytest.approx(ref.velocity_m_s, rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(got.period_end_q_m, ref.period_end_q_m, rtol=0, atol=1e-15)
        assert got.regime == ref.regime


def test_sweep_does_not_depend_on_slots_or_segment_length(small_grid, small_map):
    other = velocity_map(ss.lu2015_slc1720(), small_grid, periods=PERIODS, settle=SETTLE,
                         chunk=2, segment=37)
    assert other.run.chunk == 2 and other.run.segment == 37
    np.testing.assert_allclose(other.velocity_m_s, small_map.velocity_m_s, rtol=1e-10,
                               atol=1e-15)


def test_velocity_map_shows_the_papers_regimes(small_grid, small_map):
    v = small_map.velocity_m_s
    regimes = [p.regime for p in small_map.points]
    for i in range(len(small_grid)):
        if small_grid.amplitude_V[i] >= 45:  # stepping: the slider goes the drive's way
            assert regimes[i] == "stepping"
            assert np.sign(v[i]) == (-1 if small_grid.backward[i] else 1)
        if small_grid.amplitude_V[i] == 20 and small_grid.frequency_Hz[i] <= 300:
            assert regimes[i] == "scanning"  # 20 V scans (Lu 2015)
    # At 70 V the velocity grows with frequency (steps per second), forward and back.
    for back in (False, True):
        sel = (small_grid.amplitude_V == 70) & (small_grid.backward == back)
        speeds = np.abs(v[sel][np.argsort(small_grid.frequency_Hz[sel])])
        assert np.all(np.diff(speeds) > 0)


def test_parse_values_and_grid_errors():
    np.testing.assert_allclose(parse_values("10:80:15", name="a"), np.linspace(10, 80, 15))
    np.testing.assert_allclose(parse_values("50, 100,200", name="f"), [50, 100, 200])
    for bad in ("10:80", "a,b", "1:2:0", ""):
        with pytest.raises(ValueError, match="start:stop:count"):
            parse_values(bad, name="--amplitudes")
    with pytest.raises(ValueError, match="directions"):
        DriveGrid.make([10], [50], "sideways")
    with pytest.raises(ValueError, match="> 0 Hz"):
        DriveGrid.make([10], [0.0])
    g = DriveGrid.make([10, 20], [50, 100, 200], "both")
    assert len(g) == 12 and g.direction_names().count("backward") == 6


def test_auto_chunk_balances_the_longest_point_against_total_work():
    need = np.array([5000] + [500] * 40)  # total 25 000 = 5 x the longest
    assert auto_chunk(need) == 5
    assert auto_chunk(need, 2) == 6  # a multiple of the device count
    assert auto_chunk(need, limit=3) == 3


_TWO_DEVICES = """
import json, jax
jax.config.update("jax_enable_x64", True)
import stickslip_jax as ss
from stickslip_jax.sweep import DriveGrid, velocity_map
g = DriveGrid.make([30.0, 60.0], [200.0, 500.0], "both")
m = velocity_map(ss.lu2015_slc1720(), g, periods=3, settle=1, chunk=4, segment=80)
print(json.dumps({"devices": jax.device_count(), "run_devices": m.run.devices,
                  "v": m.velocity_m_s.tolist()}))
"""


def test_sweep_on_two_devices_equals_one_device():
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
           "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", _TWO_DEVICES], env=env, capture_output=True,
                         text=True, timeout=600, check=True)
    two = json.loads(out.stdout.strip().splitlines()[-1])
    assert two["devices"] == 2 and two["run_devices"] == 2
    g = DriveGrid.make([30.0, 60.0], [200.0, 500.0], "both")
    one = velocity_map(ss.lu2015_slc1720(), g, periods=3, settle=1, chunk=4, segment=80)
    np.testing.assert_allclose(two["v"], one.velocity_m_s, rtol=1e-12, atol=1e-18)


def test_sweep_cli_writes_the_map_and_refuses_to_overwrite(tmp_path):
    runner = CliRunner()
    args = ["sweep", "--amplitudes", "20,60", "--frequencies", "200:400:2", "--periods", "3",
            "--settle", "1", "--out", str(tmp_path)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    lines = (tmp_path / "velocity_map.csv").read_text().splitlines()
    assert lines[0] == "amplitude_V,frequency_Hz,direction,velocity_um_s,step_nm,regime"
    assert len(lines) == 1 + 8
    row = dict(zip(lines[0].split(","), lines[-1].split(","), strict=True))
    assert row["direction"] == "backward" and row["regime"] == "stepping"
    assert float(row["velocity_um_s"]) < 0
    assert float(row["step_nm"]) == pytest.approx(float(row["velocity_um_s"]) * 1e3 / 400,
                                                  rel=1e-6)
    assert (tmp_path / "velocity_map.png").stat().st_size > 10_000
    assert runner.invoke(app, args).exit_code == 2
    bad = runner.invoke(app, ["sweep", "--amplitudes", "10:20", "--out", str(tmp_path / "b")])
    assert bad.exit_code == 2 and "start:stop:count" in bad.output


def test_drive_inversion_reaches_the_asked_velocity_when_simulated():
    from stickslip_jax.sweep import drive_for_velocity

    act = ss.lu2015_slc1720()
    for target in (80e-6, -80e-6):
        choices, unreachable = drive_for_velocity(act, target, frequencies=[100.0, 500.0],
                                                  amplitudes=np.linspace(10, 100, 10))
        assert not unreachable and all(c.reached for c in choices)
        for c in choices:
            # Independent check: a longer plain simulation of the chosen drive.
            periods = 20
            n = int(samples_needed(c.frequency_Hz, periods, FS))
            back = target < 0
            _, u = ss.sawtooth(c.amplitude_V, c.frequency_Hz,
                               direction="backward" if back else "forward", duration_s=n / FS)
            q = ss.simulate(act, u, dt=1 / FS, drive=ss.DriveContext.make(
                backward=back, amplitude=c.amplitude_V, frequency=c.frequency_Hz))
            v = steady_velocity(np.asarray(q), c.frequency_Hz, FS, periods, 4).velocity_m_s
            assert v == pytest.approx(target, rel=0.05)
            assert c.step_m == pytest.approx(c.velocity_m_s / c.frequency_Hz, rel=1e-12)


def test_parse_velocity_units():
    from stickslip_jax.sweep import parse_velocity

    assert parse_velocity("50um/s") == pytest.approx(50e-6)
    assert parse_velocity("0.05 mm/s") == pytest.approx(50e-6)
    assert parse_velocity("5e-5m/s") == pytest.approx(50e-6)
    assert parse_velocity("50") == pytest.approx(50e-6)
    for bad in ("fast", "50 furlong/s", "0um/s"):
        with pytest.raises(ValueError):
            parse_velocity(bad)


def test_drive_cli_prints_choices_and_writes_json(tmp_path):
    res = CliRunner().invoke(app, ["drive", "--velocity", "60um/s", "--frequencies", "200",
                                   "--amplitudes", "10:90:9", "--periods", "6", "--out",
                                   str(tmp_path / "c.json")])
    assert res.exit_code == 0, res.output
    payload = json.loads((tmp_path / "c.json").read_text())
    (choice,) = payload["choices"]
    assert choice["reached"] and choice["velocity_m_s"] == pytest.approx(60e-6, rel=0.006)
    bad = CliRunner().invoke(app, ["drive", "--velocity", "fast"])
    assert bad.exit_code == 2 and "um/s" in bad.output

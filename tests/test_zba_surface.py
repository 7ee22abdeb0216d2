"""The z_ba surface: per-recording z_ba in one vmapped solve, a smooth surface over
amplitude x frequency x direction recovered from a grid made with a *different*
functional form, and its use by simulate/sweep."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
from stickslip_jax.cli.main import app
from stickslip_jax.sweep import (
    DriveGrid,
    fit_zba_points,
    fit_zba_surface,
    load_zba_surface,
    velocity_map,
    with_zba_surface,
)
from stickslip_jax.synthetic import (
    DriveSpec,
    example_zba,
    simulate_set,
    with_drive_dependent_zba,
)

# One worker computes the module's expensive fixture once (pytest -n 2 --dist loadgroup).
pytestmark = pytest.mark.xdist_group("zba_surface_grid")

AMPS, FREQS = (40.0, 55.0, 70.0), (100.0, 300.0, 600.0)


# Not a quadratic: tanh in amplitude, square root in frequency.
true_zba = example_zba


def truth_actuator():
    return with_drive_dependent_zba(ss.lu2015_slc1720(), true_zba)


@pytest.fixture(scope="module")
def grid_recordings():
    specs = [DriveSpec("sawtooth", a, f, d, 4 / f) for d in ("forward", "backward")
             for a in AMPS for f in FREQS]
    specs.append(DriveSpec("sawtooth", 10.0, 100.0, "forward", 4 / 100.0))  # pure stick
    return simulate_set(truth_actuator(), specs, noise_m=1e-9, seed=3)


@pytest.fixture(scope="module")
def fitted(grid_recordings):
    points = fit_zba_points(ss.lu2015_slc1720(), grid_recordings)
    return points, fit_zba_surface(points)


def test_zba_per_recording_is_recovered_in_one_batched_solve(fitted):
    points, _ = fitted
    stepping = points.amplitude_V >= 40
    truth = np.asarray(true_zba(points.amplitude_V, points.frequency_Hz,
                                points.backward.astype(float)))
    assert np.all(points.converged[stepping])
    err = points.z_ba_m[stepping] / truth[stepping] - 1
    assert np.max(np.abs(err)) < 0.01, err
    # The errors are consistent with the standard errors the fit reports.
    assert np.all(np.abs(points.z_ba_m - truth)[stepping] < 6 * points.std_error_m[stepping])
    assert np.all(points.nrmse[stepping] < 1e-3)
    # At 10 V the contact never leaves the elastic region: z_ba has no effect, the
    # point is flagged and kept out of the surface.
    (stick,) = np.flatnonzero(points.amplitude_V == 10.0)
    assert not points.determined[stick]
    assert points.determined[stepping].all()


def test_surface_recovers_a_different_functional_form_within_5_percent(fitted):
    _, fit = fitted
    a, f = np.meshgrid(np.linspace(40, 70, 9), np.geomspace(100, 600, 9))
    for back in (0.0, 1.0):
        pred = jax.vmap(lambda x, y, b=back: fit.surface(x, y, b))(jnp.asarray(a.ravel()),
                                                                   jnp.asarray(f.ravel()))
        err = np.asarray(pred) / np.asarray(true_zba(a.ravel(), f.ravel(), back)) - 1
        assert np.max(np.abs(err)) < 0.05, (back, err)
    for name in ("forward", "backward"):
        st = fit.stats[name]
        assert st["supported"] and st["r2"] > 0.99 and st["loo_rms_rel"] < 0.02
        assert st["amplitude_range_V"] == [40.0, 70.0]
    assert fit.stats["forward"]["excluded_undetermined"] == 1


def test_a_sweep_with_the_surface_reproduces_the_true_velocities(fitted):
    _, fit = fitted
    grid = DriveGrid.make([45.0, 65.0], [150.0, 500.0], "both")
    kw = dict(periods=4, settle=1)
    got = velocity_map(with_zba_surface(ss.lu2015_slc1720(), fit.surface), grid, **kw)
    want = velocity_map(truth_actuator(), grid, **kw)
    np.testing.assert_allclose(got.velocity_m_s, want.velocity_m_s, rtol=0.05)
    plain = velocity_map(ss.lu2015_slc1720(), grid, **kw)  # without the surface: far off
    assert np.max(np.abs(plain.velocity_m_s / want.velocity_m_s - 1)) > 0.05


def test_zba_surface_cli_writes_points_surface_and_figure(grid_recordings, tmp_path):
    data = tmp_path / "grid"
    data.mkdir()
    for r in grid_recordings[:6] + grid_recordings[9:15]:
        ss.save_recording(r, data / f"{r.name}.csv")
    out = tmp_path / "zba"
    res = CliRunner().invoke(app, ["zba-surface", str(data), "--out", str(out)])
    assert res.exit_code == 0, res.output
    lines = (out / "zba_points.csv").read_text().splitlines()
    assert len(lines) == 13 and lines[0].startswith("recording,amplitude_V,frequency_Hz")
    surface = load_zba_surface(out / "zba_surface.json")
    assert float(surface(55.0, 300.0, 0.0)) == pytest.approx(
        float(true_zba(55.0, 300.0, 0.0)), rel=0.05)
    assert (out / "zba_surface.png").stat().st_size > 10_000
    res = CliRunner().invoke(app, ["sweep", "--amplitudes", "50", "--frequencies", "200",
                                   "--periods", "3", "--settle", "1", "--zba-surface",
                                   str(out / "zba_surface.json"), "--out", str(tmp_path / "s"),
                                   "--no-figure"])
    assert res.exit_code == 0, res.output
    assert CliRunner().invoke(app, ["zba-surface", str(data), "--out", str(out)]).exit_code == 2


def test_simulate_cli_uses_the_surface_at_the_recordings_drive(fitted, tmp_path):
    _, fit = fitted
    fit.save(tmp_path / "s.json")
    # Backward at 65 V, 500 Hz, where the true z_ba is ~17 % above the profile's.
    base = ["simulate", "--waveform", "sawtooth", "--amplitude", "65", "--frequency", "500",
            "--direction", "backward", "--duration", "0.02"]
    r1 = CliRunner().invoke(app, base + ["--out", str(tmp_path / "a.csv")])
    r2 = CliRunner().invoke(app, base + ["--out", str(tmp_path / "b.csv"), "--zba-surface",
                                         str(tmp_path / "s.json")])
    assert r1.exit_code == 0 and r2.exit_code == 0, r1.output + r2.output
    plain = ss.load_recording(tmp_path / "a.csv").position_m
    with_surface = ss.load_recording(tmp_path / "b.csv").position_m
    u = ss.sawtooth(65.0, 500.0, direction="backward", duration_s=0.02)[1]
    truth = ss.simulate(truth_actuator(), u, dt=4e-5,
                        drive=ss.DriveContext.make(True, 65.0, 500.0))
    scale = np.ptp(np.asarray(truth))
    err_surface = np.sqrt(np.mean((with_surface - np.asarray(truth)) ** 2)) / scale
    err_plain = np.sqrt(np.mean((plain - np.asarray(truth)) ** 2)) / scale
    assert err_surface < 0.002 and err_surface < err_plain / 5, (err_surface, err_plain)


def test_support_interval_is_the_convex_hull_at_a_frequency():
    from stickslip_jax.sweep.zba_surface import support_interval

    # A full grid: the whole amplitude range at every frequency inside, none outside.
    a, f = np.meshgrid([40.0, 60.0, 80.0], [100.0, 1000.0])
    assert support_interval(a.ravel(), f.ravel(), 300.0) == pytest.approx((40.0, 80.0))
    assert support_interval(a.ravel(), f.ravel(), 2000.0) is None
    # A triangle: (40, 100), (80, 100), (80, 1000); halfway in log f, from 60 V on.
    lo, hi = support_interval([40.0, 80.0, 80.0], [100.0, 100.0, 1000.0], 10**2.5)
    assert (lo, hi) == pytest.approx((60.0, 80.0))
    # Degenerate hulls: one frequency (a segment), one point.
    assert support_interval([40.0, 70.0], [200.0, 200.0], 200.0) == pytest.approx((40.0, 70.0))
    assert support_interval([40.0, 70.0], [200.0, 200.0], 300.0) is None
    assert support_interval([50.0], [200.0], 200.0) == pytest.approx((50.0, 50.0))

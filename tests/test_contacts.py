"""Seed 2 features: CEIM preload dependence, multi-contact runners (vmap over contacts)
and force generation with the elasto-plastic dead zone."""

import json

import equinox as eqx
import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
from stickslip_jax.cli.main import app
from stickslip_jax.model.ceim import CEIMElastoPlastic
from stickslip_jax.model.contacts import ExtraContacts, multi_contact
from stickslip_jax.sweep.contact_studies import force_vs_amplitude, preload_study, spread_study

AMPS = np.array([5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 60.0])


@pytest.fixture(scope="module")
def act():
    return ss.lu2015_slc1720()


@pytest.fixture(scope="module")
def ceim_act(act):
    f = act.friction
    ceim = CEIMElastoPlastic.matching(f.rho0, f.z_ba_forward, zba_ratio=f.zba_ratio,
                                      preload=1.0)
    return eqx.tree_at(lambda a: a.friction, act, ceim)


def trace(actuator, amplitude=60.0, frequency=200.0, periods=4):
    t, u = ss.sawtooth(amplitude, frequency, duration_s=periods / frequency)
    drive = ss.DriveContext.make(amplitude=amplitude, frequency=frequency)
    return np.asarray(ss.simulate(actuator, u, dt=t[1] - t[0], drive=drive))


def test_equal_elastoplastic_contacts_are_the_lumped_contact(act):
    """Stiffness shared by normal force, z_ba not: every contact follows one z(t)."""
    q0 = trace(act)
    for shares in ([1] * 6, [6, 5, 4, 2, 1, 1]):
        runner = multi_contact(act, shares)
        assert isinstance(runner.extensions[0], ExtraContacts)
        assert runner.n_states == 5 + len(shares) - 1
        np.testing.assert_allclose(trace(runner), q0, rtol=0, atol=1e-15 * np.ptp(q0) + 1e-18)


def test_ceim_at_its_reference_preload_is_the_elastoplastic_law(act, ceim_act):
    # Same law, different arithmetic (preload scaling): equal to rounding, not bit for bit.
    q0 = trace(act)
    np.testing.assert_allclose(trace(ceim_act), q0, rtol=0, atol=1e-14 * np.ptp(q0))
    f = ceim_act.friction
    assert float(f.plastic_strain()) == pytest.approx(float(f.zss_magnitude()), rel=1e-12)


def test_step_falls_and_threshold_rises_with_preload(ceim_act):
    study = preload_study(ceim_act, [0.5, 1.0, 2.0, 4.0], AMPS, 200.0)
    at_60 = study.steps_m[:, -1]
    assert np.all(np.diff(at_60) < 0), at_60
    assert np.all(np.diff(study.thresholds_V) > 0), study.thresholds_V
    # The threshold is where z_ba, growing with the preload, is first exceeded.
    assert 10 < study.thresholds_V[1] < 30


def test_the_spread_of_the_preload_over_ceim_contacts_changes_the_threshold(ceim_act):
    """CEIM's z_ba and stiffness have preload-free intercepts: six contacts at F/6 are
    not one contact at F, and an uneven split differs from an even one."""
    study = spread_study(ceim_act, {"lumped": [1], "equal": [1] * 6,
                                    "one-heavy": [20, 1, 1, 1, 1, 1]}, AMPS, 200.0)
    lumped, equal, heavy = study.thresholds_V
    assert lumped > equal + 2.0, study.thresholds_V
    assert not np.allclose(study.steps_m[1], study.steps_m[2], rtol=1e-3)


def test_force_generation_has_a_dead_zone_elastoplastic_but_not_lugre(act):
    curve = force_vs_amplitude(act, AMPS, 200.0, k_load=1e5, periods=25)
    below = AMPS <= 15.0
    assert np.all(np.abs(curve.force_N[below]) < 1e-9), curve.force_N
    assert curve.force_N[-1] > 0.02
    assert np.all(curve.force_N <= curve.coulomb_N)
    assert 15.0 < curve.dead_zone_V() < 35.0
    fc = curve.coulomb_N
    lugre = eqx.tree_at(lambda a: a.friction, act,
                        ss.LuGre(float(act.friction.rho0), 0.0, 0.0, fc, fc, 1e-3))
    lg = force_vs_amplitude(lugre, AMPS, 200.0, k_load=1e5, periods=25)
    assert lg.force_N[0] > 1e-3, lg.force_N  # force from the smallest amplitude on
    # The force has settled: the last periods agree.
    drift = np.abs(curve.history_N[:, -1] - curve.history_N[:, -2])
    assert np.all(drift < 0.01 * curve.force_N.max()), drift


def test_ceim_parameter_file_round_trip(ceim_act, tmp_path):
    path = tmp_path / "ceim.json"
    ss.save_params(ceim_act, path)
    d = json.loads(path.read_text())
    assert d["friction"] == "ceim" and d["N"] == pytest.approx(1.0)
    back = ss.load_params(path)
    np.testing.assert_array_equal(trace(back, periods=2), trace(ceim_act, periods=2))
    bad = {**d, "mu": -1.0}
    with pytest.raises(ss.ParameterError, match="mu"):
        ss.actuator_from_params(bad)


def test_contacts_cli_writes_json_and_figures(tmp_path):
    res = CliRunner().invoke(app, ["contacts", "--out", str(tmp_path), "--amplitudes",
                                   "10:60:6", "--preloads", "1,2", "--spread", "lumped=1",
                                   "--spread", "equal=1,1,1"])
    assert res.exit_code == 0, res.output
    payload = json.loads((tmp_path / "contacts.json").read_text())
    pre = payload["preload_study"]["curves"]
    assert pre[0]["threshold_V"] < pre[1]["threshold_V"]
    assert payload["notes"], "the CEIM coefficients made up from the profile are not said"
    for name in ("preload.png", "spread.png", "force.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    again = CliRunner().invoke(app, ["contacts", "--out", str(tmp_path)])
    assert again.exit_code != 0 and "--force" in again.output


def test_force_build_up_compares_the_models_at_one_amplitude():
    from stickslip_jax.sweep.contact_studies import ForceCurve, plot_force_curves

    amps = np.array([60.0, 70.0, 80.0])
    hist = np.outer([1.0, 2.0, 1.5], np.linspace(0.0, 1.0, 5)) * 1e-2
    peak_70 = ForceCurve(amps, hist[:, -1], hist, 1e5, 200.0, 0.2)  # largest force at 70 V
    fig = plot_force_curves({"a": peak_70, "b": ForceCurve(amps, amps * 1e-3,
                                                           hist[::-1], 1e5, 200.0, 0.2)})
    build_up = fig.axes[1]
    assert "80 V" in build_up.get_title()
    # Both lines are the 80 V rows: hist[2] for "a", hist[::-1][2] = hist[0] for "b".
    np.testing.assert_allclose(build_up.lines[0].get_ydata(), hist[2] * 1e3)
    np.testing.assert_allclose(build_up.lines[1].get_ydata(), hist[0] * 1e3)

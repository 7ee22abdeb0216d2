"""The spread of an entry's fitted form (stickslip_jax.diagnose.form_band): draws of its
own parameters from a refit's covariance, and the bands the report draws from them."""

from types import SimpleNamespace

import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.catalogue import candidate
from stickslip_jax.diagnose.catalogue.viscous_friction import FORM as VISCOUS
from stickslip_jax.diagnose.form_band import DRAWS, band, intervals, parameter_draws
from stickslip_jax.diagnose.report import plot_forms
from stickslip_jax.identify.parameters import ParameterMap, ParameterSpec
from stickslip_jax.plots import subplots

SLOPE = VISCOUS.slope_name(1e-3)


def _rho1(a):
    return a.friction.rho1


def _map():
    """Kp (log) and rho1 as a signed linear quantity of θ unit 2 N·s/m."""
    act = ss.lu2015_slc1720()
    return ParameterMap.make(act, ["Kp", "rho1"],
                             {"rho1": ParameterSpec(_rho1, "linear", 2.0, "N·s/m")})


def test_draws_follow_the_refits_covariance_through_each_transform():
    pmap = _map()
    rng = np.random.default_rng(3)
    jac = rng.standard_normal((500, 2)) * [40.0, 5.0]
    jac[:, 1] += 0.6 * jac[:, 0] / 40.0 * 5.0  # correlated columns
    theta = np.array([0.3, -0.2])
    draws = parameter_draws(pmap, theta, jac, ["Kp", "rho1"], rss=498.0)
    assert set(draws) == {"Kp", "rho1"} and all(v.shape == (DRAWS,) for v in draws.values())
    cov = np.linalg.inv(jac.T @ jac)  # RSS at N − p: no widening
    start = {p.name: float(p.start) for p in pmap.free}
    # linear: value = start + 2·θ, so its spread is twice θ's
    rho1 = draws["rho1"]
    assert np.mean(rho1) == pytest.approx(start["rho1"] + 2 * theta[1],
                                          abs=4 * 2 * np.sqrt(cov[1, 1] / DRAWS))
    assert np.std(rho1) == pytest.approx(2 * np.sqrt(cov[1, 1]), rel=0.2)
    # log: value = start·e^θ, positive, its log spread θ's
    assert np.all(draws["Kp"] > 0)
    assert np.std(np.log(draws["Kp"])) == pytest.approx(np.sqrt(cov[0, 0]), rel=0.2)
    # a misfit three times the noise widens the spread by √3; the seed is fixed
    wide = parameter_draws(pmap, theta, jac, ["Kp", "rho1"], rss=3 * 498.0)
    assert np.std(wide["rho1"]) == pytest.approx(np.sqrt(3) * np.std(rho1), rel=1e-9)
    again = parameter_draws(pmap, theta, jac, ["Kp", "rho1"], rss=498.0)
    assert all(np.array_equal(again[n], draws[n]) for n in draws)


def test_an_undetermined_direction_adds_no_spread_and_bad_input_gives_no_draws():
    pmap = _map()
    jac = np.zeros((100, 2))
    jac[:, 0] = 1.0  # rho1's column is all zero: the data do not see it
    draws = parameter_draws(pmap, np.zeros(2), jac, ["rho1"], rss=100.0)
    assert np.ptp(draws["rho1"]) == 0.0
    assert parameter_draws(pmap, np.zeros(2), jac, ["Mp"], rss=100.0) == {}
    bad = jac.copy()
    bad[0, 0] = np.nan
    assert parameter_draws(pmap, np.zeros(2), bad, ["rho1"], rss=100.0) == {}


def test_band_and_intervals_are_the_draws_percentiles():
    draws = {"a": np.linspace(0.0, 1.0, 201)}
    lo, hi = band(lambda p: np.array([p["a"], 2 * p["a"] + p["b"]]), {"a": 9.0, "b": 1.0},
                  draws)
    assert lo == pytest.approx([0.025, 1.05]) and hi == pytest.approx([0.975, 2.95])
    assert band(lambda p: p["a"], {"a": 1.0}, {}) is None
    assert intervals(draws) == {"a": [pytest.approx(0.025), pytest.approx(0.975)]}
    assert intervals(None) == {}


def test_the_force_found_is_drawn_with_its_band(tmp_path):
    params = {"rho2": 0.05, SLOPE: 2.0}
    draws = {"rho2": np.full(DRAWS, 0.05), SLOPE: np.linspace(1.5, 2.5, DRAWS)}
    fig, ax = subplots()
    assert candidate("viscous_friction").plot_form(ax, params, draws=draws)
    assert len(ax.collections) == 1  # the band
    (path,) = ax.collections[0].get_paths()
    y = path.vertices[:, 1]
    v_max = 2.0 * VISCOUS.speeds[-1] / 3.0  # the figure's last velocity
    top = VISCOUS.force_curve({**params, SLOPE: 2.475}, [v_max]) * 1e3
    assert y.max() == pytest.approx(float(top[0]), rel=0.05)
    fig, ax = subplots()
    assert candidate("viscous_friction").plot_form(ax, params)  # no draws: no band
    assert len(ax.collections) == 0
    out = tmp_path / "forms.png"
    assert plot_forms([SimpleNamespace(name="viscous_friction", params=params,
                                       param_draws=draws)], out)
    assert out.stat().st_size > 5000


def _example_forms():
    """(entry, refitted params) of each form drawn with a band."""
    from stickslip_jax.diagnose.catalogue.creep import SPECTRUM_TAUS, weight_name
    from stickslip_jax.diagnose.catalogue.rate_dependent_hysteresis import SAT_VOLTS, sat_name
    from stickslip_jax.diagnose.catalogue.sensor_drift import amplitude_name

    rate = {"rate_gain": 1e-10, "rate_tau": 2e-4} | {sat_name(v): 1e-10 for v in SAT_VOLTS}
    return [
        ("viscous_friction", {"rho2": 0.05, SLOPE: 2.0}),
        ("drive_bandwidth", {"drive_tau": 2e-6, "drive_mix": 1.0, "drive_tau2": 0.5e-6,
                             "drive_mix2": 0.1}),
        ("creep", {weight_name(t): 1e-10 for t in SPECTRUM_TAUS}),
        ("sensor_drift", {"sensor_drift": 1e-7, amplitude_name(0.01): 2e-8}),
        ("rate_dependent_hysteresis", rate),
        ("sensor_periodic", {"periodic_cos_1": 3e-9, "periodic_sin_1": 4e-9}),
        ("stribeck", {"stribeck_excess": 1.4, "v_s": 2e-3}),
        ("external_load", {"F_ext": 2e-3, "k_load": 30.0}),
    ]


@pytest.mark.parametrize(("name", "params"), _example_forms(), ids=lambda x: str(x)[:20])
def test_each_banded_form_draws_the_band_of_its_draws(name, params):
    draws = {k: v * np.linspace(0.8, 1.2, 21) for k, v in params.items()}
    bare, ax = subplots()
    assert candidate(name).plot_form(ax, params)
    without = len(ax.collections)
    banded, ax = subplots()
    assert candidate(name).plot_form(ax, params, draws=draws)
    assert len(ax.collections) == without + 1
    assert any("95 %" in t.get_text() for t in ax.get_legend().get_texts())


def test_stribeck_and_the_load_draw_their_laws():
    """The curves drawn are the laws': the Stribeck ratio 1 + (r − 1)/(1 + (v/v_s)²)
    (1.2 at v_s for r = 1.4, 1 far above), and the load F_ext − k_load·x (mN, µm)."""
    fig, ax = subplots()
    assert candidate("stribeck").plot_form(ax, {"stribeck_excess": 1.4, "v_s": 2e-3})
    v, f = ax.lines[0].get_xdata(), ax.lines[0].get_ydata()
    assert f[0] == pytest.approx(1.4) and np.interp(2.0, v, f) == pytest.approx(1.2, rel=1e-3)
    assert f[-1] == pytest.approx(1.0 + 0.4 / 37.0)  # at 6 v_s
    said = candidate("stribeck").describe({"stribeck_excess": 1.4, "v_s": 2e-3})
    assert "1.4x" in said and "2 mm/s" in said
    fig, ax = subplots()
    assert candidate("external_load").plot_form(ax, {"F_ext": 2e-3, "k_load": 30.0})
    x, f = ax.lines[0].get_xdata(), ax.lines[0].get_ydata()
    assert np.interp(50.0, x, f) == pytest.approx(2.0 - 30.0 * 50e-6 * 1e3)  # 0.5 mN
    assert not candidate("stribeck").plot_form(ax, {})

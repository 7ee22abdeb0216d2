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

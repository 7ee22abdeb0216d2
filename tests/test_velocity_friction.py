"""Friction against the sliding velocity as a class: the saturating terms the
viscous-friction entry fits beside the law's rho2
(:class:`~stickslip_jax.model.extensions.SaturatingViscosity`,
:mod:`~stickslip_jax.diagnose.catalogue.velocity_forms`)."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.catalogue import candidate
from stickslip_jax.diagnose.catalogue.velocity_forms import START_SHARE
from stickslip_jax.diagnose.catalogue.viscous_friction import FORM as VISCOUS
from stickslip_jax.diagnose.refit import counted_parameters
from stickslip_jax.diagnose.scores import install_probes
from stickslip_jax.identify.parameters import ParameterMap
from stickslip_jax.model.extensions import SaturatingViscosity
from stickslip_jax.synthetic import DriveSpec


def _sawtooth():
    rec = DriveSpec("sawtooth", 40.0, 500.0, "forward", 0.008).recording()
    return jnp.asarray(rec.voltage_V), rec.dt


def test_each_term_is_a_damping_at_rest_that_levels_off_above_its_speed():
    sv = SaturatingViscosity([2.0, 0.5], [1e-3, 10e-3])
    v = np.array([-1.0, -1e-6, 0.0, 1e-6, 1.0])
    f = np.asarray(sv.force(v))
    np.testing.assert_allclose(f[[1, 3]], [-2.5e-6, 2.5e-6], rtol=1e-6)  # slope 2.5 N·s/m
    np.testing.assert_allclose(f[[0, 4]], [-(2e-3 + 5e-3), 2e-3 + 5e-3], rtol=1e-12)
    assert f[2] == 0.0
    with pytest.raises(ValueError, match="one gain per speed"):
        SaturatingViscosity([1.0], [1e-3, 2e-3])


def test_a_term_far_above_the_sliding_speeds_is_the_laws_rho2():
    """A slope c saturating at 10 m/s is viscous friction c·ẋ at stepping's speeds: the
    trace of rho2 = c, to the tanh's cubic term and the stepping's rounding."""
    u, dt = _sawtooth()
    base = ss.lu2015_slc1720()
    viscous = eqx.tree_at(lambda a: a.friction.rho2, base, jnp.asarray(2.0))
    ref = np.asarray(ss.simulate(viscous, u, dt=dt))
    term = np.asarray(ss.simulate(base.with_extension(SaturatingViscosity([2.0], [10.0])),
                                  u, dt=dt))
    plain = np.asarray(ss.simulate(base, u, dt=dt))
    assert np.max(np.abs(ref - plain)) > 1e-9  # rho2 = 2 N·s/m shows
    assert np.max(np.abs(term - ref)) < 1e-3 * np.max(np.abs(ref - plain))


def test_the_entry_starts_at_the_probes_rho2_and_says_the_force_found():
    entry = candidate("viscous_friction")
    act = ss.lu2015_slc1720()
    probe, *saturating = entry.probes(act, {})
    assert probe.label == "rho2" and [p.setting["speed"] for p in saturating] == \
        list(VISCOUS.probe_speeds)
    attached, specs = entry.attach(act, 0.8, probe)
    assert float(attached.friction.rho2) == pytest.approx(float(act.friction.rho2) + 0.8)
    sv = attached.extensions[-1]
    assert isinstance(sv, SaturatingViscosity)
    np.testing.assert_allclose([float(g) for g in sv.gains], START_SHARE * 0.8)
    assert list(specs) == ["rho2"] + [VISCOUS.slope_name(v) for v in VISCOUS.speeds]
    n = len(VISCOUS.speeds)
    assert counted_parameters(specs, attached) == 1 + n
    pmap = ParameterMap.make(attached, list(specs), specs)
    theta = np.zeros(pmap.size)
    theta[1:4] = -40.0  # the three slowest terms to their bound
    fitted = pmap.actuator(theta, xp=np)
    assert counted_parameters(specs, fitted) == 1 + n - 3
    # Carried onto another start: rho2 and the terms, not the baseline's own quantities.
    other = eqx.tree_at(lambda a: a.friction.rho0, act, act.friction.rho0 * 2)
    carried = entry.carry(other, fitted)
    assert float(carried.friction.rho0) == float(other.friction.rho0)
    assert float(carried.friction.rho2) == pytest.approx(float(fitted.friction.rho2))
    assert isinstance(carried.extensions[-1], SaturatingViscosity)
    params = {"rho2": 0.1, VISCOUS.slope_name(1e-3): 3.0, VISCOUS.slope_name(30e-3): 0.0,
              VISCOUS.slope_name(0.3e-3): 6e-10}  # at its bound: not said
    np.testing.assert_allclose(VISCOUS.force_curve(params, [1e-3, 1.0]),
                               [0.1e-3 + 3e-3 * np.tanh(1.0), 0.1 + 3e-3], rtol=1e-6)
    text = entry.describe(params)
    assert "rho2 0.1 N·s/m" in text and "3 to 1 mm/s" in text and "30 mm/s" not in text
    assert "to 0.3 mm/s" not in text


def test_a_saturating_probe_starts_the_refit_at_its_speed():
    """From the probe at 1 mm/s the refit starts with the strength on the grid's 1 mm/s
    term, the others and rho2 a little above zero and the baseline's."""
    entry = candidate("viscous_friction")
    act = ss.lu2015_slc1720()
    probe = next(p for p in entry.probes(act, {}) if p.setting.get("speed") == 1e-3)
    attached, _ = entry.attach(act, 0.8, probe)
    assert float(attached.friction.rho2) == pytest.approx(float(act.friction.rho2) + 0.05)
    slopes = np.array([float(g) for g in attached.extensions[-1].gains])
    np.testing.assert_allclose(slopes, np.where(np.asarray(VISCOUS.speeds) == 1e-3, 0.8,
                                                START_SHARE * 0.8))


def test_the_saturating_probes_go_in_as_one_bank_whose_elements_are_their_strengths():
    entry = candidate("viscous_friction")
    act = ss.lu2015_slc1720()
    probe_act, installed = install_probes(act, [entry], {})
    bank = probe_act.extensions[-1]
    assert isinstance(bank, SaturatingViscosity)
    np.testing.assert_allclose(np.asarray(bank.speeds), VISCOUS.probe_speeds)
    saturating = [e for e in installed if e.probe.setting.get("speed")]
    assert [e.index for e in saturating] == [0, 1, 2]
    assert len({e.name for e in saturating}) == 1
    # Strengths set through the probes' getter: the bank's force is the three terms'.
    strengths = jnp.array([0.5, 2.0, 1.0])
    set_ = eqx.tree_at(saturating[0].spec.getter, probe_act, strengths)
    v = np.array([-4e-3, 0.2e-3, 2e-3])
    single = sum(np.asarray(SaturatingViscosity([c], [s]).force(v))
                 for c, s in zip(strengths, VISCOUS.probe_speeds, strict=True))
    np.testing.assert_allclose(np.asarray(set_.extensions[-1].force(v)), single, rtol=1e-12)
    with pytest.raises(ValueError, match="one gain per speed"):
        SaturatingViscosity((jnp.zeros(2),), VISCOUS.probe_speeds)


def test_the_report_draws_the_force_found(tmp_path):
    from types import SimpleNamespace

    from stickslip_jax.diagnose.report import form_found, plot_forms

    params = {"rho2": 0.05, VISCOUS.slope_name(1e-3): 2.0}
    assert form_found("viscous_friction", params).startswith(
        "friction against sliding velocity: rho2 0.05 N·s/m and saturating slopes 2 to 1 mm/s")
    assert form_found("viscous_friction", {"rho2": 0.2}).startswith(
        "friction against sliding velocity: rho2 0.2 N·s/m; force at 0.3 mm/s")
    path = tmp_path / "forms.png"
    assert plot_forms([SimpleNamespace(name="viscous_friction", params=params,
                                       param_draws={})], path)
    assert path.stat().st_size > 5000

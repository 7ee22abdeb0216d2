"""Creep as a class: the relaxation spectrum the catalogue's creep entry fits
(:class:`~stickslip_jax.model.extensions.CreepSpectrum`), its non-negative weights
and what a refit of it is charged."""

import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.catalogue import candidate
from stickslip_jax.diagnose.catalogue.creep import SPECTRUM_TAUS, START_SHARE, TAUS, weight_name
from stickslip_jax.diagnose.refit import counted_parameters
from stickslip_jax.identify.parameters import FreeParameter, ParameterMap, ParameterSpec
from stickslip_jax.model.extensions import Creep, CreepSpectrum
from stickslip_jax.synthetic import DriveSpec


@pytest.fixture(scope="module")
def step():
    rec = DriveSpec("step", 40.0, duration_s=0.03).recording()
    return jnp.asarray(rec.voltage_V), rec.dt


def test_a_spectrum_with_one_weight_is_first_order_creep_and_weights_add(step):
    u, dt = step
    base = ss.lu2015_slc1720()
    gains = [0.0] * len(SPECTRUM_TAUS)
    gains[2] = 5e-10
    one = ss.simulate(base.with_extension(CreepSpectrum(gains, SPECTRUM_TAUS)), u, dt=dt)
    ref = ss.simulate(base.with_extension(Creep(5e-10, SPECTRUM_TAUS[2])), u, dt=dt)
    np.testing.assert_allclose(one, ref, rtol=0, atol=1e-15)
    # Two weights: the bank of the two first-order terms.
    gains[6] = 2e-10
    two = ss.simulate(base.with_extension(CreepSpectrum(gains, SPECTRUM_TAUS)), u, dt=dt)
    bank = Creep.bank([Creep(5e-10, SPECTRUM_TAUS[2]), Creep(2e-10, SPECTRUM_TAUS[6])])
    np.testing.assert_allclose(two, ss.simulate(base.with_extension(bank), u, dt=dt),
                               rtol=0, atol=1e-15)
    assert float(np.max(np.abs(np.asarray(two) - np.asarray(one)))) > 1e-9
    with pytest.raises(ValueError, match="one gain per time constant"):
        CreepSpectrum([1e-10], SPECTRUM_TAUS)


def test_nonneg_weights_start_where_asked_stay_non_negative_and_reach_zero():
    w = FreeParameter("w", "nonneg", 1, np.asarray(0.01), 1.0)
    assert float(w.to_physical(np.zeros(1), xp=np)) == pytest.approx(0.01, rel=1e-12)
    assert float(w.to_physical(np.zeros(1))) == pytest.approx(0.01, rel=1e-12)
    # Each weight moves on its own start's θ unit (softplus'(θ0) = 1 − 1/e of it) and
    # grows nearly linearly: 5 units of θ take it to about five times its start.
    d = float(w.derivative(np.zeros(1))[0, 0])
    fd = float(w.to_physical(np.array([1e-6]), xp=np) - w.to_physical(np.array([-1e-6]),
                                                                      xp=np)) / 2e-6
    assert d == pytest.approx(fd, rel=1e-6) and d == pytest.approx(0.01 * (1 - np.exp(-1.0)))
    assert 0.05 < float(w.to_physical(np.array([5.0]), xp=np)) < 0.06
    for theta in (-10.0, -50.0, -800.0):
        assert 0.0 <= float(w.to_physical(np.array([theta]), xp=np)) < 1e-5
    # On its bound (0: a fit's softplus underflowed) a weight restarts at 2e-9 of the
    # spec's scale; a negative start or a missing scale is refused.
    zero = FreeParameter("w", "nonneg", 1, np.asarray(0.0), 3.0)
    assert float(zero.to_physical(np.zeros(1), xp=np)) == pytest.approx(
        3.0 * np.log1p(np.exp(-20.0)), rel=1e-12)
    act = ss.lu2015_slc1720().with_extension(CreepSpectrum([0.0, -1e-10], (1e-3, 2e-3)))
    get = [lambda a, i=i: a.extensions[-1].gains[i] for i in range(2)]
    ParameterMap.make(act, ["a"], {"a": ParameterSpec(get[0], "nonneg", 1e-10)})
    with pytest.raises(ValueError, match="nonneg"):
        ParameterMap.make(act, ["b"], {"b": ParameterSpec(get[1], "nonneg", 1e-10)})
    with pytest.raises(ValueError, match="nonneg"):
        ParameterMap.make(act, ["a"], {"a": ParameterSpec(get[0], "nonneg", 0.0)})


def test_the_entry_starts_at_the_probes_first_order_creep_and_pays_for_weights_it_uses():
    entry = candidate("creep")
    act = ss.lu2015_slc1720()
    probes = entry.probes(act, {})
    assert [p.setting["tau"] for p in probes] == list(TAUS)
    assert set(TAUS) <= set(SPECTRUM_TAUS)
    probe = probes[1]  # 4 ms
    strength = 3.0 * probe.spec.scale
    attached, specs = entry.attach(act, strength, probe)
    gains = np.array([float(g) for g in attached.extensions[-1].gains])
    main = SPECTRUM_TAUS.index(4e-3)
    assert gains[main] == pytest.approx(strength)
    assert np.allclose(np.delete(gains, main), START_SHARE * strength)
    assert list(specs) == [weight_name(t) for t in SPECTRUM_TAUS]
    pmap = ParameterMap.make(attached, list(specs), specs)
    np.testing.assert_allclose(
        [float(g) for g in pmap.actuator(np.zeros(pmap.size), xp=np).extensions[-1].gains],
        gains, rtol=1e-12)
    # Every weight counts while it is off its bound; a weight a fit sent to 0 does not.
    assert counted_parameters(specs, attached) == len(SPECTRUM_TAUS)
    theta = np.zeros(pmap.size)
    theta[[0, 3, 8]] = -40.0
    theta[[1, 7]] = 40.0  # about 40 times their start: 40 % of the scale
    fitted = pmap.actuator(theta, xp=np)
    assert counted_parameters(specs, fitted) == len(SPECTRUM_TAUS) - 3
    # The report's words for the form found.
    params = {n: float(s.getter(fitted)) for n, s in specs.items()}
    text = entry.describe(params)
    assert "creep spectrum" in text and "from 2.45 to 50 ms" in text and "(3 of 12)" in text
    # A first-order strength of the wrong sign starts every weight small, none negative.
    low, _ = entry.attach(act, -strength, probe)
    assert np.allclose([float(g) for g in low.extensions[-1].gains], START_SHARE * strength)


def test_the_report_says_and_draws_the_spectrum_found(tmp_path):
    from types import SimpleNamespace

    from stickslip_jax.diagnose.report import form_found, plot_forms

    weights = (0, 0, 3e-10, 1e-10, 0, 0, 0, 2e-11) + (0,) * (len(SPECTRUM_TAUS) - 8)
    params = {weight_name(t): w for t, w in zip(SPECTRUM_TAUS, weights, strict=True)}
    assert form_found("creep", params).startswith("creep spectrum: total gain 4.2e-10 m/V")
    assert form_found("learned_force", params) == ""
    assert form_found("sensor_delay", {"delay": 1e-6}) == ""
    path = tmp_path / "forms.png"
    creep = SimpleNamespace(name="creep", params=params, param_draws={})
    delay = SimpleNamespace(name="sensor_delay", params={"delay": 1e-6},
                            param_draws={})
    assert plot_forms([creep, delay], path) and path.stat().st_size > 5000
    assert not plot_forms([delay], tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()

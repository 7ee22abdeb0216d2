"""Unit checks of the model's components against docs/model.md, by hand-computed values and
independent re-implementations of the contract's formulas."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.model.base import DriveContext

DT = 4e-5
ZBA, RATIO, RHO0 = 0.4e-6, 0.667, 3.517e5
ZSS = ZBA / RATIO
FWD = DriveContext.make()


# ---- Prandtl-Ishlinskii ---------------------------------------------------------------
def test_play_operator_hand_sequence():
    pi = ss.PrandtlIshlinskii([0.0, 1.0, 2.0], [1.0, 0.5, 0.25])
    m = pi.initial_memory(jnp.asarray(0.0))
    np.testing.assert_array_equal(m, [0.0, 0.0, 0.0])
    # U: 0 → 3 → 1 → 2 → −1. Plays p_i = max(U − r_i, min(U + r_i, p_i)), by hand:
    expected = [
        (3.0, [3.0, 2.0, 1.0], 3.0 + 1.0 + 0.25),
        (1.0, [1.0, 2.0, 1.0], 1.0 + 1.0 + 0.25),
        (2.0, [2.0, 2.0, 1.0], 2.0 + 1.0 + 0.25),
        (-1.0, [-1.0, 0.0, 1.0], -1.0 + 0.0 + 0.25),
    ]
    for u, plays, gamma in expected:
        # output() plays from the memory without committing it ...
        assert float(pi.output(m, jnp.asarray(u))) == pytest.approx(gamma, abs=1e-15)
        m = pi.update(m, jnp.asarray(u))
        np.testing.assert_allclose(m, plays, atol=1e-15)
        # ... and the committed memory gives the same output.
        assert float(pi.output(m, jnp.asarray(u))) == pytest.approx(gamma, abs=1e-15)


def test_play_operator_matches_max_min_form():
    rng = np.random.default_rng(1)
    r = np.sort(rng.uniform(0, 30, 12))
    r[0] = 0.0
    w = rng.uniform(0.1, 1.0, 12) * 1e-9
    pi = ss.PrandtlIshlinskii(r, w)
    u_seq = rng.uniform(-10, 60, 200)
    p = np.clip(0.0, u_seq[0] - r, u_seq[0] + r)
    m = pi.initial_memory(jnp.asarray(u_seq[0]))
    for u in u_seq[1:]:
        p = np.maximum(u - r, np.minimum(u + r, p))      # docs/model.md, literally
        m = pi.update(m, jnp.asarray(u))
        np.testing.assert_allclose(m, p, rtol=0, atol=1e-12)
        assert float(pi.output(m, jnp.asarray(u))) == pytest.approx(float(w @ p), rel=1e-13)


def test_pi_initial_memory_convention():
    pi = ss.PrandtlIshlinskii([0.0, 1.0, 2.0], [1.0, 0.5, 0.25])
    # clip(0, U0 − r, U0 + r): as if risen from 0 (or fallen, for U0 < 0).
    np.testing.assert_allclose(pi.initial_memory(jnp.asarray(1.5)), [1.5, 0.5, 0.0])
    np.testing.assert_allclose(pi.initial_memory(jnp.asarray(-1.5)), [-1.5, -0.5, 0.0])
    np.testing.assert_allclose(pi.initial_memory(jnp.asarray(5.0)), [5.0, 4.0, 3.0])
    risen = pi.update(pi.initial_memory(jnp.asarray(0.0)), jnp.asarray(1.5))
    np.testing.assert_array_equal(pi.initial_memory(jnp.asarray(1.5)), risen)
    assert float(pi.output(pi.initial_memory(jnp.asarray(1.5)), jnp.asarray(1.5))) == \
        pytest.approx(1.75)


# ---- friction ---------------------------------------------------------------------------
def test_transition_alpha_values():
    a = ss.transition_alpha
    w = ZSS - ZBA
    assert float(a(0.0, ZBA, ZSS)) == 0.0
    assert float(a(ZBA, ZBA, ZSS)) == 0.0
    assert float(a(ZBA + w / 4, ZBA, ZSS)) == pytest.approx(0.5 - math.sqrt(2) / 4, abs=1e-14)
    assert float(a(0.5 * (ZBA + ZSS), ZBA, ZSS)) == pytest.approx(0.5, abs=1e-14)
    assert float(a(ZBA + 3 * w / 4, ZBA, ZSS)) == pytest.approx(0.5 + math.sqrt(2) / 4,
                                                                 abs=1e-14)
    assert float(a(ZSS, ZBA, ZSS)) == 1.0
    assert float(a(2 * ZSS, ZBA, ZSS)) == 1.0
    # C¹ ramp: zero slope at both ends, π/(2w) in the middle.
    da = jax.grad(lambda z: a(z, ZBA, ZSS))
    top = math.pi / (2 * w)
    assert abs(float(da(ZBA + 1e-6 * w))) < 1e-4 * top
    assert abs(float(da(ZSS - 1e-6 * w))) < 1e-4 * top
    assert float(da(0.5 * (ZBA + ZSS))) == pytest.approx(top, rel=1e-12)


def test_transition_alpha_ratio_one_is_a_step():
    a = ss.transition_alpha
    assert float(a(ZBA, ZBA, ZBA)) == 0.0
    assert float(a(ZBA * (1 + 1e-12), ZBA, ZBA)) == 1.0
    assert float(a(ZBA * (1 - 1e-12), ZBA, ZBA)) == 0.0
    g = jax.grad(lambda zb: a(1.2 * ZBA, zb, zb))(ZBA)
    assert np.isfinite(float(g)) and float(g) == 0.0


def _zrate_contract(z, xdot, zba, zss_mag):
    """docs/model.md, literally: ż = ẋ·(1 − α·z/z_ss(ẋ)), z_ss = sgn(ẋ)·|z_ss|."""
    out = np.empty(np.broadcast(z, xdot).shape)
    for idx, (zi, vi) in enumerate(zip(*np.broadcast_arrays(z, xdot), strict=True)):
        if vi == 0.0:
            out[idx] = 0.0
            continue
        zss = math.copysign(zss_mag, vi)
        if np.sign(vi) != np.sign(zi) or abs(zi) <= zba:
            alpha = 0.0
        elif abs(zi) >= zss_mag:
            alpha = 1.0
        else:
            alpha = 0.5 * math.sin(math.pi * (abs(zi) - (zss_mag + zba) / 2)
                                   / (zss_mag - zba)) + 0.5
        out[idx] = vi * (1 - alpha * zi / zss)
    return out


def test_elastoplastic_rate_follows_the_contract():
    fr = ss.ElastoPlastic(RHO0, ZBA, 0.45e-6, zba_ratio=RATIO)
    zz, vv = np.meshgrid(np.linspace(-ZSS, ZSS, 61),
                         np.r_[-np.logspace(-6, 0, 7), np.logspace(-6, 0, 7)])
    z, v = zz.ravel(), vv.ravel()
    for drive, zba in ((FWD, ZBA), (DriveContext.make(True), 0.45e-6)):
        got = np.asarray(fr.z_rate(jnp.asarray(z), jnp.asarray(v), drive))
        want = _zrate_contract(z, v, zba, zba / RATIO)
        assert np.all(np.abs(got - want) <= 1e-12 * np.abs(want) + 1e-15 * np.abs(v))
    # Same-sign motion in the mixed regime really is damped (not a trivial ż = ẋ).
    assert float(fr.z_rate(0.5e-6, 1.0, FWD)) < 0.7


def test_elastoplastic_rate_is_continuous_across_zero_velocity():
    fr = ss.ElastoPlastic(RHO0, ZBA, zba_ratio=RATIO)
    for z in (0.5e-6, -0.5e-6, 0.59e-6, 0.1e-6):
        assert float(fr.z_rate(z, 0.0, FWD)) == 0.0
        for eps in (1e-3, 1e-6, 1e-9, 1e-12):
            up, down = float(fr.z_rate(z, eps, FWD)), float(fr.z_rate(z, -eps, FWD))
            assert abs(up) <= eps and abs(down) <= eps * (1 + 1e-12)
            assert abs(up - down) <= 2 * eps * (1 + 1e-12)
    # Lipschitz in ẋ with constant ≤ 2 (|1 − α·z/z_ss| ≤ 2) over a fine grid.
    v = jnp.linspace(-1e-4, 1e-4, 2001)
    for z in (0.5e-6, -0.5e-6):
        r = np.asarray(fr.z_rate(z, v, FWD))
        assert np.all(np.abs(np.diff(r)) <= 2 * float(v[1] - v[0]) * (1 + 1e-9))


def test_force_and_saturation():
    fr = ss.ElastoPlastic(RHO0, ZBA, zba_ratio=RATIO, rho1=2.0, rho2=0.5)
    assert float(fr.force(1e-7, 1e-3, 2e-3, FWD)) == pytest.approx(RHO0 * 1e-7 + 2e-3 + 1e-3)
    assert float(fr.project(1e-6, 0.1, FWD)) == pytest.approx(ZSS, rel=1e-15)
    assert float(fr.project(-1e-6, 0.1, FWD)) == pytest.approx(-ZSS, rel=1e-15)
    assert float(fr.project(0.3e-6, 0.1, FWD)) == 0.3e-6
    assert float(fr.coulomb_force(FWD)) == pytest.approx(RHO0 * ZSS, rel=1e-15)   # 0.211 N


def test_stribeck_zss_bounds():
    base = ZBA / RATIO
    fr = ss.StribeckElastoPlastic(RHO0, ZBA, stribeck_ratio=1.5, v_s=1e-3, zba_ratio=RATIO)
    v = jnp.r_[-jnp.logspace(-8, 1, 50), 0.0, jnp.logspace(-8, 1, 50)]
    zss = np.asarray(fr.zss_magnitude(v, FWD))
    assert np.all(zss >= base * (1 - 1e-15))
    assert float(fr.zss_magnitude(0.0, FWD)) == pytest.approx(1.5 * base, rel=1e-14)
    assert float(fr.zss_magnitude(1e-3, FWD)) == pytest.approx(1.25 * base, rel=1e-14)
    assert float(fr.zss_magnitude(-1e-3, FWD)) == pytest.approx(1.25 * base, rel=1e-14)
    assert float(fr.zss_magnitude(1.0, FWD)) == pytest.approx(base, rel=1e-6)
    # Saturation follows |z_ss(ẋ)|, the Coulomb level stays rho0·z_ba/ratio.
    assert float(fr.project(1.0, 0.0, FWD)) == pytest.approx(1.5 * base, rel=1e-14)
    assert float(fr.coulomb_force(FWD)) == pytest.approx(RHO0 * base, rel=1e-14)
    # stribeck_ratio = 1 is the plain law.
    plain = ss.StribeckElastoPlastic(RHO0, ZBA, stribeck_ratio=1.0, v_s=1e-3, zba_ratio=RATIO)
    np.testing.assert_allclose(plain.zss_magnitude(v, FWD), base, rtol=1e-15)


# ---- actuator: rest state, signs ---------------------------------------------------------
def _loaded_actuator(F_ext=0.05, k_load=0.0, friction=None):
    base = ss.lu2015_slc1720()
    return eqx.tree_at(
        lambda a: (a.piezo, a.slider, a.friction), base,
        (ss.PiezoElement(base.piezo.Mp, base.piezo.Dp, base.piezo.Kp, Kact2=2.0, N=0.05),
         ss.Slider(base.slider.Ms, base.slider.Ds, F_ext=F_ext, k_load=k_load),
         base.friction if friction is None else friction))


@pytest.mark.parametrize("law", ["elastoplastic", "lugre"])
def test_initial_state_is_rest_equilibrium(law):
    friction = None if law == "elastoplastic" else ss.LuGre(2e5, 1.0, 0.0, 0.2, 0.24, 1e-3)
    act = _loaded_actuator(friction=friction)
    stiffness = RHO0 if law == "elastoplastic" else 2e5
    u0 = 30.0
    y0, m0 = act.initial_state(jnp.asarray(u0), FWD)
    gamma = float(act.hysteresis.output(m0, jnp.asarray(u0)))
    np.testing.assert_array_equal(m0, act.hysteresis.initial_memory(jnp.asarray(u0)))
    x1 = gamma - (2.0 * 0.05 - 0.05) / float(act.piezo.Kp)
    np.testing.assert_allclose(y0, [x1, 0.0, 0.0, 0.0, -0.05 / stiffness], rtol=1e-14,
                               atol=0)
    assert x1 < gamma                                     # Kact2·N − F_ext > 0 retracts
    f = np.asarray(act.vector_field(y0, jnp.asarray(u0), jnp.asarray(gamma), FWD))
    scale_a1 = float(act.piezo.Kp) * gamma / float(act.piezo.Mp)
    assert f[0] == 0.0 and f[2] == 0.0 and f[4] == 0.0
    assert abs(f[1]) < 1e-12 * scale_a1
    assert abs(f[3]) < 1e-12 * 0.05 / float(act.slider.Ms)
    # Held at U0, the simulated actuator does not move.
    q = np.asarray(ss.simulate(act, np.full(200, u0), dt=DT))
    assert q[0] == pytest.approx(x1, rel=1e-14)
    assert np.abs(q - q[0]).max() < 1e-12 * abs(q[0])


def test_backward_sawtooth_starts_at_its_amplitude():
    act = ss.lu2015_slc1720()
    _, u = ss.sawtooth(40.0, 100.0, direction="backward", duration_s=0.002)
    q = np.asarray(ss.simulate(act, u, dt=DT, drive=DriveContext.make(True, 40.0, 100.0)))
    gamma = float(act.hysteresis.output(act.hysteresis.initial_memory(jnp.asarray(40.0)),
                                        jnp.asarray(40.0)))
    assert q[0] == pytest.approx(gamma, rel=1e-14) and gamma > 0.9e-6   # 0.945 µm


def test_force_signs_and_momentum_balance():
    act = _loaded_actuator(F_ext=0.05, k_load=1e3)
    p, s = act.piezo, act.slider
    # External force along +x accelerates the slider +x; the load spring pulls back.
    assert float(s.acceleration(0.0, 0.0, 0.0)) == pytest.approx(0.05 / float(s.Ms))
    assert float(s.acceleration(1e-6, 0.0, 0.0)) == pytest.approx((0.05 - 1e-3) / float(s.Ms))
    assert float(ss.Slider.gravity(0.01, 1.0).F_ext) == pytest.approx(-0.01 * 9.80665)
    assert float(ss.Slider.gravity(0.01, 1.0, upward_is_positive=False).F_ext) > 0
    # Friction pushes the slider along +Ff and the piezo along −Ff (docs/model.md).
    rng = np.random.default_rng(3)
    for _ in range(20):
        y = jnp.asarray(rng.normal(size=5) * np.array([1e-7, 1e-3, 1e-7, 1e-3, 1e-7]))
        u, gamma = 10.0, 3e-7
        f = np.asarray(act.vector_field(y, jnp.asarray(u), jnp.asarray(gamma), FWD))
        x1, v1, x2, v2, z = np.asarray(y)
        zdot = float(act.friction.z_rate(y[4], y[1] - y[3], FWD))
        ff = float(act.friction.force(y[4], zdot, y[1] - y[3], FWD))
        assert f[3] * float(s.Ms) == pytest.approx(
            ff + 0.05 - 1e3 * x2 - float(s.Ds) * v2, rel=1e-10)
        # Internal friction cancels in the momentum balance.
        total = f[1] * float(p.Mp) + f[3] * float(s.Ms)
        external = (float(p.Kp) * (gamma - x1) - float(p.Dp) * v1 - 0.1
                    - float(s.Ds) * v2 + 0.05 - 1e3 * x2)
        assert total == pytest.approx(external, rel=1e-9, abs=1e-12 * abs(ff))


def test_external_force_and_load_spring_in_simulation():
    f, n = 100.0, 6
    _, u = ss.sawtooth(40.0, f, duration_s=n / f)
    p = round(25_000 / f)

    def steps(act):
        q = np.asarray(ss.simulate(act, u, dt=DT, drive=DriveContext.make(False, 40.0, f)))
        ends = q[p - 1 :: p]
        return q, np.diff(ends)

    _, free = steps(_loaded_actuator(F_ext=0.0))
    _, helped = steps(_loaded_actuator(F_ext=0.05))
    _, hindered = steps(_loaded_actuator(F_ext=-0.05))
    # A force along +x lengthens forward steps, one along −x shortens them
    # (measured 365.0 nm per period free, 524.5 with +0.05 N, 215.4 with −0.05 N).
    assert free[-1] == pytest.approx(364.95e-9, rel=1e-3)
    assert helped[-1] == pytest.approx(524.49e-9, rel=1e-3)
    assert hindered[-1] == pytest.approx(215.38e-9, rel=1e-3)
    # A stiff load spring stalls the slider: per-period steps shrink as it compresses
    # (measured 119, 96, 78, 64, 54 nm), the slider staying short of the stall
    # position f_c/k_load = 2.1 µm.
    q, loaded = steps(_loaded_actuator(F_ext=0.0, k_load=1e5))
    assert loaded[-1] < 0.2 * free[-1]
    assert np.all(np.diff(loaded) < 0) and np.all(loaded > 0)
    assert q.max() < 2 * 0.211 / 1e5


# ---- transformations ---------------------------------------------------------------------
def test_simulate_under_jit_and_vmap_gives_identical_numbers():
    act = ss.lu2015_slc1720()
    volts = np.stack([ss.sawtooth(a, 200.0, direction=d, duration_s=0.01)[1]
                      for a, d in ((20.0, "forward"), (40.0, "backward"), (60.0, "forward"))])
    drives = [DriveContext.make(d, a, 200.0) for a, d in ((20.0, 0.0), (40.0, 1.0),
                                                          (60.0, 0.0))]
    # One plan (a traced actuator cannot plan from its values).
    plan = ss.plan_steps(act, DT)
    eager = np.stack([np.asarray(ss.simulate(act, v, dt=DT, drive=d))
                      for v, d in zip(volts, drives, strict=True)])
    # Same numbers up to floating-point reassociation by XLA: 1e-13 of the trace's scale
    # (measured ≤ 3e-21 m on ~1e-6 m traces).
    tol = {"rtol": 0.0, "atol": 1e-13 * np.abs(eager).max()}
    jitted = jax.jit(lambda a, v, d: ss.simulate(a, v, dt=DT, drive=d, stepping=plan))
    for i in range(3):
        np.testing.assert_allclose(jitted(act, volts[i], drives[i]), eager[i], **tol)
    mapped = jax.vmap(lambda v, d: ss.simulate(act, v, dt=DT, drive=d))(
        jnp.asarray(volts), ss.stack_drives(drives))
    np.testing.assert_allclose(mapped, eager, **tol)
    for batching in ("vmap", "map"):  # one batched scan, or the rows one after the other
        batched = ss.simulate_batch(act, volts, dt=DT, drives=ss.stack_drives(drives),
                                    batching=batching)
        np.testing.assert_allclose(batched, eager, **tol)
    with pytest.raises(ValueError, match="batching"):
        ss.simulate_batch(act, volts, dt=DT, batching="pmap")
    # The rows are different motions (scan, backward and forward stepping).
    assert eager[1, -1] < -0.5e-6 < 0.5e-6 < eager[2, -1]

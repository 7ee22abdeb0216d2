"""Pieces of the identification: start-up estimates, transforms, spectra, statistics."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.identify import Dataset, ParameterMap, parameter_uncertainty
from stickslip_jax.identify.dataset import length_buckets
from stickslip_jax.identify.initial import (
    measured_step_mode,
    resample_pi,
    scale_pi_quasistatic,
    scale_to_step_mode,
    stroke_along,
)
from stickslip_jax.identify.parameters import PI_SUM_FLOOR
from stickslip_jax.identify.report import classify_regime
from stickslip_jax.identify.residuals import band_log_psd, band_matrix, noise_floor_psd
from stickslip_jax.noise import noise_sigma


def _recording(t, q):
    return ss.make_recording(t, np.zeros_like(t), waveform="step",
                             amplitude_V=0.0, name="noise").with_position_m(q)


def test_step_mode_recovers_damped_ringing_under_noise():
    fs = 25_000.0
    t = np.arange(1500) / fs
    f_d, zeta = 612.0, 0.3
    sigma = zeta * 2 * np.pi * f_d / np.sqrt(1 - zeta**2)
    after = t >= 2e-3
    tt = t - 2e-3
    q = np.where(after, 1e-6 * (1 - np.exp(-sigma * tt) * np.cos(2 * np.pi * f_d * tt)), 0.0)
    q = q + 2e-9 * np.random.default_rng(1).standard_normal(t.size)
    rec = ss.make_recording(t, np.where(after, 40.0, 0.0), waveform="step",
                            amplitude_V=40.0, name="ring").with_position_m(q)
    f_est, z_est = measured_step_mode(rec)
    assert f_est == pytest.approx(f_d, rel=0.01)
    assert z_est == pytest.approx(zeta, abs=0.03)


def test_step_mode_is_none_without_ringing():
    t = np.arange(800) / 25_000.0
    rec = _recording(t, 1e-9 * np.random.default_rng(0).standard_normal(t.size))
    assert measured_step_mode(rec) is None


def test_scaling_to_a_measured_mode_moves_the_first_mode_there():
    act = ss.lu2015_slc1720()
    moved, k, d = scale_to_step_mode(act, 700.0, 0.25)
    m = ss.stick_modes(moved)
    assert m.damped_Hz[0] == pytest.approx(700.0, rel=0.01)
    assert m.damping_ratio[0] == pytest.approx(0.25, rel=0.05)
    assert float(moved.slider.Ms) == float(act.slider.Ms)  # masses keep the scale
    assert k > 1.0


def test_quasistatic_gain_matches_a_stuck_sine():
    act = ss.lu2015_slc1720()
    t, u = ss.sine(40.0, 20.0, duration_s=0.1)
    q = 2.0 * 1.25 * stroke_along(act, u)  # stick: q = 2·Γ, with a 25 % stronger PI
    rec = ss.make_recording(t, u, waveform="sine", amplitude_V=40.0,
                            frequency_Hz=20.0, name="slow").with_position_m(q)
    _, gain = scale_pi_quasistatic(act, rec)
    assert gain == pytest.approx(1.25, rel=1e-6)


def test_resample_pi_keeps_the_loading_curve_on_shared_thresholds():
    pi = ss.lu2015_slc1720().hysteresis
    r = np.asarray(pi.thresholds)
    same = resample_pi(pi, r)
    np.testing.assert_allclose(np.asarray(same.weights), np.asarray(pi.weights), rtol=1e-12)
    coarse = resample_pi(pi, r[::5])
    assert np.all(np.cumsum(np.asarray(coarse.weights)) > 0)


def test_length_buckets_group_similar_lengths_and_cover_every_recording():
    lengths = np.array([1250, 500, 2500, 1250, 500, 2500, 1500])
    buckets = length_buckets(lengths)
    assert sorted(i for idx, _ in buckets for i in idx) == list(range(7))
    for idx, n in buckets:
        assert n == max(lengths[list(idx)])
        assert min(lengths[list(idx)]) >= 0.75 * n
    assert len(buckets) == 3


def test_bucketed_simulation_equals_one_padded_batch(fixtures_dir):
    from dataclasses import replace

    from stickslip_jax.identify import simulate_dataset

    recs = [ss.load_recording(fixtures_dir / "identification" / f"{n}.csv")
            for n in ("step_40V", "saw_40V_500Hz_bwd", "sine_40V_50Hz")]
    data = Dataset.from_recordings(recs)
    assert len(data.buckets) == 2
    act = ss.lu2015_slc1720()
    plan = ss.plan_steps(act, data.dt, substeps=4)
    q = np.asarray(simulate_dataset(act, data, plan=plan))
    q1 = np.asarray(simulate_dataset(act, replace(data, buckets=()), plan=plan))
    np.testing.assert_allclose(q * data.mask, q1 * data.mask, rtol=1e-12, atol=1e-20)
    # Recordings one after the other (CPU default) or vmapped: the same numbers.
    for batching in ("map", "vmap"):
        qb = np.asarray(simulate_dataset(act, data, plan=plan, batching=batching))
        np.testing.assert_allclose(qb * data.mask, q * data.mask, rtol=1e-12, atol=1e-20)
    with pytest.raises(ValueError, match="batching"):
        simulate_dataset(act, data, batching="pmap")


def test_parameter_map_starts_at_the_start_and_keeps_pi_monotone():
    act = ss.lu2015_slc1720()
    pmap = ParameterMap.make(act, ["Mp", "zba_ratio", "rho1", "pi_weights"])
    back = pmap.actuator(pmap.zeros())
    assert float(back.piezo.Mp) == pytest.approx(float(act.piezo.Mp), rel=1e-14)
    assert float(back.friction.zba_ratio) == pytest.approx(0.667, rel=1e-12)
    np.testing.assert_allclose(np.asarray(back.hysteresis.weights),
                               np.asarray(act.hysteresis.weights), rtol=1e-12, atol=1e-24)
    theta = jnp.asarray(np.random.default_rng(3).normal(0, 2.0, pmap.size))
    moved = pmap.actuator(theta)
    assert np.all(np.cumsum(np.asarray(moved.hysteresis.weights)) > 0)
    assert 0 < float(moved.friction.zba_ratio) < 1
    assert float(moved.friction.rho1) >= 0
    with pytest.raises(KeyError, match="not a fittable"):
        ParameterMap.make(act, ["mass"])


def test_a_floored_log_parameter_stops_at_its_floor_with_its_derivative_there():
    """A log parameter with a floor never goes below it; a map started at the floor
    has the whole derivative there (θ = 0), none below; numpy and JAX agree."""
    from stickslip_jax.identify.parameters import ParameterSpec
    from stickslip_jax.model.extensions import SlewLimitedInput

    act = eqx.tree_at(lambda a: a.input_stage, ss.lu2015_slc1720(),
                      SlewLimitedInput(1e6, 5e-6))
    spec = ParameterSpec(lambda a: a.input_stage.tau, "log", 1.0, "s", floor=1e-6)
    pmap = ParameterMap.make(act, ["tau"], {"tau": spec})
    for theta, want in ((0.5, 5e-6 * np.exp(0.5)), (-1.0, 5e-6 * np.exp(-1.0)),
                        (-2.0, 1e-6), (-700.0, 1e-6)):
        for xp in (np, jnp):
            got = float(pmap.actuator(xp.asarray([theta]), xp=xp).input_stage.tau)
            assert got == pytest.approx(want, rel=1e-14)
    at_floor = eqx.tree_at(lambda a: a.input_stage.tau, act, jnp.asarray(1e-6))
    fresh = ParameterMap.make(at_floor, ["tau"], {"tau": spec})

    def tau(th):
        return fresh.actuator(th).input_stage.tau

    assert float(jax.grad(lambda th: tau(th)[()])(jnp.zeros(1))[0]) == pytest.approx(1e-6)
    assert float(jax.grad(lambda th: tau(th)[()])(jnp.full(1, -0.1))[0]) == 0.0
    np.testing.assert_allclose(fresh.free[0].derivative(np.zeros(1)), [[1e-6]])
    np.testing.assert_allclose(fresh.free[0].derivative(np.full(1, -0.1)), [[0.0]])
    with pytest.raises(ValueError, match="floor"):
        ParameterMap.make(act, ["tau"], {"tau": ParameterSpec(
            lambda a: a.input_stage.tau, "log", 1.0, "s", floor=1e-5)})


def test_a_pi_partial_sum_at_rounding_level_is_lifted_a_folded_loop_is_refused():
    # set_10 from the profile: after a 75-step polish one partial sum of the PI
    # weights rounded to ≤ 0 and the diagnosis stopped with "not monotone".
    act = ss.lu2015_slc1720()
    w = np.asarray(act.hysteresis.weights).copy()
    top = float(np.cumsum(w).max())
    w[3] = -np.sum(w[:3])                       # partial sum 3 rounds to 0 (or −1e-17)
    w[4] += 0.3 * top                           # the loop goes on rising after it
    folded = np.cumsum(w)
    assert abs(folded[3]) < 1e-15 * top and np.all(np.delete(folded, 3) > 0)
    rounded = eqx.tree_at(lambda a: a.hysteresis.weights, act, jnp.asarray(w))
    pmap = ParameterMap.make(rounded, ["pi_weights"])
    start = np.asarray(pmap.actuator(pmap.zeros()).hysteresis.weights)
    sums = np.cumsum(start)
    assert np.all(sums > 0)
    assert sums[3] == pytest.approx(PI_SUM_FLOOR * folded.max(), rel=1e-6)
    np.testing.assert_allclose(start, w, rtol=0, atol=2 * PI_SUM_FLOOR * top)
    # A partial sum clearly below zero is a folded loop, not rounding.
    w[3] -= 1e-6 * top
    with pytest.raises(ValueError, match="not monotone"):
        ParameterMap.make(eqx.tree_at(lambda a: a.hysteresis.weights, act, jnp.asarray(w)),
                          ["pi_weights"])


def test_noise_floor_of_white_noise_gives_its_sigma():
    rng = np.random.default_rng(7)
    t = np.arange(4000) / 25_000.0
    rec = _recording(t, 3e-9 * rng.standard_normal(t.size))
    assert noise_sigma(rec) == pytest.approx(3e-9, rel=0.05)
    bands, centres = band_matrix(t.size, 4e-5)
    lp = band_log_psd(rec.position_m, 4e-5, bands, xp=np)
    level = np.log10(noise_floor_psd(rec.position_m, 4e-5))
    bins = 1.0 / bands.max(axis=1)
    wide = bins >= 10  # n Hann-windowed bins scatter by ~0.43/√(n/2) in log10
    assert wide.sum() > 10
    err = (lp - level)[wide]
    assert np.sqrt(np.mean(err**2)) < 0.12
    assert abs(np.mean(err)) < 0.06  # no bias: the level is the mean, not the median
    assert len(centres) == bands.shape[0]


def test_uncertainty_matches_the_linear_regression_formula_and_flags_null_directions():
    rng = np.random.default_rng(11)
    x = np.linspace(0, 1, 200)
    jac = np.stack([np.ones_like(x), x], axis=1)
    resid = 0.1 * rng.standard_normal(x.size)
    unc = parameter_uncertainty(jac, resid, np.eye(2), np.array([1.0, 2.0]), ["a", "b"])
    sigma2 = np.sum(resid**2) / (x.size - 2)
    cov = sigma2 * np.linalg.inv(jac.T @ jac)
    np.testing.assert_allclose(unc.std_errors, np.sqrt(np.diag(cov)), rtol=1e-10)
    assert unc.determined.all()
    degenerate = np.stack([x, x, np.ones_like(x)], axis=1)  # a and b enter only as a + b
    unc2 = parameter_uncertainty(degenerate, resid, np.eye(3), np.ones(3), ["a", "b", "c"])
    assert list(unc2.determined) == [False, False, True]
    # A non-finite Jacobian (an overflowed simulation) determines nothing, no error.
    jac[3, 1] = np.nan
    unc3 = parameter_uncertainty(jac, resid, np.eye(2), np.array([1.0, 2.0]), ["a", "b"])
    assert not unc3.determined.any() and np.isinf(unc3.std_errors).all()
    assert unc3.as_dict()["a"]["std_error"] is None


def test_regimes_of_the_fixture_set(fixtures_dir):
    folder = fixtures_dir / "identification"
    regimes = {n: classify_regime(ss.load_recording(folder / f"{n}.csv"))
               for n in ("saw_20V_100Hz_fwd", "saw_40V_100Hz_fwd", "saw_60V_50Hz_bwd",
                         "sine_40V_50Hz", "step_40V")}
    assert regimes == {"saw_20V_100Hz_fwd": "scanning", "saw_40V_100Hz_fwd": "stepping_forward",
                       "saw_60V_50Hz_bwd": "stepping_backward", "sine_40V_50Hz": "sine",
                       "step_40V": "step"}


def test_noise_sigma_ignores_slip_edges_of_fixture_traces(fixtures_dir):
    # The fixtures carry 1 nm white noise on top of traces full of slip edges, whose
    # spectrum would swamp a spectral estimate at high drive frequency.
    for rec in ss.load_recordings(fixtures_dir / "identification"):
        assert noise_sigma(rec) == pytest.approx(1e-9, rel=0.15), rec.name


def test_solver_converges_to_the_least_squares_optimum_and_says_when_it_has_not():
    from stickslip_jax.identify.solve import solve_least_squares

    t = jnp.linspace(0.0, 1.0, 200)
    noise = 0.01 * np.random.default_rng(0).standard_normal(200)
    y = 2.0 * jnp.exp(-1.3 * t) + noise

    def residuals(th):
        return th[0] * jnp.exp(-th[1] * t) - y

    out = solve_least_squares(residuals, jnp.array([1.0, 0.5]))
    assert out.converged and out.message.startswith("converged")
    # The optimum: the gradient of the cost vanishes there.
    grad = np.asarray(jax.grad(lambda th: jnp.sum(residuals(th) ** 2))(jnp.asarray(out.theta)))
    assert np.max(np.abs(grad)) < 1e-6
    assert out.theta == pytest.approx([2.0, 1.3], abs=0.02)
    assert out.cost_end < out.cost_start
    short = solve_least_squares(residuals, jnp.array([1.0, 0.5]), max_steps=2)
    assert not short.converged and "max_steps=2" in short.message


def test_a_jacobian_whose_columns_are_shared_among_threads_is_the_whole_jacobian(monkeypatch):
    from stickslip_jax.identify.solve import ColumnSplitJacobian, jacobian_threads

    def fn(th, scale):
        return jnp.stack([th[0] * th[1], scale * jnp.sin(th[2]), th[3] ** 2 + th[4],
                          th[4] * th[0], jnp.exp(th[1] - th[3])])

    x = jnp.array([0.3, -1.2, 0.7, 2.0, 0.5])
    want = np.asarray(jax.jacfwd(fn)(x, 2.0))
    assert want.shape == (5, 5) and np.count_nonzero(want) == 9
    # 1 thread; 2 and 3 (5 columns: shares of 3 and 2, 2 and 2 and 1, padded with
    # zero tangents); more threads than columns.
    for threads in (1, 2, 3, 8):
        value, jac = ColumnSplitJacobian(fn, threads)(x, 2.0)
        np.testing.assert_allclose(np.asarray(value), np.asarray(fn(x, 2.0)), rtol=1e-15)
        np.testing.assert_allclose(np.asarray(jac), want, rtol=1e-13, atol=1e-15)
    monkeypatch.setenv("STICKSLIP_JACOBIAN_THREADS", "3")
    assert jacobian_threads() == 3
    monkeypatch.setenv("STICKSLIP_JACOBIAN_THREADS", "0")
    with pytest.raises(ValueError, match="STICKSLIP_JACOBIAN_THREADS"):
        jacobian_threads()


def test_transform_derivatives_in_numpy_are_jaxs():
    act = ss.lu2015_slc1720()
    names = ["Mp", "zba_ratio", "rho1", "pi_weights", "z_ba_forward"]
    pmap = ParameterMap.make(act, names)
    theta = np.random.default_rng(4).normal(0, 0.5, pmap.size)

    def flat(th):
        return jnp.concatenate([jnp.atleast_1d(v) for v in jax.tree.leaves(
            eqx.filter(pmap.actuator(th), mask))])

    from stickslip_jax.identify.sensitivities import perturbed_mask

    mask = perturbed_mask(act, names)
    # The actuator, its values and their derivatives in numpy, as JAX has them.
    np_act, jax_act = pmap.actuator(theta, xp=np), pmap.actuator(jnp.asarray(theta))
    for a, b in zip(jax.tree.leaves(np_act), jax.tree.leaves(jax_act), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=0)
    want = np.asarray(jax.jacfwd(flat)(jnp.asarray(theta)))  # (leaf values, θ)
    got = np.concatenate([x.reshape(pmap.size, -1) for x in
                          jax.tree.leaves(pmap.leaf_tangents(theta, mask))], axis=1).T
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)
    labels = np.asarray(jax.jacfwd(lambda th: jnp.concatenate(
        [jnp.atleast_1d(p.to_physical(th[s])) for p, s in
         zip(pmap.free, pmap.slices().values(), strict=True)]))(jnp.asarray(theta)))
    np.testing.assert_allclose(pmap.value_jacobian(theta), labels, rtol=1e-12, atol=1e-300)


def test_residual_jacobian_by_the_chain_rule_is_the_jvp_of_the_residual(fixtures_dir):
    from stickslip_jax.identify.residuals import TraceResiduals

    recs = [ss.load_recording(fixtures_dir / "identification" / f"{n}.csv")
            for n in ("step_40V", "saw_40V_500Hz_bwd", "sine_40V_50Hz")]
    data = Dataset.from_recordings(recs)
    pmap = ParameterMap.make(ss.lu2015_slc1720(), ["Mp"])
    rng = np.random.default_rng(5)
    q = np.asarray(data.measured) + 1e-9 * rng.standard_normal(data.measured.shape)
    dq = 1e-8 * rng.standard_normal(data.measured.shape + (3,))
    # Every term: time traces, log-PSD of the step, step lengths; whitened; in metres.
    for options in (dict(w_psd=0.01, w_steps=1.0), dict(whiten=True), dict(in_metres=True)):
        res = TraceResiduals.make(pmap, data, **options)
        r, jac = res.jacobian_from_outputs(q, dq)
        r_jax, jac_jax = jax.vmap(lambda d, res=res: jax.jvp(res.from_output, (jnp.asarray(q),),
                                                            (d,)),
                                  in_axes=2, out_axes=(None, 1))(jnp.asarray(dq))
        np.testing.assert_allclose(r, np.asarray(r_jax), rtol=1e-10,
                                   atol=1e-12 * np.max(np.abs(r_jax)))
        np.testing.assert_allclose(jac, np.asarray(jac_jax), rtol=1e-10,
                                   atol=1e-12 * np.max(np.abs(jac_jax)))


def test_shared_programs_give_the_steps_residuals_and_jacobians(fixtures_dir):
    from stickslip_jax.identify.residuals import TraceResiduals
    from stickslip_jax.identify.sensitivities import (
        RecordingPrograms,
        StepJacobian,
        perturbed_mask,
    )
    from stickslip_jax.identify.solve import value_and_jacobian

    recs = [ss.load_recording(fixtures_dir / "identification" / f"{n}.csv")
            for n in ("saw_40V_500Hz_bwd", "step_40V", "saw_20V_500Hz_fwd")]
    data = Dataset.from_recordings(recs)
    act = ss.lu2015_slc1720()
    union = ["Mp", "Kp", "rho0", "z_ba_forward", "z_ba_backward"]
    plan = ss.plan_steps(act, data.dt, substeps=3)
    mask = perturbed_mask(act, union)
    assert RecordingPrograms(data, act, mask, threads=2).width == 3  # 5 quantities
    # Two tangents per call: the step's three columns take two shares.
    programs = RecordingPrograms(data, act, mask, threads=2, width=2)
    rows = [0, 2]  # the sawtooths, as a step would pick them
    sub = Dataset.from_recordings([recs[b] for b in rows])
    pmap = ParameterMap.make(act, ["Kp", "z_ba_forward", "z_ba_backward"])
    res = TraceResiduals.make(pmap, sub, stepping=plan, w_steps=1.0)
    theta = np.array([0.05, -0.1, 0.2])
    r, jac = StepJacobian(res, programs, rows)(theta)
    r_ref, jac_ref = value_and_jacobian(res, jnp.asarray(theta))
    np.testing.assert_allclose(r, r_ref, rtol=1e-9, atol=1e-12 * np.max(np.abs(r_ref)))
    np.testing.assert_allclose(jac, jac_ref, rtol=1e-8, atol=1e-10 * np.max(np.abs(jac_ref)))
    # One column (2·1 ≤ width): one plain JVP per recording, the other program.
    res1 = TraceResiduals.make(ParameterMap.make(act, ["z_ba_backward"]), sub, stepping=plan,
                               whiten=True)
    r1, jac1 = StepJacobian(res1, programs, rows)(np.array([0.1]))
    r1_ref, jac1_ref = value_and_jacobian(res1, jnp.array([0.1]))
    np.testing.assert_allclose(r1, r1_ref, rtol=1e-9, atol=1e-12 * np.max(np.abs(r1_ref)))
    np.testing.assert_allclose(jac1, jac1_ref, rtol=1e-8,
                               atol=1e-10 * np.max(np.abs(jac1_ref)))
    # The traces alone, every recording, padded with the last real value.
    q = programs.simulate(act, plan)
    q_ref = np.asarray(ss.simulate_batch(act, data.voltages, dt=data.dt, drives=data.drives,
                                         stepping=plan))
    np.testing.assert_allclose(q * data.mask, q_ref * data.mask, rtol=1e-12, atol=1e-20)
    last = int(data.mask[1].sum()) - 1  # the step, the shortest recording
    np.testing.assert_array_equal(q[1, last:], q[1, last])


def test_levenberg_marquardt_steps_are_optimistixs():
    # The numpy steps against optimistix's LevenbergMarquardt driven one step at a time,
    # on a problem with rejected steps (Rosenbrock) and a damping started low and high.
    import optimistix as optx

    from stickslip_jax.identify.solve import LevenbergMarquardtSteps

    def fn(y, _):
        return jnp.stack([10 * (y[1] - y[0] ** 2), 1 - y[0], 0.1 * y[2] * y[0] - 0.2]), None

    y0 = jnp.array([-1.2, 1.0, 0.5])
    rejected = 0
    for damping in (1.0, 1e-6):
        solver = optx.LevenbergMarquardt(rtol=1e-6, atol=1e-8, norm=optx.rms_norm)
        state = solver.init(fn, y0, None, {}, jax.eval_shape(lambda: fn(y0, None)[0]), None,
                            frozenset())
        state = eqx.tree_at(lambda st: st.search_state.step_size, state,
                            jnp.asarray(1.0 / damping))
        ours = LevenbergMarquardtSteps(y0, step_size=1.0 / damping, rtol=1e-6, atol=1e-8)
        y = y0
        for _ in range(60):
            value, jac = fn(ours.y_eval, None)[0], jax.jacfwd(lambda v: fn(v, None)[0])(
                ours.y_eval)
            rejected += not ours.step(np.asarray(value), np.asarray(jac))
            y, state, _ = solver.step(fn, y, None, {}, state, frozenset())
            assert int(state.num_accepted_steps) == ours.accepted
            np.testing.assert_allclose(ours.y_eval, np.asarray(state.y_eval), rtol=1e-10,
                                       atol=1e-13)
            np.testing.assert_allclose(ours.y, np.asarray(y), rtol=1e-10, atol=1e-13)
            assert ours.terminate == bool(state.terminate)
            if ours.terminate:
                break
        assert ours.terminate
    assert rejected > 0  # the trust region's rejections took part


def test_a_trial_step_off_the_scale_gives_infinite_values_without_warnings():
    """A solver's trial θ in the hundreds (a direction the data barely see) maps to
    infinite or NaN values, silently: the trial's cost is then not finite and the
    solver rejects it (the numpy transforms once printed overflow warnings in the
    middle of a diagnosis)."""
    import warnings

    act = ss.lu2015_slc1720()
    pmap = ParameterMap.make(act, ["Mp", "pi_weights"])
    theta = np.full(pmap.size, 800.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        values = pmap.physical(theta)
        jac = pmap.value_jacobian(theta)
        pmap.actuator(theta, xp=np)
    assert np.isinf(values["Mp"]) and not np.all(np.isfinite(values["pi_weights"]))
    assert not np.all(np.isfinite(jac))
    # Within the scale nothing changed: θ = 0 is the start.
    np.testing.assert_allclose(pmap.physical(np.zeros(pmap.size))["Mp"], act.piezo.Mp)
    # A finite residual too large to square: the trial's cost is infinite, rejected,
    # silently (the solver's value-first test once printed "overflow in square").
    from stickslip_jax.identify.solve import solve_least_squares

    def value(th):  # steep, and off the scale past |θ| = 1
        th = float(np.asarray(th)[0])
        return np.full(3, 1e200) if abs(th) > 1.0 else np.full(3, 40.0 * (th - 0.5))

    def jacobian(th):  # 10x too flat: the first steps overshoot past |θ| = 1
        return value(th), np.full((3, 1), 4.0)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = solve_least_squares(value, np.zeros(1), max_steps=6, initial_damping=1e-12,
                                  scale_by_jacobian=False, value=value, jacobian=jacobian)
    assert out.values > out.jacobians  # points were tried and rejected


def test_a_rejected_point_costs_a_value_not_a_jacobian():
    """Given a value-only function, the solver evaluates a tried point's residual
    first and its Jacobian only once the point is accepted: the same steps, decisions
    and optimum as evaluating both at every point, and one Jacobian per accepted
    point."""
    from stickslip_jax.identify.solve import solve_least_squares

    t = np.linspace(0.0, 1.0, 200)
    y = 2.0 * np.exp(-1.3 * t) + 0.01 * np.random.default_rng(0).standard_normal(200)

    @jax.jit
    def residuals(th):
        return th[0] * jnp.exp(-th[1] * t) - y

    calls = {"jacobian": 0, "value": 0}
    jac_of = jax.jit(jax.jacfwd(residuals))

    def jacobian(th):
        calls["jacobian"] += 1
        th = jnp.asarray(th)
        return np.asarray(residuals(th)), np.asarray(jac_of(th))

    def value(th):
        calls["value"] += 1
        return np.asarray(residuals(jnp.asarray(th)))

    # Nearly undamped steps from far away: the first ones overshoot and are rejected.
    kw = {"initial_damping": 1e-9, "gn_tol": 1e-4, "max_steps": 60}
    both = solve_least_squares(residuals, jnp.array([0.2, 6.0]), jacobian=jacobian, **kw)
    n_both = calls["jacobian"]
    calls.update(jacobian=0, value=0)
    lazy = solve_least_squares(residuals, jnp.array([0.2, 6.0]), jacobian=jacobian,
                               value=value, **kw)
    assert both.converged and lazy.converged
    assert lazy.iterations == both.iterations
    np.testing.assert_allclose(lazy.theta, both.theta, rtol=1e-12)
    assert lazy.cost_end == pytest.approx(both.cost_end, rel=1e-12)
    # Every point tried got a value; only the accepted ones (and the start) a Jacobian.
    assert n_both == both.iterations + 1
    assert calls["value"] == lazy.iterations + 1
    rejected = n_both - calls["jacobian"]
    assert rejected >= 2, (n_both, calls)
    # The result counts them (what a diagnosis's budget charges).
    assert (both.jacobians, both.values) == (n_both, 0)
    assert (lazy.jacobians, lazy.values) == (calls["jacobian"], calls["value"])
    print(f"{lazy.iterations} steps, {rejected} rejected: {n_both} Jacobians -> "
          f"{calls['jacobian']}")

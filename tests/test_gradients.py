"""Derivatives of the simulator with respect to the physical parameters.

Parameters are perturbed multiplicatively, p = p0·(1 + δ), so every Jacobian column
is p·∂q/∂p [m] and one relative finite-difference step (δ = 1e-6, central) suits all
of them. The trace: default profile, 22 V forward sawtooth at 200 Hz, 12 ms (300
samples). It sticks at the samples (max |z| = 0.39 µm there) but the flyback strains
the contact a little past z_ba = 0.40 µm between samples, so α's smooth sine ramp
is active and q depends smoothly on z_ba; |z| stays below |z_ss| = 0.60 µm, so the
saturation never switches. Measured: jacfwd vs central differences agree to
5e-9 - 5e-8 (relative, norm over the trace) for every parameter; reverse-mode grad
of a mean-square loss vs forward mode to 1e-14 and vs central differences to ≤ 2e-7.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss

DT = 4e-5
NAMES = ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0", "z_ba")
FD_STEP = 1e-6


def _where(a):
    return (a.piezo.Mp, a.piezo.Dp, a.piezo.Kp, a.slider.Ms, a.slider.Ds, a.friction.rho0,
            a.friction.z_ba_forward)


@pytest.fixture(scope="module")
def setup():
    base = ss.lu2015_slc1720()
    p0 = jnp.stack(_where(base))
    w0 = base.hysteresis.weights
    u = jnp.asarray(ss.sawtooth(22.0, 200.0, duration_s=0.012)[1])
    u_scan = jnp.asarray(ss.sawtooth(15.0, 200.0, duration_s=0.012)[1])

    def actuator(delta, delta_w):
        a = eqx.tree_at(_where, base, tuple(p0 * (1.0 + delta)))
        return eqx.tree_at(lambda a: a.hysteresis.weights, a, w0 * (1.0 + delta_w))

    # One plan for every call: traced (jacfwd) and concrete (differences) calls then
    # take the same steps (a traced call cannot plan from the parameter values).
    plan = ss.plan_steps(base, DT)

    def q_of(delta, delta_w=None, voltage=u):
        if delta_w is None:
            delta_w = jnp.zeros_like(w0)
        return ss.simulate(actuator(delta, delta_w), voltage, dt=DT, stepping=plan)

    zero = jnp.zeros(len(NAMES))
    jac = np.asarray(jax.jacfwd(q_of)(zero))
    return {"q_of": q_of, "zero": zero, "w0": w0, "jac": jac, "u": u, "u_scan": u_scan,
            "plan": plan}


def _central(fun, n, i, h=FD_STEP):
    e = np.zeros(n)
    e[i] = h
    return (np.asarray(fun(jnp.asarray(e))) - np.asarray(fun(jnp.asarray(-e)))) / (2 * h)


def test_jacfwd_matches_central_differences(setup):
    q_of, jac = setup["q_of"], setup["jac"]
    assert jac.shape == (300, len(NAMES))
    for i, name in enumerate(NAMES):
        fd = _central(q_of, len(NAMES), i)
        err = np.linalg.norm(fd - jac[:, i]) / np.linalg.norm(jac[:, i])
        assert err < 1e-6, (name, err)
        # Every column matters: p·∂q/∂p is 0.3-1.8 µm (norm over 300 samples).
        assert np.linalg.norm(jac[:, i]) > 1e-7, name


def test_jacfwd_wrt_pi_weights(setup):
    q_of, w0 = setup["q_of"], setup["w0"]
    zero = setup["zero"]
    n = w0.shape[0]
    jac_w = np.asarray(jax.jacfwd(lambda dw: q_of(zero, dw))(jnp.zeros(n)))
    assert jac_w.shape == (300, n)
    # Open plays (thresholds 0, 2.5, 8.8, 19.9 V). The last carries a weight 50× below
    # the linear play's, so rounding in the difference quotient weighs more: measured
    # errors 2e-9, 1e-7, 4e-7, 1.9e-6.
    for i, tol in ((0, 1e-6), (3, 1e-6), (8, 1e-6), (15, 1e-5)):
        fd = _central(lambda dw: q_of(zero, dw), n, i)
        err = np.linalg.norm(fd - jac_w[:, i]) / np.linalg.norm(jac_w[:, i])
        assert err < tol, (i, err)
    # The linear play dominates the stroke (20 of 25 nm/V).
    norms = np.linalg.norm(jac_w, axis=0)
    assert norms.argmax() == 0
    # Plays with thresholds above the 22 V drive never open: exactly no influence.
    closed = np.asarray(ss.lu2015_slc1720().hysteresis.thresholds) >= 22.0
    assert closed.any() and np.all(norms[closed] == 0.0)
    assert np.all(norms[~closed] > 0.0)


def test_jvp_equals_jacfwd_column(setup):
    q_of, jac, zero = setup["q_of"], setup["jac"], setup["zero"]
    v = jnp.asarray(np.random.default_rng(0).normal(size=len(NAMES)))
    _, tangent = jax.jvp(q_of, (zero,), (v,))
    np.testing.assert_allclose(tangent, jac @ np.asarray(v), rtol=1e-10,
                               atol=1e-12 * np.abs(tangent).max())
    e3 = jnp.zeros(len(NAMES)).at[3].set(1.0)
    _, col = jax.jvp(q_of, (zero,), (e3,))
    np.testing.assert_allclose(col, jac[:, 3], rtol=1e-12, atol=1e-25)


def test_reverse_mode_gradient(setup):
    q_of, jac, zero = setup["q_of"], setup["jac"], setup["zero"]
    target = np.asarray(q_of(jnp.full(len(NAMES), 0.01)))   # a 1 % different actuator

    def loss(delta):
        return jnp.mean((q_of(delta) - target) ** 2) / 1e-18   # [nm²]

    g = np.asarray(jax.grad(loss)(zero))
    residual = np.asarray(q_of(zero)) - target
    g_fwd = 2 * residual @ jac / residual.size / 1e-18
    np.testing.assert_allclose(g, g_fwd, rtol=1e-9)
    for i, name in enumerate(NAMES):
        fd = float(_central(loss, len(NAMES), i))
        assert fd == pytest.approx(g[i], rel=1e-5), (name, fd, g[i])   # ≤ 2e-7
    assert np.all(np.abs(g) > 1e-6 * np.abs(g).max())


def _perturbed(delta):
    """The default profile with the NAMES scaled by ``1 + delta``."""
    base = ss.lu2015_slc1720()
    return eqx.tree_at(_where, base, tuple(jnp.stack(_where(base)) * (1.0 + delta)))


def _perturbed_q(setup, delta, voltage, adjoint):
    return ss.simulate(_perturbed(delta), voltage, dt=DT, adjoint=adjoint,
                       stepping=setup["plan"])


def _loss(setup, target, delta, voltage, adjoint):
    return jnp.mean((_perturbed_q(setup, delta, voltage, adjoint) - target) ** 2) / 1e-18


def _batch_q(setup, delta, adjoint):
    """Both drives of the setup in one batched simulation, (2, 300)."""
    return ss.simulate_batch(_perturbed(delta), jnp.stack([setup["u"], setup["u_scan"]]),
                             dt=DT, adjoint=adjoint, stepping=setup["plan"])


def _batch_loss(setup, delta, adjoint):
    return jnp.sum(_batch_q(setup, delta, adjoint) ** 2) / 1e-12


@pytest.fixture(scope="module")
def forward_mode(setup):
    """The reference derivatives, from plain forward mode (``CheckpointedScan()``, no
    rule of ours): the loss's gradient over the parameters (from the setup's Jacobian),
    over the voltage (a Jacobian over its 300 samples) and the batched loss's over the
    parameters. Plain reverse mode is what the fallback below runs (compiling reverse
    mode through the simulator's loops takes ~70 s a program with native loops)."""
    target = np.asarray(setup["q_of"](jnp.full(len(NAMES), 0.01)))
    zero, u, plain = setup["zero"], setup["u"], ss.CheckpointedScan()
    # d/dx mean((q − target)²)/1e-18 = 2·(q − target)·∂q/∂x / n / 1e-18
    r = np.asarray(_perturbed_q(setup, zero, u, plain)) - target
    jac_u = np.asarray(jax.jacfwd(lambda v: _perturbed_q(setup, zero, v, plain))(u))
    grad = {0: 2 * r @ setup["jac"] / r.size / 1e-18, 1: 2 * r @ jac_u / r.size / 1e-18}
    grad[(0, 1)] = (grad[0], grad[1])
    jac_b = np.asarray(jax.jacfwd(lambda d: _batch_q(setup, d, plain))(zero))  # (2, 300, 7)
    qs = np.asarray(_batch_q(setup, zero, plain))
    batch = 2 * np.einsum("bt,btk->k", qs, jac_b) / 1e-12
    return {"target": target, "grad": grad, "batch": batch, "jac_u": jac_u, "jac_b": jac_b}


@pytest.mark.parametrize("max_directions", [64, 2])
def test_forward_sensitivities_give_the_same_derivatives(setup, forward_mode, max_directions):
    """ForwardSensitivities (the default adjoint) changes how a derivative is computed,
    not its value: gradients, jacfwd and the batched simulation all equal plain forward
    mode's. With max_directions=64 the seven parameters take the rule: the gradient
    over them, and over them and the voltage at once (the voltage's part, reverse mode
    through the simulator, is the one program here that compiles for over a minute).
    With max_directions=2 they take the fallback, plain JAX derivatives: reverse mode
    over both at once, and forward mode (jacfwd) unbatched and batched. A tangent in
    the voltage alone (no parameter perturbed: the fallback whatever the limit) is
    checked as a JVP; its transpose is the same reverse-mode program as the
    fallback's. Reverse mode through the batched fallback is JAX's own vmap of the
    checked rule, and would cost another such compile, so it is not repeated."""
    adjoint = ss.ForwardSensitivities(max_directions=max_directions)
    target, zero, u = forward_mode["target"], setup["zero"], setup["u"]
    rule = max_directions >= len(NAMES)
    for argnums in ((0, (0, 1)) if rule else ((0, 1),)):
        ref = forward_mode["grad"][argnums]
        got = jax.grad(lambda d, v: _loss(setup, target, d, v, adjoint), argnums)(zero, u)
        for r, g in zip(jax.tree.leaves(ref), jax.tree.leaves(got), strict=True):
            np.testing.assert_allclose(g, r, rtol=1e-9, atol=1e-12 * np.abs(r).max())
            assert np.abs(r).max() > 0
    jac = jax.jacfwd(lambda d: _perturbed_q(setup, d, u, adjoint))(zero)
    np.testing.assert_allclose(jac, setup["jac"], rtol=1e-9, atol=1e-12 * np.abs(jac).max())
    if rule:
        np.testing.assert_allclose(jax.grad(lambda d: _batch_loss(setup, d, adjoint))(zero),
                                   forward_mode["batch"], rtol=1e-9)
        w = jnp.asarray(np.random.default_rng(1).normal(size=u.shape))
        _, t_q = jax.jvp(lambda v: _perturbed_q(setup, zero, v, adjoint), (u,), (w,))
        ref = forward_mode["jac_u"] @ np.asarray(w)
        np.testing.assert_allclose(t_q, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    else:
        jac_b = jax.jacfwd(lambda d: _batch_q(setup, d, adjoint))(zero)
        np.testing.assert_allclose(jac_b, forward_mode["jac_b"], rtol=1e-9,
                                   atol=1e-12 * np.abs(jac_b).max())


def test_zba_has_no_influence_in_pure_stick(setup):
    # A 15 V scan never strains the contact past z_ba: the gradient says, exactly,
    # that such a recording cannot identify z_ba (and nothing is NaN).
    q_of, zero = setup["q_of"], setup["zero"]
    jac = np.asarray(jax.jacfwd(lambda d: q_of(d, voltage=setup["u_scan"]))(zero))
    assert np.all(np.isfinite(jac))
    assert np.all(jac[:, NAMES.index("z_ba")] == 0.0)
    assert np.all(np.linalg.norm(jac[:, :6], axis=0) > 1e-8)
    fd = _central(lambda d: q_of(d, voltage=setup["u_scan"]), len(NAMES), NAMES.index("z_ba"))
    assert np.all(fd == 0.0)


def test_vmap_over_parameter_sets_equals_loop(setup):
    q_of = setup["q_of"]
    deltas = jnp.asarray([[0.0] * 7,
                          [0.05, -0.1, 0.02, 0.0, 0.1, -0.05, 0.1],
                          [-0.02, 0.2, -0.05, 0.1, -0.1, 0.1, -0.1]])
    batched = np.asarray(jax.vmap(q_of)(deltas))
    looped = np.stack([np.asarray(q_of(d)) for d in deltas])
    np.testing.assert_allclose(batched, looped, rtol=1e-12, atol=1e-22)
    # The sets really differ (not a broadcast of one trace).
    assert np.abs(looped[1] - looped[0]).max() > 1e-9
    assert np.abs(looped[2] - looped[1]).max() > 1e-9


def test_with_forward_jacobian_changes_how_not_what():
    """Every derivative of the wrapped function equals plain JAX's (JVP, gradient,
    reverse and forward Jacobians, a Hessian), for a pytree in and out."""
    def fn(x):
        a, b = x["a"], x["b"]
        return {"s": jnp.sin(a) * b[0] + b[1] ** 3, "v": jnp.exp(a) * b}

    x = {"a": jnp.asarray(0.3), "b": jnp.asarray([1.5, -0.7])}
    wrapped = ss.with_forward_jacobian(fn)
    t = {"a": jnp.asarray(0.2), "b": jnp.asarray([-1.0, 0.5])}
    pairs = [(jax.jvp(fn, (x,), (t,)), jax.jvp(wrapped, (x,), (t,))),
             (jax.jacrev(fn)(x), jax.jacrev(wrapped)(x)),
             (jax.jacfwd(fn)(x), jax.jacfwd(wrapped)(x)),
             (jax.hessian(lambda y: fn(y)["s"])(x), jax.hessian(lambda y: wrapped(y)["s"])(x))]
    for plain, ours in pairs:
        for p, o in zip(jax.tree.leaves(plain), jax.tree.leaves(ours), strict=True):
            np.testing.assert_allclose(o, p, rtol=1e-13, atol=1e-15)
    assert float(jax.grad(lambda y: wrapped(y)["s"])(x)["b"][1]) == pytest.approx(3 * 0.49)


def test_a_waveform_gradient_from_forward_mode_equals_plain_forward_mode():
    """The voltage keeps reverse mode in the simulator's rule; a drive built from a few
    knots can take its gradient from forward mode instead: the same numbers."""
    plan = ss.plan_steps(ss.lu2015_slc1720(), DT)

    def step(theta):
        one = jnp.interp(jnp.arange(25) / 25, jnp.linspace(0, 1, 3),
                         jnp.concatenate([jnp.zeros(1), 60.0 * jax.nn.sigmoid(theta)]))
        q = ss.simulate(ss.lu2015_slc1720(), jnp.tile(one, 4), dt=DT, stepping=plan)
        return (q[-1] - q[-26]) / 1e-9

    theta = jnp.asarray([0.5, 1.0])
    wrapped = ss.with_forward_jacobian(step)
    # How: plain reverse mode runs loops backwards (scans with reverse=True); ours none.
    assert "reverse=True" in str(jax.make_jaxpr(jax.grad(step))(theta))
    assert "reverse=True" not in str(jax.make_jaxpr(jax.grad(wrapped))(theta))
    ours = np.asarray(jax.jit(jax.grad(wrapped))(theta))
    plain = np.asarray(jax.jit(jax.jacfwd(step))(theta))
    np.testing.assert_allclose(ours, plain, rtol=1e-12)
    assert np.all(np.abs(plain) > 1e-3)   # both knots move the step [nm per unit θ]

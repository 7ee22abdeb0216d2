"""Model extensions of the diagnosis catalogue: zero settings, known responses."""

from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose import CATALOGUE, NAMES
from stickslip_jax.diagnose.scores import install_probes, probe_batches
from stickslip_jax.model.extensions import (
    ChainedOutput,
    Creep,
    ExponentialDrift,
    LowPassInput,
    RateDependentStroke,
    RateLagForm,
    SensorOutput,
    StructuralMode,
    delayed,
)
from stickslip_jax.synthetic import DriveSpec

REQUIRED = ("creep", "stribeck", "viscous_friction", "contact_damping",
            "rate_dependent_hysteresis", "drive_bandwidth", "structural_mode", "sensor_delay",
            "sensor_drift", "external_load", "preload_dependence")


def test_catalogue_has_the_required_names():
    assert set(REQUIRED) <= set(NAMES)
    slots = {c.name: c.slot for c in CATALOGUE}
    assert slots["drive_bandwidth"] == "input_stage"
    assert slots["sensor_delay"] == slots["sensor_drift"] == "output_map"
    assert slots["creep"] == slots["structural_mode"] == "extension"


@pytest.fixture(scope="module")
def saw():
    rec = DriveSpec("sawtooth", 40.0, 500.0, "forward", 0.008).recording()
    return rec, jnp.asarray(rec.voltage_V)


def test_probe_batches_split_the_catalogue_in_order_into_the_fewest_even_batches():
    """The score test's programs: every entry once, in order, never split; as few
    batches as the limit allows, the largest as small as an entry-wise cut makes it."""
    base = ss.lu2015_slc1720()
    hints = {"peaks_Hz": [2500.0], "max_slew_V_s": 1.5e6}

    def quantities(cands):
        return len({e.name for e in install_probes(base, cands, hints)[1]})

    sizes = [quantities([c]) for c in CATALOGUE]
    total = sum(sizes)
    assert total > 6  # the default splits the catalogue
    for most in (total, 6, 4, 3):
        batches = probe_batches(base, CATALOGUE, hints, most)
        assert [c.name for b in batches for c in b] == [c.name for c in CATALOGUE]
        assert len(batches) == -(-total // most)
        if len(batches) == 2:  # no other two-way cut has a smaller largest batch
            largest = max(quantities(b) for b in batches)
            assert all(largest <= max(sum(sizes[:c]), sum(sizes[c:]))
                       for c in range(1, len(sizes)))
    assert probe_batches(base, CATALOGUE, hints, total) == [list(CATALOGUE)]
    assert probe_batches(base, CATALOGUE[:1], hints, 1) == [list(CATALOGUE[:1])]
    assert probe_batches(base, [], hints) == [[]]


def test_every_probe_at_zero_strength_is_the_baseline(saw):
    """All probes installed at once (the score test's actuator) leave q unchanged."""
    rec, u = saw
    base = ss.lu2015_slc1720()
    probe_act, entries = install_probes(base, CATALOGUE, {"peaks_Hz": [2500.0],
                                                           "max_slew_V_s": 1.5e6})
    assert len(entries) >= 16
    assert sum("drive" in e.probe.label for e in entries) == 2  # both drive forms
    assert probe_act.n_states > base.n_states
    # One plan for both (the probes' own modes would otherwise set another step).
    plan = ss.plan_steps(probe_act, rec.dt)
    q0 = ss.simulate(base, u, dt=rec.dt, stepping=plan)
    q1 = ss.simulate(probe_act, u, dt=rec.dt, stepping=plan)
    assert float(jnp.max(jnp.abs(q1 - q0))) < 1e-15
    # ...and each strength moves it.
    for e in entries:
        value = jnp.asarray(e.spec.getter(probe_act))
        step = 20 * e.spec.scale
        moved = eqx.tree_at(e.spec.getter, probe_act,
                            value.at[e.index].add(step) if value.ndim else value + step)
        dq = ss.simulate(moved, u, dt=rec.dt, stepping=plan) - q0
        assert float(jnp.max(jnp.abs(dq))) > 1e-10, e.probe.label
        if e.probe.extension is not None:
            # The strength addressed is this probe's own (in a bank: its element).
            alone = base.with_extension(eqx.tree_at(e.probe.strength_getter(),
                                                    e.probe.extension,
                                                    jnp.asarray(step)))
            dq_alone = ss.simulate(alone, u, dt=rec.dt, stepping=plan) - q0
            np.testing.assert_allclose(dq, dq_alone, rtol=0,
                                       atol=1e-9 * float(jnp.max(jnp.abs(dq))))


@pytest.mark.parametrize("cls", [Creep, RateDependentStroke])
def test_a_bank_is_its_members_side_by_side(saw, cls):
    """A bank of first-order extensions (the score test's form of several time
    constants) gives the trace of its members as separate extensions, and at zero gain
    the same derivative along each member's gain."""
    rec, u = saw
    base = ss.lu2015_slc1720()
    taus, gains = (0.1e-3, 2e-3), (3e-10, -2e-10)
    plan = ss.plan_steps(base, rec.dt)
    apart = base.with_extension(cls(gains[0], taus[0])).with_extension(cls(gains[1], taus[1]))
    bank = base.with_extension(cls.bank([cls(g, t) for g, t in zip(gains, taus, strict=True)]))
    assert bank.n_states == apart.n_states == base.n_states + 2
    q_apart = np.asarray(ss.simulate(apart, u, dt=rec.dt, stepping=plan))
    q_bank = np.asarray(ss.simulate(bank, u, dt=rec.dt, stepping=plan))
    assert np.max(np.abs(q_apart - ss.simulate(base, u, dt=rec.dt, stepping=plan))) > 1e-9
    np.testing.assert_allclose(q_bank, q_apart, rtol=0, atol=1e-12 * np.ptp(q_apart))

    def along(act, getter, direction):
        return jax.jvp(lambda g: ss.simulate(eqx.tree_at(getter, act, g), u, dt=rec.dt,
                                             stepping=plan), (getter(act),), (direction,))[1]

    zero_bank = eqx.tree_at(lambda a: a.extensions[0].gain, bank, jnp.zeros(2))
    for j in range(2):
        zero_apart = eqx.tree_at(lambda a: (a.extensions[0].gain, a.extensions[1].gain),
                                 apart, (jnp.asarray(0.0), jnp.asarray(0.0)))
        d_apart = along(zero_apart, lambda a, j=j: a.extensions[j].gain, jnp.asarray(1e-9))
        d_bank = along(zero_bank, lambda a: a.extensions[0].gain,
                       jnp.zeros(2).at[j].set(1e-9))
        assert np.max(np.abs(d_apart)) > 1e-9
        np.testing.assert_allclose(d_bank, d_apart, rtol=0,
                                   atol=1e-10 * float(np.max(np.abs(d_apart))))
    with pytest.raises(ValueError, match="one length"):
        cls(jnp.zeros(2), jnp.ones(3))


def test_delay_interpolates_between_samples():
    t = jnp.arange(10) * 1e-3
    q = jnp.arange(10.0) ** 2
    out = delayed(t, q, 2.5e-3)
    # q(t - 2.5 ms) by linear interpolation: mean of q[k-2] and q[k-3].
    np.testing.assert_allclose(out[5:], 0.5 * (q[3:8] + q[2:7]))
    assert float(out[0]) == 0.0
    np.testing.assert_allclose(SensorOutput(0.0, 2e-6)(t, q), q + 2e-6 * t)
    chained = ChainedOutput((SensorOutput(1e-3), ExponentialDrift(1.0, 1e-3)))
    np.testing.assert_allclose(chained(t, q)[3], q[2] + 1 - np.exp(-3.0))


def test_creep_settles_to_its_gain_with_its_time_constant():
    """A 40 V step: the creep stroke approaches gain·40 V as 1 − exp(−t/τ)."""
    base = ss.lu2015_slc1720()
    rec = DriveSpec("step", 40.0, duration_s=0.03).recording()
    u = jnp.asarray(rec.voltage_V)
    gain, tau = 5e-10, 4e-3
    q0 = np.asarray(ss.simulate(base, u, dt=rec.dt))
    q1 = np.asarray(ss.simulate(base.with_extension(Creep(gain, tau)), u, dt=rec.dt))
    k_step = int(np.argmax(np.asarray(u) > 1.0))
    t = rec.time_s[k_step:] - rec.time_s[k_step]
    d = q1[k_step:] - q0[k_step:]
    # While the slider sticks it is carried with the tip, so q = x1 + x2 moves by
    # twice a slow stroke change (less the small compliance of the contact).
    static = d[-1] / (gain * 40.0 * (1 - np.exp(-t[-1] / tau)))
    assert 1.9 < static < 2.02
    expected = static * gain * 40.0 * (1 - np.exp(-t / tau))
    late = t > 2e-3  # after the ringing of the step
    assert np.max(np.abs(d[late] - expected[late])) < 0.02 * static * gain * 40.0


def test_low_pass_input_follows_a_step_exponentially(saw):
    """The stage alone: a 0 → 10 V command step reaches the piezo as 10·(1 − e^(−t/τ))
    (RK4 on the stage's own rate); the mix blends it with the command."""
    tau = 20e-6
    stage = LowPassInput(tau, mix=1.0)
    h, s = 1e-7, stage.initial_state(0.0)
    for _ in range(400):  # 40 µs = 2 τ
        k1 = stage.rate(s, 10.0)
        k2 = stage.rate(s + 0.5 * h * k1, 10.0)
        k3 = stage.rate(s + 0.5 * h * k2, 10.0)
        k4 = stage.rate(s + h * k3, 10.0)
        s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(float(stage.voltage(s, 10.0)), 10 * (1 - np.exp(-2.0)),
                               rtol=1e-9)
    half = LowPassInput(tau, mix=0.5)
    np.testing.assert_allclose(float(half.voltage(s, 10.0)), 5 + 5 * (1 - np.exp(-2.0)),
                               rtol=1e-9)
    # In the simulator: a 20 µs amplifier changes a stepping trace by well over the noise.
    rec, u = saw
    base = ss.lu2015_slc1720()
    act = eqx.tree_at(lambda a: a.input_stage, base, LowPassInput(tau))
    assert not act.stroke_follows_command
    dq = np.asarray(ss.simulate(act, u, dt=rec.dt) - ss.simulate(base, u, dt=rec.dt))
    assert 1e-8 < np.max(np.abs(dq)) < 1e-6


def test_slew_limited_stages_and_parallel_inputs(saw):
    """The hard-limited amplifier (the concealed set's drive) follows a slow change with
    lag τ and a fast one at exactly S; the tanh form is close to it; stages side by
    side at mix 0 are the pass-through, and at mix 1 each adds its own departure."""
    slew, tau = 1.2e6, 8e-6
    hard, soft = ss.ClippedSlewInput(slew, tau), ss.SlewLimitedInput(slew, tau)
    s = hard.initial_state(0.0)
    # A 60 V jump: the hard stage moves at S until the gap is S·τ = 9.6 V.
    np.testing.assert_allclose(float(hard.rate(s, 60.0)[0]), slew, rtol=1e-12)
    np.testing.assert_allclose(float(hard.rate(s, 1.0)[0]), 1.0 / tau, rtol=1e-12)
    assert 0.99 * slew < float(soft.rate(s, 60.0)[0]) < slew
    # Small signals: the same first-order response (tanh x ≈ x).
    np.testing.assert_allclose(float(soft.rate(s, 0.1)[0]), 0.1 / tau, rtol=1e-4)
    assert float(hard.voltage(jnp.asarray([3.0]), 10.0)) == 3.0
    assert float(ss.SlewLimitedInput(slew, tau, 0.25).voltage(jnp.asarray([2.0]), 10.0)) == 8.0
    par = ss.ParallelInputs((LowPassInput(20e-6, 0.0), ss.SlewLimitedInput(slew, tau, 0.0)))
    assert par.n_states == 2
    state = par.initial_state(5.0)
    np.testing.assert_allclose(np.asarray(state), [5.0, 5.0])
    assert float(par.voltage(jnp.asarray([1.0, 2.0]), 7.0)) == 7.0
    on = ss.ParallelInputs((LowPassInput(20e-6, 1.0), ss.SlewLimitedInput(slew, tau, 1.0)))
    assert float(on.voltage(jnp.asarray([1.0, 2.0]), 7.0)) == 7.0 + (1.0 - 7.0) + (2.0 - 7.0)
    np.testing.assert_allclose(np.asarray(on.rate(jnp.asarray([1.0, 7.0]), 7.0)),
                               [6.0 / 20e-6, 0.0], rtol=1e-12)
    # In the simulator: the hard-limited drive slows the 500 Hz edges measurably.
    rec, u = saw
    base = ss.lu2015_slc1720()
    act = eqx.tree_at(lambda a: a.input_stage, base, hard)
    dq = np.asarray(ss.simulate(act, u, dt=rec.dt) - ss.simulate(base, u, dt=rec.dt))
    assert 1e-9 < np.max(np.abs(dq)) < 1e-5


def test_periodic_sensor_error_is_a_sine_of_the_position():
    from stickslip_jax.model.extensions import PeriodicSensorError

    q = jnp.linspace(0.0, 1e-6, 101)
    out = np.asarray(PeriodicSensorError(2.5e-9)(jnp.zeros(101), q))
    # A quarter period (79.1 nm) in, the error peaks at its amplitude.
    err = out - np.asarray(q)
    np.testing.assert_allclose(np.max(np.abs(err)), 2.5e-9, rtol=2e-3)
    np.testing.assert_allclose(err[0], 0.0, atol=1e-22)
    i = int(np.argmin(np.abs(np.asarray(q) - 316.4e-9 / 4)))
    assert err[i] > 0.99 * 2.5e-9


def test_every_independent_variant_changes_the_trace(saw):
    """Each variant of the concealed effects is a real change of the simulated output
    (above the 1 nm noise somewhere in a 500 Hz stepping trace or its step response)."""
    from stickslip_jax.testing.concealed import VARIANTS, with_variant

    rec, u = saw
    base = ss.load_params(Path(__file__).resolve().parent.parent / "fixtures" / "identification"
                          / "truth.json")
    step = DriveSpec("step", 40.0, duration_s=0.01).recording()
    ref = [ss.simulate_recording(base, r) for r in (rec, step)]
    for name in VARIANTS:
        act = with_variant(base, name)
        diff = max(float(np.max(np.abs(ss.simulate_recording(act, r) - q)))
                   for r, q in zip((rec, step), ref, strict=True))
        assert diff > 2e-9, (name, diff)
    with pytest.raises(ValueError, match="unknown variant"):
        with_variant(base, "magic")


def test_a_learned_feature_switched_off_adds_no_force_and_keeps_the_structure(saw):
    """``LearnedForce.active`` switches features off as data: the sparse refit's
    actuator has the full fit's structure (the same compiled programs), and a feature
    switched off contributes nothing however large its coefficient."""
    import jax

    from stickslip_jax.model.extensions import LEARNED_FEATURES, LearnedForce

    rec, u = saw
    base = ss.lu2015_slc1720()
    scales = (1e-5, 1e-3, 1e-3, 1e-4, 100.0, 1e-7)
    n = len(LEARNED_FEATURES)
    coef = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1e-3])  # the compression term alone
    on = base.with_extension(LearnedForce(coef, scales))
    off = base.with_extension(LearnedForce(coef, scales, active=np.r_[np.ones(n - 1), 0.0]))
    assert jax.tree.structure(on) == jax.tree.structure(off)
    plan = ss.plan_steps(on, rec.dt)
    q0 = ss.simulate(base, u, dt=rec.dt, stepping=plan)
    q_on = ss.simulate(on, u, dt=rec.dt, stepping=plan)
    q_off = ss.simulate(off, u, dt=rec.dt, stepping=plan)
    assert float(jnp.max(jnp.abs(q_on - q0))) > 1e-9  # the feature moves the slider
    assert float(jnp.max(jnp.abs(q_off - q0))) < 1e-15


def test_a_mode_excited_by_the_stack_is_the_independent_reaction_mode(saw):
    """The structural mode's second excitation (the stack's push on its base) against
    the test generator's own base mode (stickslip_jax/testing/effects.py, written from
    the stack's forces Kp·(Γ − x1) − Dp·ẋ1 apart from the model's core)."""
    from stickslip_jax.testing.effects import ReactionMode

    rec, u = saw
    base = ss.lu2015_slc1720()
    ours = base.with_extension(StructuralMode(4000.0, 0.03, 0.0, 5e-8))
    theirs = base.with_extension(ReactionMode(4000.0, 0.03, 5e-8, base.piezo.Kp,
                                              base.piezo.Dp))
    q0 = np.asarray(ss.simulate(base, u, dt=rec.dt))
    q1 = np.asarray(ss.simulate(ours, u, dt=rec.dt))
    q2 = np.asarray(ss.simulate(theirs, u, dt=rec.dt))
    assert np.ptp(q1 - q0) > 1e-9  # the base rings by nanometres
    np.testing.assert_allclose(q1, q2, rtol=0, atol=1e-13)
    # The two excitations add: contact and stack together are the sum of each alone.
    both = base.with_extension(StructuralMode(4000.0, 0.03, 2e-8, 5e-8))
    contact = base.with_extension(StructuralMode(4000.0, 0.03, 2e-8))
    q3 = np.asarray(ss.simulate(both, u, dt=rec.dt))
    q4 = np.asarray(ss.simulate(contact, u, dt=rec.dt))
    np.testing.assert_allclose(q3 - q0, (q1 - q0) + (q4 - q0), rtol=0, atol=1e-12)


def test_the_rate_lag_class_holds_the_first_order_and_the_saturating_lag(saw):
    """RateLagForm: its linear term alone is the first-order RateDependentStroke; one
    saturating term alone is the test generator's independent SaturatingRateStroke
    (stickslip_jax/testing/effects.py)."""
    from stickslip_jax.testing.effects import SaturatingRateStroke

    rec, u = saw
    base = ss.lu2015_slc1720()
    w = float(base.hysteresis.weights[0])

    def q(ext):
        return np.asarray(ss.simulate(base.with_extension(ext), u, dt=rec.dt))

    first = q(RateDependentStroke(0.05 * w, 0.2e-3))
    np.testing.assert_allclose(q(RateLagForm(0.05 * w, 0.2e-3, (0.0, 0.0), (1.0, 3.0))), first,
                               rtol=0, atol=1e-15)
    saturating = q(SaturatingRateStroke(0.05 * w, 0.2e-3, 3.0))
    np.testing.assert_allclose(q(RateLagForm(0.0, 0.2e-3, (0.0, 0.05 * w), (1.0, 3.0))),
                               saturating, rtol=0, atol=1e-15)
    assert np.max(np.abs(saturating - first)) > 1e-9  # the two forms differ by nanometres
    with pytest.raises(ValueError, match="one saturating gain per voltage"):
        RateLagForm(0.0, 1e-4, (0.0,), (1.0, 3.0))

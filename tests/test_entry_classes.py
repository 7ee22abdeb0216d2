"""Sensor drift and the structural mode as classes (stickslip_jax/diagnose/catalogue/
sensor_drift.py, structural_mode.py): what they fit and what the report says of it."""

import equinox as eqx
import jax.numpy as jnp
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.catalogue import candidate
from stickslip_jax.diagnose.catalogue.sensor_drift import (
    FASTEST_SHARE,
    GRID_RATIO,
    SLOWEST_MULTIPLE,
    amplitude_name,
    settle_times,
)
from stickslip_jax.model.extensions import SensorOutput

matplotlib.use("Agg")
PROTOCOL = (0.02, 0.1)  # the paper protocol's shortest and longest recording [s]


def test_the_drift_is_linear_plus_settling_terms():
    t = jnp.linspace(0.0, 0.1, 101)
    out = SensorOutput(delay=0.0, drift=2e-7, settling=(3e-9, -1e-9), settle_times=(0.01, 0.05))
    want = 2e-7 * t + 3e-9 * (1 - jnp.exp(-t / 0.01)) - 1e-9 * (1 - jnp.exp(-t / 0.05))
    np.testing.assert_allclose(out(t, jnp.zeros_like(t)), want, rtol=0, atol=1e-22)
    # No settling terms: the linear drift of before.
    np.testing.assert_allclose(SensorOutput(drift=2e-7)(t, t), t + 2e-7 * t, atol=1e-22)
    with pytest.raises(ValueError, match="one settling amplitude per time constant"):
        SensorOutput(settling=(1e-9,), settle_times=(0.01, 0.02))


def test_the_grid_spans_the_recordings_and_is_fine_enough_for_any_settling_between():
    times = np.asarray(settle_times(PROTOCOL))
    assert times[0] == pytest.approx(FASTEST_SHARE * PROTOCOL[0])
    assert times[-1] == pytest.approx(SLOWEST_MULTIPLE * PROTOCOL[1])
    assert np.all(times[1:] / times[:-1] <= GRID_RATIO * (1 + 1e-12))
    # A settling of 50 nm whose time constant falls between two grid points is matched by
    # the class's terms (linear drift and grid) to well under the noise (0.5-2 nm).
    t = np.linspace(0.0, PROTOCOL[1], 1001)
    basis = np.column_stack([t] + [1 - np.exp(-t / tau) for tau in times])
    for tau in np.sqrt(times[1:] * times[:-1]):
        target = 50e-9 * (1 - np.exp(-t / tau))
        fit = basis @ np.linalg.lstsq(basis, target, rcond=None)[0]
        assert np.max(np.abs(fit - target)) < 0.05e-9, tau
    # One linear term alone misses most of them by nanometres: the terms are needed.
    tau = float(np.sqrt(times[1] * times[2]))
    target = 50e-9 * (1 - np.exp(-t / tau))
    line = np.column_stack([t, np.ones_like(t)])
    miss = line @ np.linalg.lstsq(line, target, rcond=None)[0] - target
    assert np.max(np.abs(miss)) > 5e-9


def test_the_entry_frees_the_linear_drift_and_every_settling_amplitude():
    entry = candidate("sensor_drift")
    act = eqx.tree_at(lambda a: a.output_map, ss.lu2015_slc1720(), SensorOutput(delay=3e-6))
    probe = entry.probes(act, {"recording_durations_s": PROTOCOL})[0]
    attached, specs = entry.attach(act, 4e-7, probe)
    times = settle_times(PROTOCOL)
    out = attached.output_map
    assert float(out.delay) == 3e-6  # a delay already named is kept
    assert float(out.drift) == 4e-7
    assert len(out.settling) == len(times) and all(float(a) == 0.0 for a in out.settling)
    assert list(specs) == ["sensor_drift"] + [amplitude_name(t) for t in times]
    # Each amplitude's getter addresses its own term.
    for i, t in enumerate(times):
        assert specs[amplitude_name(t)].getter(attached) is out.settling[i]
    # Without the recordings' durations, the linear drift alone (as before the class).
    bare = entry.attach(act, 4e-7, entry.probes(act, {})[0])[1]
    assert list(bare) == ["sensor_drift"]


def test_the_report_says_and_draws_the_drift_found():
    entry = candidate("sensor_drift")
    times = settle_times(PROTOCOL)
    params = {"sensor_drift": 1e-7} | {amplitude_name(t): 0.0 for t in times}
    params[amplitude_name(times[2])] = 20e-9
    said = entry.describe(params)
    assert "linear 0.1 nm/ms" in said and f"+20 nm at {times[2] * 1e3:.3g} ms" in said
    end = 1e-7 * 0.1 + 20e-9 * (1 - np.exp(-0.1 / times[2]))
    assert f"{end * 1e9:.3g} nm at the end of the longest recording" in said
    fig, ax = plt.subplots()
    assert entry.plot_form(ax, params)
    drawn = ax.lines[0].get_ydata()
    assert drawn[-1] == pytest.approx(end * 1e9, rel=1e-3)
    plt.close(fig)


def test_the_structural_mode_says_and_draws_both_excitations():
    entry = candidate("structural_mode")
    params = {"mode_frequency": 5500.0, "mode_damping": 0.02, "mode_compliance": 1e-8,
              "mode_stack_compliance": -5e-8}
    said = entry.describe(params)
    assert "5500 Hz" in said and "contact force (10 nm/N)" in said and "(-50 nm/N)" in said
    fig, ax = plt.subplots()
    assert entry.plot_form(ax, params)
    contact, stack = (line.get_ydata() for line in ax.lines)
    f = ax.lines[0].get_xdata()
    # Static well below the mode; near it the static response over 2ζ.
    assert contact[0] == pytest.approx(10.0, rel=0.02)
    assert np.max(stack) == pytest.approx(50.0 / (2 * 0.02), rel=0.05)
    assert f[np.argmax(stack)] == pytest.approx(5500.0, rel=0.01)
    np.testing.assert_allclose(stack / contact, 5.0)
    plt.close(fig)


def test_the_rate_lag_entry_frees_the_form_and_says_the_lag_found():
    from stickslip_jax.diagnose.catalogue.rate_dependent_hysteresis import SAT_VOLTS, sat_name
    from stickslip_jax.model.extensions import RateLagForm

    entry = candidate("rate_dependent_hysteresis")
    act = ss.lu2015_slc1720()
    probe = entry.probes(act, {})[2]
    attached, specs = entry.attach(act, 2e-9, probe)
    form = attached.extensions[-1]
    assert isinstance(form, RateLagForm) and float(form.tau) == probe.setting["tau"]
    assert list(specs) == ["rate_gain", "rate_tau"] + [sat_name(v) for v in SAT_VOLTS]
    assert all(specs[sat_name(v)].kind == "nonneg" for v in SAT_VOLTS)
    # A lag saturating at 3 V: 2 nm/V·3 V·tanh(d/3 V).
    params = {"rate_gain": 0.0, "rate_tau": 2e-4} | {sat_name(v): 0.0 for v in SAT_VOLTS}
    params[sat_name(3.0)] = 2e-9
    said = entry.describe(params)
    assert "saturating 2 nm/V to 3 V" in said
    assert f"{2 * 3 * np.tanh(10 / 3):.3g} nm at 10 V" in said
    fig, ax = plt.subplots()
    assert entry.plot_form(ax, params)
    assert ax.lines[0].get_ydata()[-1] == pytest.approx(6.0, rel=1e-3)  # 6 nm at 40 V
    plt.close(fig)


def test_a_fitted_mode_offers_a_bank_with_one_more_at_a_residual_peak_away_from_it():
    from stickslip_jax.diagnose.catalogue.structural_mode import MAX_MODES
    from stickslip_jax.model.extensions import StructuralMode
    from stickslip_jax.synthetic import DriveSpec

    entry = candidate("structural_mode")
    base = ss.lu2015_slc1720()
    one = base.with_extension(StructuralMode(3000.0, 0.04, 2e-8, -1e-8))
    # The peak a sixth of an octave from the fitted mode is its own misfit; the next one.
    [(start, specs)] = entry.refined_forms(one, {"peaks_Hz": [3400.0, 7100.0, 1200.0]})
    modes = [e for e in start.extensions if isinstance(e, StructuralMode)]
    assert [float(m.frequency) for m in modes] == [3000.0, 7100.0]
    assert float(modes[1].compliance) == 0.0 == float(modes[1].stack_compliance)
    assert list(specs) == [f"{p}{k}" for p in ("mode_", "mode2_")
                           for k in ("frequency", "damping", "compliance", "stack_compliance")]
    assert float(specs["mode2_frequency"].getter(start)) == 7100.0
    assert float(specs["mode_compliance"].getter(start)) == 2e-8
    assert specs["mode2_compliance"].scale == 2e-8
    # The start is the fitted model: the new mode at zero compliance adds nothing.
    rec = DriveSpec("sawtooth", 40.0, frequency_Hz=500.0, direction="forward",
                    duration_s=0.006).recording()
    u = jnp.asarray(rec.voltage_V)
    np.testing.assert_allclose(ss.simulate(start, u, dt=rec.dt), ss.simulate(one, u, dt=rec.dt),
                               rtol=0, atol=1e-11)
    # No peak far enough, no mode fitted, or the bank full: nothing to offer.
    assert entry.refined_forms(one, {"peaks_Hz": [2700.0]}) == []
    assert entry.refined_forms(base, {"peaks_Hz": [7100.0]}) == []
    full = one
    for f in (6000.0, 12000.0)[:MAX_MODES - 1]:
        full = full.with_extension(StructuralMode(f, 0.03, 1e-8))
    assert entry.refined_forms(full, {"peaks_Hz": [1000.0]}) == []


def test_a_bank_of_modes_is_said_drawn_and_judged_mode_by_mode():
    entry = candidate("structural_mode")
    params = {"mode_frequency": 3000.0, "mode_damping": 0.03, "mode_compliance": 2e-8,
              "mode_stack_compliance": 0.0, "mode2_frequency": 7100.0, "mode2_damping": 0.05,
              "mode2_compliance": 0.0, "mode2_stack_compliance": 4e-8}
    said = entry.describe(params)
    assert said.startswith("2 structural modes") and "3000 Hz" in said and "7100 Hz" in said
    assert "(40 nm/N)" in said
    assert entry.implausible(params) == ""
    assert "mode 2" in entry.implausible({**params, "mode2_damping": 0.5})
    fig, ax = plt.subplots()
    assert entry.plot_form(ax, params)
    assert len(ax.lines) == 2  # one excitation each
    assert "7100 Hz" in ax.get_title()
    plt.close(fig)


def test_a_weak_slew_share_is_offered_a_start_with_its_lag_scaled_too():
    """The drive entry's slew limit starts at the probe's small-signal lag τ0 (attach)
    and, as a second option the sizing weighs by cost, at the share of it the probe
    measured (not below the refit's floor); a low-pass, or a whole share, has one."""
    act = ss.lu2015_slc1720()
    entry = candidate("drive_bandwidth")
    probes = entry.probes(act, {"max_slew_V_s": 1.5e6, "sample_interval_s": 40e-6})
    low_pass, slew = probes
    assert slew.setting["form"] == "slew" and slew.setting["tau"] == 5e-6
    first, second = entry.attach_options(act, 0.2, slew)
    assert float(first[0].input_stage.tau) == 5e-6
    assert float(second[0].input_stage.tau) == pytest.approx(1e-6, rel=1e-15)
    assert float(second[0].input_stage.slew) == float(first[0].input_stage.slew)
    assert second[1]["drive_tau"].floor == pytest.approx(0.4e-6)
    # A share whose τ would fall below the floor starts at the floor.
    _, weak = entry.attach_options(act, 0.005, slew)
    assert float(weak[0].input_stage.tau) == pytest.approx(0.4e-6, rel=1e-12)
    assert len(entry.attach_options(act, 1.5, slew)) == 1
    assert len(entry.attach_options(act, 0.2, low_pass)) == 1
    # Other entries offer their attach alone.
    stribeck = candidate("stribeck")
    [only] = stribeck.attach_options(act, 0.3, stribeck.probes(act, {})[0])
    assert float(only[0].friction.stribeck_ratio) == pytest.approx(1.3)

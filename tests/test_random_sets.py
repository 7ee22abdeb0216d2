"""The random-set generator of the frozen test split (issue #27): deterministic draws,
stated ranges, forms per entry, the null share, and effect sizes. No diagnosis runs
here; the simulations use a five-recording protocol and a coarse stepping."""

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest

from stickslip_jax.diagnose import NAMES
from stickslip_jax.model.base import DriveContext
from stickslip_jax.model.friction import StribeckElastoPlastic
from stickslip_jax.stepping import Stepping
from stickslip_jax.synthetic import paper_protocol
from stickslip_jax.testing import random_sets as rs
from stickslip_jax.testing.effects import SensorLowPass, VariantElastoPlastic
from stickslip_jax.testing.truth import PI_GRIDS, TRUTH_RANGES, identification_truth

CANNOT_SHOW = {"preload_dependence"}  # one preload in the protocol
SEEDS = (rs.DEV_SEED, rs.TEST_SEED, 7, 123456789)


def short_protocol():
    """Five short recordings (step, sine, scan, 60 V 500 Hz both ways): 90 ms."""
    return paper_protocol(periods=1, amplitudes=(60.0,), frequencies=(500.0,),
                          step_duration_s=0.01, sine_periods=1)


COARSE = Stepping(radians_per_step=2.0, refine=1)
"""Four times the default step, nothing refined: an effect size only needs to be > 0."""


def test_draws_are_deterministic():
    for i in (0, 1, 5, 23, 40):
        assert rs.draw_set(rs.DEV_SEED, i) == rs.draw_set(rs.DEV_SEED, i)
    assert rs.draw_split(rs.DEV_SEED, 6) == [rs.draw_set(rs.DEV_SEED, i) for i in range(6)]
    dev, other = rs.draw_split(rs.DEV_SEED, 12), rs.draw_split(rs.DEV_SEED + 1, 12)
    assert [s.truth for s in dev] != [s.truth for s in other]
    assert len({s.recording_seed for s in dev}) == len(dev)


def test_ranges_hold():
    central = identification_truth()
    for seed in (rs.DEV_SEED, 11):
        for spec in rs.draw_split(seed, 150):
            lo, hi = rs.NOISE_RANGE_M
            assert lo <= spec.noise_m <= hi
            for k, (flo, fhi) in TRUTH_RANGES.items():
                assert flo <= spec.truth_factors[k] <= fhi, k
            for k in ("Mp", "Dp", "Kp", "Ds", "rho0", "z_ba_forward", "z_ba_backward"):
                assert spec.truth[k] == pytest.approx(central[k] * spec.truth_factors[k])
            for k in ("Ms", "zba_ratio", "pi_thresholds", "F_ext", "k_load"):
                assert spec.truth[k] == central[k], k
            w = spec.truth["pi_weights"]
            assert w[0] == pytest.approx(1.9e-8 * spec.truth_factors["pi_linear"])
            assert sum(w[1:]) == pytest.approx(0.6e-8 * spec.truth_factors["pi_tail"])
            f = rs.form(spec.effect, spec.form)
            assert spec.catalogue_form == f.catalogue
            if spec.effect == "none":
                assert spec.strength == 0.0 and spec.others == {}
                continue
            assert f.low <= abs(spec.strength) <= f.high
            assert f.signed or spec.strength > 0
            assert spec.others.keys() == f.others.keys()
            for k, (olo, ohi) in f.others.items():
                assert olo <= spec.others[k] <= ohi, (spec.form, k)


def test_every_entry_has_two_forms_at_most_one_the_catalogues():
    showable = [n for n in NAMES if n not in CANNOT_SHOW]
    assert set(rs.CLASSES) == {*showable, "uncatalogued"}
    for entry in rs.EFFECTS:
        forms = rs.forms_of(entry)
        assert len(forms) >= 2, entry
        assert sum(f.catalogue for f in forms) <= 1, entry
        assert len({f.name for f in forms}) == len(forms)
        for f in forms:
            assert 0 < f.low < f.high
    assert not any(f.catalogue for f in rs.forms_of("uncatalogued"))


@pytest.mark.parametrize("seed", SEEDS)
def test_a_third_of_every_split_is_null(seed):
    specs = rs.draw_split(seed, 24)
    effects = [s.effect for s in specs]
    assert effects.count("none") >= 8
    for b in range(8):  # one null in every block of three
        assert effects[3 * b:3 * b + 3].count("none") == 1
    # 33 sets hold 22 non-null ones: every effect before any repeats.
    non_null = [e for e in (s.effect for s in rs.draw_split(seed, 33)) if e != "none"]
    assert set(non_null[:len(rs.EFFECTS)]) == set(rs.EFFECTS)


def test_null_effect_size_is_zero():
    spec = next(s for s in rs.draw_split(rs.DEV_SEED, 3) if s.effect == "none")
    size = rs.effect_size(spec, short_protocol(), stepping=COARSE)
    assert size == {"rms_m": 0.0, "to_noise": 0.0, "rms_raw_m": 0.0}
    assert rs.effect_size(spec, beyond_baseline=True)["beyond_baseline_m"] == 0.0


def test_every_form_has_a_positive_effect():
    """Each form at the middle of its range, on the short protocol (about 30 s)."""
    drives = short_protocol()
    for f in rs.FORMS:
        spec = rs.fixed_set(f.entry, f.name, math.sqrt(f.low * f.high))
        size = rs.effect_size(spec, drives, stepping=COARSE)
        assert np.isfinite(size["rms_m"]) and size["rms_m"] > 1e-12, (f.entry, f.name)
        assert size["to_noise"] == pytest.approx(size["rms_m"] / 1e-9)


def test_recordings_follow_the_spec():
    spec = rs.draw_set(rs.DEV_SEED, 1)
    drives = short_protocol()
    a = rs.make_recordings(spec, drives, stepping=COARSE)
    b = rs.make_recordings(spec, drives, stepping=COARSE)
    assert [r.name for r in a] == [d.name for d in drives]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.position_m, y.position_m)


def test_sensor_low_pass_is_exact_on_a_ramp():
    """τ·ẏ = q − y from y(0) = 0 on q = c·t: y = c·(t − τ·(1 − exp(−t/τ)))."""
    tau, c = 30e-6, 1e-3
    t = jnp.arange(200) * 40e-6
    y = np.asarray(SensorLowPass(tau)(t, c * t))
    expected = c * (np.asarray(t) - tau * (1 - np.exp(-np.asarray(t) / tau)))
    np.testing.assert_allclose(y, expected, rtol=1e-10, atol=1e-18)


def test_lorentzian_variant_is_the_catalogues_law():
    base = StribeckElastoPlastic(3.2e5, 0.42e-6, 0.48e-6, stribeck_ratio=1.6, v_s=2e-3)
    variant = VariantElastoPlastic.like(base, stribeck_ratio=1.6, v_s=2e-3)
    drive = DriveContext.make(backward=1.0)
    for v in (0.0, 1e-4, 2e-3, -5e-2):
        assert float(variant.zss_magnitude(v, drive)) == pytest.approx(
            float(base.zss_magnitude(v, drive)), rel=1e-14)


def test_version_one_draws_are_pinned():
    """Version 2 added streams of its own: the splits already run (dev, the frozen
    test split) draw exactly what they drew before it."""
    dev = rs.split_sets("dev", 4)
    assert [(s.effect, s.form) for s in dev] == [
        ("none", "null"), ("creep", "one_mode"), ("stribeck", "gaussian"), ("none", "null")]
    assert [round(s.noise_m * 1e12) for s in dev] == [1709, 1072, 1300, 851]
    first = rs.split_sets("test", 1)[0]
    assert (first.effect, first.form) == ("sensor_delay", "low_pass")
    assert first.strength == pytest.approx(1.3715547822568913e-06, rel=1e-12)
    assert first.noise_m == pytest.approx(5.710057278830976e-10, rel=1e-12)
    assert all(s.also == () and s.version == 1 for s in dev)
    assert dev[1].truth["pi_thresholds"] == identification_truth()["pi_thresholds"]


@pytest.mark.parametrize("name", ["dev2", "test2"])
def test_version_two_holds_48_sets_a_null_per_block_drawn_grids_and_compounds(name):
    from stickslip_jax.params import actuator_from_params

    sets = rs.split_sets(name)
    seed, design = rs.SPLITS[name]
    assert len(sets) == 48 and design.version == 2
    for b in range(12):  # one null in every block of four
        assert sum(s.effect == "none" for s in sets[4 * b: 4 * b + 4]) == 1
    fit_grid = identification_truth()["pi_thresholds"]
    kinds = set()
    for s in sets:
        t = s.truth
        kinds.add(s.truth_factors["pi_grid"])
        assert t["pi_thresholds"] != fit_grid
        assert len(t["pi_thresholds"]) == len(t["pi_weights"]) == s.truth_factors["pi_operators"]
        assert t["pi_thresholds"][0] == 0.0 and np.all(np.diff(t["pi_thresholds"]) > 0)
        # The stroke per volt stays that of the truth's own law: the weights' sum.
        assert sum(t["pi_weights"]) == pytest.approx(
            1.9e-8 * s.truth_factors["pi_linear"] + 0.6e-8 * s.truth_factors["pi_tail"])
        actuator_from_params(t)  # a valid model
    assert kinds == set(PI_GRIDS)
    compound = [s for s in sets if s.also]
    assert 4 <= len(compound) <= 6
    for s in compound:
        first, second = s.hidden
        assert rs.PLACES[first] != rs.PLACES[second]
    assert rs.split_sets(name, 5) == sets[:5]  # deterministic


def test_a_compound_set_hides_both_effects():
    spec = next(s for s in rs.split_sets("dev2") if s.also)
    drives = short_protocol()
    both = rs.effect_size(spec, drives, stepping=COARSE)["rms_m"]
    first = rs.effect_size(dataclasses.replace(spec, also=()), drives,
                           stepping=COARSE)["rms_m"]
    second = rs.effect_size(dataclasses.replace(
        spec, effect=spec.also[0]["effect"], form=spec.also[0]["form"],
        strength=spec.also[0]["strength"], others=spec.also[0]["others"], also=()),
        drives, stepping=COARSE)["rms_m"]
    assert first > 0 and second > 0
    assert both != pytest.approx(first, rel=1e-3) and both != pytest.approx(second, rel=1e-3)

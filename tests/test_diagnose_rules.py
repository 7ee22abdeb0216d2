"""The diagnosis's refit and sizing rules, on the numbers of full concealed-set runs.

(Whole diagnoses are in test_diagnose.py; these rules decide where their time goes.)
"""

import inspect

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.diagnose.catalogue import (
    CATALOGUE,
    NAMES,
    PROBE_TAU_DRIVE,
    Candidate,
    CatalogueEntry,
    candidate,
)
from stickslip_jax.diagnose.policy import (
    COMPETITIVE_SHARE,
    LATER_SCORE_SHARE,
    LEADER_ALONE_LEAD,
    LEADER_ALONE_SHARE,
    SECOND_LOOK_CHI2,
    Policy,
)
from stickslip_jax.diagnose.problem import ProjectedResiduals
from stickslip_jax.diagnose.records import Acceptance, RefitOutcome, SizingOutcome, amended
from stickslip_jax.diagnose.results import CandidateResult, CandidateStatus
from stickslip_jax.diagnose.rules import (
    fallback_refits,
    far_from_noise,
    first_refits,
    identification_bent,
    rank_value,
    reidentify_order,
    second_look,
    size_before_polish,
    why_not_refitted,
)
from stickslip_jax.diagnose.sizing import chosen_for_sizing, worth_sizing_after_acceptance
from stickslip_jax.identify.solve import solve_least_squares


def _ranked(*values):
    return [CandidateResult(name, score=score, sizing=SizingOutcome(drop=drop))
            for name, score, drop in values]


# The cases below are generated around the policy's thresholds (whitened RSS over
# N = 24 000 samples, a baseline at BASE): what each rule must do just inside and
# just outside them, not numbers recorded from a fixture set.
N, BASE = 24_000.0, 1.0e6
EXCESS = BASE - N


def test_only_competitive_entries_are_refitted_beside_the_leader():
    lead = 3.0e5
    ranked = _ranked(("drive_bandwidth", 0.2 * lead, lead),
                     ("rate_dependent_hysteresis", 0.1 * lead, (COMPETITIVE_SHARE - 0.1) * lead),
                     ("structural_mode", 0.02 * lead, (COMPETITIVE_SHARE - 0.14) * lead))
    assert [r.name for r in first_refits(ranked, top=3)] == ["drive_bandwidth"]
    # One within the share is refitted; ``top`` still caps the count.
    ranked[2].sizing = amended(ranked[2].sizing, drop=COMPETITIVE_SHARE * lead + 1.0)
    assert [r.name for r in first_refits(ranked, top=3)] == ["drive_bandwidth",
                                                             "structural_mode"]
    assert [r.name for r in first_refits(ranked, top=2)] == ["drive_bandwidth"]
    # The score counts as well as the sizing drop.
    ranked[1].score = (COMPETITIVE_SHARE + 0.05) * lead
    assert [r.name for r in first_refits(ranked, top=2)] == [
        "drive_bandwidth", "rate_dependent_hysteresis"]
    assert first_refits([], top=3) == []
    # Wrong first-order sign and a sizing that raised the cost: no refit first.
    assert first_refits(_ranked(("sensor_delay", -1e3, -2e3)), top=3) == []


def test_below_the_leader_a_sizing_converged_above_the_baseline_waits_for_the_fallback():
    ranked = _ranked(("creep", 0.8 * BASE, 0.7 * BASE),
                     ("rate_dependent_hysteresis", 0.4 * BASE, 0.35 * BASE),
                     ("drive_bandwidth", 0.3 * BASE, -3.0 * BASE))
    # Stopped at its step cap above the baseline (a seed far off): its rank value
    # (its score here) judges it, as it does the others.
    assert [r.name for r in first_refits(ranked, top=3)] == [
        "creep", "rate_dependent_hysteresis", "drive_bandwidth"]
    assert "converged above" not in why_not_refitted(ranked[2], ranked, 3)
    # Converged there: an optimum worse than no entry contradicts the score.
    ranked[2].sizing = amended(ranked[2].sizing, converged=True)
    assert [r.name for r in first_refits(ranked, top=3)] == ["creep",
                                                             "rate_dependent_hysteresis"]
    # The leader is refitted whatever its sizing did.
    assert [r.name for r in first_refits(ranked[2:], top=3)] == ["drive_bandwidth"]
    # If the first refits explain nothing, the fallback takes it.
    for r in ranked[:2]:
        r.refit = RefitOutcome()
    assert [r.name for r in fallback_refits(ranked)] == ["drive_bandwidth"]


def test_after_an_acceptance_only_entries_scoring_a_share_of_the_excess_are_sized():
    left = 2.0e4  # (e/σ)² still over the noise after the acceptance
    chosen = _ranked(("structural_mode", 0.03 * left, 0.0), ("sensor_delay", -0.05 * left, 0.0),
                     ("stribeck", -0.02 * left, 0.0))
    assert worth_sizing_after_acceptance(chosen, left) == []
    assert all("not sized" in r.note for r in chosen)
    # A second effect scoring like a first one did is sized, whatever its sign.
    big = _ranked(("creep", 0.3 * left, 0.0),
                  ("sensor_delay", -(LATER_SCORE_SHARE + 0.01) * left, 0.0),
                  ("stribeck", (LATER_SCORE_SHARE - 0.01) * left, 0.0))
    kept = worth_sizing_after_acceptance(big, left)
    assert [r.name for r in kept] == ["creep", "sensor_delay"]
    assert big[2].note and not big[0].note
    # Nothing left over the noise: the floor is zero and every entry is kept.
    assert len(worth_sizing_after_acceptance(_ranked(("creep", 1.0, 0.0)), -5.0)) == 1


def test_round_one_sizes_the_top_admissible_scores_and_every_seeded_entry():
    results = _ranked(("creep", 9.0e3, 0.0), ("sensor_delay", -8.0e3, 0.0),
                      ("stribeck", 5.0e3, 0.0), ("structural_mode", 1.0e2, 0.0),
                      ("external_load", -2.0e3, 0.0))
    said = []
    chosen = chosen_for_sizing(results, seeded=set(), size_at_most=2, excess_left=None,
                               say=said.append)
    # Admissible signs first, whatever a wrong sign's |score|: a large wrong-sign score
    # is not sized past the cap (the removed wrong_sign_share rule did that).
    assert [r.name for r in chosen] == ["creep", "stribeck"]
    # A seeded entry past the cap is sized anyway, once.
    chosen = chosen_for_sizing(results, seeded={"external_load", "creep"}, size_at_most=3,
                               excess_left=None, say=said.append)
    assert [r.name for r in chosen] == ["creep", "stribeck", "structural_mode",
                                        "external_load"]
    assert not said


def test_the_fallback_refits_every_other_sized_entry_but_those_pointing_the_wrong_way():
    ranked = _ranked(("sensor_drift", 0.02 * BASE, 0.015 * BASE),
                     ("stribeck", 0.011 * BASE, -0.002 * BASE),
                     ("structural_mode", 0.010 * BASE, 0.012 * BASE),
                     ("rate_dependent_hysteresis", 0.008 * BASE, -0.002 * BASE),
                     ("contact_damping", 0.005 * BASE, 0.002 * BASE),
                     ("drive_bandwidth", -0.001 * BASE, -0.9 * BASE))
    for r in ranked:
        r.refit = RefitOutcome() if r.name in ("sensor_drift", "structural_mode") else None
    again = fallback_refits(ranked)
    # A positive score whose sizing did not lower the cost still gets its refit.
    assert [r.name for r in again] == ["stribeck", "rate_dependent_hysteresis",
                                      "contact_damping"]
    assert "wrong first-order sign" in ranked[-1].note
    # Entries already refitted or set aside with a note are not refitted again.
    assert fallback_refits(ranked) == again
    ranked[1].set_aside(CandidateStatus.REFIT_FAILED, "refit not possible")
    assert [r.name for r in fallback_refits(ranked)] == ["rate_dependent_hysteresis",
                                                         "contact_damping"]


def test_an_entry_without_a_refit_is_told_why():
    lead = 0.7 * BASE
    ranked = _ranked(("creep", 0.8 * BASE, lead),
                     ("drive_bandwidth", (COMPETITIVE_SHARE + 0.1) * lead, -3.0 * BASE),
                     ("external_load", 0.1 * lead, (COMPETITIVE_SHARE - 0.1) * lead),
                     ("sensor_drift", 0.03 * lead, 0.05 * lead),
                     ("stribeck", -0.01 * lead, -1.0))
    ranked[1].sizing = amended(ranked[1].sizing, converged=True)
    assert "sizing converged above the baseline's cost" in why_not_refitted(
        ranked[1], ranked, 3)
    assert f"below {100 * COMPETITIVE_SHARE:.0f} % of the leader" in why_not_refitted(
        ranked[2], ranked, 3)
    ranked[3].score = (COMPETITIVE_SHARE + 0.05) * lead
    assert "below the top 3" in why_not_refitted(ranked[3], ranked, 3)
    assert "wrong first-order sign" in why_not_refitted(ranked[4], ranked, 3)
    assert all("explained the residual" in why_not_refitted(r, ranked, 3)
               for r in ranked[1:4])


def test_a_leader_whose_sizing_reached_the_noise_is_refitted_alone():
    lead = (LEADER_ALONE_SHARE + 0.05) * EXCESS
    ranked = _ranked(("rate_dependent_hysteresis", 0.8 * EXCESS, lead),
                     ("creep", 0.5 * EXCESS, (LEADER_ALONE_LEAD - 0.1) * lead),
                     ("structural_mode", 0.05 * EXCESS, 0.3 * lead))
    assert [r.name for r in first_refits(ranked, top=3)] == [
        "rate_dependent_hysteresis", "creep", "structural_mode"]
    assert [r.name for r in first_refits(ranked, top=3, excess=EXCESS)] == [
        "rate_dependent_hysteresis"]
    note = why_not_refitted(ranked[1], ranked, 3, EXCESS)
    share, other = 100 * lead / EXCESS, 100 * ranked[1].size_drop / EXCESS
    assert (f"sizing alone removed {share:.0f} % of the excess, this entry's "
            f"{other:.0f} %") in note
    # A competitor whose sizing came within LEADER_ALONE_LEAD of the leader's keeps
    # its refit.
    ranked[1].sizing = amended(ranked[1].sizing, drop=LEADER_ALONE_LEAD * ranked[0].size_drop)
    assert [r.name for r in first_refits(ranked, top=3, excess=EXCESS)] == [
        "rate_dependent_hysteresis", "creep", "structural_mode"]
    # A leader short of LEADER_ALONE_SHARE has company.
    ranked[1].sizing = amended(ranked[1].sizing, drop=0.3 * EXCESS)
    ranked[0].sizing = amended(ranked[0].sizing, drop=(LEADER_ALONE_SHARE - 0.01) * EXCESS)
    assert len(first_refits(ranked, top=3, excess=EXCESS)) == 3


def test_the_entries_re_identified_are_the_top_of_the_ranking_that_show_promise():
    # The first-order ranking decides, not the refits from a bent baseline (which can
    # rank a mimic above the right entry).
    ranked = _ranked(("sensor_delay", 0.3 * BASE, 1.5 * BASE),
                     ("stribeck", 0.1 * BASE, -0.1 * BASE),
                     ("sensor_drift", 0.02 * BASE, 0.08 * BASE),
                     ("external_load", 0.025 * BASE, 0.08 * BASE),
                     ("rate_dependent_hysteresis", 0.026 * BASE, 0.02 * BASE),
                     ("drive_bandwidth", -0.05 * BASE, -14.0 * BASE))
    for r, after in zip(ranked[:5], (0.75, 0.4, 0.85, 0.74, 0.73), strict=True):
        r.refit = RefitOutcome(rss_after=after * BASE)
    assert [r.name for r in reidentify_order(ranked, top=3)] == [
        "sensor_delay", "stribeck", "sensor_drift"]
    # Never one whose score and sizing both point the wrong way.
    assert [r.name for r in reidentify_order(ranked[-1:], top=3)] == []


def test_only_a_baseline_the_polish_moved_far_is_re_identified():
    gain = Policy().reidentify_polish_gain
    assert identification_bent(gain * BASE, BASE)
    assert identification_bent(10 * gain * BASE, BASE)
    assert not identification_bent(0.99 * gain * BASE, BASE)
    assert not identification_bent(BASE, BASE)
    assert not identification_bent(float("nan"), 1.0)


def _two_actuators():
    """The default profile and a 'refitted' one: every baseline quantity moved, each
    slot holding an entry."""
    from stickslip_jax.model.extensions import Creep, LowPassInput, SensorOutput

    init = ss.lu2015_slc1720()
    fitted = eqx.tree_at(lambda a: (a.piezo.Mp, a.friction.rho0, a.friction.z_ba_forward,
                                    a.friction.z_ba_backward, a.friction.rho1,
                                    a.slider.F_ext),
                         init, tuple(np.asarray(v) for v in (1e-5, 9e5, 1e-7, 2e-7, 3.0,
                                                             -0.02)))
    fitted = eqx.tree_at(lambda a: (a.output_map, a.input_stage), fitted,
                         (SensorOutput(delay=5e-6), LowPassInput(4e-6, 1.0)))
    return init, fitted.with_extension(Creep(1e-9, 3e-3))


def test_a_re_identification_starts_from_the_start_with_only_the_entry_moved():
    init, fitted = _two_actuators()
    for name, moved in [("sensor_delay", lambda a: a.output_map.delay),
                        ("drive_bandwidth", lambda a: a.input_stage.tau),
                        ("creep", lambda a: a.extensions[-1].tau),
                        ("external_load", lambda a: a.slider.F_ext),
                        ("contact_damping", lambda a: a.friction.rho1)]:
        slot = candidate(name).slot
        start = candidate(name).carry(init, fitted)
        assert float(moved(start)) == float(moved(fitted)), slot
        # The baseline's quantities are the start's, not the refit's.
        assert float(start.piezo.Mp) == float(init.piezo.Mp)
        assert float(start.friction.rho0) == float(init.friction.rho0)
        assert float(start.friction.z_ba_forward) == float(init.friction.z_ba_forward)
        assert float(start.friction.z_ba_backward) == float(init.friction.z_ba_backward)
        # Other slots stay as they were.
        assert (slot == "extension") == (len(start.extensions) == 1)
        assert (slot == "output_map") == (type(start.output_map) is not type(init.output_map))


def test_every_entry_is_a_final_class_of_the_abstract_entry():
    init, fitted = _two_actuators()
    assert inspect.isabstract(CatalogueEntry) and Candidate is CatalogueEntry
    with pytest.raises(TypeError):
        CatalogueEntry()
    assert len({type(c) for c in CATALOGUE}) == len(CATALOGUE) == len(NAMES)
    for cand in CATALOGUE:
        cls = type(cand)
        assert isinstance(cand, CatalogueEntry) and not inspect.isabstract(cls)
        assert getattr(cls, "__final__", False) and not cls.__subclasses__(), cls
        assert cls.slot in ("input_stage", "extension", "friction", "slider", "output_map")
        assert isinstance(cls.signature, str) and cls.signature
        # Each one's carry runs on an actuator holding a component in every slot.
        cand.carry(init, fitted)
    # A concrete entry is never extended.
    with pytest.raises(TypeError, match="final"):
        type("Wider", (type(candidate("creep")),), {})


def test_a_seeded_entry_gets_a_second_look_when_the_explaining_refit_leaves_structure():
    # An explaining refit (90 % of the excess) that leaves (e/σ)² far above the noise,
    # beside a seeded entry sized but never refitted.
    rss = 3 * SECOND_LOOK_CHI2 * N
    rate, mode, amp = _ranked(("rate_dependent_hysteresis", 0.3 * BASE, 0.2 * BASE),
                              ("structural_mode", 0.03 * BASE, 0.1 * BASE),
                              ("drive_bandwidth", -0.02 * BASE, 0.02 * BASE))
    rate.refit = RefitOutcome(rss_after=rss, chi2_after=rss / N, material=True,
                              explained=0.9, criterion_delta=-1.0e5)
    ranked = [rate, mode, amp]
    assert far_from_noise(ranked, N)
    assert [r.name for r in second_look(ranked, {"drive_bandwidth"})] == ["drive_bandwidth"]
    # An explaining refit near the noise leaves nothing to look for.
    rate.refit = amended(rate.refit, chi2_after=SECOND_LOOK_CHI2 - 0.01)
    assert not far_from_noise(ranked, N)
    rate.refit = amended(rate.refit, chi2_after=rss / N)
    # Only refits that would be accepted count (ΔBIC, share explained).
    rate.refit = amended(rate.refit, criterion_delta=5.0)
    assert not far_from_noise(ranked, N)
    rate.refit = amended(rate.refit, criterion_delta=-1.0e5, explained=0.5)
    assert not far_from_noise(ranked, N)
    # A seeded entry already refitted, or pointing the wrong way twice, gets none.
    amp.refit = RefitOutcome()
    assert second_look(ranked, {"drive_bandwidth"}) == []
    amp.refit = None
    amp.sizing = amended(amp.sizing, drop=-1e4)
    assert second_look(ranked, {"drive_bandwidth"}) == []


def test_the_rules_read_their_thresholds_from_the_policy():
    from dataclasses import replace

    from stickslip_jax.diagnose.policy import DEFAULT_POLICY, Policy
    from stickslip_jax.diagnose.report import CRITERION, criterion_text, score_test_text

    # The former module constants are the defaults.
    assert (COMPETITIVE_SHARE, LATER_SCORE_SHARE, SECOND_LOOK_CHI2) == (
        Policy().competitive_share, Policy().later_score_share, Policy().second_look_chi2)
    ranked = _ranked(("drive_bandwidth", 5.61e4, 293_374.0),
                     ("rate_dependent_hysteresis", 2.5e4, 44_180.0))
    assert len(first_refits(ranked, top=3)) == 1
    assert len(first_refits(ranked, top=3, policy=replace(DEFAULT_POLICY,
                                                          competitive_share=0.1))) == 2
    # What diagnosis.json says of the criterion follows the policy it ran under.
    assert criterion_text() == CRITERION and "below -10 " in CRITERION
    strict = Policy(bic_min=-20.0, explained_min=0.9, score_min=50.0)
    assert "below -20 " in criterion_text(strict) and "90 %" in criterion_text(strict)
    assert "≥ 50 " in score_test_text(strict)


def test_verdicts_and_statuses_keep_their_strings():
    import json

    from stickslip_jax.diagnose.results import SET_ASIDE, Verdict

    assert [str(v) for v in Verdict] == ["augmented", "baseline adequate",
                                         "unexplained residual", "partly explained"]
    assert json.dumps({"verdict": Verdict.UNEXPLAINED}) == '{"verdict": "unexplained residual"}'
    r = CandidateResult("creep")
    assert r.waiting and r.status is CandidateStatus.SCORED
    r.set_aside(CandidateStatus.SKIPPED, "skipped: its 1 sample-evaluations would pass")
    assert not r.waiting and r.status in SET_ASIDE


def _significance():
    """The tolerance of N samples in four recordings, noise estimates 1 % uncertain."""
    from stickslip_jax.significance import Significance

    return Significance(np.full(4, N / 4), np.full(4, 1e-9), np.full(4, 0.01),
                        np.zeros(4), 3.0)


def test_the_baseline_before_its_polish_is_sized_only_when_the_polish_moved_it():
    """A polish that removed more than the tolerance (the noise estimate's uncertainty
    and the numerical floor) leaves two baselines the data tell apart: both are sized;
    one that removed less, or nothing (an identification that already minimised the
    whitened residual), leaves one: sized once. A cost that is not finite: once."""
    sig = _significance()
    rss = 1.3 * N
    moved = rss + 2 * sig.tolerance * N
    assert size_before_polish(moved, rss, sig)
    assert not size_before_polish(rss + 0.5 * sig.tolerance * N, rss, sig)
    assert not size_before_polish(rss, rss, sig)
    assert not size_before_polish(float("nan"), rss, sig)


def _refitted(name, explained, *, delta=-1e3, material=True, predicts=True, adequate=False):
    r = CandidateResult(name, refit=RefitOutcome(
        explained=explained, criterion_delta=delta, material=material, predicts=predicts,
        adequate=adequate))
    return r


def test_an_entry_is_named_only_when_every_test_holds():
    from stickslip_jax.diagnose.rules import acceptable, acceptable_partly

    assert acceptable(_refitted("creep", 0.9))
    # Statistically strong but immaterial (within the noise estimate's tolerance), or
    # predicting the regimes left out worse than the baseline: not named.
    assert not acceptable(_refitted("creep", 0.9, material=False))
    assert not acceptable(_refitted("creep", 0.9, predicts=False))
    assert not acceptable(_refitted("creep", 0.9, delta=-5.0))
    # A residual left at the noise level explains whatever the share.
    assert acceptable(_refitted("creep", 0.3, adequate=True))
    # Between the partial and the full share: a partial answer only.
    partly = _refitted("creep", 0.6)
    assert not acceptable(partly) and acceptable_partly(partly)
    assert not acceptable_partly(_refitted("creep", 0.4))
    assert not acceptable_partly(_refitted("creep", 0.6, material=False))


def test_a_mode_too_damped_to_ring_is_no_resonance_and_never_named():
    from stickslip_jax.diagnose.catalogue.structural_mode import MODE_DAMPING_MAX
    from stickslip_jax.diagnose.rules import acceptable, acceptable_partly, explains
    from stickslip_jax.diagnose.run import _accept

    mode = candidate("structural_mode")
    # The ringing decays by e in 1/(2π ζ) cycles: at most one cycle is no ringing.
    assert MODE_DAMPING_MAX == pytest.approx(1 / (2 * np.pi))
    ringing = {"mode_frequency": 3300.0, "mode_damping": 0.1, "mode_compliance": 2e-8}
    assert mode.implausible(ringing) == ""
    damped = {**ringing, "mode_frequency": 575.0, "mode_damping": 0.44}
    assert "no ringing" in mode.implausible(damped)
    # Other entries call any value plausible.
    assert candidate("creep").implausible({"creep_gain": 1e-9, "creep_tau": 1e-3}) == ""
    r = _refitted("structural_mode", 0.8)
    r.implausible = mode.implausible(damped)
    assert not explains(r) and not acceptable(r) and not acceptable_partly(r)
    r.refit = amended(r.refit, adequate=True)  # even at the noise level
    assert not explains(r)
    # The next refit that explains is named instead; alone, nothing is.
    other = _refitted("contact_damping", 0.76, delta=-500.0)
    best = _accept([r, other], Policy(), _significance(), lambda _: None)
    assert best is other and best.indistinguishable_from == ()
    assert _accept([r], Policy(), _significance(), lambda _: None) is None
    assert "not the physics" in r.note


def test_a_partial_answer_is_kept_when_nothing_explains_and_only_then():
    from stickslip_jax.diagnose.run import _accept

    def say(_):
        return None

    sig = _significance()
    full, partly = _refitted("stribeck", 0.8, delta=-500.0), _refitted("creep", 0.6)
    best = _accept([partly, full], Policy(), sig, say)  # best ΔBIC first: creep
    assert best is full and not best.partial
    partly, wrong = _refitted("creep", 0.6, delta=-900.0), _refitted("external_load", 0.3)
    best = _accept([wrong, partly], Policy(), sig, say)
    assert best is partly and best.partial and best.accepted
    # The decision is one frozen record, made by the acceptance alone.
    assert best.decision == Acceptance(accepted=True, partial=True,
                                       indistinguishable_from=best.indistinguishable_from)
    with pytest.raises(AttributeError):
        best.accepted = False
    assert not wrong.accepted and wrong.decision == Acceptance()
    none = _accept([_refitted("creep", 0.3)], Policy(), sig, say)
    assert none is None


def test_the_verdict_says_augmented_only_within_the_noise_tolerance():
    from stickslip_jax.diagnose.results import Verdict
    from stickslip_jax.diagnose.run import _verdict

    kept = _refitted("creep", 0.6)
    assert _verdict(True, [kept], within=False) is Verdict.PARTLY_EXPLAINED
    assert _verdict(True, [], within=False) is Verdict.UNEXPLAINED
    assert _verdict(False, [kept], within=True) is Verdict.AUGMENTED
    assert _verdict(False, [], within=True) is Verdict.BASELINE_ADEQUATE
    # An entry that removed most of the excess but leaves the residual beyond the
    # tolerance (no structure the fallback would chase) is a partial answer.
    assert _verdict(False, [kept], within=False) is Verdict.PARTLY_EXPLAINED


def test_what_a_partial_answer_leaves_is_said_in_nm_and_by_recording():
    from types import SimpleNamespace

    from stickslip_jax.diagnose.report import _left_markdown
    from stickslip_jax.diagnose.run import _left

    sig = _significance()  # σ = 1 nm everywhere
    chi2_rec = np.array([1.0, 1.0, 1.0, 5.0])  # one recording left with (e/σ)² 5
    analyses = [SimpleNamespace(recording=f"r{i}", chi2=c, flagged=False)
                for i, c in enumerate(chi2_rec)]
    rss = float(np.sum(chi2_rec * N / 4))
    left = _left(sig, rss, chi2_rec, analyses)
    assert left["chi2_per_sample"] == pytest.approx(2.0)
    assert left["recordings_beyond"] == ["r3"]
    # Beyond 1 + τ: √((2 − 1 − τ)) nm RMS over the samples.
    assert left["beyond_tolerance_nm"] == pytest.approx(np.sqrt(1 - sig.tolerance))
    text = "\n".join(_left_markdown(left))
    assert "What is left" in text and "r3" in text and "partial answer" in text


def test_a_sub_microsecond_drive_low_pass_is_attached_at_its_measured_lag():
    # The probe's share of its 20 µs stage's lag maps to τ = share·20 µs, also below
    # 2 µs: the stage advances in closed form apart from the mechanics, so no floor
    # is needed (a 2 µs floor started a 0.67 µs amplifier at 3x its lag).
    act = ss.lu2015_slc1720()
    cand = candidate("drive_bandwidth")
    probe = next(p for p in cand.probes(act, {}) if p.setting["form"] == "low-pass")
    for share in (0.0335, 0.5):
        start, specs = cand.attach(act, share, probe)
        assert float(start.input_stage.tau) == pytest.approx(share * PROBE_TAU_DRIVE)
        assert list(specs) == ["drive_tau"]
    # And a simulation with it is finite and lags a ramp by about τ.
    start, _ = cand.attach(act, 0.0335, probe)
    dt = 2e-5
    u = np.linspace(0.0, 50.0, 100)                   # a 2 ms ramp, 25 V/ms
    q_with = np.asarray(ss.simulate(start, u, dt=dt))
    q_without = np.asarray(ss.simulate(act, u, dt=dt))
    assert np.all(np.isfinite(q_with))
    lag = (q_without[-1] - q_with[-1]) / (np.gradient(q_without, dt)[-1])
    assert lag == pytest.approx(0.0335 * PROBE_TAU_DRIVE, rel=0.1)


def test_an_entry_the_baseline_absorbed_is_ranked_by_its_drop_with_the_baseline_free():
    # Held, the absorbed entry removes a tenth of the leader's drop (below the
    # competitive share); with the baseline free to first order it removes more than the
    # leader: it leads, and the leader still gets its first refit beside it.
    lead = 0.4 * EXCESS
    ranked = _ranked(("sensor_delay", lead, lead),
                     ("drive_bandwidth", 0.03 * lead, 0.1 * lead))
    assert [r.name for r in first_refits(ranked, top=3)] == ["sensor_delay"]
    ranked[0].sizing = amended(ranked[0].sizing, drop_free=1.05 * lead)
    ranked[1].sizing = amended(ranked[1].sizing, drop_free=1.2 * lead)
    ranked.sort(key=lambda r: -rank_value(r))
    assert [r.name for r in first_refits(ranked, top=3)] == ["drive_bandwidth",
                                                             "sensor_delay"]
    # A free drop never lifts an entry whose held sizing converged above the baseline.
    ranked[1].sizing = amended(ranked[1].sizing, drop=-1.0, converged=True)
    assert [r.name for r in first_refits(ranked, top=3)] == ["drive_bandwidth"]


class _Line(eqx.Module):
    """A linear residual ``A θ − y``: the entry's columns of a linear problem."""

    a: np.ndarray
    y: np.ndarray

    def __call__(self, theta, args=None):
        return self.a @ theta - self.y


def test_the_projected_fit_is_the_joint_fit_with_the_baseline_linear():
    # Variable projection: fitting the entry's parameters to the residual less its part
    # in the baseline's span gives the entry's values and the cost of the joint fit of
    # entry and baseline (exact when the baseline enters linearly).
    rng = np.random.default_rng(7)
    n, k_base, k_entry = 400, 6, 2
    j_base = rng.normal(size=(n, k_base))
    a = rng.normal(size=(n, k_entry)) + 0.5 * j_base[:, :k_entry]  # partly mimicked
    y = rng.normal(size=n) + a @ np.array([0.7, -1.3])
    basis, _ = np.linalg.qr(j_base)
    projected = ProjectedResiduals(_Line(a, y), jnp.asarray(basis))
    out = solve_least_squares(projected, np.zeros(k_entry), max_steps=20,
                              gn_tol=1e-6, label="projected")
    joint, *_ = np.linalg.lstsq(np.hstack([a, j_base]), y, rcond=None)
    joint_cost = float(np.sum((np.hstack([a, j_base]) @ joint - y) ** 2))
    np.testing.assert_allclose(out.theta, joint[:k_entry], rtol=1e-5)
    np.testing.assert_allclose(out.cost_end, joint_cost, rtol=1e-8)
    held, *_ = np.linalg.lstsq(a, y, rcond=None)
    assert out.cost_end < float(np.sum((a @ held - y) ** 2)) - 10.0  # not the held fit


def test_a_rival_is_indistinguishable_only_within_the_tolerance_of_the_best():
    # Tolerance τ = 0.08 over N samples: a rival whose refit costs more than τ·N above
    # the best's is told apart, however close its ΔBIC is in share (a strong effect:
    # both remove nearly all of a huge excess).
    from stickslip_jax.diagnose.rules import indistinguishable

    sig = _significance()
    assert sig.tolerance > 0
    tol = sig.tolerance * N
    best = CandidateResult("sensor_delay",
                           refit=RefitOutcome(rss_after=N, criterion_delta=-3.68e6))
    near = CandidateResult("rate_dependent_hysteresis", refit=RefitOutcome(
        rss_after=N + 0.9 * tol, criterion_delta=-3.68e6 + 0.9 * tol))
    far = CandidateResult("drive_bandwidth", refit=RefitOutcome(
        rss_after=N + 5 * tol, criterion_delta=0.97 * -3.68e6))
    assert indistinguishable(near, best, sig)
    assert not indistinguishable(far, best, sig)  # 97 % of the best ΔBIC: told apart
    near.refit = amended(near.refit, criterion_delta=-5.0)  # not accepted-grade: no rival
    assert not indistinguishable(near, best, sig)


def test_a_refits_reach_is_bounded_by_its_converged_sizings_only():
    from stickslip_jax.diagnose.rules import refit_reach

    r = CandidateResult("creep", score=900.0,
                        sizing=SizingOutcome(drop=1000.0, drop_free=1600.0))
    assert refit_reach(r) == np.inf  # the free sizing did not converge: no bound
    r.sizing = amended(r.sizing, free_converged=True)
    assert refit_reach(r) == 2 * 1600.0 - 1000.0  # as much again as the freedom bought
    r.score = 5000.0
    assert refit_reach(r) == 5000.0  # never below the first-order promise


class _Bent(eqx.Module):
    """``y − a·p − (j·b + c·(j·b)²)``: an entry ``p`` entering linearly beside a baseline
    ``b`` that enters with a quadratic bend (``c``): the refit's drop then differs from
    the projected sizing's, which takes the baseline to first order."""

    a: jnp.ndarray
    j: jnp.ndarray
    y: jnp.ndarray
    c: float
    free: tuple  # which of (p, b) are fitted, the other held at ``at``
    at: jnp.ndarray

    def __call__(self, theta, args=None):
        k = self.a.shape[1]
        full = self.at.at[jnp.asarray(self.free)].set(theta)
        p, b = full[:k], full[k:]
        z = self.j @ b
        return self.a @ p + z + self.c * z**2 - self.y


@pytest.mark.parametrize("bend", [0.0, 0.5, 1.0])
def test_the_reach_bounds_the_refits_drop_where_the_baseline_bends(bend):
    # Generated cases: an entry the baseline partly mimics, baselines from linear to
    # clearly bent. The sizing held, the sizing with the baseline free to first order
    # and the joint refit, each to its optimum, from the baseline's own optimum.
    rng = np.random.default_rng(11)
    n, kb, ke = 300, 4, 2
    j = rng.normal(size=(n, kb)) / np.sqrt(n)
    a = (rng.normal(size=(n, ke)) + 0.6 * (j[:, :ke] * np.sqrt(n))) / np.sqrt(n)
    truth_b = np.array([3.0, -2.0, 1.0, 0.5])
    z = j @ truth_b
    y = jnp.asarray(a @ np.array([2.0, -1.5]) + z + bend * z**2
                    + 0.05 * rng.normal(size=n))
    zeros = jnp.zeros(ke + kb)

    def solve(free, at, start):
        model = _Bent(jnp.asarray(a), jnp.asarray(j), y, bend, tuple(free), at)
        out = solve_least_squares(model, jnp.asarray(start), max_steps=200, gn_tol=1e-8,
                                  label="bent")
        return at.at[jnp.asarray(free)].set(out.theta), float(out.cost_end), model

    base_idx, entry_idx = list(range(ke, ke + kb)), list(range(ke))
    at0, cost0, _ = solve(base_idx, zeros, np.zeros(kb))
    _, cost_held, _ = solve(entry_idx, at0, np.zeros(ke))
    _, cost_joint, _ = solve(entry_idx + base_idx, at0, np.asarray(at0))
    # The baseline's Jacobian at its optimum, its span taken out of the entry's fit.
    jb = np.asarray(jnp.asarray(j) * (1 + 2 * bend * (jnp.asarray(j) @ at0[ke:]))[:, None])
    basis, _ = np.linalg.qr(jb)
    model = _Bent(jnp.asarray(a), jnp.asarray(j), y, bend, tuple(entry_idx), at0)
    free = solve_least_squares(ProjectedResiduals(model, jnp.asarray(basis)),
                               jnp.zeros(ke), max_steps=200, gn_tol=1e-8, label="free")
    from stickslip_jax.diagnose.rules import refit_reach

    r = CandidateResult("creep", score=0.0, sizing=SizingOutcome(
        drop=cost0 - cost_held,
        drop_free=max(cost0 - float(free.cost_end), cost0 - cost_held),
        free_converged=bool(free.converged)))
    refit_drop = cost0 - cost_joint
    assert r.size_drop < 0.9 * refit_drop  # the baseline absorbed part of the effect
    assert refit_drop <= refit_reach(r)
    if bend == 0.0:  # a linear baseline: the projected sizing is the refit
        np.testing.assert_allclose(r.size_drop_free, refit_drop, rtol=1e-6)
    else:  # a bent one: the refit removes more than the projected sizing
        assert refit_drop > r.size_drop_free + 1e-3


def test_the_fallback_spends_no_refit_on_an_entry_out_of_reach():
    from stickslip_jax.diagnose.rules import acceptance_reach, refit_reach

    sig = _significance()
    tol = sig.tolerance * N
    assert sig.tolerance_rss == pytest.approx(tol)
    reach = acceptance_reach(EXCESS, sig.tolerance_rss)
    assert reach == pytest.approx(min(0.5 * EXCESS, EXCESS - tol))
    # Little excess left: reaching the tolerance needs less than half of it.
    assert acceptance_reach(1.2 * tol, tol) == pytest.approx(0.2 * tol)
    ranked = _ranked(("sensor_drift", 0.3 * BASE, 0.3 * BASE),
                     ("creep", 0.1 * BASE, 0.2 * BASE),
                     ("stribeck", 0.05 * BASE, 0.01 * BASE),
                     ("external_load", 0.01 * BASE, 0.1 * BASE))
    ranked[0].refit = RefitOutcome()
    for r, free, converged in zip(ranked[1:], (0.24, 0.02, 0.11), (True, False, True),
                                  strict=True):
        r.sizing = amended(r.sizing, drop_free=free * BASE, free_converged=converged)
    assert refit_reach(ranked[1]) < reach  # 0.28 of BASE: cannot reach half the excess
    again = fallback_refits(ranked, reach)
    # The unconverged free sizing bounds nothing: refitted; the others are out of reach.
    assert [r.name for r in again] == ["stribeck"]
    assert ranked[1].status is CandidateStatus.OUT_OF_REACH
    assert ranked[3].status is CandidateStatus.OUT_OF_REACH
    assert "any acceptance needs" in ranked[1].note
    assert not ranked[1].waiting


def test_an_entry_out_of_reach_is_refitted_when_it_could_rival_an_acceptance():
    from stickslip_jax.diagnose.rules import rivals_in_reach

    sig = _significance()
    tol = sig.tolerance * N
    best = _refitted("sensor_drift", 0.6)
    best.refit = amended(best.refit, rss_after=BASE - 0.6 * EXCESS)
    near = CandidateResult("creep", sizing=SizingOutcome(
        drop=0.5 * EXCESS, free_converged=True, drop_free=0.6 * EXCESS - 0.6 * tol))
    far = CandidateResult("stribeck", sizing=SizingOutcome(
        drop=0.1 * EXCESS, free_converged=True, drop_free=0.1 * EXCESS))
    for r in (near, far):
        r.set_aside(CandidateStatus.OUT_OF_REACH, "out of reach")
    # A reach within the tolerance of the accepted-grade drop: it could end
    # indistinguishable from it, so it gets its refit; the far one does not.
    assert rivals_in_reach([best, near, far], BASE, tol, N) == [near]
    best.refit = amended(best.refit, explained=0.3)  # nothing accepted-grade: no rival
    assert rivals_in_reach([best, near, far], BASE, tol, N) == []


def test_a_first_refit_that_cannot_rival_an_acceptance_is_not_spent():
    """Once a refit would be accepted, a competitive entry's refit is spent only where
    its sizings let it reach within the tolerance of that drop (it could end
    indistinguishable) or past it less the ΔBIC penalty of the parameters the accepted
    one has beyond one (it could be preferred); an unconverged free sizing bounds
    nothing, and nothing is pruned before a refit would be accepted."""
    from stickslip_jax.diagnose.rules import cannot_rival, rival_bar

    sig = _significance()
    tol = sig.tolerance * N
    drop = 0.9 * EXCESS
    best = _refitted("drive_bandwidth", 0.9, delta=-drop + 3 * np.log(N))
    best.refit = amended(best.refit, rss_after=BASE - drop, added=3)
    assert rival_bar([best], BASE, tol, N) == pytest.approx(drop - tol)
    near = CandidateResult("stribeck", sizing=SizingOutcome(
        drop=0.5 * drop, free_converged=True, drop_free=drop - 0.5 * tol))  # 1.5 drop - tol
    far = CandidateResult("creep", sizing=SizingOutcome(
        drop=0.5 * drop, free_converged=True, drop_free=0.7 * drop))  # reach 0.9 drop
    loose = CandidateResult("external_load", sizing=SizingOutcome(
        drop=0.5 * drop, drop_free=0.6 * drop))  # free sizing unconverged
    ranked = [best, near, far, loose]
    bar = rival_bar(ranked, BASE, tol, N)
    assert not cannot_rival(near, bar)
    assert cannot_rival(far, bar)
    assert not cannot_rival(loose, bar)
    # Where the ΔBIC penalty of the accepted refit's extra parameters exceeds the
    # tolerance, a rival with fewer parameters is preferred a little below its drop.
    best.refit = amended(best.refit, added=3 + int(2 * tol / np.log(N)))
    assert rival_bar(ranked, BASE, tol, N) == pytest.approx(
        drop - (best.added - 1) * np.log(N))
    # Nothing that would be accepted yet (a share below the policy's): no bar.
    best.refit = amended(best.refit, explained=0.3)
    assert rival_bar(ranked, BASE, tol, N) is None
    assert not cannot_rival(far, None)


def test_an_unconverged_free_sizing_is_carried_on_before_it_bounds_a_refit():
    from stickslip_jax.diagnose.rules import unbounded

    ranked = _ranked(("creep", 0.1 * BASE, 0.2 * BASE), ("stribeck", 0.05 * BASE, 0.01 * BASE),
                     ("external_load", 0.01 * BASE, 0.1 * BASE),
                     ("drive_bandwidth", -0.001 * BASE, -0.9 * BASE))
    ranked[0].sizing = amended(ranked[0].sizing, drop_free=0.24 * BASE, free_converged=True)
    # stribeck's stopped short of its optimum:
    ranked[1].sizing = amended(ranked[1].sizing, drop_free=0.02 * BASE)
    # drive_bandwidth: no promise, never refitted, never carried on.
    ranked[3].sizing = amended(ranked[3].sizing, drop_free=-0.5 * BASE)
    # external_load: no free sizing at all (-inf): nothing to carry on.
    assert [r.name for r in unbounded(ranked)] == ["stribeck"]
    # Where it stopped, stribeck's bound is already its score (0.05 BASE, above
    # 2·0.02 − 0.01): carried on, the bound could only rise, so a decision whose bar it
    # reaches carries nothing on; one above it does.
    assert unbounded(ranked, 0.05 * BASE) == []
    assert [r.name for r in unbounded(ranked, 0.06 * BASE)] == ["stribeck"]
    ranked[1].refit = RefitOutcome()
    assert unbounded(ranked) == []


def test_the_baselines_first_order_move_is_the_joint_least_squares_step():
    # BaselineSpan.move: the δ that takes out the residual's part in the span of J_b
    # (columns of very different scales, as θ of a mass and of a PI weight are), and
    # reach its largest |δ|, against the least-squares solution of the full system.
    from stickslip_jax.diagnose.problem import FIRST_ORDER_REACH, BaselineSpan

    rng = np.random.default_rng(11)
    n, k = 500, 5
    j_b = rng.normal(size=(n, k)) * np.array([1e3, 1.0, 1e-2, 30.0, 0.5])
    span = BaselineSpan.of(j_b)
    np.testing.assert_allclose(span.basis.T @ span.basis, np.eye(k), atol=1e-12)
    for size in (0.3, 3.0):
        delta = size * np.array([0.2, -1.0, 0.5, 0.1, 0.7])
        noise = rng.normal(size=n)
        noise -= span.basis @ (span.basis.T @ noise)  # nothing the baseline could take
        residual = -j_b @ delta + noise
        np.testing.assert_allclose(span.move(residual), delta, rtol=1e-9)
        assert span.reach(residual) == pytest.approx(size)
        assert (span.reach(residual) > FIRST_ORDER_REACH) == (size > 1.0)
    # A residual the baseline cannot mimic at all asks no move.
    assert span.reach(noise) < 1e-9


def test_an_extrapolated_free_sizing_counts_nothing_and_is_not_carried_on():
    from stickslip_jax.diagnose.problem import BaselineSpan
    from stickslip_jax.diagnose.rules import rank_value, refit_reach, unbounded
    from stickslip_jax.diagnose.sizing import FreeSizing, record_free_sizing

    span = BaselineSpan.of(np.eye(3))
    rss = 10_000.0

    def free(cost, converged, reach):
        return FreeSizing("drive_bandwidth", None, np.zeros(1), span, cost, converged,
                          np.array([0.1, -reach, 0.0]))  # reach: the largest |move|

    r = CandidateResult("drive_bandwidth", score=150.0, sizing=SizingOutcome(drop=200.0))
    record_free_sizing(r, free(6_000.0, True, 0.6), rss)  # within the first-order range
    assert (r.size_drop_free, r.size_free_converged, r.size_free_extrapolated) == (
        4_000.0, True, False)
    assert rank_value(r) == 4_000.0 and refit_reach(r) == 2 * 4_000.0 - 200.0
    # The same fall with the baseline moved by more than a factor e: the linearisation's
    # fall, not one a refit can reach. Ranked by its held sizing, bounding nothing.
    r = CandidateResult("drive_bandwidth", score=150.0, sizing=SizingOutcome(drop=200.0))
    record_free_sizing(r, free(6_000.0, False, 1.7), rss)
    assert (r.size_drop_free, r.size_free_converged, r.size_free_extrapolated) == (
        200.0, False, True)
    assert rank_value(r) == 200.0 and refit_reach(r) == np.inf
    assert r.size_free_reach == 1.7  # reported (diagnosis.json)
    assert unbounded([r]) == []  # carried on, it would extrapolate further
    # An unconverged sizing within range is carried on; if that ends beyond the range,
    # its earlier drop no longer counts either.
    r = CandidateResult("drive_bandwidth", score=150.0, sizing=SizingOutcome(drop=200.0))
    record_free_sizing(r, free(9_000.0, False, 0.4), rss)
    assert unbounded([r]) == [r] and r.size_drop_free == 1_000.0
    record_free_sizing(r, free(6_000.0, False, 2.5), rss)
    assert r.size_drop_free == 200.0 and unbounded([r]) == []


def test_a_free_sizings_point_is_the_entry_on_the_baseline_moved_to_first_order():
    from types import SimpleNamespace

    from stickslip_jax.diagnose.problem import BaselineSpan
    from stickslip_jax.diagnose.sizing import FreeSizing
    from stickslip_jax.identify.parameters import ParameterMap

    act = ss.lu2015_slc1720()
    # The "entry": Kp, sized in the held sizing's coordinates (log: θ = 0.1 is ×e^0.1);
    # the baseline's move: Mp by 0.2, Dp by −0.3 (log coordinates).
    program = SimpleNamespace(pmap=ParameterMap.make(act, ["Kp"]))
    free = FreeSizing("x", program, np.array([0.1]), BaselineSpan.of(np.eye(2)), 1.0,
                      True, np.array([0.2, -0.3]))
    assert free.reach == 0.3 and not free.extrapolated
    point = free.point(["Mp", "Dp"])
    np.testing.assert_allclose(
        [point.piezo.Kp, point.piezo.Mp, point.piezo.Dp],
        [act.piezo.Kp * np.exp(0.1), act.piezo.Mp * np.exp(0.2),
         act.piezo.Dp * np.exp(-0.3)], rtol=1e-12)
    assert float(point.slider.Ms) == float(act.slider.Ms)


@pytest.mark.parametrize("case", ["below", "cheaper", "dearer", "extrapolated", "folded"])
def test_a_refit_starts_where_the_sizings_cost_least_once_the_held_one_passes_the_baseline(
        case):
    """A held sizing at or below the round's cost is the start; one above it gives way
    to its free sizing's point when that costs less (one evaluation), and only then."""
    from types import SimpleNamespace

    from stickslip_jax.diagnose.refit import RoundStart, refit_start
    from stickslip_jax.diagnose.sizing import HeldSizing

    evaluated = []

    class Point:
        pass

    point = Point()

    def evaluate(act):
        evaluated.append(act)
        return ({"cheaper": 5e5, "dearer": 2e6}[case], None, None)

    def point_of(base_names):
        if case == "folded":
            raise ValueError("a partial sum below zero")
        return point

    problem = SimpleNamespace(evaluate=evaluate, say=lambda s: None)
    setup = SimpleNamespace(problem=problem, base_names=["Mp"])
    at = RoundStart(act=None, rss=2.28e5, nrmse=0.0, excess=1e5, reserve=0.0)
    held_start = object()
    held = HeldSizing(held_start, {}, None, np.zeros(1),
                      2e5 if case == "below" else 1.1e6, False)
    free = SimpleNamespace(extrapolated=case == "extrapolated",
                           reach=0.4, point=point_of)
    res = CandidateResult("drive_bandwidth")
    start = refit_start(setup, at, res, held, free)
    if case == "cheaper":
        assert start is point and evaluated == [point]
        assert (res.refit_start, res.refit_start_cost) == ("free sizing's point", 5e5)
        return
    assert start is held_start
    assert (res.refit_start, res.refit_start_cost) == ("held sizing", held.cost)
    assert evaluated == ([point] if case == "dearer" else [])
    # No free sizing: the held one, whatever its cost.
    assert refit_start(setup, at, CandidateResult("x"), held, None) is held_start

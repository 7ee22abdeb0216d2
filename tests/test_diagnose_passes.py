"""The refit passes (stickslip_jax.diagnose.passes): each refits what its rule takes,
in order, records itself on the entry, and a configuration without it is its ablation.

The refit itself is replaced by a stand-in that gives each entry a prescribed outcome
(the refits are tested in test_diagnose_refit.py); what is tested here is which pass
spends a refit on which entry.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from stickslip_jax.diagnose import DiagnoseConfig
from stickslip_jax.diagnose.passes import (
    DEFAULT_PASSES,
    PASS_NAMES,
    CarryOnDeciding,
    FallbackRefits,
    FirstRefits,
    RefitPass,
    RefitRound,
    Reidentify,
    RivalsInReach,
    SecondLook,
)
from stickslip_jax.diagnose.passes import base as passes_base
from stickslip_jax.diagnose.passes import carry_on as passes_carry_on
from stickslip_jax.diagnose.policy import Policy
from stickslip_jax.diagnose.records import RefitOutcome, SizingOutcome, amended
from stickslip_jax.diagnose.refit import RoundStart
from stickslip_jax.diagnose.results import CandidateResult, CandidateStatus
from stickslip_jax.diagnose.run import _refit_round

N, BASE = 24_000.0, 1.0e6


def _round(ranked, outcomes, monkeypatch, *, seeded=()):
    """A round over ``ranked`` whose refits end as ``outcomes`` (per name: the share of
    the excess removed, or absent: removes nothing), and the list of refits run."""
    calls = []

    def fake_refit(setup, at, res, cand, held, free, *, budgeted=True):
        calls.append(res.name)
        share = outcomes.get(res.name, 0.0)
        rss = at.rss - share * at.excess
        res.status = CandidateStatus.REFITTED
        res.refit = RefitOutcome(
            actuator=object(), rss_after=rss, criterion_delta=rss - at.rss + 3 * np.log(N),
            explained=share, chi2_after=rss / N, material=share > 0, added=3,
            converged=outcomes.get("converged", True))

    monkeypatch.setattr(passes_base, "refit", fake_refit)
    problem = SimpleNamespace(n_obs=N, say=lambda s: None,
                              significance=SimpleNamespace(tolerance_rss=0.01 * N))
    setup = SimpleNamespace(problem=problem, policy=Policy(), carry_on_steps=30)
    at = RoundStart(act=None, rss=BASE, nrmse=0.0, excess=BASE - N, reserve=0.0)
    names = [r.name for r in ranked]
    pool = [SimpleNamespace(name=n) for n in names]
    held = {n: SimpleNamespace(specs={}) for n in names}
    rnd = RefitRound(setup, at, ranked, pool, held, {}, set(seeded),
                     top=3, first_budgeted=False)
    return rnd, calls


def _ranked(*values):
    return [CandidateResult(name, score=score, sizing=SizingOutcome(drop=drop))
            for name, score, drop in values]


def test_the_passes_run_in_order_and_each_refit_names_its_pass(monkeypatch):
    # The leader explains nothing; the fallback refits the entry below 25 % of it.
    ranked = _ranked(("external_load", 1e5, 4e5), ("creep", 1e4, 1e4),
                     ("stribeck", -5e3, -1e3))
    rnd, calls = _round(ranked, {"creep": 0.9}, monkeypatch)
    _refit_round(rnd, DEFAULT_PASSES)
    assert calls == ["external_load", "creep"]
    by = {r.name: (r.refit_pass, r.status) for r in ranked}
    assert by["external_load"] == ("first", CandidateStatus.REFITTED)
    assert by["creep"] == ("fallback", CandidateStatus.REFITTED)
    # Wrong sign and a sizing that raised the cost: no pass spends a refit on it.
    assert by["stribeck"] == ("", CandidateStatus.NO_PROMISE)


def test_after_an_explaining_refit_a_competitor_is_refitted_only_if_it_could_rival_it(
        monkeypatch):
    # The leader's refit removes 97 % of the excess; the competitor ranks at half the
    # leader (a first refit by its share). Its sizings' bound on its refit decides
    # whether it is refitted after the leader; a leader whose own sizing removed
    # nearly all of the excess is refitted alone whatever that bound.
    excess = BASE - N

    def run(leader_drop, drop_free):
        ranked = [CandidateResult("rate_dependent_hysteresis", score=0.8 * excess,
                                  sizing=SizingOutcome(drop=leader_drop * excess,
                                                       drop_free=leader_drop * excess,
                                                       free_converged=True)),
                  CandidateResult("creep", score=0.45 * excess,
                                  sizing=SizingOutcome(drop=0.25 * excess,
                                                       drop_free=drop_free * excess,
                                                       free_converged=True))]
        rnd, calls = _round(ranked, {"rate_dependent_hysteresis": 0.97, "creep": 0.4},
                            monkeypatch)
        _refit_round(rnd, DEFAULT_PASSES)
        return calls, ranked[1]
    # Bound max(0.45, 2·0.3 − 0.25) of the excess, below the 0.97 less the penalty it
    # would need: set aside, no refit spent.
    calls, creep = run(0.85, 0.3)
    assert calls == ["rate_dependent_hysteresis"]
    assert creep.status is CandidateStatus.CANNOT_RIVAL and "rival" in creep.note
    # Bound 2·0.7 − 0.25 = 1.15 of the excess: it could rival the leader, so it gets
    # its first refit.
    calls, creep = run(0.85, 0.7)
    assert calls == ["rate_dependent_hysteresis", "creep"]
    assert creep.refit_pass == "first"
    # The same competitor beside a leader whose sizing alone removed 95 % (at least
    # leader_alone_share, and creep's sizing below leader_alone_lead of it): alone.
    calls, creep = run(0.95, 0.7)
    assert calls == ["rate_dependent_hysteresis"]
    assert creep.status is CandidateStatus.NOT_REFITTED and "alone" in creep.note


def test_a_configuration_without_a_pass_is_its_ablation(monkeypatch):
    ranked = _ranked(("external_load", 1e5, 4e5), ("creep", 1e4, 1e4))
    rnd, calls = _round(ranked, {"creep": 0.9}, monkeypatch)
    passes = DiagnoseConfig().without("fallback").refit_passes
    assert [p.name for p in passes] == ["first"]
    _refit_round(rnd, passes)
    assert calls == ["external_load"]
    assert ranked[1].status is CandidateStatus.NOT_REFITTED and not ranked[1].refit_pass
    assert "ranked below 25 % of the leader" in ranked[1].note


def test_the_second_look_refits_the_seeded_entries_only_far_from_the_noise(monkeypatch):
    def run(share):
        ranked = _ranked(("rate_dependent_hysteresis", 5e5, 5e5),
                         ("drive_bandwidth", 1e4, 1e4))
        rnd, calls = _round(ranked, {"rate_dependent_hysteresis": share}, monkeypatch,
                            seeded={"drive_bandwidth"})
        _refit_round(rnd, (FirstRefits(), SecondLook()))
        return calls, ranked
    # Explains 80 % of an excess of 40x the noise: (e/σ)² 8.8 left, above 2.
    calls, ranked = run(0.8)
    assert calls == ["rate_dependent_hysteresis", "drive_bandwidth"]
    assert ranked[1].refit_pass == "second_look"
    # Leaves (e/σ)² 1.04: the seeded entry is not refitted.
    calls, _ = run(1.0 - 0.04 * N / (BASE - N))
    assert calls == ["rate_dependent_hysteresis"]


def test_a_new_pass_is_one_class_handed_to_the_configuration(monkeypatch):
    class EveryWaitingEntry(RefitPass):
        """Refit everything still waiting (a test's pass)."""

        name = "every"

        def run(self, rnd):
            rnd.refit_all([r for r in rnd.ranked if r.waiting], self)

    ranked = _ranked(("external_load", 1e5, 4e5), ("creep", 1e4, 1e4))
    rnd, calls = _round(ranked, {"external_load": 0.9}, monkeypatch)
    config = DiagnoseConfig(passes=(FirstRefits(), EveryWaitingEntry()))
    assert config.record()["passes"] == ["first", "every"]
    _refit_round(rnd, config.refit_passes)
    assert calls == ["external_load", "creep"]
    assert [r.refit_pass for r in ranked] == ["first", "every"]


def test_the_default_passes_are_named_and_an_unknown_one_is_refused():
    assert list(PASS_NAMES) == ["first", "fallback", "rivals", "second_look", "reidentify",
                                "carry_on"]
    assert DiagnoseConfig().record()["passes"] == ["first", "fallback"]
    assert isinstance(DiagnoseConfig().refit_passes[1], FallbackRefits)
    added = DiagnoseConfig().with_passes("carry_on")
    assert added.record()["passes"] == ["first", "fallback", "carry_on"]
    assert isinstance(added.refit_passes[-1], CarryOnDeciding)
    with pytest.raises(ValueError, match="no refit pass"):
        added.with_passes("carry_on")  # runs already
    # Opt-in passes run in their own order whatever the order asked: these three give
    # the five passes that were the default before the ablation, as they ran.
    old = DiagnoseConfig().with_passes("reidentify", "rivals", "second_look")
    assert old.record()["passes"] == list(PASS_NAMES)[:5]
    assert [type(p) for p in old.refit_passes[2:]] == [RivalsInReach, SecondLook, Reidentify]
    with pytest.raises(ValueError, match="no refit pass"):
        DiagnoseConfig().without("second_look")  # not run by default
    with pytest.raises(ValueError, match="no refit pass"):
        DiagnoseConfig().with_passes("seconds_look")


def test_the_deciding_refits_stopped_at_their_cap_are_carried_on(monkeypatch):
    """The top refits by ΔBIC that stopped at their step cap, plausible ones only."""
    ranked = _ranked(("stribeck", 3e5, 3e5), ("external_load", 2e5, 2e5),
                     ("creep", 1e5, 1e5), ("sensor_delay", 9e4, 9e4))
    rnd, calls = _round(ranked, {"stribeck": 0.7, "external_load": 0.6, "creep": 0.5,
                                 "sensor_delay": 0.4, "converged": False}, monkeypatch)
    rnd.top = 4
    carried = []
    monkeypatch.setattr(passes_carry_on, "carry_on_refit",
                        lambda setup, at, res, cand, specs: carried.append(res.name))
    FirstRefits().run(rnd)
    assert calls == ["stribeck", "external_load", "creep", "sensor_delay"]
    ranked[1].implausible = "a load of 3 N"
    ranked[2].refit = amended(ranked[2].refit, converged=True)
    rnd.top = 3
    CarryOnDeciding().run(rnd)
    # By ΔBIC: stribeck, external_load (implausible), creep (converged), sensor_delay
    # (fourth: beyond the top 3).
    assert carried == ["stribeck"]

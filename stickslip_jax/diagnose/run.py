"""The diagnosis loop: baseline, locate, score the catalogue, size, refit, accept, repeat.

:func:`diagnose` reads as its phases (:func:`_baseline_phase`, :func:`locate_phase`, the
rounds of :func:`_run_rounds`, :func:`_final_phase`); each lives in its own module, and
every threshold it decides by is a field of its :class:`~.policy.Policy`. Within the
rounds one record (:class:`_Rounds`) says where the model stands; what every round reads
is made once (:class:`_Context`). What the sizing and the refit
phases make of an entry are frozen records (:mod:`.records`: :class:`~.records.
SizingOutcome`, :class:`~.records.RefitOutcome`) on its
:class:`~.results.CandidateResult`, made once by their phase and read by the later ones:

1. **Baseline** (:func:`_baseline`): the paper's model (one parameter set, z_ba per
   direction, rho1 = rho2 = 0, q = x1 + x2), identified by
   :func:`~stickslip_jax.identify.identify` and then polished on the noise-whitened
   time-domain residual (each recording's residual divided by its own noise level,
   estimated from the data; :mod:`.problem`), the metric that every later comparison
   uses.
   The tolerance is set here (:func:`_significance`); a baseline within it is scored
   for the record and the detection limits, and nothing is sized or named. A baseline
   beyond it has its PI grid refined (:mod:`.hysteresis_shape`, a threshold between
   each pair); the refined one is the baseline when that brings it within the
   tolerance (the loop's shape, not a missing effect), else the grid stays.
2. **Locate** the mismatch per recording (:func:`_locate`, :mod:`.locate`).
3. **Score** every catalogue entry by how well its signature matches the residual
   (:mod:`.scores`): a score (Lagrange-multiplier) test. With ``J_b`` the Jacobian of
   the whitened residual ``r`` in the baseline parameters and ``c`` its derivative in
   the entry's strength at zero, ``c⊥`` the part of ``c`` the baseline parameters
   cannot mimic, the statistic ``S = (r·c⊥)²/|c⊥|²`` is the drop of the residual sum
   of squares that the entry would buy to first order, χ²(1) when the entry is
   absent. Strengths of the wrong sign (negative damping, negative delay) score
   ``−S``, after every admissible one.
4. **Size** the entries with the largest ``|S|`` (:mod:`.sizing`; at most
   :attr:`~.Policy.size_at_most`, ``|S|`` above :attr:`~.Policy.score_min`;
   admissible signs first, then the others, as a large effect can turn the
   first-order sign around): each starts from the Gauss-Newton step of the score
   test, the entry at its strength and the baseline moved by its share of the step
   (the best of 1, 1/2, 1/4, 1/8 of it), and its own parameters are fitted with the
   baseline held; in round one, when the polish removed a material part of the
   identified baseline's cost (more than the tolerance), on the baseline before its
   polish too, the better kept. After an acceptance, only entries whose ``|S|`` reaches
   :attr:`~.Policy.later_score_share` of the excess left are sized. Entries with seeds
   (a rugged cost: the under-damped amplifier) start from their cheapest seed. The
   sized entry is then fitted once more with the baseline free to first order (the
   residual less its part in the span of ``J_b``: variable projection), which predicts
   what its refit will remove where the baseline absorbed part of the effect while it
   was identified.
5. **Refit** (:func:`_refit_round`): the round's refit passes in order, each one class
   of :mod:`.passes` with what it is for (the configuration's
   :attr:`~.config.DiagnoseConfig.passes`; the rules they decide by in :mod:`.rules`,
   the refits in :mod:`.refit`). Each refit frees the entry's parameters and every
   baseline parameter, from the round's optimum: from its held sizing, or, where that
   costs more than the round's optimum, from its free sizing's point when that costs
   less (:func:`~.refit.refit_start`). The default passes:
   :class:`~.passes.FirstRefits` (the leader and its competitors, the ``top`` at most;
   once one would be accepted, only those that could rival it) and
   :class:`~.passes.FallbackRefits` (when none explains: every other sized entry whose
   sizings leave room for an acceptance). Opt-in (:data:`~.passes.OPT_IN_PASSES`: they
   changed no decision on the development splits): :class:`~.passes.RivalsInReach`
   (those the fallback set aside that could still tie with an acceptance),
   :class:`~.passes.SecondLook` (the seeded entries, when the explaining refits stay
   far from the noise), :class:`~.passes.Reidentify` (round one of a bent
   identification: the leading entries attached to the identification itself) and
   :class:`~.passes.CarryOnDeciding`.
6. **Accept** (:func:`_accept`) by the Bayesian information criterion of the whitened
   residual (known noise level): ``ΔBIC = ΔRSS + k·ln N`` (k added parameters, N
   samples). The best entry is accepted when ``ΔBIC <`` :attr:`~.Policy.bic_min`
   (strong evidence), what it removes is material (more than the tolerance of
   :mod:`~stickslip_jax.significance`: the noise estimate's uncertainty and the
   simulator's numerical error) *and* it explains the residual: it removes at least
   :attr:`~.Policy.explained_min` of the residual's squared excess over the noise, or
   leaves a residual within the tolerance. Accepted-grade rivals (ΔBIC below
   :attr:`~.Policy.bic_min`) whose refit's cost exceeds the best's by no more than the
   tolerance (the data cannot tell the two fits apart) are reported as
   indistinguishable from it. An accepted entry that leaves the model beyond the
   tolerance is followed by phase 1b on the augmented model (the PI grid refined, the
   accepted entries held): an effect hidden under a loop of another shape than the
   grid's leaves, once named, the grid's residue, which no entry is for; the refined
   model is kept, and the loop ends, when it is within the tolerance. Repeat from 3
   until no entry is accepted.
7. **Learned correction** (:func:`_learned_correction`, :mod:`.learned`): if a
   structured residual remains that no entry explains, fit the data-driven
   correction (:class:`~stickslip_jax.model.extensions.LearnedForce`, sparse
   regression) and report it as ``unexplained`` with what it depends on; then the
   :class:`~.results.Verdict` (:func:`_verdict`): "augmented" only when what the
   accepted entries leave is within the tolerance, else "partly explained", with what
   is left (:attr:`~.results.Diagnosis.left`).

A work budget (:mod:`.budget`, ``work_budget``, in sample-evaluations: counted solver
work, never seconds, so that machine speed and load cannot change a decision) bounds
the run: the baseline, the scores, the sizings, round one's first refits and the
learned correction always run, and their work is charged (the baseline's on an account
of its own, never against the budget: a bent identification cannot spend the refits'
work); fallback refits, second looks, re-identifications and later rounds are skipped
when their estimated work would pass it (work is kept for the learned correction while
nothing is accepted), and the entries' notes and the diagnosis's notes say so.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..blas_threads import one_blas_thread
from ..identify.dataset import Dataset
from ..identify.parameters import ParameterMap, scale_invariant_names
from ..identify.residuals import numerical_error
from ..identify.sampling import check_sample_rates
from ..identify.solve import gauss_newton_drop
from ..identify.steps import STEPS, identify
from ..model.actuator import Actuator
from ..model.hysteresis import PrandtlIshlinskii
from ..noise import noise_sigma_relative_se
from ..precision import require_float64
from ..significance import Significance
from .budget import UNIT, Budget
from .catalogue import CATALOGUE, Candidate
from .config import DEFAULT_CONFIG, DiagnoseConfig
from .form_refinement import refine_forms
from .holdout import held_out_cost
from .hysteresis_shape import with_refined_hysteresis
from .learned import fit_learned
from .locate import analyse_recording, mismatch_entries, residual_peaks
from .passes import RefitPass, RefitRound, Reidentification
from .policy import Policy
from .problem import Problem, baseline_free, recentred
from .records import Acceptance
from .refit import RefitSetup, RoundStart
from .results import CandidateResult, CandidateStatus, Diagnosis, Verdict
from .rules import (
    acceptable,
    acceptable_partly,
    explains,
    indistinguishable,
    rank_value,
    size_before_polish,
    why_not_refitted,
)
from .scores import score_candidates
from .sizing import (
    FreeSizing,
    chosen_for_sizing,
    size_entries,
)


@dataclass(frozen=True)
class _Baseline:
    """The baseline of phase 1."""

    act: Actuator
    """Polished on the whitened residual."""
    unpolished: Actuator
    """Before its polish: identified, or ``init``."""
    rss: float
    """Whitened RSS of ``act``."""
    rss_identified: float
    """Whitened RSS of ``unpolished`` (the polish's starting cost)."""
    nrmse: np.ndarray
    """NRMSE per recording of ``act`` [-]."""
    q: np.ndarray
    """Simulated outputs of ``act`` (B, T) [m]."""
    names: list[str]
    """The baseline's fitted quantities (:func:`~.problem.baseline_free`)."""
    n_base: int
    """Their θ columns."""
    residual: np.ndarray | None
    """Whitened residual at ``act`` (the polish's last point)."""
    jacobian: np.ndarray | None
    """Its Jacobian in the baseline's θ there (the leave-one-regime-out check)."""
    jacobian_at_act: np.ndarray | None
    """The same around ``act`` (θ = 0 there: :func:`~.problem.recentred`), the
    baseline's columns of round one's score test."""


def _baseline(problem: Problem, init: Actuator, identify_steps: Sequence[str],
              config: DiagnoseConfig, notes: list[str]) -> _Baseline:
    """Phase 1: identify the paper's model (unless ``identify_steps`` is empty), then
    polish it on the whitened residual; what falls short of its optimum goes to
    ``notes``."""
    data, fix, say, budget = problem.data, problem.fix, problem.say, problem.budget
    act = init
    if identify_steps:
        say("[baseline] identification (the paper's model)")
        ident = identify(data.recordings, init=init, fix=fix, steps=identify_steps,
                         max_steps=config.identify_max_steps, echo=say)
        act = ident.actuator
        budget.charge(problem.identification_work(ident, init))
        notes += [f"Baseline identification, step '{s.name}': {s.result.message}; the "
                  f"polish starts from where it stopped." for s in ident.steps
                  if s.result is not None and not s.converged]
    # The identification's joint step already minimised this residual (the ML
    # whitened one): the polish starts near its optimum, with little damping.
    base, polish = _polished(problem, act, "baseline polish", 3 * config.max_steps,
                             1e-3 if identify_steps else 1.0,
                             damping_update=config.polish_damping_update)
    if not polish.converged:
        # Every later comparison is against this optimum: a baseline short of its own
        # optimum leaves residual that any entry with a baseline-like signature buys.
        notes.append(f"Baseline polish: {polish.message} (cost {polish.cost_start:.5g} "
                     f"-> {polish.cost_end:.5g}); the baseline may be short of its "
                     f"optimum, and part of what the entries remove may be its own.")
    return base


def _baseline_program(problem: Problem, start: Actuator):
    """The residual and Jacobian program of every baseline quantity around ``start``."""
    return problem.program(start, baseline_free(start, problem.data, problem.fix), {})


def _polished(problem: Problem, start: Actuator, label: str, max_steps: int,
              initial_damping: float, program=None,
              damping_update: str = "classical") -> tuple[_Baseline, object]:
    """``start`` polished on the whitened residual with every baseline quantity free
    (``program``: :func:`_baseline_program` of ``start`` when already made): the
    baseline it makes (``start`` as its unpolished one) and the solve's result.
    ``damping_update``: the LM's (:meth:`~.problem.Problem.fit_from`)."""
    program = program or _baseline_program(problem, start)
    names = list(program.pmap.names)
    n_base = int(np.size(program.pmap.zeros()))  # θ columns
    act, _, polish = problem.fit_from(program, program.pmap.zeros(), label=label,
                                      max_steps=max_steps, initial_damping=initial_damping,
                                      damping_update=damping_update)
    rss, nrmse0, q0 = problem.evaluate(act)
    rss_start = float(polish.cost_start)  # the identification's (or init's) cost
    at_act = (None if polish.jacobian is None
              else recentred(polish.jacobian, program.pmap, polish.theta))
    return _Baseline(act, start, rss, rss_start, nrmse0, q0, names, n_base,
                     polish.residual, polish.jacobian, at_act), polish


def _refined_hysteresis(problem: Problem, act: Actuator, rss: float,
                        significance: Significance, config: DiagnoseConfig,
                        notes: list[str], after: str = "") -> _Baseline | None:
    """Phase 1b (:mod:`.hysteresis_shape`): ``act`` (whitened RSS ``rss``) with its PI
    grid refined and polished (at most ``config.refine_steps`` steps, every baseline
    quantity free, the accepted entries held), when that makes it adequate; else None
    (the coarse grid stays, and the refinement is said in ``notes``). ``after``: the
    accepted entries ``act`` holds, for the note (empty: the baseline)."""
    start = with_refined_hysteresis(act)
    n_old, n_new = act.hysteresis.n_memory, start.hysteresis.n_memory
    n_obs = problem.n_obs
    said = (f"Hysteresis shape{f' (after {after})' if after else ''}: the PI grid "
            f"refined from {n_old} to {n_new} operators")
    # First the Gauss-Newton step from the refined start (the new weights at zero): a
    # refinement that to first order stays beyond the tolerance is not polished.
    program = _baseline_program(problem, start)
    r, jac = (np.asarray(a) for a in program(program.pmap.zeros()))
    problem.budget.charge(problem.evaluation_work(start, program.simulated_columns))
    drop = gauss_newton_drop(r, jac)
    # No measurable step (a Jacobian not finite or overflowing) predicts no fall.
    predicted = float(r @ r) - (drop if np.isfinite(drop) else 0.0)
    kept = None
    whose = "the model" if after else "the baseline"
    if predicted > n_obs + significance.tolerance_rss:
        said += (f" would to first order leave mean (e/σ)² {predicted / n_obs:.4g}, beyond "
                 f"the noise tolerance: not polished, {whose} keeps its grid.")
    else:
        fine, polish = _polished(problem, start, "hysteresis refined", config.refine_steps,
                                 1.0, program)
        said += (f" takes mean (e/σ)² from {rss / n_obs:.4g} to "
                 f"{fine.rss / n_obs:.4g} ({polish.message})")
        if significance.adequate(fine.rss, problem.chi2_per_recording(fine.nrmse)):
            kept = fine
            said += (f": within the noise tolerance, so the refined grid is {whose} "
                     f"(the loop's shape, not a missing effect).")
        else:
            said += (f": still beyond the noise tolerance, so {whose} keeps its grid "
                     f"(a refinement could take up part of an effect).")
    notes.append(said)
    problem.say(f"[hysteresis shape] {said}")
    return kept


def _refined_after(problem: Problem, act: Actuator, rss: float,
                   significance: Significance, config: DiagnoseConfig, notes: list[str],
                   accepted: list[str]) -> _Baseline | None:
    """:func:`_refined_hysteresis` of the model with the ``accepted`` entries, when the
    configuration refines the hysteresis and the work budget allows its polish (else
    None, said in ``notes``)."""
    if not config.refine_hysteresis or not isinstance(act.hysteresis, PrandtlIshlinskii):
        return None
    fine = with_refined_hysteresis(act)
    names = baseline_free(fine, problem.data, problem.fix)
    n_cols = int(np.size(ParameterMap.make(fine, names, {}).zeros()))
    need = problem.fit_estimate(fine, n_cols, config.refine_steps + 1)
    what = f"hysteresis shape after {', '.join(accepted)}"
    if not problem.budget.allows(need):
        notes.append(f"Hysteresis shape after {', '.join(accepted)}: "
                     f"{problem.budget.skip(what, need)}.")
        return None
    return _refined_hysteresis(problem, act, rss, significance, config, notes,
                               after=", ".join(accepted))


def locate_phase(problem: Problem, q0: np.ndarray, config: DiagnoseConfig):
    """Phase 2: each recording's residual analysis, the flagged ones, and the hints
    the probes use (shared residual peaks, the largest voltage slew, the shortest and
    longest recording, and each recording's model output, residual and noise, for
    entries that start a quantity per recording from them)."""
    data, sigmas = problem.data, problem.sigmas
    counts = np.asarray(data.mask).sum(axis=1).astype(int)
    outputs = tuple(np.asarray(q0[i, :n], dtype=float) for i, n in enumerate(counts))
    analyses = [analyse_recording(r, q0[i], sigmas[i]) for i, r in enumerate(data.recordings)]
    mismatch = mismatch_entries(analyses)
    hints = {"peaks_Hz": residual_peaks(data.recordings, q0, sigmas,
                                        band=config.peak_band_Hz, n_peaks=config.n_peaks,
                                        noise_z=config.policy.significance_z,
                                        min_level=config.peak_min_level,
                                        octaves=config.peak_octaves),
             "max_slew_V_s": max(float(np.max(np.abs(np.diff(r.voltage_V)))) / r.dt
                                 for r in data.recordings),
             "sample_interval_s": min(float(r.dt) for r in data.recordings),
             "recording_durations_s": (min(r.n * r.dt for r in data.recordings),
                                       max(r.n * r.dt for r in data.recordings)),
             "outputs_m": outputs,
             "residuals_m": tuple(np.asarray(data.measured[i, :n], dtype=float) - outputs[i]
                                  for i, n in enumerate(counts)),
             "noise_m": tuple(float(x) for x in sigmas)}
    return analyses, mismatch, hints


def _candidate_pool(candidates: Sequence[str] | None,
                    recordings: Sequence) -> tuple[list[Candidate], dict[str, str]]:
    """The catalogue entries to test (``candidates``: names, None for all), and those
    the recordings cannot test, with why."""
    pool = [c for c in CATALOGUE if candidates is None or c.name in candidates]
    not_testable = {}
    for c in pool:
        why = c.needs(recordings)
        if why:
            not_testable[c.name] = why
    return [c for c in pool if c.name not in not_testable], not_testable


def _score(problem: Problem, act: Actuator, base_names: list[str],
           pool: Sequence[Candidate], hints: dict, base_jacobian: np.ndarray | None = None):
    """Phase 3: the score test of every entry of ``pool`` at ``act``; the scores and
    detection limits and the baseline's first-order span
    (:func:`~.scores.score_candidates`; ``base_jacobian``: the baseline's columns at
    ``act`` when a fit already has them) and a result per entry, best score first."""
    scores, limits, span = score_candidates(problem, act, base_names, pool, hints,
                                            base_jacobian)
    results = [CandidateResult(name, probe.label, s, b) for name, (s, b, probe, _) in
               sorted(scores.items(), key=lambda kv: -kv[1][0])]
    problem.say("[score] " + ", ".join(f"{r.name} {r.score:.3g}" for r in results))
    return scores, results, limits, span


def _work_estimate(problem: Problem, init: Actuator, total: float | None) -> str:
    """The line printed before the work: what one evaluation of the paper's model on
    these recordings counts, and how many the work budget holds (counted work, for
    display; nothing is charged)."""
    columns = int(np.size(ParameterMap.make(init, baseline_free(init, problem.data,
                                                                problem.fix)).zeros()))
    one = problem.evaluation_work(init, columns)
    head = (f"estimate: one evaluation of these {len(problem.data)} recordings "
            f"({problem.samples:,} padded samples, {columns} parameters with the "
            f"Jacobian, at the start's sub-steps) counts {one:.3g} {UNIT}")
    if not total:
        return head + "; no work budget"
    return (f"{head}; the work budget, {total:.3g}, holds about {total / one:.0f} of them "
            f"(the core, baseline to round one's first refits, runs whatever it holds; "
            f"the optional work stops at it)")


def _significance(problem: Problem, base: _Baseline, policy: Policy) -> Significance:
    """The tolerance of practical significance (:mod:`~stickslip_jax.significance`): the noise
    estimates' standard errors and the simulator's error at the baseline."""
    data = problem.data
    plan = problem.plan_for(base.act)  # the plan base.q was simulated at
    numerical = numerical_error(base.act, data, plan, base.q)
    problem.budget.charge(2 * problem.evaluation_work(base.act, 0))  # the doubled plan
    rel_se = np.array([noise_sigma_relative_se(r) for r in data.recordings])
    return Significance(problem.counts, problem.sigmas, rel_se, numerical,
                        policy.significance_z)


def _refit_round(rnd: RefitRound, passes: Sequence[RefitPass]) -> None:
    """Phase 5: the round's refit passes in order (:mod:`.passes`), from ``rnd.at``;
    every sized entry ends refitted or set aside with a note."""
    for refit_pass in passes:
        refit_pass.run(rnd)
    for res in rnd.ranked:
        if res.waiting:
            res.set_aside(CandidateStatus.NOT_REFITTED,
                          why_not_refitted(res, rnd.ranked, rnd.top, rnd.excess_or_none,
                                           rnd.policy))


def _accept(refitted: list[CandidateResult], policy: Policy, significance: Significance,
            say: Callable[[str], None]) -> CandidateResult | None:
    """Phase 6: the best refit (``refitted``: best ΔBIC first), that explains the
    residual if any does, marked accepted when :func:`~.rules.acceptable`; its rivals
    named that :func:`~.rules.indistinguishable` from it (``significance``: the
    tolerance). When none explains, the best
    that :func:`~.rules.acceptable_partly` is accepted as a partial answer. None, with a
    note on the best, when nothing is accepted."""
    # The best-scoring entry that explains the residual; else the best overall.
    best, partial = next((r for r in refitted if explains(r, policy)), refitted[0]), False
    if not acceptable(best, policy):
        partly = next((r for r in refitted if acceptable_partly(r, policy)), None)
        if partly is not None:
            best, partial = partly, True
    rivals = tuple(r.name for r in refitted if r is not best
                   if indistinguishable(r, best, significance, policy))
    accepted = partial or acceptable(best, policy)
    best.decision = Acceptance(accepted, partial, rivals)
    if accepted:
        held = ""
        if best.held_out:
            held = f"; regimes left out: cost {sum(best.held_out.values()):.5g}"
        say(f"[accept] {best.name}{' (partial answer)' if partial else ''}: ΔBIC "
            f"{best.criterion_delta:.1f}, explains {100 * best.explained:.0f} % of the "
            f"excess, removes {best.removed_nm:.3g} nm RMS{held}")
        return best
    if best.implausible:
        why = "its refitted values are not the physics it names"
    elif best.criterion_delta >= policy.bic_min:
        why = "ΔBIC above the threshold"
    elif not best.predicts:
        why = ("it predicts the regimes left out of its refit worse than the model it "
               "extends (leave one regime out)")
    elif not best.material:
        why = (f"removes {best.removed_nm:.3g} nm RMS ({100 * best.removed_noise_share:.2g} % "
               f"of the noise variance), within the tolerance of the noise estimate "
               f"and the numerical floor")
    else:
        why = f"explains only {100 * best.explained:.0f} % of the excess over the noise"
    best.add_note("not accepted: " + why)
    say(f"[reject] {best.name}: {best.note}")
    return None


def _learned_correction(problem: Problem, act: Actuator, base_names: list[str],
                        rss: float, q: np.ndarray, max_steps: int,
                        policy: Policy) -> tuple[dict, Actuator | None]:
    """Phase 7: the learned force correction on ``act`` (whitened RSS ``rss``, outputs
    ``q``): ``(unexplained, corrected)``, the report of where the residual is and what
    the correction depends on, and ``act`` with the correction when its ΔBIC is below
    :attr:`~.Policy.bic_min` (else None)."""
    data, sigmas, n_obs = problem.data, problem.sigmas, problem.n_obs
    problem.say("[fallback] no catalogue entry explains the residual: sparse regression "
                "of a force correction")
    analyses_now = [analyse_recording(r, q[i], sigmas[i])
                    for i, r in enumerate(data.recordings)]
    learned = fit_learned(problem, act, base_names, rss, max_steps, policy)
    k = len(learned["features"])
    delta = learned["rss"] - rss + k * np.log(n_obs)
    where = mismatch_entries(analyses_now)[:3]
    unexplained = {
        "where": where,
        "depends_on": learned["features"],
        "coefficients_N": learned.get("coefficients_N", {}),
        "criterion_delta": float(delta),
        "chi2_before": rss / n_obs,
        "chi2_after": learned["rss"] / n_obs,
    }
    corrected = learned["actuator"] if k and delta < policy.bic_min else None
    return unexplained, corrected


def _verdict(structured: bool, accepted: list[CandidateResult], within: bool) -> Verdict:
    """Entries accepted: augmented only when the final residual is ``within`` the noise
    tolerance, else partly explained (what they leave is still told from the noise,
    whatever share of the excess they removed). None accepted: unexplained when a
    ``structured`` residual is left, else the baseline was adequate."""
    if accepted:
        return Verdict.AUGMENTED if within else Verdict.PARTLY_EXPLAINED
    return Verdict.UNEXPLAINED if structured else Verdict.BASELINE_ADEQUATE


def _left(significance: Significance, rss: float, chi2_rec: np.ndarray,
          analyses: list) -> dict:
    """What accepted entries leave beyond the noise tolerance (:attr:`.Diagnosis.left`):
    whitened RSS ``rss``, per recording mean ``(e/σ)²`` ``chi2_rec``, the final
    residual's ``analyses``."""
    n_obs = significance.n_obs
    beyond = chi2_rec > 1 + significance.recording_tolerances()
    return {"chi2_per_sample": rss / n_obs, "tolerance_chi2": significance.tolerance,
            "beyond_tolerance_nm": significance.nm(rss - n_obs - significance.tolerance_rss),
            "recordings_beyond": [a.recording for a, b in zip(analyses, beyond, strict=True)
                                  if b],
            "where": mismatch_entries(analyses)[:3]}


def _terms(act: Actuator) -> list[str]:
    terms = ["piezo", type(act.hysteresis).__name__, "slider", type(act.friction).__name__]
    if not act.input_stage.is_identity:
        terms.append(type(act.input_stage).__name__)
    terms += [type(e).__name__ for e in act.extensions]
    if type(act.output_map).__name__ != "IdentityOutput":
        terms.append(type(act.output_map).__name__)
    return terms


@dataclass
class _Rounds:
    """Where phases 3-6 stand (one mutable record, written by :func:`_run_rounds` only):
    the model so far, its cost, the entries left to test and those accepted."""

    act: Actuator
    rss: float
    """Whitened RSS of ``act``."""
    nrmse: float
    """Mean NRMSE of ``act`` [-]."""
    held_out: dict | None
    """The leave-one-regime-out cost of the round's start (:mod:`.holdout`)."""
    pool: list[Candidate]
    hints: dict
    """The probes' hints (:func:`locate_phase`), the per-recording ones where the model
    now stands."""
    accepted: list[CandidateResult] = field(default_factory=list)
    rounds: list[list[CandidateResult]] = field(default_factory=list)
    detection_limits: dict[str, dict] = field(default_factory=dict)


@dataclass(frozen=True)
class _Context:
    """What every round reads, made before the rounds."""

    problem: Problem
    base: _Baseline
    init: Actuator
    fix: dict
    config: DiagnoseConfig
    significance: Significance
    setup: RefitSetup
    unpolished: Actuator
    """Round one sizes from it too (the baseline before its polish, when that differs
    to the data; else the polished one)."""
    staged: tuple[str, ...]
    """The identification steps a re-identification repeats (all but the joint one)."""
    notes: list[str]
    timings: dict[str, float]


def _held_quantities(init: Actuator, fix: dict | None) -> tuple[dict, list[str]]:
    """``fix`` with the mass scale held when it holds none (position data fix only the
    ratios), and the note that says so."""
    fix = dict(fix or {})
    if any(n in fix for n in scale_invariant_names(init)):
        return fix, []
    fix["Ms"] = float(init.slider.Ms)
    return fix, [f"Ms held at {fix['Ms']:g} kg (position data fix only ratios of the "
                 f"masses, dampings and stiffnesses)."]


def _baseline_phase(problem: Problem, init: Actuator, identify_steps: Sequence[str],
                    config: DiagnoseConfig, notes: list[str],
                    timings: dict[str, float]) -> tuple[_Baseline, Significance, bool]:
    """Phase 1 and 1b: the baseline, its tolerance, and whether it is adequate (its PI
    grid refined when that makes it so)."""
    budget = problem.budget
    t0 = time.perf_counter()
    with budget.baseline():  # its own account: never what skips an entry's refit
        base = _baseline(problem, init, identify_steps, config, notes)
        significance = _significance(problem, base, config.policy)
    problem.significance = significance
    timings["baseline_s"] = time.perf_counter() - t0
    adequate = significance.adequate(base.rss, problem.chi2_per_recording(base.nrmse))
    if not adequate and config.refine_hysteresis:
        t0 = time.perf_counter()
        with budget.baseline():
            refined = _refined_hysteresis(problem, base.act, base.rss, significance,
                                          config, notes)
        if refined is not None:
            base, adequate = refined, True
        timings["hysteresis_shape_s"] = time.perf_counter() - t0
    problem.say(f"[significance] tolerance: mean (e/σ)² within 1 + "
                f"{significance.tolerance:.3g} "
                f"({significance.nm(significance.tolerance_rss):.3g} nm RMS; noise "
                f"estimate SE {significance.chi2_se:.3g}, numerical "
                f"{significance.numerical_chi2:.2g}); the baseline is "
                f"{'within' if adequate else 'beyond'} it")
    return base, significance, adequate


def _run_rounds(ctx: _Context, now: _Rounds, baseline_adequate: bool) -> None:
    """Phases 3-6, round after round, until no entry is accepted, an accepted one
    leaves the model within the tolerance, the rounds run out or the work budget
    stops a later round; ``now`` follows."""
    problem, config, budget = ctx.problem, ctx.config, ctx.problem.budget
    say, timings = problem.say, ctx.timings
    round_one_work = 0.0  # what round one's scores and sizings cost
    for rnd in range(config.max_rounds):
        # A later round: its scores and sizings (as round one's) and one refit.
        later = round_one_work + problem.refit_estimate(now.act, ctx.base.n_base + 1,
                                                        config.max_steps)
        if rnd > 0 and not budget.allows(later):
            note = budget.skip(f"round {rnd + 1}", later)
            say(f"[budget] round {rnd + 1} {note}")
            return
        spent_before_round = budget.spent

        # 3. Score.
        t0 = time.perf_counter()
        scores, results, limits, span = _score(
            problem, now.act, ctx.base.names, now.pool, now.hints,
            ctx.base.jacobian_at_act if rnd == 0 else None)
        timings[f"score_round{rnd + 1}_s"] = time.perf_counter() - t0
        if rnd == 0:
            now.detection_limits = limits
            if baseline_adequate:
                # Nothing the data can tell from the noise: scored for the record (and
                # the detection limits), but no entry is sized, refitted or named.
                say("[score] the baseline's residual is within the tolerance of the "
                    "noise: nothing to explain")
                now.rounds.append(results)
                return

        # 4. Size (either sign: a large effect can turn the first-order sign around),
        # with the baseline held, then free to first order; rank by the largest of the
        # score and the sizing's drops.
        t0 = time.perf_counter()
        seeded = {c.name for c in now.pool if c.seeds(ctx.init)}
        chosen = chosen_for_sizing(results, seeded, config.sized_per_round,
                                   now.rss - problem.n_obs if now.accepted else None,
                                   say, config.policy)
        free_sizings: dict[str, FreeSizing] = {}
        sized = size_entries(problem, chosen, now.pool, scores, now.act, ctx.unpolished,
                             now.rss, ctx.base.names, seeded, round_one=rnd == 0,
                             max_steps=config.size_steps, policy=config.policy,
                             baseline_span=span, free_sizings=free_sizings)
        ranked = sorted([r for r in results if r.name in sized],
                        key=lambda r: -rank_value(r))
        if rnd == 0:
            round_one_work = budget.spent - spent_before_round
        timings[f"size_round{rnd + 1}_s"] = time.perf_counter() - t0

        # 5. Refit, from the round's optimum.
        t0 = time.perf_counter()
        reserve = (ctx.setup.learned_reserve(now.act)
                   if config.fallback and not now.accepted else 0.0)
        at = RoundStart(now.act, now.rss, now.nrmse, max(now.rss - problem.n_obs, 1e-9),
                        reserve, now.held_out)
        again = (Reidentification(ctx.base.rss_identified, ctx.init, ctx.fix, ctx.staged)
                 if rnd == 0 else None)
        _refit_round(RefitRound(ctx.setup, at, ranked, now.pool, sized, free_sizings,
                                seeded, config.top, first_budgeted=rnd > 0,
                                reidentification=again, timings=timings),
                     config.refit_passes)
        timings[f"refit_round{rnd + 1}_s"] = time.perf_counter() - t0
        refitted = sorted([r for r in results if r.refitted],
                          key=lambda r: r.criterion_delta)
        now.rounds.append(results)
        if not refitted:
            return

        # 6. Accept, or stop.
        best = _accept(refitted, config.policy, ctx.significance, say)
        if best is None:
            return
        now.accepted.append(best)
        now.act, now.rss = best.actuator, best.rss_after
        now.held_out = best.held_out or None
        now.pool = [c for c in now.pool if c.name != best.name]
        now.nrmse = best.nrmse_after
        if best.adequate or _after_acceptance(ctx, now, rnd):
            return


def _after_acceptance(ctx: _Context, now: _Rounds, rnd: int) -> bool:
    """After round ``rnd``'s acceptance: the accepted entries' forms refined within
    their classes, then the loop's shape (phase 1b on the augmented model); whether
    either left the model within the tolerance (the rounds then stop)."""
    problem, config, significance = ctx.problem, ctx.config, ctx.significance
    # The accepted entries' forms within their classes (a tanh slew limit's corner
    # freed, ...): a residue of the fitted form is not another effect's.
    if config.refine_forms:
        t0 = time.perf_counter()
        # The hints where the model now stands (a second mode's residual peak shows
        # once the first is fitted).
        hints_now = locate_phase(problem, problem.evaluate(now.act)[2], config)[2]
        refined_act, now.rss = refine_forms(problem, now.act, now.rss, now.accepted,
                                            hints_now, significance=significance,
                                            policy=config.policy,
                                            max_steps=config.max_steps, notes=ctx.notes)
        # The next round's starts per recording from the residual where the model
        # now stands (a periodic error's fringe phases show once another effect's
        # misfit is gone); the shared peaks stay the baseline's.
        now.hints = now.hints | {k: hints_now[k] for k in ("outputs_m", "residuals_m")}
        ctx.timings[f"refine_round{rnd + 1}_s"] = time.perf_counter() - t0
        if refined_act is not now.act:
            now.act = refined_act
            nrmse = problem.evaluate(now.act)[1]
            now.nrmse = float(nrmse.mean())
            if significance.adequate(now.rss, problem.chi2_per_recording(nrmse)):
                return True
    # The loop's shape after the entries: an effect hidden under a hysteresis on
    # another grid than the baseline's leaves, once named, the grid's residue,
    # which no entry is for (phase 1b could not tell it while the effect was
    # there). Kept only when the refined model is within the tolerance.
    refined = _refined_after(problem, now.act, now.rss, significance, config, ctx.notes,
                             [r.name for r in now.accepted])
    if refined is None:
        return False
    now.act, now.rss, now.nrmse = refined.act, refined.rss, float(refined.nrmse.mean())
    return True


@dataclass(frozen=True)
class _Final:
    """Phase 7's outcome: the final model and what is said of it."""

    act: Actuator
    rss: float
    nrmse: np.ndarray
    q: np.ndarray
    analyses: list
    unexplained: dict | None
    verdict: Verdict
    left: dict | None
    numerical: np.ndarray


def _final_phase(ctx: _Context, now: _Rounds, chi2_0: float) -> _Final:
    """Phase 7: the learned correction when a structured residual is left (the residual
    is above the noise and the accepted entries, if any, removed less than the policy's
    share of the baseline's excess), the verdict, what is left, and the simulator's own
    error at the final model (``chi2_0``: the baseline's mean (e/σ)²)."""
    problem, config, significance = ctx.problem, ctx.config, ctx.significance
    n_obs, act = problem.n_obs, now.act
    rss, nrmse, q = problem.evaluate(act)
    excess0 = max(chi2_0 * n_obs - n_obs, 1e-9)
    share_left = (rss - n_obs) / excess0
    within = significance.adequate(rss, problem.chi2_per_recording(nrmse))
    structured = not within and (not now.accepted
                                 or share_left > 1 - config.policy.explained_min)
    unexplained = None
    if structured and config.fallback:
        t0 = time.perf_counter()
        unexplained, corrected = _learned_correction(problem, act, ctx.base.names, rss, q,
                                                     config.max_steps, config.policy)
        if corrected is not None:
            act = corrected
            rss, nrmse, q = problem.evaluate(act)
        ctx.timings["fallback_s"] = time.perf_counter() - t0
    data, sigmas = problem.data, problem.sigmas
    analyses = [analyse_recording(r, q[i], sigmas[i]) for i, r in enumerate(data.recordings)]
    chi2_rec = problem.chi2_per_recording(nrmse)
    within = significance.adequate(rss, chi2_rec)  # again: the correction moved it
    left = (None if within or not now.accepted
            else _left(significance, rss, chi2_rec, analyses))
    # The simulator's own error at the final model (step doubling), next to the noise.
    numerical = numerical_error(act, data, problem.plan_for(act))
    problem.say(f"numerical floor: the simulator's error at the final model is at most "
                f"{numerical.max() * 1e9:.3g} nm RMS per recording (noise: "
                f"{sigmas.min() * 1e9:.3g}-{sigmas.max() * 1e9:.3g} nm)")
    return _Final(act, rss, nrmse, q, analyses, unexplained,
                  _verdict(structured, now.accepted, within), left, numerical)


@one_blas_thread
def diagnose(recordings: Sequence, *, init: Actuator, fix: dict | None = None,
             identify_steps: Sequence[str] = STEPS, candidates: Sequence[str] | None = None,
             config: DiagnoseConfig | None = None,
             echo: Callable[[str], None] | None = None, **changes) -> Diagnosis:
    """Diagnose what the baseline model leaves out of ``recordings`` (module docstring).

    ``init`` the starting actuator; ``fix`` quantities held (SI; the mass scale, e.g.
    ``{"Ms": 0.0247}``); ``identify_steps`` the identification steps run before the
    polish (empty: start the polish from ``init``); ``candidates`` catalogue names to
    consider (default all); ``config`` how it runs (:class:`~.config.DiagnoseConfig`:
    the policy every decision reads, rounds, refits per round, step caps, the work
    budget), with ``changes`` to its fields as keywords (``max_steps=15``,
    ``work_budget=0``, ``policy=Policy(...)``). Work past the budget that is optional
    (fallback refits, second looks, re-identifications, refits after round one) is
    skipped and said in the notes (:mod:`.budget`). No decision depends on wall time;
    ``timings`` are for display.
    """
    require_float64("diagnose")
    config = (config or DEFAULT_CONFIG).replace(**changes)
    say = echo or (lambda s: None)
    timings: dict[str, float] = {}
    t_all = time.perf_counter()
    budget = Budget(config.work_budget)
    data = Dataset.from_recordings(recordings)
    check_sample_rates(data.recordings, init)  # before anything, --skip-identify too
    fix, notes = _held_quantities(init, fix)
    problem = Problem.whitened(data, fix, say, budget,
                               gauss_newton_trial=config.gauss_newton_trial)
    say(f"[budget] {_work_estimate(problem, init, config.work_budget)}")

    # 1. Baseline.
    base, significance, adequate = _baseline_phase(problem, init, identify_steps, config,
                                                   notes, timings)
    chi2_0 = base.rss / problem.n_obs
    # 2. Locate.
    analyses0, mismatch, hints = locate_phase(problem, base.q, config)
    say(f"[baseline] NRMSE {100 * base.nrmse.mean():.4f} %, chi2/sample {chi2_0:.3f}, "
        f"{len(mismatch)} recording(s) flagged; residual peaks "
        f"{', '.join(f'{f:.0f} Hz' for f in hints['peaks_Hz']) or 'none'}")
    say(f"[budget] {budget.progress()}")

    # 3-6. Score, size, refit, accept, round after round.
    pool, not_testable = _candidate_pool(candidates, data.recordings)
    regimes = tuple(a.regime for a in analyses0)
    ctx = _Context(problem, base, init, fix, config, significance,
                   RefitSetup.from_config(problem, base.names, base.n_base, config, regimes),
                   (base.unpolished if size_before_polish(base.rss_identified, base.rss,
                                                          significance) else base.act),
                   tuple(st for st in identify_steps if st != "joint"), notes, timings)
    held_out = (held_out_cost(base.residual, base.jacobian, regimes)
                if base.jacobian is not None and base.residual is not None else None)
    now = _Rounds(base.act, base.rss, float(base.nrmse.mean()), held_out, pool, hints)
    _run_rounds(ctx, now, adequate)
    if budget.skipped:
        notes.append(f"Work budget {budget.total:.3g} {UNIT}: skipped "
                     f"{', '.join(budget.skipped)} (their notes say so); "
                     f"--work-budget 0 lifts the limit, --work-budget 2 doubles it.")

    # 7. Learned correction, verdict.
    final = _final_phase(ctx, now, chi2_0)
    timings["total_s"] = time.perf_counter() - t_all
    say(f"[budget] {budget.progress()}")
    return Diagnosis(data, problem.sigmas, base.act, final.act, base.nrmse, final.nrmse,
                     chi2_0, final.rss / problem.n_obs, analyses0, final.analyses,
                     mismatch, now.accepted, now.rounds, not_testable, final.unexplained,
                     final.verdict, base.q, final.q, _terms(final.act), timings, notes,
                     [float(p) for p in hints["peaks_Hz"]], final.numerical,
                     budget.record(), config.policy, significance.record(),
                     now.detection_limits, config, final.left)

"""Outputs of a diagnosis: ``diagnosis.json``, ``report.md`` and its figures."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..files import atomic_write_text, check_output_path
from ..identify.residuals import periodogram_psd
from ..model.extensions import LearnedForce
from ..params import save_params
from ..plots import save_figure, subplots
from .catalogue import NAMES, candidate
from .form_band import intervals
from .locate import residual_of
from .policy import DEFAULT_POLICY, Policy
from .records import RefitOutcome, SizingOutcome
from .results import CandidateResult, CandidateStatus, Diagnosis, Verdict


def criterion_text(policy: Policy = DEFAULT_POLICY) -> str:
    """How an entry is accepted under ``policy``, in words (``diagnosis.json``'s
    ``criterion``)."""
    return ("BIC of the noise-whitened time-domain residual (noise level estimated from "
            "each recording): criterion_delta = ΔRSS/σ² + k·ln N; accepted below "
            f"{policy.bic_min:g} when what the entry removes is material (its drop of "
            f"mean (e/σ)² exceeds the tolerance: {policy.significance_z:g} standard "
            f"errors of the noise estimate plus the simulator's numerical error) and it "
            f"removes at least {100 * policy.explained_min:.0f} % of the residual's "
            f"excess over the noise or leaves a residual within the tolerance")


def score_test_text(policy: Policy = DEFAULT_POLICY) -> str:
    """The score test and its threshold under ``policy``, in words (``diagnosis.json``'s
    ``score_test``)."""
    return (f"Lagrange-multiplier score of each entry's first-order signature, "
            f"refitted when ≥ {policy.score_min:g} (χ²(1) under no effect)")


CRITERION = criterion_text()
"""The acceptance criterion of the default policy, in words."""


def named_line(c) -> str:
    """One accepted entry in words: its name, a partial answer's share, what it
    removed, its ΔBIC and parameters."""
    share = (f"partial answer: {100 * c.explained:.0f} % of the excess; the rest is "
             f"structured, " if c.partial else "")
    params = ", ".join(f"{k}={v:.4g}" for k, v in c.params.items())
    form = form_found(c.name, c.params)
    return (f"{c.name} ({share}removes {c.removed_nm:.3g} nm RMS, ΔBIC "
            f"{c.criterion_delta:.1f}; {params})" + (f"; {form}" if form else ""))


def form_found(name: str, params: dict) -> str:
    """The form entry ``name``'s refit found, in words (empty when its parameters say
    it, or for a name not in the catalogue: the learned correction)."""
    return candidate(name).describe(params) if name in NAMES else ""


def unexplained_line(d: Diagnosis) -> str:
    """Where the structure no entry explains is, and what the learned correction
    depends on."""
    u = d.unexplained
    where = ", ".join(f"{w['recording']} ({w['statistic']['dominant_phase']})"
                      for w in u["where"][:3])
    return ("unexplained residual" + (f" at {where}" if where else "")
            + "; learned correction depends on: "
            + (", ".join(u["depends_on"]) or "nothing significant"))


def _finite(x):
    x = float(x)
    return x if np.isfinite(x) else None


def _percent(fraction):
    """An NRMSE [-] as the percentage every output reports (``*nrmse_percent`` keys)."""
    x = _finite(fraction)
    return None if x is None else 100.0 * x


def _per_recording(nrmse, analyses, numerical=None) -> list[dict]:
    rows = [{"recording": a.recording, "regime": a.regime, "nrmse_percent": _percent(n),
             "chi2_per_sample": a.chi2, "noise_nm": a.noise_m * 1e9,
             "rms_residual_nm": a.rms_residual_m * 1e9}
            for a, n in zip(analyses, nrmse, strict=True)]
    if numerical is not None:
        for row, e in zip(rows, numerical, strict=True):
            row["numerical_error_nm"] = float(e) * 1e9
    return rows


def left_line(left: dict) -> str:
    """What the accepted entries leave beyond the noise tolerance, in a sentence
    (:attr:`~.results.Diagnosis.left`)."""
    return (f"the accepted entries leave mean (e/σ)² {left['chi2_per_sample']:.3f}, beyond "
            f"the tolerance 1 + {left['tolerance_chi2']:.3g} by "
            f"{left['beyond_tolerance_nm']:.3g} nm RMS: a partial answer")


def _left_markdown(left: dict) -> list[str]:
    """report.md's lines on what the accepted entries leave beyond the noise tolerance."""
    where = ", ".join(f"{m['recording']} ({m['regime']}, {m['band_Hz'][0]:.0f}-"
                      f"{m['band_Hz'][1]:.0f} Hz)" for m in left["where"])
    return ["## What is left", "",
            f"{left_line(left).capitalize()}. Recordings beyond their own tolerance: "
            f"{', '.join(left['recordings_beyond']) or 'none (the mean only)'}"
            + (f"; worst: {where}." if where else "."), ""]


UNCONVERGED_MARK = "†"
"""Marks, in report.md, a sizing's drop where that sizing stopped at its step cap."""


def _sizing_drops(c: dict) -> str:
    """An entry's sizing drops for report.md, ``held, free`` (each marked
    :data:`UNCONVERGED_MARK` where its sizing did not converge); empty when not sized."""
    if c["status"] in (CandidateStatus.SCORED, CandidateStatus.NOT_SIZED):
        return ""
    drops = [(c["sizing_drop"], c.get("sizing_converged")),
             (c["sizing_drop_baseline_free"], c["sizing_baseline_free_converged"])]
    return ", ".join(f"{d:.3g}{'' if ok else UNCONVERGED_MARK}"
                     for d, ok in drops if d is not None)


def _evidence(c) -> dict:
    return {"score_statistic": c.score, "probe": c.probe, "sizing_drop": c.size_drop,
            "sizing_converged": c.size_converged,
            "sizing_drop_baseline_free": _finite(c.size_drop_free),
            "sizing_baseline_free_converged": c.size_free_converged,
            "sizing_baseline_free_move": _finite(c.size_free_reach),
            "sizing_baseline_free_extrapolated": c.size_free_extrapolated,
            "explained_share_of_excess": _finite(c.explained),
            "chi2_per_sample_after": _finite(c.chi2_after),
            "removed_nm": _finite(c.removed_nm),
            "held_out_cost_by_regime": c.held_out,
            "predicts_regimes_left_out": c.predicts,
            "removed_share_of_noise_variance": _finite(c.removed_noise_share),
            "material": c.material,
            "indistinguishable_from": list(c.indistinguishable_from),
            "note": c.note}


def _number(x) -> float:
    return math.nan if x is None else float(x)


def entry_from_record(c: dict, unrecorded_converged: bool = True) -> CandidateResult:
    """One recorded entry of ``diagnosis.json``'s ``candidates_by_round``, as the
    decision rules read it (replays of a changed rule, ``benchmarks/bench_ablation.py``).
    Records from before the held sizing's convergence was written take
    ``unrecorded_converged`` for it."""
    drop_free = c.get("sizing_drop_baseline_free")
    refit = None
    if c.get("refitted", False):
        refit = RefitOutcome(
            rss_after=_number(c.get("rss_after")),
            criterion_delta=_number(c.get("criterion_delta")),
            added=c.get("added_parameters", 0),
            explained=_number(c.get("explained_share_of_excess")),
            chi2_after=_number(c.get("chi2_after")), adequate=bool(c.get("adequate", False)),
            material=bool(c.get("material", False)),
            predicts=bool(c.get("predicts_regimes_left_out", True)))
    sizing = SizingOutcome(
        drop=float(c["sizing_drop"]),
        converged=bool(c.get("sizing_converged", unrecorded_converged)),
        drop_free=-math.inf if drop_free is None else float(drop_free),
        free_converged=bool(c.get("sizing_baseline_free_converged", False)),
        free_reach=_number(c.get("sizing_baseline_free_move")))
    return CandidateResult(
        c["name"], score=float(c["score_statistic"]), sizing=sizing, refit=refit,
        implausible=c.get("implausible", ""), status=CandidateStatus(c["status"]))


def diagnosis_dict(d: Diagnosis) -> dict:
    """The content of ``diagnosis.json``."""
    missing = [{"name": c.name, "partial": c.partial, "summary": named_line(c),
                "evidence": _evidence(c), "form": form_found(c.name, c.params),
                "params": c.params, "params_interval_95": intervals(c.param_draws),
                "nrmse_before_percent": _percent(c.nrmse_before),
                "nrmse_after_percent": _percent(c.nrmse_after),
                "criterion_delta": c.criterion_delta}
               for c in d.accepted]
    rounds = [[{"name": c.name, "score_statistic": c.score, "probe": c.probe,
                "sizing_drop": c.size_drop, "sizing_converged": c.size_converged,
                "sizing_drop_baseline_free": _finite(c.size_drop_free),
                "sizing_baseline_free_move": _finite(c.size_free_reach),
                "sizing_baseline_free_extrapolated": c.size_free_extrapolated,
                "sizing_baseline_free_converged": c.size_free_converged,
                "status": c.status, "refitted": c.refitted, "refit_pass": c.refit_pass,
                "refit_converged": c.refit_converged, "carried_on": c.carried_on,
                "refit_start": c.refit_start,
                "refit_start_cost": _finite(c.refit_start_cost),
                # Whitened costs before and after the refit, and the parameters it
                # added: with the sizings, what a change of the refit rules can be
                # replayed on without running the diagnosis again.
                "rss_before": _finite(c.rss_before), "rss_after": _finite(c.rss_after),
                "added_parameters": c.added,
                "criterion_delta": _finite(c.criterion_delta),
                "explained_share_of_excess": _finite(c.explained),
                "removed_nm": _finite(c.removed_nm),
                "held_out_cost_by_regime": c.held_out,
                "predicts_regimes_left_out": c.predicts, "material": c.material,
                "adequate": c.adequate, "chi2_after": _finite(c.chi2_after),
                "implausible": c.implausible,
                "nrmse_after_percent": _percent(c.nrmse_after), "accepted": c.accepted,
                "partial": c.partial,
                "note": c.note, "wall_s": c.wall_s} for c in rnd] for rnd in d.rounds]
    out = {
        "baseline": {"nrmse_percent": _percent(d.nrmse_baseline.mean()),
                     "chi2_per_sample": d.chi2_baseline,
                     "per_recording": _per_recording(d.nrmse_baseline, d.analyses_baseline)},
        "mismatch": d.mismatch,
        "residual_peaks_Hz": d.peaks_Hz,
        "missing_physics": missing,
        "final": {"nrmse_percent": _percent(d.nrmse_final.mean()),
                  "chi2_per_sample": d.chi2_final,
                  "terms": d.terms,
                  "per_recording": _per_recording(d.nrmse_final, d.analyses_final,
                                                  d.numerical_error_m)},
        # The simulator's own error at the final model (step doubling) beside the noise.
        "numerical_floor_nm": (None if d.numerical_error_m is None
                               else float(np.max(d.numerical_error_m)) * 1e9),
        "verdict": d.verdict,
        # What the data can tell from the noise (stickslip_jax/significance.py).
        "significance": d.significance,
        "detection_limits": d.detection_limits,
        # Everything it ran with (the policy included): the run can be repeated as is.
        "config": d.config.record() if d.config is not None else None,
        "criterion": criterion_text(d.policy),
        "score_test": score_test_text(d.policy),
        "candidates_by_round": rounds,
        "indistinguishable_here": d.not_testable,
        "notes": d.notes,
        # What decided which optional work ran: counted work, never seconds.
        "work_budget": d.work,
        "timings_s": d.timings,
    }
    if d.left is not None:
        out["left"] = d.left
    if d.unexplained is not None:
        u = dict(d.unexplained)
        out["unexplained"] = u
    return out


def write_diagnosis(d: Diagnosis, out_dir: str | Path, *, force: bool = False,
                    inputs=(), figures: bool = True) -> dict[str, Path]:
    """Write ``diagnosis.json``, ``report.md`` and figures into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    content = diagnosis_dict(d)
    path = out_dir / "diagnosis.json"
    check_output_path(path, force=force, inputs=inputs)
    atomic_write_text(path, json.dumps(content, indent=1, default=float) + "\n")
    written["diagnosis"] = path
    written["params"] = save_params(d.final, out_dir / "params.json", force=force,
                                    inputs=inputs, fit_status=final_fit_status(d))
    written["baseline_params"] = save_params(d.baseline, out_dir / "baseline_params.json",
                                             force=force, inputs=inputs)
    rivals = rival_models(d)
    if rivals:
        (out_dir / "rivals").mkdir(exist_ok=True)
    for name, (act, status) in rivals.items():
        written[f"rival_{name}"] = save_params(act, out_dir / "rivals" / f"{name}.json",
                                               force=force, inputs=inputs, fit_status=status)
    figs = {}
    if figures:
        fig_dir = out_dir / "figures"
        fig_dir.mkdir(exist_ok=True)
        for name, fn in (("residual_map", plot_residual_map), ("overlays", plot_overlays),
                         ("residual_psd", plot_residual_psd)):
            p = fig_dir / f"{name}.png"
            check_output_path(p, force=force, inputs=inputs)
            fn(d, p)
            figs[name] = p
        forms = [c for c in d.accepted if c.name in NAMES]
        if forms:
            p = fig_dir / "forms_found.png"
            check_output_path(p, force=force, inputs=inputs)
            if plot_forms(forms, p):
                figs["forms_found"] = p
        written.update(figs)
    report = out_dir / "report.md"
    check_output_path(report, force=force, inputs=inputs)
    atomic_write_text(report, report_markdown(content, figs, out_dir))
    written["report"] = report
    return written


def rival_models(d: Diagnosis) -> dict[str, tuple]:
    """``name → (actuator, fit_status)``: the refitted model of each entry the data
    could not tell from an accepted one (:attr:`~.results.CandidateResult.
    indistinguishable_from`), as refitted in the round the accepted one was named;
    the other explanation of these recordings, to simulate beside the final model."""
    out = {}
    for rnd in d.rounds:
        named = [c for c in rnd if c.accepted]
        for c in named:
            for r in rnd:
                if (r.name in c.indistinguishable_from and r.refit is not None
                        and r.refit.actuator is not None and r.name not in out):
                    out[r.name] = (r.refit.actuator,
                                   f"rival: indistinguishable from {c.name} on these "
                                   f"recordings, not named (diagnosis.json)")
    return out


def final_fit_status(d: Diagnosis) -> str | None:
    """The ``fit_status`` mark of the final model's parameter file: None where it
    describes the recordings to the noise (augmented, or a baseline adequate), else
    why not (what the named physics left, or a residual no entry explains)."""
    if d.verdict is Verdict.PARTLY_EXPLAINED and d.left is not None:
        return f"misspecified: partly explained: {left_line(d.left)} (diagnosis.json)"
    if d.verdict is Verdict.UNEXPLAINED:
        learned = any(isinstance(e, LearnedForce) for e in d.final.extensions)
        return ("misspecified: unexplained residual: no catalogue entry explains what the "
                "baseline leaves" + (" (a learned force correction stands in for it)"
                                     if learned else "") + " (diagnosis.json)")
    return None


def report_markdown(content: dict, figs: dict, out_dir: Path) -> str:
    """``report.md``: verdict, what was named, tables, figures."""
    lines = ["# Diagnosis", "", f"**Verdict: {content['verdict']}**", ""]
    b, f = content["baseline"], content["final"]
    lines += [f"Baseline NRMSE {b['nrmse_percent']:.4f} % (mean (e/σ)² "
              f"{b['chi2_per_sample']:.3f}); final {f['nrmse_percent']:.4f} % "
              f"({f['chi2_per_sample']:.3f}). Model terms: {', '.join(f['terms'])}.", "",
              "The final model (the baseline and what was named, refitted) is "
              "`params.json`, the baseline `baseline_params.json`: `stickslip simulate "
              "--params params.json` runs it"
              + ("" if content["verdict"] in (Verdict.AUGMENTED, Verdict.BASELINE_ADEQUATE)
                 else " (marked misspecified: it does not describe these recordings to "
                      "the noise)") + ".", ""]
    sig = content.get("significance") or {}
    if sig:
        lines += [f"Tolerance of the noise: mean (e/σ)² within 1 + "
                  f"{sig['tolerance_chi2']:.3g} ({sig['tolerance_nm']:.3g} nm RMS): "
                  f"{sig['z']:g} standard errors of the noise estimate "
                  f"({sig['noise_estimate_se_chi2']:.3g}) plus the simulator's numerical "
                  f"error ({sig['numerical_chi2']:.2g}). Less than this is not told "
                  f"from noise, and no entry is named for removing less.", ""]
    lines += ["## Missing physics, best first", ""]
    if content["missing_physics"]:
        lines += ["| name | NRMSE before | NRMSE after | removed [nm RMS] | ΔBIC | "
                  "parameters |", "|---|---|---|---|---|---|"]
        for m in content["missing_physics"]:
            spread = m.get("params_interval_95") or {}
            params = ", ".join(f"{k}={v:.4g}" + (f" [{spread[k][0]:.3g}, {spread[k][1]:.3g}]"
                                                  if k in spread else "")
                               for k, v in m["params"].items())
            removed = m["evidence"].get("removed_nm")
            removed = "" if removed is None else f"{removed:.3g}"
            name = m["name"] + (" (partial)" if m.get("partial") else "")
            lines.append(f"| {name} | {m['nrmse_before_percent']:.4f} % | "
                         f"{m['nrmse_after_percent']:.4f} % | {removed} | "
                         f"{m['criterion_delta']:.1f} | {params} |")
            if m.get("form"):
                lines.append(f"|  | {m['form']} | | | | |")
            ind = m["evidence"]["indistinguishable_from"]
            if ind:
                lines.append(f"|  | indistinguishable from: {', '.join(ind)} (refitted: "
                             f"{', '.join(f'`rivals/{n}.json`' for n in ind)}) | | | | |")
    else:
        lines.append("None accepted.")
    lines += ["", f"Criterion: {content['criterion']}.", ""]
    if "left" in content:
        lines += _left_markdown(content["left"])
    if "unexplained" in content:
        u = content["unexplained"]
        lines += ["## Unexplained residual", "",
                  ("The named entries leave it. " if content["missing_physics"] else
                   "No catalogue entry explains it. ")
                  + f"A learned force correction depends on: "
                  f"{', '.join(u['depends_on']) or 'nothing significant'} (ΔBIC "
                  f"{u['criterion_delta']:.1f}, mean (e/σ)² {u['chi2_before']:.3f} → "
                  f"{u['chi2_after']:.3f}).", ""]
    if content["notes"]:
        lines += ["## Notes", ""] + [f"- {n}" for n in content["notes"]] + [""]
    lines += ["## Candidates scored", ""]
    for i, rnd in enumerate(content["candidates_by_round"], 1):
        lines += [f"Round {i}:", "",
                  "| name | score | sizing drop (baseline held, free) | refitted | ΔBIC "
                  "| explained | note |",
                  "|---|---|---|---|---|---|---|"]
        for c in rnd:
            dbic = "" if c["criterion_delta"] is None else f"{c['criterion_delta']:.1f}"
            ex = ("" if c["explained_share_of_excess"] is None
                  else f"{100 * c['explained_share_of_excess']:.0f} %")
            lines.append(f"| {c['name']} | {c['score_statistic']:.3g} | "
                         f"{_sizing_drops(c)} | {c['refitted']} | "
                         f"{dbic} | {ex} | {c['note']} |")
        lines.append("")
    if any(UNCONVERGED_MARK in line for line in lines):
        lines += [f"{UNCONVERGED_MARK}: the sizing stopped at its step cap, short of its "
                  "optimum.", ""]
    if content.get("detection_limits"):
        lines += ["## Detection limits on these recordings", "",
                  "The smallest strength of each entry that a refit could name (its "
                  "effect beyond what the baseline can mimic reaches the tolerance), and "
                  "the RMS the effect itself adds to the traces at that strength.", "",
                  "| entry | strength | effect [nm RMS] | probe |", "|---|---|---|---|"]
        for name, lim in content["detection_limits"].items():
            lines.append(f"| {name} | {lim['strength']:.3g} {lim['unit']} | "
                         f"{lim['effect_nm']:.3g} | {lim['probe']} |")
        lines.append("")
    if content["indistinguishable_here"]:
        lines += ["Cannot be tested with these recordings:", ""]
        lines += [f"- `{k}`: {v}" for k, v in content["indistinguishable_here"].items()]
        lines.append("")
    lines += ["## Where the baseline misses", ""]
    if content["residual_peaks_Hz"]:
        lines += ["Peaks of the residual spectrum shared by several recordings "
                  "(unmodelled resonances?): "
                  + ", ".join(f"{p:.0f} Hz" for p in content["residual_peaks_Hz"]) + ".", ""]
    lines += [
              "| recording | regime | (e/σ)² | Ljung-Box p | dominant phase | band [Hz] |",
              "|---|---|---|---|---|---|"]
    for m in content["mismatch"]:
        s = m["statistic"]
        lines.append(f"| {m['recording']} | {m['regime']} | {s['chi2_per_sample']:.2f} | "
                     f"{s['ljung_box_p']:.1e} | {s['dominant_phase']} | "
                     f"{m['band_Hz'][0]:.0f}-{m['band_Hz'][1]:.0f} |")
    lines.append("")
    for name, p in figs.items():
        lines += [f"![{name}]({p.relative_to(out_dir).as_posix()})", ""]
    return "\n".join(lines)


def plot_forms(accepted, path) -> bool:
    """The form each accepted entry's refit found (:meth:`~.catalogue.base.
    CatalogueEntry.plot_form`: the creep spectrum, ...), with the 95 % band of its
    refit's errors where the form draws one (:mod:`.form_band`), one panel each;
    False, and nothing written, when none of them has a figure."""
    fig, axes = subplots(1, len(accepted), figsize=(4.2 * len(accepted), 3.4),
                         squeeze=False)
    drawn = [candidate(c.name).plot_form(ax, c.params, draws=c.param_draws)
             for c, ax in zip(accepted, axes[0], strict=True)]
    for ax, done in zip(axes[0], drawn, strict=True):
        if not done:
            ax.set_visible(False)
    if any(drawn):
        fig.tight_layout()
        save_figure(fig, path)
    return any(drawn)


def plot_residual_map(d: Diagnosis, path):
    """Mean (e/σ)² per recording [-] (the residual's power over the noise's), baseline
    and final, in recording order with each one's regime under its name, on a log axis
    with the noise level (1) marked."""
    names = [a.recording for a in d.analyses_baseline]
    x = np.arange(len(names))
    fig, ax = subplots(figsize=(max(6, 0.45 * len(names)), 4.2))
    base = [a.chi2 for a in d.analyses_baseline]
    ax.bar(x - 0.2, base, 0.4, label="baseline model")
    ax.bar(x + 0.2, [a.chi2 for a in d.analyses_final], 0.4, label="final model")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="noise level: (e/σ)² = 1")
    ax.set_yscale("log")
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi * (hi / lo) ** 0.35)  # head room for the legend above the bars
    ax.set_xticks(x, [f"{n}\n{a.regime}" for n, a in zip(names, d.analyses_baseline,
                                                          strict=True)],
                  rotation=90, fontsize=7)
    ax.set_xlabel("recording (regime)")
    ax.set_ylabel("mean (residual/σ)² [-]")
    ax.set_title(f"Residual by recording and regime — {d.verdict}", fontsize=10)
    ax.legend(fontsize=8, loc="upper left", ncol=3, framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _worst(d: Diagnosis, n: int) -> np.ndarray:
    """Indices of the ``n`` recordings with the largest baseline (e/σ)²."""
    return np.argsort([-a.chi2 for a in d.analyses_baseline])[:n]


def plot_overlays(d: Diagnosis, path, n: int = 4):
    """Measured vs baseline vs final output q [µm] (top), and both residuals [nm] with
    the ±1σ noise band (bottom), for the worst recordings; every panel labelled, a
    legend in each row."""
    order = _worst(d, n)
    fig, axes = subplots(2, len(order), figsize=(3.8 * len(order), 5.8), squeeze=False)
    for j, i in enumerate(order):
        rec = d.data.recordings[i]
        t = rec.time_s * 1e3
        e0 = residual_of(rec, d.q_baseline[i])
        e1 = residual_of(rec, d.q_final[i])
        q = rec.position_m
        # Measured beneath (wide, light) so that the models drawn on it stay visible.
        axes[0, j].plot(t, q * 1e6, color="0.55", lw=2.6, alpha=0.8, label="measured")
        axes[0, j].plot(t, (q - e0) * 1e6, color="tab:red", lw=0.8, label="baseline model")
        axes[0, j].plot(t, (q - e1) * 1e6, color="tab:blue", lw=0.8, ls=(0, (4, 2)),
                        label="final model")
        axes[0, j].set_title(rec.name, fontsize=8)
        axes[0, j].set_xlabel("t [ms]", fontsize=8)
        axes[0, j].set_ylabel("q [µm]", fontsize=8)
        sigma_nm = float(d.sigmas[i]) * 1e9
        axes[1, j].axhspan(-sigma_nm, sigma_nm, color="tab:orange", alpha=0.3, lw=0,
                           label=f"±1σ noise ({sigma_nm:.3g} nm)")
        axes[1, j].plot(t, e0 * 1e9, color="tab:red", lw=0.6, label="baseline")
        axes[1, j].plot(t, e1 * 1e9, color="tab:blue", lw=0.6, label="final")
        lo, hi = axes[1, j].get_ylim()
        axes[1, j].set_ylim(lo, hi + 0.45 * (hi - lo))  # head room for the legend
        axes[1, j].set_xlabel("t [ms]", fontsize=8)
        axes[1, j].set_ylabel("measured − model [nm]", fontsize=8)
        axes[1, j].legend(fontsize=6, loc="upper right", framealpha=0.85)
        for ax in axes[:, j]:
            ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7, loc="best", framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_residual_psd(d: Diagnosis, path, n: int = 4):
    """Residual PSD over the noise's (white noise of each recording's σ: σ²·dt in
    :func:`~stickslip_jax.identify.residuals.periodogram_psd`'s normalisation), baseline (solid)
    and final (dotted) in one colour per recording, worst recordings."""
    from ..plots import colormap

    order = _worst(d, n)
    fig, ax = subplots(figsize=(7.5, 4.4))
    colours = colormap("tab10")(np.arange(len(order)) % 10)
    for colour, i in zip(colours, order, strict=True):
        rec = d.data.recordings[i]
        level = d.sigmas[i] ** 2 * rec.dt
        for q, ls, what in ((d.q_baseline[i], "-", "baseline"), (d.q_final[i], ":", "final")):
            f, p = periodogram_psd(residual_of(rec, q), rec.dt, np)
            ax.loglog(f[1:], p[1:] / level, ls=ls, lw=0.9 if ls == ":" else 0.7,
                      color=colour, label=f"{rec.name} ({what})")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="noise level (white, σ of each "
                                                       "recording)")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("residual PSD / noise PSD [-]")
    ax.set_title(f"Residual spectrum, {len(order)} worst recordings: baseline (solid), "
                 f"final (dotted)", fontsize=10)
    ax.grid(True, which="major", alpha=0.25)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)

"""The next recordings: the drives that settle what a diagnosis left open.

:func:`design_experiment` reads a diagnosis's outputs (``diagnosis.json``, the final
model ``params.json``, ``baseline_params.json`` and the rivals ``rivals/NAME.json``) and
asks its questions (:mod:`.hypotheses`): each tie between a named entry and a rival,
and each entry not named at the strength of its detection limit. Every candidate drive
(:mod:`.drives`) is simulated once with each model and its Jacobian taken, beside the
user's recordings, through the diagnosis's own whitened residual
(:class:`~stickslip_jax.diagnose.problem.Problem`; the new recordings at the user's
median noise level). Each question's evidence on any choice of recordings then follows
from per-recording summaries (:mod:`.evidence`), without simulating again.

The plan is chosen greedily within the total recording time: at each step the unit of
recording that raises ``Σ_q log(λ_q/τ)`` most per second, where ``λ_q/τ`` is the
question's evidence over the tolerance the diagnosis would need to exceed. The sum of
logarithms weighs every question alike whatever its scale (for the detection limits it
is the product of the limits after, minimised), and stops paying for a question only as
fast as its evidence grows. The same recording time spent on the user's own protocol
(the recordings given, each taken proportionally longer) is what the plan is compared
with.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..blas_threads import one_blas_thread
from ..diagnose.catalogue import NAMES, candidate
from ..diagnose.config import DiagnoseConfig
from ..diagnose.problem import Problem, baseline_free
from ..diagnose.run import locate_phase
from ..diagnose.scores import install_probes
from ..identify.dataset import Dataset
from ..identify.parameters import set_quantity
from ..model.actuator import Actuator
from ..noise import noise_sigma, noise_sigma_relative_se
from ..params import load_params
from ..significance import SIGNIFICANCE_Z
from ..simulate import simulate_recordings
from ..synthetic import DriveSpec
from .drives import DriveLimits, candidate_drives
from .evidence import Separation, separation_of, tolerance_rss
from .hypotheses import Hypothesis, Question

RATIO_FLOOR = 1e-300
"""The least evidence ratio a logarithm is taken of (a question no recording can
touch keeps a constant term)."""


@dataclass(frozen=True)
class QuestionOutcome:
    """One question's evidence over the tolerance (``λ/τ``, ≥ 1: the diagnosis tells
    the two models apart) now, after the protocol repeated for the same time, and after
    the plan; for a ``limit`` question also the detection limit each gives [``unit``]."""

    label: str
    kind: str
    entry: str
    ratio_now: float
    ratio_default: float
    ratio_designed: float
    unit: str = ""
    limit_now: float | None = None
    limit_default: float | None = None
    limit_designed: float | None = None


@dataclass(frozen=True)
class PlannedRecording:
    """One recording of the plan: ``drive`` (its duration ``units`` candidate units)
    and the question its units raised most (``serves``)."""

    drive: DriveSpec
    units: int
    serves: str


@dataclass(frozen=True)
class ExperimentPlan:
    """What :func:`design_experiment` proposes and what it expects of it."""

    recordings: tuple[PlannedRecording, ...]
    questions: tuple[QuestionOutcome, ...]
    total_time_s: float
    noise_nm: float
    limits: DriveLimits
    candidates: int
    tolerances: tuple[float, float, float] = (np.nan, np.nan, np.nan)
    """The tolerance ``τ`` [whitened RSS] now, after the protocol again and after the
    plan: a question's expected excess cost ``λ`` is its ratio times these."""
    asked: tuple[Question, ...] = ()
    """The questions as asked, in the order of :attr:`questions`: their models (a
    ``limit`` question's truth at the strength found on these recordings)."""
    notes: tuple[str, ...] = ()
    timings_s: dict = dataclasses.field(default_factory=dict)

    @property
    def planned_time_s(self) -> float:
        return float(sum(r.drive.duration_s for r in self.recordings))


@dataclass(frozen=True)
class _Asked:
    """A question with its separations (one way, or both ways of a tie) and, for a
    limit, the entry's strength in the truth."""

    question: Question
    ways: tuple[Separation, ...]

    def ratio(self, weights, tol: float) -> float:
        return max(min(w.at(weights) for w in self.ways) / tol, RATIO_FLOOR)


def _load_outputs(diagnosis: str | Path) -> tuple[Path, dict]:
    """The folder of a diagnosis's outputs and its ``diagnosis.json`` (``diagnosis``:
    the file or its folder)."""
    path = Path(diagnosis)
    folder = path if path.is_dir() else path.parent
    json_path = folder / "diagnosis.json"
    if not json_path.is_file():
        raise FileNotFoundError(f"{json_path}: no diagnosis.json; run `stickslip diagnose "
                                f"... --out {folder}` first")
    for name in ("params.json", "baseline_params.json"):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"{folder / name}: missing; diagnoses written before "
                                    f"parameter files held their models lack it: run the "
                                    f"diagnosis again")
    return folder, json.loads(json_path.read_text(encoding="utf-8"))


def _config_of(content: dict) -> DiagnoseConfig:
    """The residual-peak settings the diagnosis ran with (its probes' hints)."""
    record = content.get("config") or {}
    keep = {}
    for name in ("n_peaks", "peak_min_level", "peak_octaves"):
        if name in record:
            keep[name] = record[name]
    if "peak_band_Hz" in record:
        keep["peak_band_Hz"] = tuple(record["peak_band_Hz"])
    return DiagnoseConfig(**keep)


def ask_questions(content: dict, final: Actuator, baseline: Actuator,
                  rivals: dict[str, Actuator], hints: dict,
                  entries: Sequence[str] | None = None) -> tuple[list[Question], list[str]]:
    """The questions a diagnosis leaves (:mod:`.hypotheses`) and notes on those it
    could not ask: ties of each named entry with each rival written, then every entry
    with a detection limit that was not named and is not a rival, at that limit on the
    final model. By default a diagnosis with a tie asks its ties alone: an entry named
    but not told from a rival is the answer in doubt, and the plan's time is not spread
    over the limits of a dozen entries nobody named. ``entries``: ask about these (the
    ties they take part in and their limits), whatever else there is."""
    named = [m["name"] for m in content.get("missing_physics", [])]
    final_h = Hypothesis.of("+".join(named) or "baseline", final)
    questions: list[Question] = []
    notes: list[str] = []
    tied: set[str] = set()
    for m in content.get("missing_physics", []):
        for rival in m.get("evidence", {}).get("indistinguishable_from", []):
            if entries is not None and rival not in entries and m["name"] not in entries:
                continue
            if rival not in rivals:
                notes.append(f"{rival}: tied with {m['name']} but rivals/{rival}.json is "
                             f"missing; not asked")
                continue
            tied.add(rival)
            questions.append(Question("tie", rival, final_h,
                                      Hypothesis.of(rival, rivals[rival])))
    for name, why in (content.get("indistinguishable_here") or {}).items():
        if entries is None or name in entries:
            notes.append(f"{name}: not asked, no drive settles it ({why})")
    for name, lim in (content.get("detection_limits") or {}).items():
        if name in named or name in tied or name not in NAMES:
            continue
        if entries is not None and name not in entries:
            continue
        entry = candidate(name)
        label = lim.get("probe")
        if not any(p.label == label for p in entry.probes(final, hints)):
            notes.append(f"{name}: its detection limit's probe ({label}) is not among its "
                         f"probes on the final model; not asked")
            continue

        def at_strength(s, entry=entry, label=label):
            return probe_at(final, entry, hints, label, s)

        try:
            truth = at_strength(lim["strength"])
        except ValueError as err:
            notes.append(f"{name}: cannot be added to the final model ({err}); not asked")
            continue
        questions.append(Question("limit", name, Hypothesis.of(f"{name} at its limit", truth),
                                  final_h, float(lim["strength"]), lim.get("unit", ""),
                                  at_strength))
    if entries is None and any(q.kind == "tie" for q in questions):
        limits = [q.entry for q in questions if q.kind == "limit"]
        questions = [q for q in questions if q.kind == "tie"]
        if limits:
            notes.append(f"the ties asked alone; the detection limits of {', '.join(limits)}"
                         f" are asked with --entries")
    return questions, notes


def probe_at(act: Actuator, entry, hints: dict, label: str, strength: float) -> Actuator:
    """``act`` with every probe of ``entry`` installed as the score test installs them
    (:func:`~stickslip_jax.diagnose.scores.install_probes`), the one labelled ``label``
    at ``strength`` (in its spec's unit) and the others at zero: the model the score
    test's column is the derivative of, so that the question asks about the effect the
    detection limit was stated for. (An entry's :meth:`~stickslip_jax.diagnose.catalogue.
    CatalogueEntry.attach` starts a refit instead, and floors some strengths.)"""
    probe_act, installed = install_probes(act, [entry], hints)
    chosen = next((e for e in installed if e.probe.label == label), None)
    if chosen is None:  # install_probes skips a probe whose slot a named part holds
        raise ValueError(f"the slot of its probe {label!r} is taken")
    # The strength is the move from the probe's zero (a linear spec: start + strength;
    # a Stribeck ratio starts at 1).
    node = chosen.spec.getter(probe_act)
    start = np.array([float(x) for x in node] if isinstance(node, tuple) else node,
                     dtype=float)
    if start.ndim == 0:
        return set_quantity(chosen.spec.getter, probe_act, float(start) + float(strength))
    start[chosen.index] += float(strength)
    return set_quantity(chosen.spec.getter, probe_act, start)


def _residual_and_jacobian(problem: Problem, hyp: Hypothesis):
    names = baseline_free(hyp.actuator, problem.data, problem.fix) + list(hyp.specs)
    program = problem.program(hyp.actuator, names, hyp.specs)
    r, jac = program(np.zeros(program.pmap.size))
    return np.asarray(r), np.asarray(jac)


LIMIT_ITERATIONS = 3
"""Strengths tried at most per ``limit`` question to find where the entry's effect just
reaches the tolerance on the recordings so far (:func:`_at_the_limit`)."""
LIMIT_MATCH = 1.25
"""A strength whose evidence is within this factor of the tolerance is at the limit."""


def recorded_limit(content: dict, entry: str) -> float:
    """The first-order detection limit the diagnosis recorded for ``entry``."""
    return float(content["detection_limits"][entry]["strength"])


def _at_the_limit(q: Question, problem: Problem, fit: tuple, rows, tol_now: float,
                  now: np.ndarray) -> tuple[Question, tuple[Separation, ...]]:
    """``q`` at the strength where the entry's whole effect (not its first-order
    column, as the score test's limit) reaches the tolerance on the recordings so far,
    and its separation there. The evidence grows as the strength squared for a small
    effect: each try rescales by ``√(τ/λ)``; at most :data:`LIMIT_ITERATIONS` tries,
    the one closest to the tolerance kept (an effect that switches on at a threshold,
    a slew limit, is not quadratic)."""
    r_fit, jac = fit
    strength, best = q.strength, None
    for _ in range(LIMIT_ITERATIONS):
        truth = q.at_strength(strength)
        sep = Separation.of(r_fit - problem.whitened_residual(truth)[0], jac, rows)
        ratio = sep.at(now) / tol_now
        if ratio > 0 and (best is None or abs(np.log(ratio)) < abs(np.log(best[2]))):
            best = (strength, truth, ratio, sep)
        if ratio <= 0 or abs(np.log(ratio)) <= np.log(LIMIT_MATCH):
            break
        strength = strength / np.sqrt(ratio)
    if best is None:  # no strength tried shows: keep the first
        return q, (sep,)
    strength, truth, _, sep = best
    return dataclasses.replace(q, strength=float(strength), truth=dataclasses.replace(
        q.truth, actuator=truth)), (sep,)


def _greedy(asked: Sequence[_Asked], durations: np.ndarray, base: np.ndarray,
            tol: Callable[[np.ndarray], float], budget_s: float):
    """Units added one at a time (module docstring) until none fits in ``budget_s`` or
    none raises the objective: the weights, and per unit taken (candidate index, index
    of the question it raised most). Each trial adds one recording's summaries to the
    running totals of every question (:meth:`~.evidence.Separation.totals`)."""
    w = base.copy()
    n_old = len(base) - len(durations)
    used, taken = 0.0, []
    totals = [[way.totals(w) for way in a.ways] for a in asked]

    def logs(tots, t):
        return np.array([np.log(max(min(separation_of(*x) for x in ways) / t,
                                    RATIO_FLOOR)) for ways in tots])

    def added(tots, k):
        return [[(D + way.D[k], g + way.g[k], K + way.K[k])
                 for (D, g, K), way in zip(ways, a.ways, strict=True)]
                for ways, a in zip(tots, asked, strict=True)]

    now = logs(totals, tol(w))
    while True:
        best = None
        for c, dur in enumerate(durations):
            if used + dur > budget_s * (1 + 1e-9):
                continue
            trial = w.copy()
            trial[n_old + c] += 1.0
            tots = added(totals, n_old + c)
            after = logs(tots, tol(trial))
            rate = float(np.sum(after - now)) / dur
            if best is None or rate > best[0]:
                best = (rate, c, after, tots)
        if best is None or best[0] <= 0.0:
            return w, taken
        _, c, after, totals = best
        w[n_old + c] += 1.0
        used += durations[c]
        taken.append((c, int(np.argmax(after - now))))
        now = after


@one_blas_thread
def design_experiment(recordings: Sequence, diagnosis: str | Path, *,
                      total_time_s: float | None = None, limits: DriveLimits | None = None,
                      fix: dict | None = None, entries: Sequence[str] | None = None,
                      candidates: Sequence[DriveSpec] | None = None,
                      echo: Callable[[str], None] | None = None) -> ExperimentPlan:
    """The next recordings for the diagnosis written in ``diagnosis`` (its folder or
    ``diagnosis.json``) of ``recordings`` (module docstring).

    ``total_time_s``: recording time the plan may take [s] (default: as long as
    ``recordings`` together); ``limits``: what the amplifier allows (default:
    :meth:`~.drives.DriveLimits.from_recordings`); ``fix``: quantities the diagnosis
    held (as ``stickslip diagnose --fix``); ``entries``: ask only about these;
    ``candidates``: the drives to choose from (default: :func:`~.drives.
    candidate_drives` of the limits)."""
    say = echo or (lambda _msg: None)
    t_start = time.perf_counter()
    folder, content = _load_outputs(diagnosis)
    recordings = list(recordings)
    fix = dict(fix or {})
    final = load_params(folder / "params.json")
    baseline = load_params(folder / "baseline_params.json")
    rivals = {p.stem: load_params(p) for p in sorted((folder / "rivals").glob("*.json"))}
    limits = limits or DriveLimits.from_recordings(recordings)
    total_time_s = float(total_time_s if total_time_s is not None
                         else sum(r.n * r.dt for r in recordings))
    if not total_time_s > 0:
        raise ValueError(f"total_time_s must be positive, got {total_time_s!r}")

    old = Dataset.from_recordings(recordings)
    sigmas_old = np.array([noise_sigma(r) for r in recordings])
    se_old = np.array([noise_sigma_relative_se(r) for r in recordings])
    significance = content.get("significance") or {}
    z = float(significance.get("z", SIGNIFICANCE_Z))
    numerical_nm = significance.get("numerical_error_nm") or []
    numerical_old = (np.asarray(numerical_nm, dtype=float) * 1e-9
                     if len(numerical_nm) == len(recordings) else np.zeros(len(recordings)))

    problem_old = Problem(old, sigmas_old, fix, None)
    q_base = problem_old.evaluate(baseline)[2]
    hints = locate_phase(problem_old, q_base, _config_of(content))[2]
    questions, notes = ask_questions(content, final, baseline, rivals, hints, entries)
    if not questions:
        raise ValueError("the diagnosis leaves no question to settle: no tie with a rival "
                         "and no entry with a detection limit" +
                         (f" ({'; '.join(notes)})" if notes else ""))
    say(f"[design] {len(questions)} questions: " + "; ".join(q.label for q in questions))

    specs = list(candidates) if candidates is not None else candidate_drives(limits)
    drives = [s.recording(limits.sample_rate_Hz) for s in specs]
    t0 = time.perf_counter()
    q_new = simulate_recordings(final, drives)
    new = [rec.with_position_m(q) for rec, q in zip(drives, q_new, strict=True)]
    sigma_new = float(np.median(sigmas_old))
    sigmas = np.concatenate([sigmas_old, np.full(len(new), sigma_new)])
    counts = np.array([r.n for r in recordings] + [r.n for r in new], dtype=float)
    # The new recordings' σ known as well per sample as the user's recordings' are
    # (their median): the estimator's own spread, not the ideal Gaussian formula.
    per_sample = float(np.median(se_old * np.sqrt([r.n for r in recordings])))
    se = np.concatenate([se_old, [per_sample / np.sqrt(r.n) for r in new]])
    numerical = np.concatenate([(numerical_old / sigmas_old) ** 2,
                                np.full(len(new), float(np.median(
                                    (numerical_old / sigmas_old) ** 2)))])
    problem = Problem(Dataset.from_recordings(recordings + new), sigmas, fix, None)
    width = problem.data.mask.shape[1]
    rows = [slice(i * width, (i + 1) * width) for i in range(len(counts))]
    say(f"[design] {len(new)} candidate drives, each simulated with every model "
        f"(noise {sigma_new * 1e9:.2f} nm)")

    cache: dict[int, tuple] = {}

    def with_jacobian(hyp: Hypothesis):
        if id(hyp) not in cache:
            cache[id(hyp)] = _residual_and_jacobian(problem, hyp)
        return cache[id(hyp)]

    def tol(weights):
        return tolerance_rss(weights, counts, se, numerical, z)

    n_old = len(recordings)
    now = np.concatenate([np.ones(n_old), np.zeros(len(new))])
    asked = []
    for i, q in enumerate(questions):
        if q.kind == "limit":
            q, ways = _at_the_limit(q, problem, with_jacobian(q.rival), rows, tol(now), now)
            questions[i] = q
            say(f"[design] {q.entry}: at its limit on these recordings at {q.strength:.3g} "
                f"{q.unit} (the diagnosis's first-order limit: "
                f"{recorded_limit(content, q.entry):.3g})")
        else:
            r_a, jac_a = with_jacobian(q.truth)
            r_b, jac_b = with_jacobian(q.rival)
            ways = (Separation.of(r_b - r_a, jac_b, rows),
                    Separation.of(r_a - r_b, jac_a, rows))
        asked.append(_Asked(q, ways))
    t_models = time.perf_counter() - t0

    old_time = float(sum(r.n * r.dt for r in recordings))
    default = now.copy()
    default[:n_old] += total_time_s / old_time
    durations = np.array([s.duration_s for s in specs])
    t0 = time.perf_counter()
    designed, taken = _greedy(asked, durations, now, tol, total_time_s)
    t_choose = time.perf_counter() - t0

    outcomes = []
    for a in asked:
        ratios = [a.ratio(w, tol(w)) for w in (now, default, designed)]
        q = a.question
        lim = ([q.strength * float(np.sqrt(1.0 / r)) if r > RATIO_FLOOR else float("inf")
                for r in ratios] if q.kind == "limit" else [None] * 3)
        outcomes.append(QuestionOutcome(q.label, q.kind, q.entry, *ratios, unit=q.unit,
                                        limit_now=lim[0], limit_default=lim[1],
                                        limit_designed=lim[2]))
    planned = []
    for c in sorted({c for c, _ in taken}, key=lambda c: [t[0] for t in taken].index(c)):
        units = sum(1 for k, _ in taken if k == c)
        served = [qi for k, qi in taken if k == c]
        serves = questions[max(set(served), key=served.count)].label
        planned.append(PlannedRecording(
            dataclasses.replace(specs[c], duration_s=round(units * specs[c].duration_s, 12)),
            units, serves))
    if not planned:
        notes.append("no candidate drive adds evidence to any question: the plan is empty")
    timings = {"models_s": t_models, "choose_s": t_choose,
               "total_s": time.perf_counter() - t_start}
    say(f"[design] {len(planned)} recordings, {sum(r.drive.duration_s for r in planned):.3g}"
        f" s of {total_time_s:.3g} s")
    return ExperimentPlan(tuple(planned), tuple(outcomes), total_time_s, sigma_new * 1e9,
                          limits, len(specs),
                          tuple(float(tol(w)) for w in (now, default, designed)),
                          tuple(questions), tuple(notes), timings)

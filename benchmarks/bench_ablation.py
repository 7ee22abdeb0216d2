"""Does each refit pass and each tuned threshold of the diagnosis earn its place (#66)?

Reads the rows of ``bench_diagnose_split.py`` runs of a development split, or of
``bench_diagnose.py`` runs of the concealed sets and their variants (never the frozen
test split: that would be tuning on it) and answers from what each row recorded
(every entry's score, sizings, refit, status and the pass that refitted it):

- **Passes**: a pass switched off changes a set's answer only through its refits: one
  accepted (in any round) or named indistinguishable from the accepted one, or the
  work it spent when the set's work budget skipped something. Per pass: the sets it
  refitted on, those where it was *decisive* (one of its refits accepted or a named
  rival) and those budget-bound; elsewhere switching it off changes nothing (the
  diagnosis is deterministic and the passes before it do not read it). ``--rerun``
  diagnoses the decisive and budget-bound sets again without the pass and reports
  what they name then.
- **Thresholds**: each :class:`~stickslip_jax.diagnose.Policy` field moved by a
  factor of two each way, and the rule it sets switched off (:data:`RULE_OFF`), the
  decisions it gates replayed on the recorded numbers of
  every round (which entries are sized, which refitted first, which accepted and
  whether partly, whether the second look opens). A threshold under which no gate
  flips on any set changes nothing there; where one flips, the set is listed (the
  decisions after the flip are not replayed: a rerun says them). Not replayable from
  the records: ``significance_z`` (it sets the tolerance that every cost is measured
  against), ``reidentify_polish_gain`` (the polish gain is not in the rows) and
  ``learned_t_min`` (the learned correction's features).

    .venv/bin/python benchmarks/bench_ablation.py out/abl/dev_a.json out/abl/dev_b.json \\
        --json benchmarks/results/ablation_dev.json \\
        [--rerun --fields explained_min,second_look_chi2 --reruns-json out/reruns.json --part 0/2]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import stickslip_jax as ss  # noqa: E402

# Before SEEDED below runs JAX: the reruns diagnose in this process, about 3x slower
# on a CPU without the native small loops.
ss.fast_cpu_loops()

from stickslip_jax.diagnose import CATALOGUE, Policy  # noqa: E402
from stickslip_jax.diagnose.passes import PASS_NAMES  # noqa: E402
from stickslip_jax.diagnose.report import entry_from_record  # noqa: E402
from stickslip_jax.diagnose.results import CandidateResult, CandidateStatus  # noqa: E402
from stickslip_jax.diagnose.rules import (  # noqa: E402
    acceptable,
    acceptable_partly,
    any_explains,
    explains,
    far_from_noise,
    first_refits,
    rank_value,
)
from stickslip_jax.diagnose.sizing import chosen_for_sizing  # noqa: E402

UNSIZED = {CandidateStatus.SCORED.value, CandidateStatus.NOT_SIZED.value}
DEVELOPMENT_SPLITS = ("dev", "dev2", "concealed")
"""The splits this reads (:mod:`stickslip_jax.testing.random_sets`, and the concealed
sets with their variants, ``bench_diagnose.py``'s rows); never a test split."""
NOT_REPLAYED = ("significance_z", "reidentify_polish_gain", "learned_t_min")
TOP = 3  # diagnose()'s default refits per round
RULE_OFF = {
    "score_min": 0.0,            # every entry may be sized, however little it scores
    "bic_min": math.inf,         # no ΔBIC test in an acceptance or a rival
    "explained_min": 0.0,        # any share explains: no "partly", no structured rest
    "partial_min": math.inf,     # no partial answers
    "excess_min": 0.0,           # shares of the excess taken however small it is
    "competitive_share": 0.0,    # every promising entry of the top gets a first refit
    "leader_alone_share": math.inf,  # the leader never refitted alone
    "leader_alone_lead": math.inf,   # no competitor keeps its first refit beside it
    "later_score_share": 0.0,    # a later round sizes by score_min alone
}
"""Per rule-setting :class:`~stickslip_jax.diagnose.Policy` field, the value that
switches its rule off (the rule's test always passes, or never fires). Not here:
``size_at_most`` (work, not a rule) and ``second_look_chi2`` (its pass is opt-in, so
off by default)."""
SEEDED = {c.name for c in CATALOGUE if c.seeds(ss.lu2015_slc1720())}
"""Entries with seeds on the split's start (the profile)."""


def samples(row: dict) -> float | None:
    """``N``, the samples of the whitened cost: a refit's cost before over the row's
    (e/σ)² per sample of the baseline (None when nothing was refitted)."""
    rss = next((c["rss_before"] for c in row["candidates_by_round"][0]
                if c.get("rss_before") is not None), None)
    return None if rss is None or not row.get("chi2_before") else rss / row["chi2_before"]


def accepted_in(refitted: list[CandidateResult], policy: Policy) -> tuple[str, bool] | None:
    """``(name, partial)`` that the acceptance (:func:`~stickslip_jax.diagnose.run.
    _accept`) takes among ``refitted``, None when none."""
    if not refitted:
        return None
    refitted = sorted(refitted, key=lambda r: r.criterion_delta)
    best = next((r for r in refitted if explains(r, policy)), refitted[0])
    if acceptable(best, policy):
        return best.name, False
    partly = next((r for r in refitted if acceptable_partly(r, policy)), None)
    return None if partly is None else (partly.name, True)


def gates(row: dict, policy: Policy) -> dict[str, list]:
    """Per gate, its decision in each recorded round under ``policy``."""
    n_obs = samples(row)
    out = {"sized": [], "first": [], "accepted": [], "second_look": []}
    if n_obs is None:
        return out
    rss = None  # the round's start: round one's from its refits, later the acceptance's
    for record in row["candidates_by_round"]:
        results = [entry_from_record(c) for c in record]
        refitted = [r for r in results if r.refitted]
        start = next((c["rss_before"] for c in record if c.get("rss_before") is not None),
                     rss)
        excess = None if start is None else start - n_obs
        chosen = chosen_for_sizing([CandidateResult(r.name, score=r.score) for r in results],
                                   SEEDED, policy.size_at_most,
                                   excess if out["accepted"] else None, lambda s: None,
                                   policy)
        out["sized"].append(sorted(r.name for r in chosen if abs(r.score) >= policy.score_min))
        ranked = sorted([r for r in results if r.status.value not in UNSIZED],
                        key=lambda r: -rank_value(r))
        above = excess if excess is not None and excess > policy.excess_min * n_obs else None
        out["first"].append(sorted(r.name for r in first_refits(ranked, TOP, above, policy)))
        out["accepted"].append(accepted_in(refitted, policy))
        out["second_look"].append(any_explains(refitted, policy)
                                  and far_from_noise(refitted, n_obs, policy))
        best = next((r for r in refitted if r.name == (out["accepted"][-1] or ("",))[0]),
                    None)
        rss = None if best is None else best.rss_after
    return out


def moved(policy: Policy, name: str, factor: float) -> Policy:
    value = getattr(policy, name) * factor
    return dataclasses.replace(policy, **{name: int(round(value)) if name == "size_at_most"
                                          else value})


MOVES = ("x0.5", "x2", "off")
"""The threshold table's columns: half, twice, and the rule switched off
(:data:`RULE_OFF`; absent for a field not there)."""


def threshold_table(rows: list[dict]) -> list[dict]:
    """Per replayable Policy field and move (:data:`MOVES`): the sets where a gate
    flips."""
    default = Policy()
    base = {row["set"]: gates(row, default) for row in rows}
    table = []
    for field in dataclasses.fields(Policy):
        if field.name in NOT_REPLAYED:
            continue
        line = {"field": field.name, "default": getattr(default, field.name)}
        policies = {"x0.5": moved(default, field.name, 0.5),
                    "x2": moved(default, field.name, 2.0)}
        if field.name in RULE_OFF:
            policies["off"] = dataclasses.replace(default,
                                                  **{field.name: RULE_OFF[field.name]})
        for move, policy in policies.items():
            flips = {}
            for row in rows:
                now = gates(row, policy)
                changed = [g for g in now if now[g] != base[row["set"]][g]]
                if changed:
                    flips[row["set"]] = changed
            line[move] = {"value": getattr(policy, field.name), "flips": flips}
        table.append(line)
    return table


def pass_table(rows: list[dict]) -> list[dict]:
    """Per refit pass: the sets it refitted on, where it was decisive, budget-bound."""
    table = []
    for name in PASS_NAMES:
        used, decisive, bound = [], [], []
        for row in rows:
            mine = [c for rnd in row["candidates_by_round"] for c in rnd
                    if c.get("refit_pass") == name
                    or (name == "carry_on" and c.get("carried_on"))]
            if not mine:
                continue
            used.append(row["set"])
            rivals = set(row.get("indistinguishable_from") or [])
            if any(c["accepted"] or c["name"] in rivals for c in mine):
                decisive.append(row["set"])
            elif (row.get("work_budget") or {}).get("skipped"):
                bound.append(row["set"])
        table.append({"pass": name, "refitted_on": used, "decisive_on": decisive,
                      "budget_bound_on": bound})
    return table


def _without(name: str):
    """The default configuration without the pass ``name`` (rows made when an opt-in
    pass was a default: the default configuration itself)."""
    from stickslip_jax.diagnose import DiagnoseConfig  # noqa: PLC0415

    config = DiagnoseConfig()
    return config.without(name) if name in config.record()["passes"] else config


def unknown_names(fields: list[str], replayable: list[str], moves: tuple[str, ...]) -> str:
    """Why ``--fields``/``--moves`` name nothing this script can rerun ("" when they
    all can): a field removed from :class:`Policy`, one not replayed, or a typo would
    otherwise rerun nothing for it, silently."""
    bad_fields = [f for f in fields if f not in replayable]
    bad_moves = [m for m in moves if m not in MOVES]
    why = []
    if bad_fields:
        why.append(f"--fields: no replayable Policy field {', '.join(bad_fields)} "
                   f"(replayable: {', '.join(replayable)})")
    if bad_moves:
        why.append(f"--moves: no move {', '.join(bad_moves)} (moves: {', '.join(MOVES)})")
    return "\n".join(why)


def rerun(rows: list[dict], passes: list[dict], thresholds: list[dict],
          fields: list[str], out: Path | None, part: tuple[int, int],
          split: str = "dev", paired: bool = False,
          moves: tuple[str, ...] = MOVES) -> list[dict]:
    """Diagnose again each pass's decisive and budget-bound sets without it, and each
    set whose gates flip under a threshold of ``fields`` moved; ``part`` ``(k, n)``:
    the k-th of n interleaved shares of the runs (parallel processes); ``split`` the
    development split the rows are of (:data:`DEVELOPMENT_SPLITS`); ``paired``: each
    set rerun with the default configuration too (change ``"default"``), so that the
    change is judged against this commit, not against the rows' older one; ``moves``
    the threshold moves rerun (:data:`MOVES`). Appended to
    ``out`` as each ends; runs already there are skipped (resume)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_diagnose_split import run_one, work_spent  # noqa: PLC0415 (heavy)
    from results_record import commit_of  # noqa: PLC0415

    from stickslip_jax.diagnose import DiagnoseConfig  # noqa: PLC0415
    from stickslip_jax.testing import random_sets as rs  # noqa: PLC0415

    # Not the first refits: without them the fallback refits every sized entry, which
    # tests the fallback, not whether the first refits earn their place (they are the
    # core: every name on the split came from one).
    runs = [(f"without {p['pass']}", name, _without(p["pass"]))
            for p in passes if p["pass"] != "first"
            for name in p["decisive_on"] + p["budget_bound_on"]]
    for t in thresholds:
        if t["field"] not in fields:
            continue
        for move in moves:
            if move not in t:
                continue
            value = t[move]["value"]
            config = DiagnoseConfig(policy=dataclasses.replace(Policy(), **{t["field"]: value}))
            label = (f"{t['field']} off ({value:g})" if move == "off"
                     else f"{t['field']} = {value:g}")
            runs += [(label, name, config) for name in t[move]["flips"]]
    index = {row["set"]: row for row in rows}
    if paired:
        # Each set's default run beside its changes, the quickest sets (by the rows'
        # wall time) first: interleaved parts then run a pair side by side, and a run
        # stopped early leaves whole pairs.
        sets = sorted(dict.fromkeys(name for _, name, _ in runs),
                      key=lambda name: (index[name]["wall_s"], name))
        runs = [run for name in sets
                for run in [("default", name, DiagnoseConfig())]
                + [r for r in runs if r[1] == name]]
    done = json.loads(out.read_text())["reruns"] if out and out.exists() else []
    have = {(r["change"], r["set"]) for r in done}
    k, n = part
    for change, name, config in runs[k::n]:
        if (change, name) in have:
            continue
        row = index[name]
        print(f"== {name}, {change}", flush=True)
        seed, design = rs.SPLITS[split]
        again = run_one(rs.draw_set(seed, row["index"], design), False, config)
        done.append({"change": change, "set": name, "hidden": row["hidden"],
                     "named_with": row["named"], "verdict_with": row["verdict"],
                     "named_changed": again["named"], "verdict_changed": again["verdict"],
                     "wall_s_with": row["wall_s"], "wall_s_changed": again["wall_s"],
                     # What the change costs or saves: the counted work, not the wall.
                     "work_changed": work_spent(again), "commit": commit_of()})
        if out:
            out.write_text(json.dumps({"reruns": done}, indent=1, default=str))
    return done


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", nargs="+", type=Path, help="bench_diagnose_split.py rows (dev)")
    ap.add_argument("--json", dest="out", type=Path, default=None)
    ap.add_argument("--rerun", action="store_true",
                    help="diagnose each pass's decisive and budget-bound sets without it, "
                         "and the sets whose gates flip under --fields moved")
    ap.add_argument("--fields", default="", help="Policy fields whose flips --rerun runs")
    ap.add_argument("--moves", default=",".join(MOVES),
                    help=f"which of the fields' moves --rerun runs (of {', '.join(MOVES)})")
    ap.add_argument("--paired", action="store_true",
                    help="--rerun each set with the default configuration too, at this "
                         "commit (the rows may be older)")
    ap.add_argument("--reruns-json", type=Path, default=None,
                    help="where --rerun appends its runs (resumable)")
    ap.add_argument("--part", default="0/1", metavar="K/N",
                    help="--rerun's k-th of n interleaved shares (parallel processes)")
    args = ap.parse_args()
    rows, splits = [], set()
    for path in args.json:
        data = json.loads(path.read_text())
        if data.get("split") not in DEVELOPMENT_SPLITS or data.get("without_passes"):
            sys.exit(f"{path}: rows of a development split ({', '.join(DEVELOPMENT_SPLITS)}) "
                     f"with every pass, please")
        splits.add(data["split"])
        rows += [r for r in data["rows"] if r.get("candidates_by_round")]
    if len(splits) > 1:
        sys.exit(f"rows of one split at a time, please (got {', '.join(sorted(splits))}): "
                 f"their sets share names")
    split = splits.pop()
    if args.rerun and split == "concealed":
        sys.exit("--rerun diagnoses sets of a random split; rerun the concealed sets with "
                 "bench_diagnose.py --config FIELD=VALUE")
    passes, thresholds = pass_table(rows), threshold_table(rows)
    print(f"{len(rows)} sets of the development split {split}\n\n| pass | refitted on | "
          f"decisive on | budget-bound on |\n|---|---|---|---|")
    for p in passes:
        print(f"| {p['pass']} | {len(p['refitted_on'])} | "
              f"{', '.join(p['decisive_on']) or '-'} | {', '.join(p['budget_bound_on']) or '-'} |")
    print("\n| threshold | default | x0.5: sets whose gates flip | x2: sets whose gates flip "
          "| off: sets whose gates flip |\n|---|---|---|---|---|")
    for t in thresholds:
        cells = [", ".join(f"{s} ({'/'.join(g)})" for s, g in t[k]["flips"].items()) or "none"
                 if k in t else "-" for k in MOVES]
        print(f"| {t['field']} | {t['default']:g} | {' | '.join(cells)} |")
    print(f"\nnot replayed (need reruns): {', '.join(NOT_REPLAYED)}")
    k, n = (int(x) for x in args.part.split("/"))
    if args.rerun:
        fields = [f for f in args.fields.split(",") if f]
        moves = tuple(m for m in args.moves.split(",") if m)
        refused = unknown_names(fields, [t["field"] for t in thresholds], moves)
        if refused:
            sys.exit(refused)
        reruns = rerun(rows, passes, thresholds, fields, args.reruns_json, (k, n), split,
                       args.paired, moves=moves)
    elif args.reruns_json and args.reruns_json.exists():  # earlier reruns, reported
        reruns = json.loads(args.reruns_json.read_text())["reruns"]
    else:
        reruns = []
    now = {r["set"]: r for r in reruns if r["change"] == "default"}
    for r in reruns:
        if r["change"] == "default":
            continue
        base = now.get(r["set"])
        against = (f"{r['named_with'] or r['verdict_with']}" if base is None else
                   f"{base['named_changed'] or base['verdict_changed']} (default, rerun)")
        print(f"{r['set']}, {r['change']}: {against} -> "
              f"{r['named_changed'] or r['verdict_changed']}")
    if args.out:
        args.out.write_text(json.dumps({"split": split, "sets": [r["set"] for r in rows],
                                        "passes": passes,
                                        "thresholds": thresholds, "reruns": reruns},
                                       indent=1, default=str))


if __name__ == "__main__":
    main()

"""Replay round one's first-refit rule on recorded diagnoses under another policy.

Reads the rows of ``bench_diagnose.py`` or ``bench_diagnose_split.py`` JSON files
(each row's ``candidates_by_round``: every entry's score, sizings and status, kept
since ec4632c), rebuilds round one's sized entries, and asks
:func:`stickslip_jax.diagnose.rules.first_refits` which of them it would refit first
under the default :class:`~stickslip_jax.diagnose.Policy` and under the one given by
``--set name=value`` (its fields). Prints, per set, the first refits of both and the
entries whose first refit would change, with what their recorded refit (if any)
removed, so that a change of the rule can be judged on sets already run before any
diagnosis is run again. It replays the rule only: an entry the recorded run never
refitted has no refit to show, and later passes (fallbacks, second looks) are not
replayed. Do not replay a policy on the frozen test split to choose it: that is tuning.

    .venv/bin/python benchmarks/experiments/replay_first_refits.py out/split_dev.json \\
        --set competitive_share=0 --set leader_alone_share=inf
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from stickslip_jax.diagnose import Policy
from stickslip_jax.diagnose.report import entry_from_record
from stickslip_jax.diagnose.results import CandidateResult, CandidateStatus
from stickslip_jax.diagnose.rules import first_refits, rank_value

UNSIZED = {CandidateStatus.SCORED.value, CandidateStatus.NOT_SIZED.value}


def sized_entries(record: list[dict], unrecorded_converged: bool = True,
                  ) -> list[CandidateResult]:
    """Round one's sized entries of a recorded row, best rank value first (as the
    diagnosis ranks them). Rows before the held sizing's convergence was recorded
    (``sizing_converged``) take ``unrecorded_converged`` for it: True replays them as
    the rule then read them (every held sizing above the baseline deferred), False as
    if each had stopped at its step cap."""
    out = []
    for c in record:
        if c["status"] in UNSIZED:
            continue
        # As sized, before any refit: no refit's outcome, the status a sizing leaves.
        sized = entry_from_record(c, unrecorded_converged)
        out.append(CandidateResult(sized.name, score=sized.score, sizing=sized.sizing))
    return sorted(out, key=lambda r: -rank_value(r))


def round_one_excess(row: dict) -> tuple[float, float] | None:
    """``(excess, N)``: the (e/σ)² over the noise round one started from and the
    samples, from a refitted entry's cost before and the row's χ²/sample of the
    baseline; None when nothing was refitted."""
    record = row["candidates_by_round"][0]
    rss = next((c["rss_before"] for c in record if c.get("rss_before") is not None), None)
    if rss is None or not row.get("chi2_before"):
        return None
    n_obs = rss / float(row["chi2_before"])
    return rss - n_obs, n_obs


def replay(row: dict, policy: Policy, top: int, unrecorded_converged: bool = True,
           ) -> tuple[list[str], list[str]] | None:
    """``(default's first refits, policy's first refits)`` of round one, by name; None
    for a row without records or whose round one sized nothing
    (``unrecorded_converged``: :func:`sized_entries`)."""
    rounds = row.get("candidates_by_round")
    if not rounds:
        return None
    ranked = sized_entries(rounds[0], unrecorded_converged)
    if not ranked:
        return None
    excess = round_one_excess(row)
    names = []
    for p in (Policy(), policy):
        # As the round does: no excess to take shares of at (nearly) the noise level.
        above = (excess[0] if excess is not None and excess[0] > p.excess_min * excess[1]
                 else None)
        names.append([r.name for r in first_refits(ranked, top, above, p)])
    return names[0], names[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", nargs="+", type=Path, help="rows of bench_diagnose*.py")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="a Policy field of the replayed policy (repeatable)")
    ap.add_argument("--top", type=int, default=3, help="diagnose()'s top (default 3)")
    ap.add_argument("--unrecorded-held-sizing", choices=("converged", "unconverged"),
                    default="converged",
                    help="rows recorded without the held sizing's convergence: read "
                         "each as converged (the rule as it was) or as stopped at its "
                         "step cap")
    args = ap.parse_args()
    fields = {f.name for f in dataclasses.fields(Policy)}
    changes = {}
    for item in args.set:
        name, _, value = item.partition("=")
        if name not in fields:
            ap.error(f"{name!r} is not a Policy field; choose from {', '.join(sorted(fields))}")
        changes[name] = int(value) if name == "size_at_most" else float(value)
    policy = dataclasses.replace(Policy(), **changes)
    changed = seen = 0
    for path in args.json:
        for row in json.loads(path.read_text())["rows"]:
            got = replay(row, policy, args.top,
                         args.unrecorded_held_sizing == "converged")
            if got is None:
                continue
            seen += 1
            before, after = got
            if before == after:
                continue
            changed += 1
            record = {c["name"]: c for c in row["candidates_by_round"][0]}
            print(f"{path.name} {row['set']} (hidden {row.get('hidden', '?')}, named "
                  f"{', '.join(row['named']) or '-'}): first refits {before} -> {after}")
            for name in sorted(set(before) ^ set(after)):
                c = record[name]
                what = (f"refitted, ΔBIC {c['criterion_delta']:.4g}, explained "
                        f"{c['explained_share_of_excess']}" if c["refitted"]
                        else f"not refitted ({c['status']})")
                print(f"    {name}: {what}")
    print(f"{changed} of {seen} sets with sized entries would change their first refits "
          f"under {changes or 'the default'}")


if __name__ == "__main__":
    main()

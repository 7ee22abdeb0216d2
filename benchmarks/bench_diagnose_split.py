"""Diagnosis on a split of random sets (issue #27): confusion matrix, null false
positives, wrong names, right name first, detection against effect size, time.

    .venv/bin/python benchmarks/bench_diagnose_split.py --split dev --sets 0,1 \\
        --json out/split_dev.json --figure out/split_dev.png
    .venv/bin/python benchmarks/bench_diagnose_split.py --split test \\
        --json out/split_test.json --figure out/split_test.png     # the frozen split
    .venv/bin/python benchmarks/bench_diagnose_split.py --split dev --sets 24 \\
        --scale-strength 12 --json out/dev24_x12.json    # an analogue, 12x as strong

Each set is drawn by :func:`stickslip_jax.testing.random_sets.draw_set` from the
split's seed and its index (``dev``: develop on it; ``test``: frozen, run it once the
policy is fixed and report it, never tune on it; ``dev2`` and ``test2`` likewise, 48
sets drawn by the version-2 design: truths with their own PI operators and a few
compound sets, whose rows name every hidden effect in ``also`` and count any of them
named first as right) and simulated in memory: the 17
recordings of the protocol (``--reduced``: the tests' 8 recordings and diagnose
settings, a smoke run) from a random truth with one hidden effect or none, white noise
0.5-2 nm, integrated 16x finer than fits use. :func:`diagnose` runs on it as
``stickslip diagnose DIR --fix Ms=0.0247`` does: the baseline identified from the
default profile (dynamics, hysteresis, friction, joint), default settings and work
budget (``bench_diagnose.run_set``).

Per set (``--json``, appended as each set ends; sets already in the file are skipped,
so an interrupted run resumes): the hidden effect, its form and whether the catalogue
fits that form, strength, effect size (nm, over the noise, and the part the baseline
cannot absorb to first order), noise, verdict, the entries accepted, NRMSE before and
after, the share of the NRMSE excess over the noise floor removed, wall time and the
part of it XLA spent tracing and compiling (``compile_s``, ``programs_compiled``). The
summary (printed and in the JSON): the confusion matrix (hidden effect × first entry
named, or the verdict when none is), null false positives, the wrong-name rate, the
right-name-first rate among the sets hiding a catalogue entry, the detection rate
against effect size over noise, time per set; ``--figure`` draws the detection rate
and the confusion matrix.
"""

import argparse
import dataclasses
import json
import re
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.diagnose import NAMES, DiagnoseConfig, Verdict  # noqa: E402
from stickslip_jax.diagnose.passes import PASS_NAMES  # noqa: E402
from stickslip_jax.testing import random_sets as rs  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

# The concealed-set benchmark's diagnose run and protocols, shared.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_diagnose import REDUCED_SETTINGS, config_changes, protocol, run_set  # noqa: E402
from results_record import commit_of  # noqa: E402

SEEDS = {name: seed for name, (seed, _) in rs.SPLITS.items()}
DEV_SPLITS = ("dev", "dev2")
"""The splits to develop on (the others are frozen test splits)."""
HIDDEN = (*rs.CLASSES, "none")
"""Rows of the confusion matrix."""
UNEXPLAINED, ADEQUATE = "unexplained", "adequate"
COLUMNS = (*[n for n in NAMES if n in rs.CLASSES], UNEXPLAINED, ADEQUATE)
"""Columns: the entry named first, else the verdict (unexplained residual, baseline
adequate)."""
BINS = (0.0, 0.3, 1.0, 3.0, 10.0, 30.0, np.inf)
"""Effect size over noise bins of the detection rate."""


def outcome(row: dict) -> str:
    """The confusion matrix column of a row."""
    if row["named"]:
        return row["named"][0]
    return UNEXPLAINED if row["verdict"] == Verdict.UNEXPLAINED else ADEQUATE


def code_version() -> str:
    """The commit the code runs at (``+dirty`` with uncommitted changes), stamped on
    every row: a resumed run may span commits, and the report says which."""
    return commit_of(mark_dirty=True)


def run_one(spec: rs.SetSpec, reduced: bool, config: DiagnoseConfig | None = None) -> dict:
    """Simulate set ``spec``, diagnose it as ``config`` says (default: the default
    configuration; an ablation: without a pass, a threshold moved), and the row of the
    JSON."""
    drives = protocol(reduced)
    t0 = time.perf_counter()
    recs = rs.make_recordings(spec, drives)
    size = rs.effect_size(spec, drives, beyond_baseline=True)
    simulate_s = time.perf_counter() - t0
    row = run_set(spec.name, from_profile=True, recs=recs, config=config or DiagnoseConfig(),
                  **({"max_rounds": 3} | (REDUCED_SETTINGS if reduced else {})))
    row.update(
        index=spec.index, hidden=spec.hidden[0], form=spec.form, also=list(spec.also),
        catalogue_form=spec.catalogue_form, strength=spec.strength,
        strength_name=spec.strength_name, strength_unit=spec.strength_unit,
        others=spec.others, noise_nm=1e9 * spec.noise_m,
        effect_nm=1e9 * size["rms_m"], effect_to_noise=size["to_noise"],
        beyond_baseline_nm=1e9 * size["beyond_baseline_m"],
        beyond_to_noise=size["beyond_to_noise"], simulate_s=simulate_s,
        truth_factors=spec.truth_factors, commit=code_version())
    row["outcome"] = outcome(row)
    # A compound set (version 2) hides several: naming any of them first is right.
    row["right_first"] = bool(row["named"]) and row["named"][0] in spec.hidden
    row["wrong_first"] = bool(row["named"]) and row["named"][0] not in spec.hidden
    row["wrong_any"] = any(n not in spec.hidden for n in row["named"])
    row["right_place_first"] = right_place_first(row)
    return row


def right_place_first(row: dict) -> bool:
    """Whether a row's first name acts where a hidden effect acts (its class family,
    :data:`~stickslip_jax.testing.random_sets.PLACES`: friction, stroke, drive stage,
    structure, sensor, slider), beside the entry-level judgement: a saturating contact
    damping named as friction against the sliding velocity is the right family."""
    places = {rs.PLACES.get(h) for h in hidden_of(row)} - {None}
    return bool(row["named"]) and rs.PLACES.get(row["named"][0]) in places


# ---- summaries -------------------------------------------------------------------------
def confusion(rows: list[dict]) -> dict[str, dict[str, int]]:
    """``hidden → outcome → count`` over :data:`HIDDEN` × :data:`COLUMNS`."""
    m = {h: dict.fromkeys(COLUMNS, 0) for h in HIDDEN}
    for r in rows:
        m[r["hidden"]][r["outcome"]] += 1
    return m


def confusion_markdown(m: dict[str, dict[str, int]]) -> str:
    """The confusion matrix as a markdown table (rows with no set left out)."""
    head = "| hidden \\ named | " + " | ".join(COLUMNS) + " |"
    lines = [head, "|---" * (len(COLUMNS) + 1) + "|"]
    for h in HIDDEN:
        if sum(m[h].values()):
            lines.append(f"| {h} | " + " | ".join(str(m[h][c] or "") for c in COLUMNS) + " |")
    return "\n".join(lines)


def _rate(hits: int, n: int) -> dict:
    return {"count": hits, "of": n, "rate": hits / n if n else None}


def detection_bins(rows: list[dict], size: str = "effect_to_noise") -> list[dict]:
    """Per bin of ``size`` (effect size over noise, or its part beyond what the
    baseline absorbs to first order, ``beyond_to_noise``): of the sets hiding a
    catalogue entry, the share named right first; of all non-null sets, the share
    flagged (anything but "baseline adequate")."""
    out = []
    for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
        inside = [r for r in rows if r["hidden"] != "none" and lo <= r[size] < hi]
        cat = [r for r in inside if r["hidden"] != "uncatalogued"]
        out.append({"bin": [lo, hi], "right_first": _rate(sum(r["right_first"] for r in cat),
                                                           len(cat)),
                    "flagged": _rate(sum(r["outcome"] != ADEQUATE for r in inside),
                                     len(inside))})
    return out


def above_limit(row: dict) -> bool | None:
    """Whether the effect is above the diagnosis's detection limit on its set: the
    part the baseline cannot absorb to first order adds more to the mean ``(e/σ)²``
    than the set's tolerance of practical significance (``beyond_to_noise² >
    tolerance_chi2``; the definition of :mod:`stickslip_jax.diagnose.scores`'s limits).
    None when the row has no tolerance."""
    tol = row.get("tolerance_chi2")
    return None if tol is None else bool(row["beyond_to_noise"] ** 2 > tol)


def hidden_of(row: dict) -> list[str]:
    """Every effect a row's set hides: its first, then a compound set's others."""
    return [row["hidden"], *(e["effect"] for e in row.get("also", []))]


def summary(rows: list[dict]) -> dict:
    null = [r for r in rows if r["hidden"] == "none"]
    compound = [r for r in rows if r.get("also")]
    cat = [r for r in rows if r["hidden"] not in ("none", "uncatalogued")]
    unc = [r for r in rows if r["hidden"] == "uncatalogued"]
    named = [r for r in rows if r["named"]]
    walls = [r["wall_s"] for r in rows]
    compiles = [r["compile_s"] for r in rows if "compile_s" in r]  # rows since 36a7ecd
    worked = [r for r in rows if work_spent(r) is not None]
    works = [work_spent(r) for r in worked]
    m = confusion(rows)
    return {
        "sets": len(rows),
        "null_false_positives": _rate(sum(bool(r["named"]) for r in null), len(null)),
        "null_unexplained": _rate(sum(r["outcome"] == UNEXPLAINED for r in null), len(null)),
        "wrong_name_first": _rate(sum(r["wrong_first"] for r in rows), len(rows)),
        "wrong_name_any": _rate(sum(r["wrong_any"] for r in rows), len(rows)),
        "right_first": _rate(sum(r["right_first"] for r in cat), len(cat)),
        "right_first_above_limit": _rate(
            sum(r["right_first"] for r in cat if above_limit(r)),
            sum(bool(above_limit(r)) for r in cat)),
        "flagged_below_limit": _rate(
            sum(r["outcome"] != ADEQUATE for r in rows if r["hidden"] != "none"
                and above_limit(r) is False),
            sum(r["hidden"] != "none" and above_limit(r) is False for r in rows)),
        "right_place_first_above_limit": _rate(
            sum(right_place_first(r) for r in cat if above_limit(r)),
            sum(bool(above_limit(r)) for r in cat)),
        "right_first_catalogue_form": _rate(
            sum(r["right_first"] for r in cat if r["catalogue_form"]),
            sum(r["catalogue_form"] for r in cat)),
        "right_first_other_form": _rate(
            sum(r["right_first"] for r in cat if not r["catalogue_form"]),
            sum(not r["catalogue_form"] for r in cat)),
        "uncatalogued_unexplained": _rate(sum(r["outcome"] == UNEXPLAINED for r in unc),
                                          len(unc)),
        # Compound sets (version 2) are filed under their first effect above; here, how
        # many of them had every hidden effect named.
        "compound_all_named": _rate(
            sum(set(hidden_of(r)) <= set(r["named"]) for r in compound), len(compound)),
        "excess_halved_where_named": _rate(
            sum((r["excess_removed"] or 0.0) >= 0.5 for r in named), len(named)),
        "detection_vs_effect_to_noise": detection_bins(rows),
        "detection_vs_beyond_to_noise": detection_bins(rows, "beyond_to_noise"),
        "wall_s": {"mean": float(np.mean(walls)), "median": float(np.median(walls)),
                   "max": float(np.max(walls))} if walls else None,
        # Counted work (sample-evaluations): what bounds a diagnosis, the same on any
        # machine and under any load, unlike the wall time.
        "work": {"median": float(np.median(works)), "max": float(np.max(works)),
                 "over_budget": sum(work_spent(r) > _work_total(r) for r in worked)}
        if works else None,
        "compile_share": (float(np.median(np.array(compiles) / np.array(walls)))
                          if compiles and len(compiles) == len(walls) else None),
        "confusion": m,
        "confusion_markdown": confusion_markdown(m),
    }


def work_spent(row: dict) -> float | None:
    """The sample-evaluations a set's diagnosis spent (rows since ec4632c), or None."""
    wb = row.get("work_budget")
    return float(wb["spent"]) if isinstance(wb, dict) and "spent" in wb else None


def _work_total(row: dict) -> float:
    return float(row["work_budget"].get("total") or np.inf)


def _pct(r: dict) -> str:
    return "-" if r["rate"] is None else f"{r['count']}/{r['of']} ({100 * r['rate']:.0f} %)"


def print_summary(rows: list[dict], s: dict) -> None:
    print("\n| set | hidden | form | cat. form | effect/noise (beyond) | noise | verdict | "
          "named | NRMSE before → after | excess removed | work [1e6] | wall |")
    print("|---" * 12 + "|")
    for r in sorted(rows, key=lambda r: r["index"]):
        ex = "" if r["excess_removed"] is None else f"{100 * r['excess_removed']:.0f} %"
        spent = work_spent(r)
        work = "" if spent is None else f"{spent / 1e6:.1f}"
        print(f"| {r['set']} | {r['hidden']} | {r['form']} | {'yes' if r['catalogue_form'] else ''}"
              f" | {r['effect_to_noise']:.2g} ({r['beyond_to_noise']:.2g}) | "
              f"{r['noise_nm']:.2f} nm | {r['verdict']} | {', '.join(r['named']) or '-'} | "
              f"{100 * r['nrmse_before']:.4f} → {100 * r['nrmse_after']:.4f} % | {ex} | "
              f"{work} | {r['wall_s']:.0f} s |")
    print("\n" + s["confusion_markdown"] + "\n")
    for k in ("null_false_positives", "null_unexplained", "wrong_name_first", "wrong_name_any",
              "right_first", "right_first_above_limit", "right_place_first_above_limit",
              "flagged_below_limit",
              "right_first_catalogue_form", "right_first_other_form",
              "uncatalogued_unexplained", "compound_all_named", "excess_halved_where_named"):
        print(f"- {k.replace('_', ' ')}: {_pct(s[k])}")
    print("\nDetection (right first: sets hiding a catalogue entry; flagged: any verdict "
          "but adequate, uncatalogued sets included):\n")
    print("| effect / noise | right first | flagged | beyond / noise | right first | "
          "flagged |")
    print("|---" * 6 + "|")
    for whole, beyond in zip(s["detection_vs_effect_to_noise"],
                             s["detection_vs_beyond_to_noise"], strict=True):
        print(" | ".join(["", *(f"[{b['bin'][0]:g}, {b['bin'][1]:g}) | "
                                f"{_pct(b['right_first'])} | {_pct(b['flagged'])}"
                                for b in (whole, beyond)), ""]).strip())
    print()
    if s["wall_s"]:
        w = s["wall_s"]
        print(f"- diagnose wall time per set: mean {w['mean']:.0f} s, median "
              f"{w['median']:.0f} s, max {w['max']:.0f} s")
    if s.get("work"):
        w = s["work"]
        print(f"- counted work per set: median {w['median']:.3g}, max {w['max']:.3g} "
              f"sample-evaluations; {w['over_budget']} set(s) past the work budget")
    if s.get("compile_share") is not None:
        print(f"- XLA tracing and compiling, median share of a set's wall time: "
              f"{100 * s['compile_share']:.0f} %")


def _detection_panel(ax, rows: list[dict], bins: list[dict], size: str, label: str) -> None:
    """Right-first points (catalogue and other forms) and the binned rates against
    ``size``."""
    rng = np.random.default_rng(0)  # jitter of the points, for legibility only
    for cat_form, marker in ((True, "o"), (False, "^")):
        pts = [r for r in rows if r["hidden"] not in ("none", "uncatalogued")
               and r["catalogue_form"] == cat_form]
        ax.scatter([max(r[size], 0.06) for r in pts],
                   [float(r["right_first"]) + rng.uniform(-0.04, 0.04) for r in pts],
                   marker=marker, alpha=0.6,
                   label=f"{'catalogue' if cat_form else 'other'} form (1: right first)")
    centres, right, flagged = [], [], []
    for bn in bins:
        lo, hi = bn["bin"]
        centres.append(np.sqrt(max(lo, 0.1) * (hi if np.isfinite(hi) else 100.0)))
        right.append(np.nan if bn["right_first"]["rate"] is None else bn["right_first"]["rate"])
        flagged.append(np.nan if bn["flagged"]["rate"] is None else bn["flagged"]["rate"])
    ax.plot(centres, right, "k-", label="rate named right first (bins)")
    ax.plot(centres, flagged, "k--", label="rate flagged at all (bins)")
    ax.set_xscale("log")
    ax.set_xlim(0.05, 200.0)  # the same axis on every run, however few the sets
    ax.set_xlabel(label)
    ax.set_ylabel("rate")
    ax.set_ylim(-0.1, 1.1)
    ax.legend(fontsize=7, loc="center right")


def figure(rows: list[dict], s: dict, path: Path) -> None:
    """Detection against effect size over noise (whole, and beyond the baseline's
    first-order absorption), and the confusion matrix."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, a2, b) = plt.subplots(1, 3, figsize=(18, 5),
                                   gridspec_kw={"width_ratios": [1, 1, 1.3]})
    _detection_panel(a, rows, s["detection_vs_effect_to_noise"], "effect_to_noise",
                     "effect size / noise (RMS, offset removed)")
    a.set_title("detection against effect size")
    _detection_panel(a2, rows, s["detection_vs_beyond_to_noise"], "beyond_to_noise",
                     "effect beyond the baseline's first-order absorption / noise")
    a2.set_title("detection against what the baseline cannot absorb")
    m = s["confusion"]
    hidden = [h for h in HIDDEN if sum(m[h].values())]
    grid = np.array([[m[h][c] for c in COLUMNS] for h in hidden])
    b.imshow(grid, cmap="Blues", aspect="auto")
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            if grid[i, j]:
                b.text(j, i, str(grid[i, j]), ha="center", va="center")
    b.set_xticks(range(len(COLUMNS)), COLUMNS, rotation=60, ha="right", fontsize=8)
    b.set_yticks(range(len(hidden)), hidden, fontsize=8)
    b.set_xlabel("named first (or verdict)")
    b.set_title("confusion matrix")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def tolerances_from_logs(rows: list[dict], logs: list[Path]) -> None:
    """Set ``tolerance_chi2`` on rows without it from runs' printed output (the first
    ``[significance] tolerance: mean (e/σ)² within 1 + τ`` line after ``== set_NN``)."""
    found: dict[str, float] = {}
    for log in logs:
        name = None
        for line in log.read_text().splitlines():
            if line.startswith("== set_"):
                name = line.split()[1].rstrip(":")
            elif name and "[significance] tolerance" in line and name not in found:
                found[name] = float(re.search(r"within 1 \+ ([0-9.eE+-]+)", line).group(1))
    for r in rows:
        if r.get("tolerance_chi2") is None and r["set"] in found:
            r["tolerance_chi2"] = found[r["set"]]


def save(path: Path | None, meta: dict, rows: list[dict]) -> None:
    """The rows and their summary to ``path`` (if given), sets in index order."""
    if path:
        rows = sorted(rows, key=lambda r: r["index"])
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({**meta, "jax": jax.__version__, "rows": rows,
                                    "summary": summary(rows)}, indent=1, default=float))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=sorted(SEEDS), required=True)
    ap.add_argument("--sets", default="", help="comma-separated set indices (default 0 … n−1)")
    ap.add_argument("--n", type=int, default=None,
                    help="sets in the split (default: its design's, 24 or 48)")
    ap.add_argument("--reduced", action="store_true",
                    help="the tests' 8-recording protocol and settings (a smoke run)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--figure", type=Path, default=None)
    ap.add_argument("--merge", type=Path, nargs="+", default=[],
                    help="JSON files of other runs of the same split (parallel halves): "
                         "their rows join this run's (a set already here is kept)")
    ap.add_argument("--logs", type=Path, nargs="+", default=[],
                    help="the printed output of the runs: rows recorded before rows "
                         "carried the tolerance take it from the '[significance]' line")
    ap.add_argument("--scale-strength", type=float, default=1.0, metavar="F",
                    help="development analogues: each drawn set's effect strength times F "
                         "(its form, truth, noise and recordings' seed as drawn); dev only")
    ap.add_argument("--without", default="", metavar="PASS[,PASS]",
                    help="an ablation: leave these refit passes out "
                         f"({', '.join(PASS_NAMES)}); rows say which pass refitted each "
                         "entry (candidates_by_round's refit_pass)")
    ap.add_argument("--with", dest="with_", default="", metavar="PASS[,PASS]",
                    help="opt-in refit passes added after the default ones (carry_on)")
    ap.add_argument("--config", nargs="+", default=[], metavar="FIELD=VALUE",
                    help="an ablation of a DiagnoseConfig switch or setting, e.g. "
                         "refine_forms=False (the value as a Python literal)")
    args = ap.parse_args()
    changes = config_changes(args.config)
    without = tuple(p for p in args.without.split(",") if p)
    added = tuple(p for p in args.with_.split(",") if p)
    if args.scale_strength != 1.0 and (args.split not in DEV_SPLITS
                                       or not args.scale_strength > 0):
        sys.exit("--scale-strength takes a positive factor on a development split only: "
                 "a frozen test split is reported as drawn")
    seed, design = rs.SPLITS[args.split]
    n = design.size if args.n is None else args.n
    chosen = [int(s) for s in args.sets.split(",") if s] or list(range(n))
    meta = {"split": args.split, "seed": seed, "reduced": args.reduced}
    if args.scale_strength != 1.0:  # (absent otherwise: earlier files stay resumable)
        meta["strength_scale"] = args.scale_strength
    if without:  # (absent otherwise: earlier files stay resumable)
        meta["without_passes"] = list(without)
    if added:
        meta["with_passes"] = list(added)
    if changes:
        meta["config"] = {k: repr(v) for k, v in changes.items()}
    rows: list[dict] = []
    if args.json and args.json.exists():
        old = json.loads(args.json.read_text())
        if {k: old.get(k) for k in meta} != meta:
            sys.exit(f"{args.json} holds another run ({ {k: old.get(k) for k in meta} }); "
                     f"give another --json")
        rows = old["rows"]
    for path in args.merge:
        other = json.loads(path.read_text())
        if {k: other.get(k) for k in meta} != meta:
            sys.exit(f"{path} holds another run ({ {k: other.get(k) for k in meta} })")
        have = {r["index"] for r in rows}
        rows += [r for r in other["rows"] if r["index"] not in have]
    tolerances_from_logs(rows, args.logs)
    done = {r["index"] for r in rows}
    for i in chosen:
        if i in done:
            print(f"== set_{i:02d}: in {args.json} already", flush=True)
            continue
        spec = rs.draw_set(seed, i, design)  # times 1.0 unless scaled: exactly as drawn
        spec = dataclasses.replace(spec, strength=spec.strength * args.scale_strength)
        print(f"== {spec.name}", flush=True)
        rows.append(run_one(spec, args.reduced,
                            DiagnoseConfig(**changes).without(*without)
                            .with_passes(*added)))
        r = rows[-1]
        print(json.dumps({k: r[k] for k in ("set", "hidden", "form", "effect_to_noise",
                                            "verdict", "named", "wall_s", "compile_s",
                                            "programs_compiled", "simulate_s")},
                         default=str), flush=True)
        save(args.json, meta, rows)  # after every set: a later crash keeps the rows done
    if args.merge:
        save(args.json, meta, rows)
    rows = [r for r in rows if r["index"] in chosen] if args.sets else rows
    s = summary(rows)
    print_summary(rows, s)
    if args.figure:
        figure(rows, s, args.figure)


if __name__ == "__main__":
    main()

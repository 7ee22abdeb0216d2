"""A plan's files: ``plan.json``, ``plan.md``, one drive file per proposed recording
(``drives/NAME.csv``, the recording format without a position column: what
``stickslip simulate --voltage-from`` and a signal generator read) and a figure of each
question's evidence now, after the protocol repeated, and after the plan."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from ..files import atomic_write_text
from ..io import save_recording
from ..plots import save_figure, subplots
from .plan import ExperimentPlan


def _finite(x):
    return None if x is None or not math.isfinite(x) else float(x)


def plan_dict(plan: ExperimentPlan) -> dict:
    """The content of ``plan.json``."""
    return {
        "recordings": [{"file": f"drives/{r.drive.name}.csv",
                        "waveform": r.drive.waveform, "amplitude_V": r.drive.amplitude_V,
                        "frequency_Hz": r.drive.frequency_Hz, "direction": r.drive.direction,
                        "duration_s": r.drive.duration_s, "units": r.units,
                        "answers": r.serves} for r in plan.recordings],
        "questions": [{k: (_finite(v) if isinstance(v, float) else v)
                       for k, v in dataclasses.asdict(q).items()} for q in plan.questions],
        "evidence": ("ratio: expected excess of the wrong model's cost over the tolerance "
                     "the diagnosis needs (>= 1: the two are told apart), to first order "
                     "in the refitted model's move; limit: the strength at which the entry "
                     "reaches the tolerance"),
        "total_time_s": plan.total_time_s, "planned_time_s": plan.planned_time_s,
        "noise_nm": plan.noise_nm, "limits": dataclasses.asdict(plan.limits),
        "candidates": plan.candidates,
        "tolerance_rss": dict(zip(("now", "protocol_again", "plan"), plan.tolerances,
                                  strict=True)),
        "notes": list(plan.notes),
        "timings_s": plan.timings_s,
    }


def _cell(x, fmt="{:.3g}") -> str:
    return "—" if x is None or not math.isfinite(x) else fmt.format(x)


def plan_markdown(plan: ExperimentPlan, figure: str | None) -> str:
    """``plan.md``: the recordings to make, and what each question gains."""
    lines = ["# The next recordings", "",
             f"{len(plan.recordings)} recordings, {plan.planned_time_s:.3g} s of the "
             f"{plan.total_time_s:.3g} s allowed, chosen from {plan.candidates} candidate "
             f"drives within {plan.limits.max_voltage_V:g} V and "
             f"{plan.limits.min_frequency_Hz:g}-{plan.limits.max_frequency_Hz:g} Hz, at the "
             f"recordings' noise ({plan.noise_nm:.2f} nm).", "",
             "| file | drive | duration | answers |", "|---|---|---|---|"]
    for r in plan.recordings:
        d = r.drive
        what = f"{d.waveform} {d.amplitude_V:g} V" + (
            f" {d.frequency_Hz:g} Hz" if d.frequency_Hz else "") + (
            f" {d.direction}" if d.direction else "")
        lines.append(f"| drives/{d.name}.csv | {what} | {d.duration_s:.3g} s | {r.serves} |")
    lines += ["", "Evidence over the tolerance the diagnosis needs (≥ 1: told apart); for "
              "an entry not named, the detection limit it leaves.", "",
              "| question | now | the protocol again | the plan |", "|---|---|---|---|"]
    for q in plan.questions:
        cells = [_cell(q.ratio_now), _cell(q.ratio_default), _cell(q.ratio_designed)]
        if q.kind == "limit":
            unit = "" if q.unit in ("", "-") else f" {q.unit}"
            cells = [f"{c} (limit {_cell(lim)}{unit})" for c, lim in
                     zip(cells, (q.limit_now, q.limit_default, q.limit_designed),
                         strict=True)]
        lines.append(f"| {q.label} | " + " | ".join(cells) + " |")
    lines += ["", "To first order in the refitted model's move; each longer recording "
              "counts its periods as repeats of one unit's. For an entry not named, the "
              "ratios are at today's limit strength, where the new recordings can make "
              "its effect large and the first order overstate the evidence (a refit "
              "absorbs more than a linear move); the limit after is a small effect, "
              "where the first order holds."]
    if plan.notes:
        lines += ["", "Notes:", ""] + [f"- {n}" for n in plan.notes]
    if figure:
        lines += ["", f"![evidence per question]({figure})"]
    return "\n".join(lines) + "\n"


def plot_plan(plan: ExperimentPlan, path) -> Path:
    """Each question's evidence over the tolerance now, after the protocol repeated for
    the plan's time and after the plan (log scale, the line at 1: told apart)."""
    fig, ax = subplots(figsize=(7.0, 0.45 * len(plan.questions) + 1.6))
    y = np.arange(len(plan.questions))
    for k, (attr, label) in enumerate((("ratio_now", "now"),
                                       ("ratio_default", "the protocol again"),
                                       ("ratio_designed", "the plan"))):
        values = [max(getattr(q, attr), 1e-6) for q in plan.questions]
        ax.barh(y + (k - 1) * 0.27, values, height=0.26, label=label)
    ax.axvline(1.0, color="k", lw=0.8)
    ax.set_xscale("log")
    ax.set_yticks(y, [q.label for q in plan.questions])
    ax.invert_yaxis()
    ax.set_xlabel("evidence / tolerance")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12 - 0.5 / len(y)), ncol=3,
              fontsize=8, frameon=False)
    return save_figure(fig, path)


def write_plan(plan: ExperimentPlan, out: Path, *, figures: bool = True) -> dict[str, Path]:
    """Write the plan's files into ``out`` (a staging folder: the caller makes them
    appear whole) and return them by name."""
    out = Path(out)
    (out / "drives").mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    for r in plan.recordings:
        rec = r.drive.recording(plan.limits.sample_rate_Hz)
        written[r.drive.name] = save_recording(rec, out / "drives" / f"{r.drive.name}.csv")
    figure = None
    if figures and plan.questions:
        (out / "figures").mkdir(exist_ok=True)
        written["figure"] = plot_plan(plan, out / "figures" / "plan.png")
        figure = "figures/plan.png"
    path = out / "plan.json"
    atomic_write_text(path, json.dumps(plan_dict(plan), indent=1, default=float) + "\n")
    written["plan"] = path
    path = out / "plan.md"
    atomic_write_text(path, plan_markdown(plan, figure))
    written["report"] = path
    return written

"""Write an identification to a folder: params.json, fit.json and the figures.

``params.json`` follows the parameter contract of docs/model.md, so ``stickslip simulate
--params`` loads it. When any step did not converge it is written as
``params.unconverged.json`` instead: a result that is not trustworthy must not sit
where a good one is expected.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..figure_helper import FigureJob, draw_figures
from ..files import atomic_write_text, check_output_path
from ..noise import noise_sigma
from ..params import save_params
from .dataset import classify_regime
from .figures import (
    draw_hysteresis_loop,
    hysteresis_loop_model,
    plot_psd_overlay,
    plot_step_lengths,
)
from .parameters import unit_of

PSD_PANEL_WEIGHT = 1.5
"""A PSD panel's drawing time against an overlay's (:attr:`~stickslip_jax.
figure_helper.FigureJob.weight`): its log axes carry many minor ticks (a two-panel
PSD figure 1.3-1.6 s, an overlay 0.35-0.45 s, on the 2-core session machine). Only
the order of drawing depends on it: the PSD figures go first."""

FIGURES = ("step_psd.png", "fig11_psd.png", "hysteresis_loop.png", "step_length.png")


def output_paths(out_dir: Path, recordings) -> list[Path]:
    """Every file :func:`write_identification` may write into ``out_dir``."""
    fig = out_dir / "figures"
    return ([out_dir / "params.json", out_dir / "params.unconverged.json",
             out_dir / "fit.json"] + [fig / n for n in FIGURES]
            + [fig / f"overlay_{r.name}.png" for r in recordings])


def check_outputs(out_dir: Path, recordings, *, force: bool) -> None:
    """Refuse up front (before hours of fitting) to replace existing outputs without
    ``force``, or to write over an input recording."""
    inputs = [r.source for r in recordings if r.source]
    for p in output_paths(out_dir, recordings):
        if p.exists() or any(str(p) == str(i) for i in inputs):
            check_output_path(p, force=force, inputs=inputs)


def fit_status(result) -> str:
    """``converged``, ``misspecified`` (converged, but the model misses more than the
    noise: :mod:`.model_check`), ``not converged`` or ``undetermined`` (nothing
    fitted)."""
    blocked = getattr(result, "undetermined", None)
    if blocked is not None and blocked.blocking:
        return "undetermined"
    if not result.converged:
        return "not converged"
    return "misspecified" if getattr(result, "misspecified", False) else "converged"


def _percent(fraction) -> float | None:
    """An NRMSE [-] as the percentage every output file and console line reports
    (keys carry the unit: ``*_nrmse_percent``); None where it is not finite."""
    value = float(fraction)
    return 100.0 * value if np.isfinite(value) else None


def fit_summary(result) -> dict:
    """The content of ``fit.json`` (plain JSON types only)."""
    data = result.data
    recs = {}
    floors = []
    numerical = result.numerical_error_m
    for b, rec in enumerate(data.recordings):
        q = result.q_sim[b, : rec.n]
        diff = q - rec.position_m
        diff = diff - diff.mean()
        sigma = noise_sigma(rec)
        floors.append(sigma / data.scale[b])
        recs[rec.name] = {
            "regime": classify_regime(rec),
            "nrmse_percent": _percent(result.nrmse[b]),
            "rms_residual_nm": float(np.sqrt(np.mean(diff**2)) * 1e9),
            "noise_floor_nm": sigma * 1e9,
            "noise_floor_nrmse_percent": _percent(sigma / data.scale[b]),
            # The simulator's own error at the fit (step doubling), next to the noise.
            "numerical_error_nm": (None if numerical is None
                                   else float(numerical[b]) * 1e9),
        }
    params = {}
    unc = result.uncertainty
    spread = getattr(result, "regime_spread", None)
    check = getattr(result, "model_check", None)
    fitted = {n for s in result.steps if s.result is not None for n in s.free}
    for lab, entry in (unc.as_dict() if unc is not None else {}).items():
        base = lab.split("[")[0]
        se = entry["std_error"]
        # Determined only if a step fitted it and its standard error is finite and not
        # 0 (an SE of 0 comes from a Jacobian with fewer rows than columns, not from
        # perfect data).
        determined = bool(entry["determined"] and base in fitted and se is not None
                          and se > 0)
        params[lab] = {**entry, "determined": determined, "fitted": base in fitted,
                       "unit": unit_of(base, result.actuator)}
        if base not in fitted:  # held: its value is given, it has no standard error
            params[lab].update(std_error=None, relative_error=None)
        if spread is not None:
            params[lab]["regime_spread"] = spread.spread.get(lab)
    scalars = [i for i, lab in enumerate(unc.labels) if "[" not in lab] if unc else []
    corr = ({"labels": [unc.labels[i] for i in scalars],
             "matrix": [[None if not np.isfinite(unc.correlations[i, j]) else
                         round(float(unc.correlations[i, j]), 4) for j in scalars]
                        for i in scalars]} if unc else None)
    steps = [{
        "name": s.name, "converged": s.converged, "skipped": s.result is None,
        "message": s.result.message if s.result else s.note,
        "iterations": s.result.iterations if s.result else 0,
        "wall_s": round(s.result.wall_s, 2) if s.result else 0.0,
        "free": list(s.free), "recordings": list(s.recordings),
        # Coarse sub-steps per sample of each stretch (more than one: re-planned).
        "substeps": [seg.plan.substeps for seg in s.segments],
        "nrmse_before_percent": _percent(s.nrmse_before),
        "nrmse_after_percent": _percent(s.nrmse_after),
    } for s in result.steps]
    nrmse = float(np.mean(result.nrmse))
    floor = float(np.mean(floors))
    return {
        "status": fit_status(result),
        "converged": result.converged,
        "misspecified": bool(check is not None and check.misspecified),
        "model_check": check.as_dict() if check is not None else None,
        "regime_spread": spread.as_dict() if spread is not None else None,
        "overall": {"nrmse_percent": _percent(nrmse),
                    "noise_floor_nrmse_percent": _percent(floor),
                    "nrmse_over_floor": nrmse / floor if floor > 0 else None,
                    "numerical_floor_nm": (None if numerical is None
                                           else float(np.max(numerical)) * 1e9),
                    "residual_sigma_nm": unc.sigma * 1e9 if unc else None},
        "notes": list(result.notes),
        "fixed": {k: float(v) for k, v in result.fixed.items()},
        "recordings": recs,
        "parameters": params,
        "correlations": corr,
        # What the data determine of the hysteresis: the loading curve at its knots
        # (individual PI weights trade off against their neighbours).
        "hysteresis_loading_curve": (None if getattr(result, "loading_curve", None) is None
                                     else result.loading_curve.as_dict()),
        "steps": steps,
    }


def write_identification(result, out_dir: str | Path, *, force: bool = False,
                         inputs=(), figures: bool = True, helper=None) -> dict[str, Path]:
    """Write ``result`` (an :class:`Identification`) into ``out_dir``; returns the paths.

    ``inputs`` are files that must never be written over; ``helper`` a
    :class:`~stickslip_jax.figure_helper.FigureHelper` that draws figures beside this
    process. A result whose data could
    not determine its steps (nothing fitted) is refused with the reason (ValueError).
    """
    blocked = getattr(result, "undetermined", None)
    if blocked is not None and blocked.blocking:
        raise ValueError(blocked.statement())
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = {}
    name = "params.json" if result.converged else "params.unconverged.json"
    status = None
    if fit_status(result) == "misspecified":
        status = (f"misspecified: {result.model_check.statement()}; the values are the "
                  f"least-squares fit of a model that lacks something (fit.json)")
    written["params"] = save_params(result.actuator, out_dir / name, force=force,
                                    inputs=inputs, fit_status=status)
    fit = out_dir / "fit.json"
    check_output_path(fit, force=force, inputs=inputs)
    atomic_write_text(fit, json.dumps(fit_summary(result), indent=1) + "\n")
    written["fit"] = fit
    if figures:
        written.update(write_figures(result, out_dir / "figures", force=force,
                                     helper=helper))
    return written


def _pick(recs, sims, waveform, amplitude=None, frequency=None):
    out = [(r, q) for r, q in zip(recs, sims, strict=True) if r.drive.waveform == waveform
           and (amplitude is None or math.isclose(r.drive.amplitude_V or 0, amplitude))
           and (frequency is None or math.isclose(r.drive.frequency_Hz or 0, frequency))]
    return sorted(out, key=lambda x: bool(x[0].drive.is_backward))


def write_figures(result, fig_dir: Path, *, force: bool = False,
                  helper=None) -> dict[str, Path]:
    """The figures of the identification issue: an overlay per recording, the step PSD,
    the 20 V/500 Hz and 40 V/50 Hz sawtooth PSDs (Lu 2015 Fig. 11), the hysteresis
    loop, and the step length against amplitude. Figures that lack their recordings
    are skipped. ``helper``: a :class:`~stickslip_jax.figure_helper.FigureHelper` that
    draws some of them beside this process (the same files either way)."""
    from ..plots import plot_trace

    fig_dir.mkdir(parents=True, exist_ok=True)
    recs = list(result.data.recordings)
    sims = [np.asarray(result.q_sim[b, : r.n]) for b, r in enumerate(recs)]
    jobs = []

    def add(key, draw, *args, weight=1.0, **kwargs):
        kwargs["path"] = check_output_path(fig_dir / f"{key}.png", force=force)
        jobs.append(FigureJob(key, draw, args, kwargs, weight=weight))

    for b, (rec, q) in enumerate(zip(recs, sims, strict=True)):
        shift = np.mean(rec.position_m - q)  # show the model on the recording's zero
        add(f"overlay_{rec.name}", plot_trace, rec.time_s, rec.voltage_V, q + shift,
            q_meas_m=rec.position_m, noise_m=noise_sigma(rec),
            title=f"{rec.name}: NRMSE {100 * float(result.nrmse[b]):.3f} %")
    steps = _pick(recs, sims, "step")
    if steps:
        add("step_psd", plot_psd_overlay, [steps[0][0]], [steps[0][1]],
            title="step response PSD", weight=PSD_PANEL_WEIGHT)
    fig11 = [x for a, f in ((20.0, 500.0), (40.0, 50.0))
             for x in _pick(recs, sims, "sawtooth", a, f)[:1]]
    if fig11:
        add("fig11_psd", plot_psd_overlay, [r for r, _ in fig11], [q for _, q in fig11],
            title="sawtooth responses (Lu 2015 Fig. 11)", weight=PSD_PANEL_WEIGHT * len(fig11))
    slow = _pick(recs, sims, "sine")
    if slow:  # the model evaluated here, the figure drawn from plain data
        add("hysteresis_loop", draw_hysteresis_loop, slow[0][0], slow[0][1],
            *hysteresis_loop_model(result.actuator, slow[0][0]))
    if _pick(recs, sims, "sawtooth"):
        add("step_length", plot_step_lengths, recs, sims)
    return draw_figures(jobs, helper)

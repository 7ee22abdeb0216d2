"""Accuracy of the simulator against converged traces, at the default and on a ladder.

For every drive of the grid (stepping sawtooth at 40 and 60 V, 50 and 500 Hz, both
directions, sampled at 2.5, 25 and 100 kHz; and the issue's extra rows: 60 V 200 Hz
at 10 and 2.5 kHz, a 20 V scan, a sine and a step), 0.2 s, default profile:

- a reference: located reversals, no refinement, a uniform step 16x finer than the
  finest rung of the ladder (about 78 ns; halving it changes nothing we print);
- the default stepping (``Stepping()``: step from the model's time scales, located
  reversals, refined intervals), its RMS error [nm] (offset removed, as a fit sees
  it), and its a-posteriori estimate (``estimate_error``, step doubling);
- the stepping before event location ("today": RK4, 16 sub-steps per sample, no
  location, no refinement), its RMS error;
- the ladder: uniform steps of 5, 2.5 and 1.25 µs with located reversals and no
  refinement, its errors and the observed orders log2(e(h)/e(h/2)).

Usage::

    .venv/bin/python benchmarks/bench_accuracy.py --json out/bench_accuracy.json \
        --figure out/accuracy.png
    .venv/bin/python benchmarks/bench_accuracy.py --quick   # four drives, 0.05 s
"""

from __future__ import annotations

import argparse
import math
import platform
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from results_record import write_record  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.model.base import DriveContext  # noqa: E402

LADDER_S = (5e-6, 2.5e-6, 1.25e-6)
REF_FACTOR = 16
TODAY = ss.Stepping.uniform(16, ss.RK4.with_events(False))
TARGET_NM = 0.05


def drives(quick: bool):
    """(label, waveform, amplitude V, frequency Hz, direction, sample rate Hz)."""
    out = []
    rates = (2_500.0, 25_000.0, 100_000.0)
    for fs in rates:
        for f in (50.0, 500.0):
            for a in (40.0, 60.0):
                for d in ("forward", "backward"):
                    out.append((f"saw {a:g} V {f:g} Hz {d[:3]} @ {fs / 1e3:g} kHz",
                                "sawtooth", a, f, d, fs))
    out += [
        ("saw 60 V 200 Hz fwd @ 10 kHz", "sawtooth", 60.0, 200.0, "forward", 10_000.0),
        ("saw 60 V 200 Hz fwd @ 2.5 kHz", "sawtooth", 60.0, 200.0, "forward", 2_500.0),
        ("scan 20 V 100 Hz fwd @ 25 kHz", "sawtooth", 20.0, 100.0, "forward", 25_000.0),
        ("sine 40 V 50 Hz @ 25 kHz", "sine", 40.0, 50.0, "forward", 25_000.0),
        ("step 40 V @ 25 kHz", "step", 40.0, 0.0, "forward", 25_000.0),
    ]
    if quick:
        keep = (1, 7, 13, -4)
        out = [out[i] for i in keep]
    return out


def voltage(wave, a, f, d, fs, duration):
    if wave == "sawtooth":
        return ss.sawtooth(a, f, direction=d, duration_s=duration, sample_rate_Hz=fs)[1]
    if wave == "sine":
        return ss.sine(a, f, duration_s=duration, sample_rate_Hz=fs)[1]
    return ss.step(a, duration_s=duration, sample_rate_Hz=fs)[1]


def rms_nm(q, ref):
    e = np.asarray(q) - np.asarray(ref)
    e = e - e.mean()
    return float(1e9 * np.sqrt(np.mean(e * e)))


def ladder_stepping(h, fs):
    """Uniform sub-steps of about ``h`` [s] (an exact divisor of the sample period)."""
    n = max(1, round(1.0 / (fs * h)))
    return ss.Stepping.uniform(n)


def run(quick: bool):
    act = ss.lu2015_slc1720()
    duration = 0.05 if quick else 0.2
    rows = []
    for label, wave, a, f, d, fs in drives(quick):
        u = voltage(wave, a, f, d, fs, duration)
        drive = DriveContext.make(d == "backward", a, f)
        dt = 1.0 / fs
        n_fine = max(1, round(dt / LADDER_S[-1]))
        ref_plan = ss.Stepping.uniform(REF_FACTOR * n_fine)
        t0 = time.perf_counter()
        ref = np.asarray(ss.simulate(act, u, dt=dt, drive=drive, stepping=ref_plan))
        t_ref = time.perf_counter() - t0
        plan = ss.plan_steps(act, dt)
        default = rms_nm(ss.simulate(act, u, dt=dt, drive=drive), ref)
        estimate = 1e9 * ss.estimate_error(act, u, dt=dt, drive=drive)
        today = rms_nm(ss.simulate(act, u, dt=dt, drive=drive, stepping=TODAY), ref)
        ladder = [rms_nm(ss.simulate(act, u, dt=dt, drive=drive,
                                     stepping=ladder_stepping(h, fs)), ref)
                  for h in LADDER_S]
        orders = [math.log2(e1 / e2) if e1 > 0 and e2 > 0 else None
                  for e1, e2 in zip(ladder[:-1], ladder[1:], strict=True)]
        rows.append({
            "drive": label, "samples": int(u.size), "sample_rate_Hz": fs,
            "reference_substeps": REF_FACTOR * n_fine,
            "reference_step_ns": 1e9 * dt / (REF_FACTOR * n_fine), "reference_s": t_ref,
            "default_substeps": plan.substeps, "default_refine": plan.refine,
            "default_nm": default, "estimate_nm": estimate, "today_nm": today,
            "ladder_step_us": [1e6 * dt / max(1, round(dt / h)) for h in LADDER_S],
            "ladder_nm": ladder, "orders": orders,
            "pass": default <= TARGET_NM,
        })
        print(f"{label:34s} default {default:8.4f} nm (est. {estimate:7.4f})  "
              f"today {today:8.3f} nm  ladder "
              + " ".join(f"{e:8.4f}" for e in ladder)
              + "  orders " + " ".join("-" if o is None else f"{o:4.1f}" for o in orders),
              flush=True)
    return rows


def figure(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.4))
    for r in rows:
        if not r["drive"].startswith("saw") or r["drive"].startswith("scan"):
            continue
        ax.loglog(r["ladder_step_us"], np.maximum(r["ladder_nm"], 1e-6), "o-", lw=0.8,
                  ms=3, alpha=0.7)
    h = np.array(LADDER_S) * 1e6
    ax.loglog(h, 0.05 * (h / h[-1]) ** 4, "k--", lw=1.2, label="slope 4")
    ax.axhline(TARGET_NM, color="r", lw=0.8, ls=":", label=f"{TARGET_NM} nm")
    ax.set_xlabel("uniform sub-step h [µs] (reversals located, no refinement)")
    ax.set_ylabel("RMS error vs converged [nm]")
    ax.set_title("Convergence through slips (sawtooth drives)")
    ax.legend(fontsize=8)
    x = np.arange(len(rows))
    bx.semilogy(x, [max(r["today_nm"], 1e-6) for r in rows], "s", ms=4,
                label="before: RK4, 16 sub-steps/sample")
    bx.semilogy(x, [max(r["default_nm"], 1e-6) for r in rows], "o", ms=4,
                label="default now")
    bx.semilogy(x, [max(r["estimate_nm"], 1e-6) for r in rows], "x", ms=4,
                label="its a-posteriori estimate")
    bx.axhline(TARGET_NM, color="r", lw=0.8, ls=":")
    bx.set_xticks(x)
    bx.set_xticklabels([r["drive"] for r in rows], rotation=90, fontsize=6)
    bx.set_ylabel("RMS error [nm]")
    bx.set_title("Default settings, every drive (0.2 s)")
    bx.legend(fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--figure", help="write the convergence figure here (PNG)")
    ap.add_argument("--quick", action="store_true", help="four drives, 0.05 s")
    args = ap.parse_args()
    ss.fast_cpu_loops()
    rows = run(args.quick)
    worst = max(r["default_nm"] for r in rows)
    print(f"worst default error {worst:.4f} nm (target {TARGET_NM} nm): "
          f"{'PASS' if worst <= TARGET_NM else 'MISS'}")
    if args.json:
        write_record(Path(args.json), machine=platform.node(), jax=jax.__version__,
                     target_nm=TARGET_NM, worst_default_nm=worst, rows=rows)
    if args.figure:
        figure(rows, args.figure)


if __name__ == "__main__":
    main()

"""Sweep scale: velocity maps of 50, 200 and 800 grid points against a serial numba loop.

    .venv/bin/python benchmarks/bench_sweep.py --json out/bench_sweep.json [--repeats 5]

Grids: n_a amplitudes in 10..80 V x n_f frequencies geometric in 50..1000 Hz x both
directions, 10 periods each at 25 kHz, default profile. The sweep runs at the
simulator's default stepping (``Stepping()``: a step from the model's fastest mode, 9
coarse RK4 sub-steps per 25 kHz sample on this profile, located slip reversals, 8x
refined intervals where the error estimate asks for it). Each grid is run once to
compile, then ``--repeats`` times; medians.
Reference: the plain numba loop of bench_simulator.py run serially over every point
of the 200-point grid (forward parameters for all points: the work per sub-step is
the same), at 16 RK4 sub-steps per sample, the scheme before event location (a fixed
yardstick, whatever the JAX default is). Throughput is compared per sample (wall /
samples: the same drive to the same sample times, each at its own stepping); per
sub-step (wall / (samples x sub-steps), the JAX sweep's coarse sub-steps, refined
intervals' extra sub-steps not counted) is given as information.
Targets (issue #4): 200 points under 10 s after compilation; time per sample of the
batched sweep at most that of the serial numba loop; time linear in grid size.
"""

import argparse
import json
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from bench_simulator import numba_plain, reference_parameters  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.signals import sawtooth  # noqa: E402
from stickslip_jax.sweep import DriveGrid, samples_needed, velocity_map  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

FS = 25_000.0
PERIODS = 10
SIZES = {50: (5, 5), 200: (10, 10), 800: (20, 20)}
NUMBA_SUBSTEPS = 16  # the numba reference's RK4 sub-steps per sample (fixed)


def plan_record(plan) -> dict:
    """The default stepping's plan at 25 kHz (for the JSON)."""
    return {"substeps": plan.substeps, "refine": plan.refine, "tolerance_m": plan.tolerance,
            "locate_events": plan.solver.locate_events}


def grid_of(n_a: int, n_f: int) -> DriveGrid:
    return DriveGrid.make(np.linspace(10, 80, n_a), np.geomspace(50, 1000, n_f), "both")


def time_sweep(grid: DriveGrid, repeats: int) -> dict:
    act = ss.lu2015_slc1720()
    t0 = time.perf_counter()
    first = velocity_map(act, grid, periods=PERIODS)
    compile_and_first = time.perf_counter() - t0
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        m = velocity_map(act, grid, periods=PERIODS)
        walls.append(time.perf_counter() - t0)
    samples = int(first.run.samples_needed)
    med = float(np.median(walls))
    substeps = ss.plan_steps(act, 1 / FS).substeps  # coarse sub-steps per sample
    return {"points": len(grid), "samples": samples, "slots": m.run.chunk,
            "samples_with_padding": int(m.run.samples_simulated),
            "first_call_s": compile_and_first, "median_s": med, "runs_s": walls,
            "substeps": substeps, "us_per_sample": med / samples * 1e6,
            "us_per_substep": med / (samples * substeps) * 1e6}


def time_numba(grid: DriveGrid, repeats: int) -> dict:
    prm, r, w = reference_parameters(ss.lu2015_slc1720())
    prm = np.asarray(prm)
    drives = []
    for a, f in zip(grid.amplitude_V, grid.frequency_Hz, strict=True):
        n = int(samples_needed(f, PERIODS, FS))
        drives.append(sawtooth(a, f, duration_s=n / FS)[1])
    numba_plain(drives[0][:32], 1 / FS, NUMBA_SUBSTEPS, prm, r, w)  # compile
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for u in drives:
            numba_plain(u, 1 / FS, NUMBA_SUBSTEPS, prm, r, w)
        walls.append(time.perf_counter() - t0)
    samples = int(sum(len(u) for u in drives))
    med = float(np.median(walls))
    return {"points": len(grid), "samples": samples, "median_s": med, "runs_s": walls,
            "substeps": NUMBA_SUBSTEPS, "us_per_sample": med / samples * 1e6,
            "us_per_substep": med / (samples * NUMBA_SUBSTEPS) * 1e6}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    res = {"platform": platform.platform(), "devices": [str(d) for d in jax.devices()],
           "jax": jax.__version__, "stepping": "default",
           "plan": plan_record(ss.plan_steps(ss.lu2015_slc1720(), 1 / FS)),
           "numba_substeps": NUMBA_SUBSTEPS, "periods": PERIODS, "sweeps": {}}
    for n, (n_a, n_f) in SIZES.items():
        res["sweeps"][str(n)] = time_sweep(grid_of(n_a, n_f), args.repeats)
        s = res["sweeps"][str(n)]
        print(f"{n:4d} points: {s['samples']:8d} samples, {s['slots']:3d} slots, first call "
              f"{s['first_call_s']:.2f} s, median {s['median_s']:.3f} s, "
              f"{s['us_per_sample']:.3f} µs/sample, {s['us_per_substep']:.3f} µs/coarse "
              f"sub-step ({s['substeps']} per sample)", flush=True)
    nb = time_numba(grid_of(*SIZES[200]), max(1, args.repeats // 2))
    res["numba_serial_200"] = nb
    s200 = res["sweeps"]["200"]
    ratio = s200["us_per_sample"] / nb["us_per_sample"]
    ratio_substep = s200["us_per_substep"] / nb["us_per_substep"]
    lin = {k: v["median_s"] / v["samples"] for k, v in res["sweeps"].items()}
    res["checks"] = {
        "grid200_s": s200["median_s"], "grid200_target_s": 10.0,
        "sweep_over_numba_per_sample": ratio, "target_ratio": 1.0,
        "sweep_over_numba_per_substep": ratio_substep,
        "seconds_per_sample_by_size": lin,
    }
    print(f"numba serial, 200 points ({NUMBA_SUBSTEPS} sub-steps/sample): median "
          f"{nb['median_s']:.3f} s, {nb['us_per_sample']:.3f} µs/sample, "
          f"{nb['us_per_substep']:.3f} µs/sub-step")
    print(f"200-point grid: {s200['median_s']:.2f} s (target < 10 s: "
          f"{'PASS' if s200['median_s'] < 10 else 'MISS'}); per sample sweep/numba "
          f"{ratio:.2f} (target ≤ 1: {'PASS' if ratio <= 1 else 'MISS'}); per sub-step "
          f"{ratio_substep:.2f} (info: {s200['substeps']} against {NUMBA_SUBSTEPS} per "
          "sample)")
    print("time per sample by grid size [µs]: " +
          ", ".join(f"{k}: {v * 1e6:.2f}" for k, v in lin.items()))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

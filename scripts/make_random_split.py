"""Write a split of random recording sets (issue #27) to a folder, with its answers.

    .venv/bin/python scripts/make_random_split.py --split dev --out out/random_dev
    .venv/bin/python scripts/make_random_split.py --split test --out out/random_test --n 24
    .venv/bin/python scripts/make_random_split.py --calibrate [--forms creep,sensor_delay]

Each set ``DIR/set_NN`` holds the 17 recordings of the protocol as CSV, simulated from
:func:`stickslip_jax.testing.random_sets.draw_set` (the split's seed, the set's index:
a random truth, one hidden effect or none, white noise; see that module). The answers
are in ``DIR/answers.json``: per set the effect, its form, whether the catalogue fits
that form, the strength and the other parameters, the noise, the truth, and the effect
size (RMS of the trace with the effect minus without it, offset removed, in nm and
over the noise; and the part the baseline cannot absorb to first order, unless
``--no-beyond``). About 10-90 s per set. The sets are not committed: the seeds are.
The test split is frozen: generate it to report on it, never to tune on it.

``--calibrate`` prints instead the effect size at each form's range ends (and the
middle) at the central truth, the numbers the module's ranges were set from.
"""

import argparse
import json
import math
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.stepping import DEFAULT_STEPPING  # noqa: E402
from stickslip_jax.testing import random_sets as rs  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

SEEDS = {name: seed for name, (seed, _) in rs.SPLITS.items()}


def answer(spec: rs.SetSpec, size: dict) -> dict:
    """The answers.json entry of one set: its spec, and its effect size in nm."""
    out = spec.to_json()
    out["effect_size"] = {
        "rms_nm": 1e9 * size["rms_m"], "to_noise": size["to_noise"],
        "rms_raw_nm": 1e9 * size["rms_raw_m"],
        **({"beyond_baseline_nm": 1e9 * size["beyond_baseline_m"],
            "beyond_to_noise": size["beyond_to_noise"]} if "beyond_baseline_m" in size else {}),
    }
    return out


def write_split(args) -> None:
    seed = SEEDS[args.split]
    args.out.mkdir(parents=True, exist_ok=True)
    answers = {"split": args.split, "seed": seed,
               "protocol": "stickslip_jax.synthetic.paper_protocol() (17 recordings, 25 kHz)",
               "stepping": "REFERENCE_STEPPING",
               "generator": "stickslip_jax.testing.random_sets.split_sets(split)",
               "sets": {}}
    path = args.out / "answers.json"
    ss.files.check_output_path(path, force=args.force)
    for spec in rs.split_sets(args.split, args.n):
        t0 = time.perf_counter()
        folder = args.out / spec.name
        folder.mkdir(exist_ok=True)
        for rec in rs.make_recordings(spec):
            ss.save_recording(rec, folder / f"{rec.name}.csv", force=args.force)
        size = rs.effect_size(spec, beyond_baseline=not args.no_beyond)
        answers["sets"][spec.name] = answer(spec, size)
        # After every set: an interrupted run keeps the answers of what it wrote.
        ss.files.atomic_write_text(path, json.dumps(answers, indent=1) + "\n")
        print(f"{spec.name}: {spec.effect} ({spec.form}), effect "
              f"{1e9 * size['rms_m']:.3g} nm = {size['to_noise']:.3g} x noise "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    print(f"wrote {len(answers['sets'])} sets and {path}")


def calibrate(args) -> None:
    """Effect size of each form at its range ends and middle, at the central truth
    (offset removed, default stepping, 1 nm noise for the ratio); with ``--beyond``
    on the strong end the share the baseline cannot absorb."""
    chosen = [s for s in args.forms.split(",") if s]
    print("| entry | form | strength | weak end | middle | strong end | beyond share |")
    print("|---|---|---|---|---|---|---|")
    for f in rs.FORMS:
        if chosen and f.entry not in chosen and f.name not in chosen:
            continue
        nm, share = [], ""
        for s in (f.low, math.sqrt(f.low * f.high), f.high):
            last = s == f.high and not args.no_beyond
            size = rs.effect_size(rs.fixed_set(f.entry, f.name, s), stepping=DEFAULT_STEPPING,
                                  beyond_baseline=last)
            nm.append(f"{1e9 * size['rms_m']:.3g} nm")
            if last:
                share = f"{size['beyond_baseline_m'] / size['rms_m']:.3f}"
        print(f"| {f.entry} | {f.name} | {f.strength} [{f.unit}] {f.low:.3g} - {f.high:.3g} | "
              + " | ".join(nm) + f" | {share} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=sorted(SEEDS))
    ap.add_argument("--out", type=Path)
    ap.add_argument("--n", type=int, default=None,
                    help="sets 0 … n−1 of the split (default: its design's size)")
    ap.add_argument("--force", action="store_true", help="replace existing files")
    ap.add_argument("--no-beyond", action="store_true",
                    help="skip the effect size beyond the baseline (about 20 s a set)")
    ap.add_argument("--calibrate", action="store_true",
                    help="print each form's effect size at its range ends instead")
    ap.add_argument("--forms", default="", help="with --calibrate: entries or forms")
    args = ap.parse_args()
    if args.calibrate:
        calibrate(args)
        return
    if args.split is None or args.out is None:
        ap.error("--split and --out are needed (or --calibrate)")
    if args.n is not None and args.n < 1:
        ap.error("--n must be at least 1")
    write_split(args)


if __name__ == "__main__":
    main()

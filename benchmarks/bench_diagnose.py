"""Diagnosis on every concealed set: which effect it names, the fit before and after, time.

    .venv/bin/python benchmarks/bench_diagnose.py --json out/bench_diagnose.json
    .venv/bin/python benchmarks/bench_diagnose.py --sets set_03,set_09 --from-profile
    .venv/bin/python benchmarks/bench_diagnose.py --variants all --json out/variants.json
    .venv/bin/python benchmarks/bench_diagnose.py --sets set_06 --from-profile \
        --config gauss_newton_trial=False --json out/set_06_damped.json   # an ablation

For each folder of fixtures/concealed/ (17 recordings, the identification protocol with
one hidden effect, see fixtures/concealed/README.md) run :func:`diagnose` and compare
with ``answers.json``. The baseline starts from the identification truth without the
effect (``fixtures/identification/truth.json``) and is polished on the data; with
``--from-profile`` it is identified from the default profile first (the paper's three
steps plus joint, as `stickslip diagnose` does without ``--skip-identify``), which is
the end-to-end timing of the issue (target: < 10 min per 17-recording set).

``--variants`` runs instead the independent variants of
:data:`stickslip_jax.testing.concealed.VARIANTS`: other functional forms and
magnitudes of the effects (a second-order amplifier, a two-mode creep, a 2.2 kHz mode,
an 8 µs delay, a negative load, an interferometer periodic error of one sine, ...),
simulated in memory on the same protocol (``--reduced``: the tests' 8-recording
protocol), to check that the diagnosis is not tuned to the fixtures' generator, and
those of :data:`~stickslip_jax.testing.concealed.FRINGE_START_VARIANTS`, read as a
real interferometer reads a set: each recording from its own random point of the
fringe. ``--config FIELD=VALUE`` runs it with a :class:`DiagnoseConfig` change (recorded in the
JSON): an ablation of a switch beside a default run, in one checkout.

Columns: hidden effect, named effect (first accepted; ``unexplained`` when the verdict
is the unexplained residual; ``-`` when nothing was named), verdict, mean NRMSE before
and after, the noise floor (mean σ/peak-to-peak), the share of the NRMSE excess over the
floor removed, wall time (compilation included; ``compile_s`` and
``programs_compiled`` in the JSON: XLA's tracing and compiling within it). No
persistent compilation cache unless ``$STICKSLIP_CACHE_DIR`` names a folder (the
rows' ``compilation_cache``).
"""

import argparse
import ast
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.compilation_cache import (  # noqa: E402
    cache_dir_from_env,
    use_compilation_cache,
)
from stickslip_jax.diagnose import DiagnoseConfig, Policy, Verdict, diagnose  # noqa: E402
from stickslip_jax.diagnose.report import diagnosis_dict, form_found  # noqa: E402
from stickslip_jax.synthetic import paper_protocol, simulate_set  # noqa: E402
from stickslip_jax.testing.concealed import (  # noqa: E402
    FRINGE_START_VARIANTS,
    VARIANTS,
    fringe_start_sensor,
    read_from_fringe_starts,
    with_variant,
)

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)
# No persistent cache unless $STICKSLIP_CACHE_DIR names one (wall times are then those
# of a run whose programs another run compiled; each row says which, "compilation_cache").
CACHE_DIR = cache_dir_from_env(default=None)
CACHE_ON = use_compilation_cache(CACHE_DIR)

ROOT = Path(__file__).resolve().parent.parent
CONCEALED = ROOT / "fixtures" / "concealed"


TRUTH = ROOT / "fixtures" / "identification" / "truth.json"


REDUCED_SETTINGS = dict(max_rounds=1, top=2, max_steps=20, size_at_most=3)
"""``--reduced``: the tests' diagnose settings (fewer, shorter refits)."""


def protocol(reduced: bool):
    """The 17 drives of the fixtures, or (``reduced``) the 8-recording protocol of
    tests/test_diagnose.py."""
    if reduced:
        return paper_protocol(periods=3, amplitudes=(60.0,), frequencies=(100.0, 500.0),
                              step_duration_s=0.03, sine_periods=2)
    return paper_protocol()


def variant_recordings(variant: str, *, reduced: bool, seed: int):
    """The protocol simulated from the truth with one variant effect, 1 nm noise (the
    variants read per recording: each from its own point of the fringe)."""
    specs = protocol(reduced)
    if variant in FRINGE_START_VARIANTS:
        clean = simulate_set(ss.load_params(TRUTH), specs, noise_m=0.0)
        return read_from_fringe_starts(clean, lambda o: fringe_start_sensor(variant, o),
                                       noise_m=1e-9, seed=seed)[0]
    act = with_variant(ss.load_params(TRUTH), variant)
    return simulate_set(act, specs, noise_m=1e-9, seed=seed)


class CompileClock:
    """XLA's tracing, lowering and compiling, summed from JAX's monitoring events since
    the process started: how much of a diagnosis's wall time is compiling (each fit
    compiles its own Jacobian program) and how many programs it compiled."""

    EVENTS = ("/jax/core/compile/backend_compile_duration",
              "/jax/core/compile/jaxpr_trace_duration",
              "/jax/core/compile/jaxpr_to_mlir_module_duration")

    def __init__(self):
        self.seconds, self.programs = 0.0, 0
        jax.monitoring.register_event_duration_secs_listener(self._listen)

    def _listen(self, event: str, duration: float, **_):
        if event in self.EVENTS:
            self.seconds += duration
            self.programs += event == self.EVENTS[0]


COMPILE_CLOCK = CompileClock()


def run_set(folder: Path | str, *, from_profile: bool, max_rounds: int, recs=None,
            **kw) -> dict:
    recs = ss.load_recordings([folder]) if recs is None else recs
    if from_profile:
        init, steps = ss.lu2015_slc1720(), ("dynamics", "hysteresis", "friction", "joint")
    else:
        init, steps = ss.load_params(TRUTH), ()
    t0 = time.perf_counter()
    compile0 = (COMPILE_CLOCK.seconds, COMPILE_CLOCK.programs)
    d = diagnose(recs, init=init, fix={"Ms": 0.0247}, identify_steps=steps,
                 max_rounds=max_rounds, echo=lambda s: print("   ", s, flush=True), **kw)
    wall = time.perf_counter() - t0
    floor = float(np.mean([a.noise_m / np.ptp(r.position_m)
                           for a, r in zip(d.analyses_baseline, recs, strict=True)]))
    before, after = float(d.nrmse_baseline.mean()), float(d.nrmse_final.mean())
    excess = before - floor
    named = [c.name for c in d.accepted]
    return {
        "set": getattr(folder, "name", folder), "verdict": d.verdict, "named": named,
        "first": ("unexplained" if d.verdict is Verdict.UNEXPLAINED and not named
                  else named[0] if named else "-"),
        "indistinguishable_from": d.accepted[0].indistinguishable_from if named else [],
        "nrmse_before": before, "nrmse_after": after, "noise_floor_nrmse": floor,
        "excess_removed": (before - after) / excess if excess > 0 else None,
        "chi2_before": d.chi2_baseline, "chi2_after": d.chi2_final,
        "unexplained_depends_on": (d.unexplained or {}).get("depends_on"),
        "wall_s": wall, "timings_s": d.timings,
        "compile_s": COMPILE_CLOCK.seconds - compile0[0],
        "programs_compiled": COMPILE_CLOCK.programs - compile0[1],
        "compilation_cache": str(CACHE_DIR) if CACHE_ON else None,
        "tolerance_chi2": d.significance.get("tolerance_chi2"),
        "detection_limits": d.detection_limits,
        # Each round's entries (scores, sizings, refits, status) and the counted work:
        # enough to replay a change of the refit rules on this set offline.
        "candidates_by_round": diagnosis_dict(d)["candidates_by_round"],
        # What each accepted entry's refit found: its parameters and form in words.
        "accepted": [{"name": c.name, "params": c.params, "form": form_found(c.name, c.params)}
                     for c in d.accepted],
        "passes": d.config.record()["passes"] if d.config is not None else None,
        "work_budget": d.work,
    }


def config_changes(items: list[str]) -> dict:
    """``FIELD=VALUE`` items as :class:`DiagnoseConfig` changes (values as Python
    literals, or ``inf``); a :class:`Policy` field changes the configuration's policy
    (``leader_alone_share=inf``: that rule off); a field of neither is an error."""
    fields = {f.name for f in dataclasses.fields(DiagnoseConfig)}
    thresholds = {f.name for f in dataclasses.fields(Policy)}
    changes, policy = {}, {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or name not in fields | thresholds:
            sys.exit(f"--config {item!r}: give FIELD=VALUE with FIELD one of "
                     f"{', '.join(sorted(fields | thresholds))}")
        value = float(text) if text.strip().lower() in ("inf", "-inf") else ast.literal_eval(text)
        (policy if name in thresholds else changes)[name] = value
    if policy:
        changes["policy"] = dataclasses.replace(changes.get("policy", Policy()), **policy)
    return changes


def write_json(args, rows: list[dict]) -> None:
    """The rows so far to ``--json`` (if given)."""
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"split": "concealed", "rows": rows,
                                         "from_profile": args.from_profile,
                                         "variants": bool(args.variants),
                                         "reduced": args.reduced,
                                         **({"config": args.config} if args.config else {}),
                                         "jax": jax.__version__}, indent=1, default=float))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="", help="comma-separated set folders (default all)")
    ap.add_argument("--from-profile", action="store_true",
                    help="identify the baseline from the default profile first")
    ap.add_argument("--max-rounds", type=int, default=3)
    ap.add_argument("--variants", default="",
                    help="comma-separated independent variants, or 'all' (instead of sets)")
    ap.add_argument("--reduced", action="store_true",
                    help="variants on the tests' 8-recording protocol and settings")
    ap.add_argument("--seed", type=int, default=9000,
                    help="noise seed of the variants (variant i draws seed + 17 i)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--config", nargs="+", default=[], metavar="FIELD=VALUE",
                    help="a DiagnoseConfig change, e.g. gauss_newton_trial=False (an "
                         "ablation beside the default run; the value a Python literal)")
    args = ap.parse_args()
    config = DiagnoseConfig().replace(**config_changes(args.config))
    answers = json.loads((CONCEALED / "answers.json").read_text())["sets"]
    chosen = [s for s in args.sets.split(",") if s] or sorted(answers)
    variants = VARIANTS | FRINGE_START_VARIANTS
    if args.variants:
        chosen = list(variants) if args.variants == "all" else args.variants.split(",")
        unknown = [v for v in chosen if v not in variants]
        if unknown:
            sys.exit(f"unknown variant(s) {unknown}; choose from {', '.join(variants)}")
    kw = REDUCED_SETTINGS if args.reduced else {}
    rows = []
    for name in chosen:
        print(f"== {name}", flush=True)
        if args.variants:
            # The noise draw goes with the variant, whichever others run beside it.
            seed = args.seed + 17 * list(variants).index(name)
            recs = variant_recordings(name, reduced=args.reduced, seed=seed)
            row = run_set(name, from_profile=args.from_profile, recs=recs, config=config,
                          **{"max_rounds": args.max_rounds, **kw})
            row["hidden"] = f"{variants[name][0]} ({variants[name][1]})"
        else:
            row = run_set(CONCEALED / name, from_profile=args.from_profile,
                          max_rounds=args.max_rounds, config=config)
            row["hidden"] = answers[name]
        rows.append(row)
        write_json(args, rows)  # after every set: a later crash keeps the rows done
        print(json.dumps({k: row[k] for k in ("set", "hidden", "first", "verdict",
                                              "nrmse_before", "nrmse_after", "wall_s")}),
              flush=True)
    print("\n| set | hidden effect | named first | verdict | NRMSE before | NRMSE after | "
          "floor | excess removed | work [1e6] | wall |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        ex = "" if r["excess_removed"] is None else f"{100 * r['excess_removed']:.0f} %"
        work = f"{r['work_budget']['spent'] / 1e6:.1f}" if r.get("work_budget") else ""
        print(f"| {r['set']} | {r['hidden']} | {r['first']} | {r['verdict']} | "
              f"{100 * r['nrmse_before']:.4f} % | {100 * r['nrmse_after']:.4f} % | "
              f"{100 * r['noise_floor_nrmse']:.4f} % | {ex} | {work} | {r['wall_s']:.0f} s |")
    sys.exit(0)


if __name__ == "__main__":
    main()

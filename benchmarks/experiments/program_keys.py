"""Which per-recording programs reduced diagnoses trace, one after the other in one
process (as a test worker runs them), and at which stepping plan: the programs a later
diagnosis traces again, and why (another structure, or the same at other sub-steps).

    .venv/bin/python benchmarks/experiments/program_keys.py none sensor_delay \\
        --cache out/program_keys_cache --json out/program_keys.json

The diagnoses are ``tests/test_diagnose.py``'s reduced sets (8 recordings, the baseline
polished from the truth, one round). The traced-program store (in ``--cache``, which
must be empty for a cold count) is where every per-recording program is made; each
program it makes is listed with the diagnosis it was made in, the function, the plan's
sub-steps per sample and the extensions in the actuator's structure.
"""

from __future__ import annotations

import argparse
import collections
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("effects", nargs="+", help="hidden effects, in the order to run them")
    ap.add_argument("--cache", type=Path, required=True, help="an empty folder")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    import jax
    jax.config.update("jax_enable_x64", True)
    import stickslip_jax as ss
    from stickslip_jax import program_store
    from stickslip_jax.compilation_cache import use_compilation_cache
    ss.fast_cpu_loops()
    use_compilation_cache(args.cache)
    sys.path.insert(0, str(ROOT / "tests"))
    import test_diagnose as td

    made: list[dict] = []
    phase = {"effect": None}
    original = program_store._load_or_export

    def logged(fn, name, folder, treedef, static, static_def, static_leaves, leaves, avals):
        text = str(static_def)
        plan = re.search(r"StepPlan\[\(Missing, (\d+),", text)
        parts = re.findall(r"CustomNode\((\w+)\[", text)
        made.append({"diagnosis": phase["effect"], "program": name.split(".")[-1],
                     "substeps": int(plan.group(1)) if plan else None,
                     "structure": sorted(set(parts))})
        return original(fn, name, folder, treedef, static, static_def, static_leaves,
                        leaves, avals)

    program_store._load_or_export = logged
    base = ss.load_params(td.TRUTH)
    for effect in args.effects:
        phase["effect"] = effect
        kw = {} if effect in ("uncatalogued", "none") else {"fallback": False}
        _, d = td.run(base, effect, **kw)
        mine = [m for m in made if m["diagnosis"] == effect]
        plans = collections.Counter(m["substeps"] for m in mine if m["substeps"])
        print(f"{effect}: {d.verdict}; {len(mine)} programs made; sub-steps per sample "
              f"{dict(sorted(plans.items()))}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(made, indent=1))


if __name__ == "__main__":
    main()

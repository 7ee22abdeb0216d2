"""Is ``tangents_per_call``'s rule (k columns go one per call while 2·k ≤ width, else in
one call of the width) where the two costs cross? The derivatives of every recording
along k tangents, one per call against one call of the wide program, after a warm-up,
medians of five.

    .venv/bin/python benchmarks/experiments/tangent_width_rule.py reduced fixtures \\
        --json out/tangent_width_rule.json

``reduced``: tests/test_diagnose.py's reduced protocol (8 recordings, nothing hidden);
``fixtures``: the 17 bundled identification recordings. The actuator is the fixtures'
truth, the programs carry every fittable quantity but Ms (their width: that size shared
between the Jacobian threads), the k tangents are unit vectors along the first k
scalars. Same programs, same threads as an identification's; XLA's native loops on.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))  # results_record
sys.path.insert(0, str(ROOT / "tests"))  # test_diagnose: the tests' reduced protocol
from results_record import write_record  # noqa: E402

import stickslip_jax as ss  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

import equinox as eqx  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from stickslip_jax.identify import sensitivities  # noqa: E402
from stickslip_jax.identify.dataset import Dataset  # noqa: E402
from stickslip_jax.identify.parameters import fittable_names  # noqa: E402
from stickslip_jax.identify.residuals import dataset_plan  # noqa: E402

COLUMNS = (1, 2, 3, 4, 6, 8, 10)


def recordings(which: str, base) -> list:
    if which == "reduced":
        import test_diagnose

        return test_diagnose.reduced_set(base, "none")
    folder = ROOT / "fixtures" / "identification"
    return [ss.load_recording(p) for p in sorted(folder.glob("*.csv"))]


def unit_tangents(free, k: int):
    """k unit tangents along the first k scalars of the leaves of ``free``."""
    leaves, start, out = jax.tree.leaves(free), 0, []
    for x in leaves:
        n = int(np.size(x))
        t = np.zeros((k, n))
        for j in range(start, min(k, start + n)):
            t[j, j - start] = 1.0
        out.append(t.reshape((k,) + np.shape(x)))
        start += n
    return jax.tree.unflatten(jax.tree.structure(free), out)


def median_s(f, repeats: int = 5) -> float:
    f()  # warm-up: compiles
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def measure(which: str) -> dict:
    base = ss.load_params(ROOT / "fixtures" / "identification" / "truth.json")
    data = Dataset.from_recordings(recordings(which, base))
    mask = sensitivities.perturbed_mask(base, [n for n in fittable_names(base) if n != "Ms"])
    plan = dataset_plan(base, data)
    programs = sensitivities.RecordingPrograms(data, base, mask)
    free = eqx.filter(base, mask)
    rule = sensitivities.tangents_per_call
    rows = []
    value_s = median_s(lambda: programs.simulate(base, plan))
    try:
        for k in COLUMNS:
            tangents = unit_tangents(free, k)
            costs = {}
            for how, per_call in (("singly", lambda k, w: 1), ("wide", lambda k, w: w)):
                sensitivities.tangents_per_call = per_call
                costs[how] = median_s(lambda t=tangents: programs.sensitivities(base, t, plan))
            rows.append({"columns": k, **{f"{h}_s": c for h, c in costs.items()},
                         "rule": "singly" if rule(k, programs.width) == 1 else "wide"})
            print(f"{which} k={k:2d}: singly {1e3 * costs['singly']:6.0f} ms, wide("
                  f"{programs.width}) {1e3 * costs['wide']:6.0f} ms, the rule: "
                  f"{rows[-1]['rule']}", flush=True)
    finally:
        sensitivities.tangents_per_call = rule
    return {"set": which, "recordings": len(data), "samples": int(data.voltages.shape[1]),
            "plan": repr(plan), "width": programs.width, "threads": programs.threads,
            "value_s": value_s, "rows": rows}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sets", nargs="+", choices=("reduced", "fixtures"))
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    write_record(args.json, sets=[measure(s) for s in args.sets])


if __name__ == "__main__":
    main()

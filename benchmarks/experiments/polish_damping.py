"""How the diagnosis's baseline polish changes its Levenberg-Marquardt damping: the
classical update (λ/3.5 only after a step that met 99 % of its predicted fall) beside
Nielsen's (λ lowered after every step that met half of it), on the concealed sets.

Each set is polished as ``stickslip diagnose SET --params PARAMS --skip-identify`` does
it (every baseline quantity free on the whitened residual, from PARAMS, three times the
refit step cap, initial damping 1), once with each update, in one process, the order
alternating by set; per polish: the steps, how it ended, its whitened cost and wall
time. A converged polish ends by the Gauss-Newton test (a tenth of a standard error),
so the two should end at one optimum, and the steps are what differs.

    .venv/bin/stickslip identify fixtures/identification --out out/id --fix Ms=0.0247
    .venv/bin/python benchmarks/experiments/polish_damping.py --params out/id/params.json \\
        --sets set_01,set_03 --json out/polish_damping.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import stickslip_jax as ss  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)


from stickslip_jax.diagnose import DiagnoseConfig  # noqa: E402
from stickslip_jax.diagnose.budget import Budget  # noqa: E402
from stickslip_jax.diagnose.problem import Problem, baseline_free  # noqa: E402
from stickslip_jax.identify.dataset import Dataset  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from results_record import write_record  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
UPDATES = ("classical", "nielsen")


def polish(recordings, init, fix: dict, update: str) -> dict:
    """The baseline polish of ``recordings`` from ``init`` with ``update``."""
    data = Dataset.from_recordings(recordings)
    problem = Problem.whitened(data, fix, lambda s: None, Budget(None))
    program = problem.program(init, baseline_free(init, data, fix), {})
    t0 = time.perf_counter()
    _, cost, out = problem.fit_from(program, program.pmap.zeros(), label="baseline polish",
                                    max_steps=3 * DiagnoseConfig().max_steps,
                                    damping_update=update)
    return {"update": update, "steps": int(out.iterations), "converged": bool(out.converged),
            "message": out.message, "cost_start": float(out.cost_start), "cost_end": cost,
            "wall_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--params", type=Path, required=True,
                    help="identified parameters (JSON) the polish starts from")
    ap.add_argument("--sets", default="set_01,set_03,set_04,set_05,set_06,set_09,set_10,set_12")
    ap.add_argument("--fix", default="Ms=0.0247", help="NAME=VALUE[,NAME=VALUE]")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    init = ss.load_params(args.params)
    fix = {k: float(v) for k, v in (kv.split("=") for kv in args.fix.split(",") if kv)}
    rows = []
    for i, name in enumerate(args.sets.split(",")):
        recordings = ss.load_recordings(ROOT / "fixtures" / "concealed" / name)
        for update in (UPDATES if i % 2 == 0 else UPDATES[::-1]):
            row = {"set": name, **polish(recordings, init, fix, update)}
            rows.append(row)
            print(f"{name} {update:9s} {row['steps']:3d} steps, {row['wall_s']:6.1f} s, "
                  f"cost {row['cost_end']:.10g} ({row['message']})", flush=True)
    if args.json:
        write_record(args.json, params=str(args.params), rows=rows)


if __name__ == "__main__":
    main()

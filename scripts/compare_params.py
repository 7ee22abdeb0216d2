"""Print a fitted parameter set against a known truth: relative error, and, from the
fit.json beside FITTED.json, the standard error and z = (fitted − truth)/SE, so that
"within error" can be judged.

    python scripts/compare_params.py FITTED.json TRUTH.json

A parameter the identification held fixed (``fixed`` in that fit.json, e.g. ``--fix
Ms=0.0247``) is marked "fixed" instead of an error: it was given, not found.
"""

import json
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import stickslip_jax as ss  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

NAMES = ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0", "z_ba_forward", "z_ba_backward")


def main(fitted_path: str, truth_path: str) -> None:
    fitted = ss.params_from_actuator(ss.load_params(fitted_path))
    truth = ss.params_from_actuator(ss.load_params(truth_path))
    fit_json = Path(fitted_path).with_name("fit.json")
    fit = json.loads(fit_json.read_text()) if fit_json.is_file() else {}
    fixed, stated = fit.get("fixed", {}), fit.get("parameters", {})
    print(f"{'parameter':15s} {'fitted':>13s} {'truth':>13s} {'error':>10s} "
          f"{'SE':>10s} {'z':>6s}")
    for name in NAMES:
        f, t = float(fitted[name]), float(truth[name])
        if name in fixed:
            print(f"{name:15s} {f:13.6g} {t:13.6g} {'fixed':>10s}")
            continue
        se = (stated.get(name) or {}).get("std_error")
        z = f"{(f - t) / se:+6.2f}" if se else f"{'-':>6s}"
        print(f"{name:15s} {f:13.6g} {t:13.6g} {100 * (f / t - 1):+8.3f} % "
              f"{se if se else float('nan'):10.3g} {z}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])

"""Print a fitted parameter set against a known truth (relative errors).

    python scripts/compare_params.py FITTED.json TRUTH.json

A parameter the identification held fixed (``fixed`` in the fit.json beside
FITTED.json, e.g. ``--fix Ms=0.0247``) is marked "fixed" instead of an error: it was
given, not found.
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
    fixed = json.loads(fit_json.read_text()).get("fixed", {}) if fit_json.is_file() else {}
    print(f"{'parameter':15s} {'fitted':>13s} {'truth':>13s} {'error':>10s}")
    for name in NAMES:
        f, t = float(fitted[name]), float(truth[name])
        error = "fixed" if name in fixed else f"{100 * (f / t - 1):+8.3f} %"
        print(f"{name:15s} {f:13.6g} {t:13.6g} {error:>10s}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])

"""Print a fitted parameter set against a known truth (relative errors).

    python scripts/compare_params.py FITTED.json TRUTH.json
"""

import sys

import jax

jax.config.update("jax_enable_x64", True)

import stickslip_jax as ss  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

NAMES = ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0", "z_ba_forward", "z_ba_backward")


def main(fitted_path: str, truth_path: str) -> None:
    fitted = ss.params_from_actuator(ss.load_params(fitted_path))
    truth = ss.params_from_actuator(ss.load_params(truth_path))
    print(f"{'parameter':15s} {'fitted':>13s} {'truth':>13s} {'error':>9s}")
    for name in NAMES:
        f, t = float(fitted[name]), float(truth[name])
        print(f"{name:15s} {f:13.6g} {t:13.6g} {100 * (f / t - 1):+8.3f} %")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])

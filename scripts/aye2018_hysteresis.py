"""PI identification on real measured piezo hysteresis (Aye & Ang 2018, MIT).

    .venv/bin/python scripts/aye2018_hysteresis.py [--json out/aye2018.json]

Trains the hysteresis-only model (stickslip_jax.identify.hysteresis_only) on one
200-sample cycle of model_vi_do (from row 3152, 1-based, as the authors did) and
validates it on test_vi_do_di without inverse compensation: the authors' two cycles
(rows 3852 and 5052, small and growing amplitude) and the full-amplitude part
(rows 1-3200). NRMSE is RMS residual / peak-to-peak of the measured segment; it is
given as is and with the sensor offset re-estimated per segment (the raw capacitive
sensor drifts between files by a fraction of a volt). Linear-gain baseline beside.
"""

import argparse
import json
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import stickslip_jax as ss  # noqa: E402
from stickslip_jax.identify.hysteresis_only import fit_hysteresis_only  # noqa: E402

ss.fast_cpu_loops()  # XLA: native small loops (before any JAX computation)

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "aye2018"
TRAIN = slice(3151, 3351)
VALIDATION = {"cycle_3852": slice(3851, 4051), "cycle_5052": slice(5051, 5251),
              "full_amplitude_1_3200": slice(0, 3200)}


def scores(y_model, y, seg: slice) -> dict:
    r = np.asarray(y_model)[seg] - np.asarray(y)[seg]
    span = float(np.ptp(np.asarray(y)[seg]))
    return {"nrmse": float(np.sqrt(np.mean(r**2)) / span),
            "nrmse_offset_refit": float(np.std(r) / span)}


def evaluate(fit_lag: bool) -> dict:
    model_rec = ss.load_recording(FIXTURES / "model_vi_do.csv")
    test_rec = ss.load_recording(FIXTURES / "test_vi_do_di.csv")
    fit = fit_hysteresis_only(model_rec.voltage_V, model_rec.sensor_V, TRAIN, fit_lag=fit_lag)
    y_test = np.asarray(fit.model.output(test_rec.voltage_V))
    base_test = fit.baseline.output(test_rec.voltage_V)
    return {
        "converged": fit.solve.converged, "iterations": fit.solve.iterations,
        "wall_s": fit.solve.wall_s, "lag": float(fit.model.lag),
        "train": {"pi": fit.train_nrmse, "linear": fit.baseline_train_nrmse},
        "validation": {name: {"pi": scores(y_test, test_rec.sensor_V, seg),
                              "linear": scores(base_test, test_rec.sensor_V, seg)}
                       for name, seg in VALIDATION.items()},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    results = {"no_lag": evaluate(False), "one_sample_lag": evaluate(True)}
    for label, res in results.items():
        print(f"{label}: converged {res['converged']} in {res['iterations']} steps "
              f"({res['wall_s']:.1f} s), lag {res['lag']:.2f}")
        print(f"  train NRMSE: PI {100 * res['train']['pi']:.2f} %, "
              f"linear {100 * res['train']['linear']:.2f} %")
        for name, v in res["validation"].items():
            print(f"  {name:22s} PI {100 * v['pi']['nrmse']:6.2f} % "
                  f"({100 * v['pi']['nrmse_offset_refit']:5.2f} % offset refit)   linear "
                  f"{100 * v['linear']['nrmse']:6.2f} % "
                  f"({100 * v['linear']['nrmse_offset_refit']:5.2f} %)")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()

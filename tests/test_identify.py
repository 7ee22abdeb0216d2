"""Identification end to end: recovery of a known truth, the default profile, and the
independent conformance traces; the outputs in DIR; the CLI's verdicts.

The bundled fixture fit (17 recordings, 42 free parameters) takes a few minutes on
two cores; it runs once per session and its result serves several tests.
"""

import json

import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.identify import identify
from stickslip_jax.identify.loading_curve import loading_curve
from stickslip_jax.identify.report import fit_summary, write_identification
from stickslip_jax.synthetic import paper_protocol, simulate_set

# One worker computes the module's expensive fixture once (pytest -n 2 --dist loadgroup).
pytestmark = pytest.mark.xdist_group("identify_fixture_fit")

RECOVERED = ("Mp", "Dp", "Kp", "Ds", "rho0", "z_ba_forward", "z_ba_backward")
# A start 30-50 % away from the truth, in both directions.
START_FACTORS = {"Mp": 1.4, "Dp": 0.6, "Kp": 1.5, "Ds": 0.65, "rho0": 0.6,
                 "z_ba_forward": 1.4, "z_ba_backward": 0.65}


def perturbed(params: dict, factors=START_FACTORS, pi_factor=1.3) -> dict:
    out = dict(params)
    for name, f in factors.items():
        out[name] = out[name] * f
    out["pi_weights"] = [w * pi_factor for w in out["pi_weights"]]
    return out


def relative_errors(found, truth, names=RECOVERED) -> dict:
    pf, pt = ss.params_from_actuator(found), ss.params_from_actuator(truth)
    return {n: pf[n] / pt[n] - 1 for n in names}


def known_floor(recordings, sigma_m=1e-9) -> float:
    """Mean over recordings of the NRMSE that white noise of ``sigma_m`` alone gives."""
    return float(np.mean([sigma_m / np.ptp(r.position_m) for r in recordings]))


@pytest.fixture(scope="session")
def fixture_fit(fixtures_dir):
    folder = fixtures_dir / "identification"
    truth = ss.load_params(folder / "truth.json")
    recordings = ss.load_recordings(folder)
    start = ss.actuator_from_params(perturbed(ss.params_from_actuator(truth)))
    result = identify(recordings, init=start, fix={"Ms": float(truth.slider.Ms)})
    return truth, recordings, result


def test_fixture_fit_recovers_the_truth_within_5_percent(fixture_fit):
    truth, recordings, result = fixture_fit
    assert result.converged, [(s.name, s.result.message) for s in result.steps]
    errors = relative_errors(result.actuator, truth)
    assert all(abs(e) < 0.05 for e in errors.values()), errors
    # The breakaway strains are what the stepping traces pin down best.
    assert abs(errors["z_ba_forward"]) < 0.01 and abs(errors["z_ba_backward"]) < 0.01


def test_fixture_fit_reaches_the_noise_floor(fixture_fit):
    _, recordings, result = fixture_fit
    ratio = float(np.mean(result.nrmse)) / known_floor(recordings)
    assert ratio < 1.2, ratio
    # The floor the tool estimates from the data agrees with the 1 nm it was made with.
    summary = fit_summary(result)
    floor_percent = summary["overall"]["noise_floor_nrmse_percent"]
    assert floor_percent == pytest.approx(100 * known_floor(recordings), rel=0.1)
    assert summary["overall"]["residual_sigma_nm"] == pytest.approx(1.0, rel=0.15)


def test_fixture_fit_uncertainty_covers_the_truth(fixture_fit):
    truth, _, result = fixture_fit
    unc = result.uncertainty.as_dict()
    pt = ss.params_from_actuator(truth)
    for name in RECOVERED:
        entry = unc[name]
        assert entry["determined"], name
        assert entry["std_error"] > 0
        # Within 3 standard errors: the joint step is the maximum-likelihood fit,
        # converged to a tenth of an error, and its errors are the sandwich's (with the
        # NRMSE-weighted joint fit of before, Mp, Dp and Kp sat 3 of its errors off).
        assert abs(entry["value"] - pt[name]) < 3 * entry["std_error"], name
    # The hysteresis as the data determine it: the loading curve at every knot.
    curve = result.loading_curve
    true = np.asarray(loading_curve(np.asarray(pt["pi_thresholds"]),
                                    np.asarray(pt["pi_weights"]), curve.voltage_V))
    assert np.all(curve.stroke_determined) and np.all(curve.slope_m_per_V > 0)
    z = (curve.stroke_m - true) / curve.stroke_se_m
    assert np.max(np.abs(z)) < 3.5, z


def test_fixture_fit_writes_params_fit_and_figures(fixture_fit, tmp_path):
    truth, recordings, result = fixture_fit
    written = write_identification(result, tmp_path)
    params = ss.load_params(tmp_path / "params.json")
    assert float(params.piezo.Kp) == pytest.approx(float(result.actuator.piezo.Kp), rel=1e-12)
    fit = json.loads((tmp_path / "fit.json").read_text())
    assert fit["converged"] is True
    assert set(fit["recordings"]) == {r.name for r in recordings}
    assert fit["recordings"]["saw_20V_500Hz_fwd"]["regime"] == "scanning"
    assert fit["recordings"]["saw_60V_100Hz_bwd"]["regime"] == "stepping_backward"
    for name in RECOVERED:
        assert fit["parameters"][name]["std_error"] > 0
    curve = fit["hysteresis_loading_curve"]
    assert len(curve["voltage_V"]) == len(curve["stroke_std_error_m"]) > 10
    assert curve["voltage_V"][-1] == pytest.approx(max(float(r.voltage_V.max())
                                                       for r in recordings))
    assert [s["name"] for s in fit["steps"]] == ["dynamics", "hysteresis", "friction", "joint"]
    assert all(s["converged"] for s in fit["steps"])
    # Each step's sub-steps per sample, a stretch at a time (at least one each).
    assert all(s["substeps"] and min(s["substeps"]) >= 1 for s in fit["steps"])
    assert any("Ms" in n for n in fit["notes"]) is False  # Ms was given, no default note
    for fig in ("step_psd.png", "fig11_psd.png", "hysteresis_loop.png", "step_length.png",
                "overlay_saw_40V_50Hz_fwd.png"):
        assert (tmp_path / "figures" / fig).stat().st_size > 10_000
    assert len(written) == 2 + 4 + len(recordings)
    with pytest.raises(ss.OutputExistsError):
        write_identification(result, tmp_path)


def test_default_profile_set_is_recovered_from_a_perturbed_start():
    truth = ss.lu2015_slc1720()
    specs = paper_protocol(periods=3, step_duration_s=0.03, sine_periods=2,
                           frequencies=(100.0, 500.0))
    recordings = simulate_set(truth, specs, noise_m=1e-9, seed=5)
    start = ss.actuator_from_params(perturbed(ss.params_from_actuator(truth),
                                              {**START_FACTORS, "Mp": 0.65, "Kp": 1.35},
                                              pi_factor=0.7))
    result = identify(recordings, init=start, fix={"Ms": float(truth.slider.Ms)})
    assert result.converged
    errors = relative_errors(result.actuator, truth)
    assert all(abs(e) < 0.05 for e in errors.values()), errors
    assert float(np.mean(result.nrmse)) < 1.2 * known_floor(recordings)


def test_conformance_traces_are_fitted_from_a_perturbed_start(fixtures_dir):
    """Data this simulator did not make: the independent implementation's traces."""
    folder = fixtures_dir / "reference"
    ref = ss.load_params(folder / "params.json")
    recordings = ss.load_recordings(folder)
    start = ss.actuator_from_params(perturbed(ss.params_from_actuator(ref),
                                              {n: 1.3 for n in RECOVERED}, pi_factor=0.8))
    result = identify(recordings, init=start, fix={"Ms": float(ref.slider.Ms)},
                      n_pi=len(ref.hysteresis.weights))
    start_nrmse = np.mean([np.sqrt(np.mean((q - q.mean() - r.position_m
                                            + r.position_m.mean())**2)) / np.ptp(r.position_m)
                           for r, q in zip(recordings, ss.simulate_recordings(start, recordings),
                                           strict=True)])
    final = float(np.mean(result.nrmse))
    assert result.converged
    assert final < 0.003 and final < start_nrmse / 10, (final, start_nrmse)
    errors = relative_errors(result.actuator, ref)
    assert abs(errors["z_ba_forward"]) < 0.05 and abs(errors["z_ba_backward"]) < 0.05, errors

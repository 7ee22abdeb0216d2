"""Parameter files: the docs/model.md contract, clear refusals, exact round trip."""

import json

import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.params import ParameterError


@pytest.fixture()
def ref_params(fixtures_dir):
    return json.loads((fixtures_dir / "reference" / "params.json").read_text())


def test_reference_params_build_the_documented_components(ref_params):
    act = ss.actuator_from_params(ref_params)
    assert float(act.piezo.Mp) == 0.003 and float(act.slider.Ds) == 45.0
    assert isinstance(act.friction, ss.ElastoPlastic)
    assert float(act.friction.z_ba_backward) == 1.25e-6
    assert float(act.friction.zba_ratio) == 0.7
    assert act.hysteresis.n_memory == 20


def test_round_trip_is_exact(ref_params, tmp_path):
    act = ss.actuator_from_params(ref_params)
    path = ss.save_params(act, tmp_path / "p.json")
    again = ss.params_from_actuator(ss.load_params(path))
    first = ss.params_from_actuator(act)
    assert again == first
    assert first["pi_weights"] == ref_params["pi_weights"]


@pytest.mark.parametrize("name", ["Mp", "Kp", "Ms", "rho0"])
def test_negative_mass_or_stiffness_is_refused(ref_params, name):
    ref_params[name] = -abs(ref_params[name])
    with pytest.raises(ParameterError, match=f"'{name}' must be positive"):
        ss.actuator_from_params(ref_params, source="P.json")


def test_unknown_name_is_an_error_that_lists_the_allowed_ones(ref_params):
    ref_params["rho_0"] = 1.0
    with pytest.raises(ParameterError) as err:
        ss.actuator_from_params(ref_params, source="P.json")
    text = str(err.value)
    assert "P.json" in text and "'rho_0'" in text and "rho0" in text and "Fix:" in text


def test_missing_required_names(ref_params):
    del ref_params["Kp"], ref_params["z_ba"], ref_params["z_ba_backward"]
    with pytest.raises(ParameterError, match="Kp.*z_ba"):
        ss.actuator_from_params(ref_params)


def test_the_directional_values_win_over_the_shorthand(ref_params):
    # z_ba sets only the directions a file leaves out (docs/model.md); written files
    # no longer carry it, so that every value in them is read.
    ref_params.update(z_ba=0.6e-6, z_ba_forward=0.4e-6, z_ba_backward=0.45e-6)
    f = ss.actuator_from_params(ref_params).friction
    assert (float(f.z_ba_forward), float(f.z_ba_backward)) == (0.4e-6, 0.45e-6)
    del ref_params["z_ba_backward"]
    assert float(ss.actuator_from_params(ref_params).friction.z_ba_backward) == 0.6e-6
    assert "z_ba" not in ss.params_from_actuator(ss.actuator_from_params(ref_params))


def test_z_ba_alone_sets_both_directions(ref_params):
    for k in ("z_ba_forward", "z_ba_backward"):
        del ref_params[k]
    f = ss.actuator_from_params(ref_params).friction
    assert float(f.z_ba_forward) == float(f.z_ba_backward) == 1.1e-6


@pytest.mark.parametrize("ratio", [0.0, -0.2, 1.5])
def test_zba_ratio_outside_unit_interval(ref_params, ratio):
    ref_params["zba_ratio"] = ratio
    with pytest.raises(ParameterError, match="zba_ratio"):
        ss.actuator_from_params(ref_params)


def test_stribeck_needs_v_s_and_builds_the_stribeck_law(ref_params):
    ref_params["stribeck_ratio"] = 1.5
    with pytest.raises(ParameterError, match="v_s"):
        ss.actuator_from_params(ref_params)
    ref_params["v_s"] = 1e-3
    assert isinstance(ss.actuator_from_params(ref_params).friction, ss.StribeckElastoPlastic)


def test_lugre_file(ref_params):
    for k in ("rho0", "rho1", "rho2", "z_ba", "z_ba_forward", "z_ba_backward", "zba_ratio"):
        del ref_params[k]
    ref_params.update(friction="lugre", sigma0=4e5, sigma1=10.0, sigma2=0.0, F_c=0.6, F_s=0.7,
                      v_s=1e-3)
    act = ss.actuator_from_params(ref_params)
    assert isinstance(act.friction, ss.LuGre)
    assert ss.params_from_actuator(act)["F_s"] == 0.7
    ref_params["rho0"] = 1.0  # an elasto-plastic name in a LuGre file
    with pytest.raises(ParameterError, match="rho0"):
        ss.actuator_from_params(ref_params)


def test_pi_lists_must_match_and_ascend(ref_params):
    bad = dict(ref_params, pi_weights=ref_params["pi_weights"][:-1])
    with pytest.raises(ParameterError, match="20 entries but pi_weights 19"):
        ss.actuator_from_params(bad)
    bad = dict(ref_params, pi_thresholds=list(reversed(ref_params["pi_thresholds"])))
    with pytest.raises(ParameterError, match="ascending"):
        ss.actuator_from_params(bad)


def test_bad_json_names_line_and_column(tmp_path):
    path = tmp_path / "p.json"
    path.write_text('{\n "Mp": 0.1,\n "Dp": ,\n}')
    with pytest.raises(ParameterError, match=r"p.json: not valid JSON \(line 3"):
        ss.load_params(path)


def test_save_refuses_overwrite_without_force(ref_params, tmp_path):
    act = ss.actuator_from_params(ref_params)
    path = ss.save_params(act, tmp_path / "p.json")
    with pytest.raises(ss.OutputExistsError):
        ss.save_params(act, path)
    ss.save_params(act, path, force=True)
    assert np.isclose(json.loads(path.read_text())["Kp"], 2.2e6)


def test_default_profile_keeps_the_printed_table():
    act = ss.lu2015_slc1720()
    t = ss.LU2015_TABLE
    for name, value in [("Mp", act.piezo.Mp), ("Dp", act.piezo.Dp), ("Kp", act.piezo.Kp),
                        ("Ms", act.slider.Ms), ("Ds", act.slider.Ds),
                        ("rho0", act.friction.rho0)]:
        assert float(value) == t[name], name
    assert float(act.piezo.Kact2) == 0.0  # the printed 1200 is not readable in SI
    assert act.hysteresis.n_memory == 35 and act.hysteresis.is_monotone()
    assert float(act.friction.zba_ratio) == 0.667

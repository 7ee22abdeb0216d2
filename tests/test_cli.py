"""The command line, driven in-process: outputs, refusals and exit codes."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
from stickslip_jax.cli.main import app

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture()
def ref(fixtures_dir):
    return fixtures_dir / "reference"


def test_help_and_version():
    res = run("--help")
    assert res.exit_code == 0 and "simulate" in res.output
    res = run("simulate", "--help")
    assert res.exit_code == 0 and "--voltage-from" in res.output and "Examples" in res.output
    assert run("--version").output.startswith("stickslip_jax ")


@pytest.mark.parametrize("command", ["simulate", "params", "identify", "sweep", "zba-surface",
                                     "drive", "diagnose", "contacts"])
def test_every_command_has_help_with_an_example(command):
    res = run(command, "--help")
    assert res.exit_code == 0
    assert "Examples" in res.output and f"stickslip {command}" in res.output


def test_generated_sawtooth_is_written_with_metadata(tmp_path):
    out = tmp_path / "trace.csv"
    res = run("simulate", "--waveform", "sawtooth", "--amplitude", 40, "--frequency", 500,
              "--direction", "backward", "--duration", 0.02, "--out", out, "--plot",
              tmp_path / "trace.png")
    assert res.exit_code == 0, res.output
    rec = ss.load_recording(out)
    assert rec.n == 500 and rec.meta["direction"] == "backward"
    assert rec.drive.amplitude_V == 40 and rec.drive.frequency_Hz == 500
    assert rec.position_m[-1] < -1e-6  # the default profile steps backward at 40 V
    assert (tmp_path / "trace.png").stat().st_size > 10_000


def test_voltage_from_matches_reference_trace_and_keeps_its_grid(ref, tmp_path):
    src = ref / "ref_saw_70V_300Hz_bwd.csv"
    out = tmp_path / "sim.csv"
    res = run("simulate", "--params", ref / "params.json", "--voltage-from", src, "--out", out)
    assert res.exit_code == 0, res.output
    a, b = ss.load_recording(src), ss.load_recording(out)
    assert np.array_equal(a.time_s, b.time_s) and np.array_equal(a.voltage_V, b.voltage_V)
    assert b.meta["direction"] == "backward" and b.meta["amplitude_V"] == "70"
    nrmse = np.sqrt(np.mean((a.position_m - b.position_m) ** 2)) / np.ptp(a.position_m)
    assert nrmse < 5e-4


def test_existing_output_needs_force(tmp_path):
    out = tmp_path / "t.csv"
    args = ("simulate", "--duration", 0.01, "--out", out)
    assert run(*args).exit_code == 0
    before = out.read_bytes()
    res = run(*args, "--amplitude", 60)
    assert res.exit_code == 2 and "--force" in res.output and out.read_bytes() == before
    assert run(*args, "--amplitude", 60, "--force").exit_code == 0
    assert out.read_bytes() != before


def test_never_writes_over_its_input(ref, tmp_path):
    src = tmp_path / "rec.csv"
    src.write_bytes((ref / "ref_scan_20V_200Hz_fwd.csv").read_bytes())
    before = src.read_bytes()
    res = run("simulate", "--voltage-from", src, "--out", src, "--force")
    assert res.exit_code == 2 and src.read_bytes() == before


def test_bad_recording_reports_file_line_and_fix(tmp_path):
    bad = tmp_path / "bad.csv"
    rows = "\n".join(f"{i * 4e-5:.8f},{i * 0.1:.3f},0.0" for i in range(20))
    rows = rows.replace("0.00040000,1.000,0.0", "0.00040000,nan,0.0")
    bad.write_text("time_s,voltage_V,position_um\n" + rows + "\n")
    res = run("simulate", "--voltage-from", bad, "--out", tmp_path / "o.csv")
    assert res.exit_code == 2
    assert "bad.csv, line 12" in res.output and "Fix:" in res.output
    assert not (tmp_path / "o.csv").exists()


def test_bad_params_exit_code(ref, tmp_path):
    p = json.loads((ref / "params.json").read_text())
    p["Ms"] = -0.03
    bad = tmp_path / "p.json"
    bad.write_text(json.dumps(p))
    res = run("simulate", "--params", bad, "--duration", 0.01, "--out", tmp_path / "o.csv")
    assert res.exit_code == 2 and "'Ms' must be positive" in res.output


def test_params_command_lists_and_writes_a_loadable_profile(tmp_path):
    res = run("params", "--list")
    assert res.exit_code == 0 and "z_ba_backward" in res.output and "[m]" in res.output
    out = tmp_path / "P.json"
    assert run("params", "--out", out).exit_code == 0
    assert float(ss.load_params(out).piezo.Kp) == 2.62e6


def _friction_case(fixtures_dir, tmp_path):
    folder = fixtures_dir / "identification"
    truth = json.loads((folder / "truth.json").read_text())
    init = {**truth, "z_ba_forward": truth["z_ba_forward"] * 1.3,
            "z_ba_backward": truth["z_ba_backward"] * 0.7}
    (tmp_path / "init.json").write_text(json.dumps(init))
    data = [folder / "saw_40V_500Hz_fwd.csv", folder / "saw_40V_500Hz_bwd.csv"]
    return truth, data, tmp_path / "init.json"


def test_identify_friction_step_writes_params_fit_and_refuses_to_overwrite(fixtures_dir,
                                                                          tmp_path):
    truth, data, init = _friction_case(fixtures_dir, tmp_path)
    out = tmp_path / "id"
    args = ("identify", *data, "--out", out, "--init", init, "--fix", "Ms=0.0247",
            "--steps", "friction", "--no-figures")
    res = run(*args)
    assert res.exit_code == 0, res.output
    assert "converged" in res.output and "[friction]" in res.output
    fitted = json.loads((out / "params.json").read_text())
    for name in ("z_ba_forward", "z_ba_backward"):
        assert fitted[name] == pytest.approx(truth[name], rel=0.01)
    fit = json.loads((out / "fit.json").read_text())
    assert fit["converged"] is True and fit["steps"][0]["name"] == "friction"
    assert fit["status"] == "converged" and fit["model_check"]["verdict"] == "adequate"
    assert fit["recordings"]["saw_40V_500Hz_bwd"]["regime"] == "stepping_backward"
    again = run(*args)
    assert again.exit_code == 2 and "--force" in again.output
    assert run(*args, "--force").exit_code == 0


def test_identify_that_does_not_converge_exits_3_without_params_json(fixtures_dir, tmp_path):
    _, data, init = _friction_case(fixtures_dir, tmp_path)
    out = tmp_path / "id"
    res = run("identify", *data, "--out", out, "--init", init, "--fix", "Ms=0.0247",
              "--steps", "friction", "--max-steps", 1, "--no-figures")
    assert res.exit_code == 3, res.output
    assert not (out / "params.json").exists()
    assert (out / "params.unconverged.json").exists()
    assert "did not converge" in res.output


def test_identify_rejects_unknown_fix_and_step(fixtures_dir, tmp_path):
    _, data, init = _friction_case(fixtures_dir, tmp_path)
    res = run("identify", *data, "--out", tmp_path / "x", "--fix", "mass=3")
    assert res.exit_code == 2 and "mass" in res.output
    res = run("identify", *data, "--out", tmp_path / "x", "--steps", "dynamics,magic")
    assert res.exit_code == 2 and "magic" in res.output


def test_identify_says_when_it_replaces_the_start_thresholds_and_keeps_them_on_request(
        fixtures_dir, tmp_path):
    truth, data, init = _friction_case(fixtures_dir, tmp_path)
    data = [*data, fixtures_dir / "identification" / "sine_40V_50Hz.csv"]
    args = ("identify", *data, "--init", init, "--fix", "Ms=0.0247", "--steps",
            "hysteresis,friction", "--no-figures")
    res = run(*args, "--out", tmp_path / "grid")
    assert res.exit_code == 0, res.output
    assert "not on the 35 of" in res.stderr and "--keep-thresholds" in res.stderr
    regridded = json.loads((tmp_path / "grid" / "params.json").read_text())
    assert regridded["pi_thresholds"] != truth["pi_thresholds"]
    res = run(*args, "--keep-thresholds", "--out", tmp_path / "kept")
    assert res.exit_code == 0, res.output
    assert "--keep-thresholds" not in res.stderr
    kept = json.loads((tmp_path / "kept" / "params.json").read_text())
    assert kept["pi_thresholds"] == truth["pi_thresholds"]

"""Requests out of scale (#65): a job too large is refused for its size, before any
heavy work, with how large it is, the limit and how to shrink it; a unit slip in a
parameter file is named (a ``warning:`` line) or, where the simulator cannot run the
model, refused naming the parameter (exit 2).

Every command case stops before the simulator runs, or replaces the slow step with a
stub, so the module takes seconds (planning steps compiles one small Jacobian).
"""

import importlib
import json
from pathlib import Path

import equinox as eqx
import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
import stickslip_jax.sweep as sweep_pkg
import stickslip_jax.sweep.contact_studies as studies
import stickslip_jax.sweep.zba_surface as zba_module
from stickslip_jax.cli import sweep_cmd
from stickslip_jax.cli.main import app
from stickslip_jax.model.friction import LuGre
from stickslip_jax.plausibility import check_actuator_plausible, implausible_parameters
from stickslip_jax.stepping import MAX_SUBSTEPS_PER_CALL, Stepping, SteppingError
from stickslip_jax.sweep import SweepRun
from stickslip_jax.sweep.grid import MAX_VALUES

runner = CliRunner()
# The module itself: the package's attribute ``simulate`` is the function.
simulate_module = importlib.import_module("stickslip_jax.simulate")


def snapshot(folder: Path) -> dict[Path, bytes]:
    """Every file under ``folder`` with its bytes (inputs must stay byte for byte)."""
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def run(folder: Path, *args, code: int, errors: int, warnings: int = 0,
        writes: bool = False):
    """Run ``stickslip args``; check the exit code, that stderr holds ``errors``
    ``error:`` lines and ``warnings`` ``warning:`` lines (among its lines), no
    traceback, and, unless ``writes``, that nothing under ``folder`` changed. Returns
    (stderr lines starting error:, those starting warning:)."""
    before = snapshot(folder)
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == code, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    assert "Traceback" not in res.output
    lines = res.stderr.strip().splitlines()
    errs = [line for line in lines if line.startswith("error: ")]
    warns = [line for line in lines if line.startswith("warning: ")]
    assert len(errs) == errors and len(warns) == warnings, res.stderr
    if writes:
        assert {p: b for p, b in snapshot(folder).items() if p in before} == before
    else:
        assert snapshot(folder) == before
    return errs, warns


@pytest.fixture()
def params_with(tmp_path, fixtures_dir):
    """Write the reference parameters with some values changed; returns the path."""

    def write(**changes) -> Path:
        p = json.loads((fixtures_dir / "reference" / "params.json").read_text())
        p.update(changes)
        path = tmp_path / "p.json"
        path.write_text(json.dumps(p))
        return path

    return write


@pytest.fixture()
def no_simulation(monkeypatch):
    """Make every slow step of the commands fail the test if it is reached."""

    def reached(*args, **kwargs):
        raise AssertionError("the heavy work was reached")

    monkeypatch.setattr(sweep_pkg, "velocity_map", reached)
    monkeypatch.setattr(sweep_pkg, "drive_for_velocity", reached)
    monkeypatch.setattr(simulate_module, "simulate_recording", reached)
    monkeypatch.setattr(zba_module, "fit_zba_points", reached)
    monkeypatch.setattr(studies, "preload_study", reached)


# ------------------------------------------------------ the stepping's two refusals


def _with(path, value):
    return eqx.tree_at(path, ss.lu2015_slc1720(), value)


def test_too_many_substeps_in_all_blames_the_job_not_a_unit_slip():
    with pytest.raises(SteppingError) as info:
        Stepping().plan(ss.lu2015_slc1720(), 4e-5, samples=10**9)
    text = str(info.value)
    assert text.startswith("too many sub-steps in all: the job is too large")
    assert "1,000,000,000 sample intervals" in text and f"{MAX_SUBSTEPS_PER_CALL:.3g}" in text
    assert "is ordinary" in text and "fewer periods" in text and "shorter duration" in text
    assert "unit slip" not in text
    assert "a lower sample rate would not help" in text  # the model's step sets the work


def test_one_substep_per_sample_suggests_a_lower_sample_rate():
    with pytest.raises(SteppingError, match="too many sub-steps in all") as info:
        Stepping().plan(ss.lu2015_slc1720(), 1e-7, samples=5 * 10**8)
    assert "or a lower sample rate" in str(info.value)


def test_too_many_substeps_per_sample_points_at_the_time_scale():
    # Kp 100x: a 164 kHz piezo mode, steppable, but 82 sub-steps per 40 µs sample.
    act = _with(lambda a: a.piezo.Kp, 2.62e8)
    with pytest.raises(SteppingError) as info:
        Stepping().plan(act, 4e-5, samples=10**8)
    text = str(info.value)
    assert text.startswith("too many sub-steps per sample: the model's fastest mode is")
    assert "unit slip" in text and "Kp/Mp" in text


def test_a_short_given_step_is_named_as_the_cause():
    with pytest.raises(SteppingError, match="the given longest step of 1 ns") as info:
        Stepping(max_step=1e-9).plan(ss.lu2015_slc1720(), 4e-5, samples=10**5)
    assert "a longer max_step" in str(info.value)


# ------------------------------------------------------------------ sweep's size


def test_a_sweep_too_large_is_refused_before_loading_anything(tmp_path, monkeypatch,
                                                              no_simulation):
    def not_loaded(*args, **kwargs):
        raise AssertionError("the parameters were loaded")

    monkeypatch.setattr(sweep_cmd, "load_actuator", not_loaded)
    (errs, _) = run(tmp_path, "sweep", "--amplitudes", "1:100:1000", "--frequencies",
                    "1:1000:1000", "--out", tmp_path / "sw", code=2, errors=1)
    err = errs[0]
    assert err.startswith("error: the grid is too large: 2,000,000 point(s) × 10 periods × ")
    assert "samples per period" in err and "at least 1 sub-step" in err
    assert f"limit of {MAX_SUBSTEPS_PER_CALL:.3g}" in err
    assert "fewer --amplitudes or --frequencies points, fewer --periods" in err
    assert "the lowest, 1 Hz, takes 25,000 samples a period" in err
    assert "unit slip" not in err and "--sample-rate" not in err
    assert not (tmp_path / "sw").exists()


def test_a_sweep_too_large_at_the_models_step_is_refused_before_simulating(
        tmp_path, no_simulation):
    # 60.6 million samples: under the limit at one sub-step each, over it at the
    # default profile's sub-steps per sample.
    substeps = ss.plan_steps(ss.lu2015_slc1720(), 1 / 25_000).substeps
    (errs, _) = run(tmp_path, "sweep", "--amplitudes", "1:100:300", "--frequencies",
                    "5:1000:50", "--out", tmp_path / "sw", code=2, errors=1)
    assert errs[0].startswith("error: the grid is too large: 30,000 point(s) × 10 periods")
    assert f"× {substeps} sub-steps = " in errs[0] and "at least" not in errs[0]
    assert "--sample-rate" not in errs[0]  # the model's step sets the work


def test_a_sweep_prints_its_counted_work_before_computing(tmp_path, monkeypatch):
    seen = {}

    class FakeMap:
        run = SweepRun(2, 250, 1, 1, 500, 502, 0.0)

        def save_csv(self, path, force=False):
            Path(path).write_text("stub\n")

    def fake_velocity_map(actuator, grid, *, stepping, **kwargs):
        seen["plan"] = stepping
        return FakeMap()

    monkeypatch.setattr(sweep_pkg, "velocity_map", fake_velocity_map)
    res = runner.invoke(app, ["sweep", "--amplitudes", "40", "--frequencies", "500,1000",
                              "--directions", "forward", "--no-figure", "--out",
                              str(tmp_path / "sw")])
    assert res.exit_code == 0, res.output
    k = seen["plan"].substeps  # the plan the estimate names is the plan that runs
    first = res.stderr.splitlines()[0]
    assert first == (f"2 grid point(s) × 10 periods: about 752 samples × {k} sub-steps = "
                     f"{752 * k:.3g} sub-steps (estimate: counted work, "
                     f"{100 * 752 * k / MAX_SUBSTEPS_PER_CALL:.2g} % of the 4e+08 a sweep "
                     f"may take; refined intervals add some)")
    assert " s)" not in first and "seconds" not in first  # work, not the machine's speed


def test_a_count_beyond_reason_is_refused_before_the_values_are_made(tmp_path):
    (errs, _) = run(tmp_path, "sweep", "--amplitudes", "1:100:1000000000", "--out",
                    tmp_path / "sw", code=2, errors=1)
    assert f"more than {MAX_VALUES:,} values" in errs[0]


# ----------------------------------------------------- plausibility of parameters


def test_the_default_profile_and_the_reference_are_plausible(fixtures_dir, capsys):
    assert implausible_parameters(ss.lu2015_slc1720()) == []
    assert implausible_parameters(ss.load_params(fixtures_dir / "reference"
                                                 / "params.json")) == []
    assert check_actuator_plausible(ss.lu2015_slc1720(), "P.json") == []
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("path, factor, name, slip", [
    (lambda a: a.piezo.Kp, 1e6, "Kp", "in N/m converted again as if from N/µm (×1e6)"),
    (lambda a: a.piezo.Kp, 1e-6, "Kp", "N/µm (×1e-6) read as N/m"),
    (lambda a: a.piezo.Mp, 1e6, "Mp", "mg (×1e6)"),
    (lambda a: a.piezo.Dp, 1e6, "Dp", "N·s/µm (×1e6)"),
    (lambda a: a.slider.Ms, 1e3, "Ms", "a value in g (×1e3)"),
    (lambda a: a.slider.Ds, 1e6, "Ds", "N·s/µm (×1e6)"),
    (lambda a: a.hysteresis.weights, 1e9, "pi_weights", "a value in nm/V (×1e9) read as m/V"),
    (lambda a: a.hysteresis.weights, 1e6, "pi_weights", "µm/V (×1e6)"),
    (lambda a: a.friction.rho0, 1e6, "rho0", "N/µm (×1e6)"),
    (lambda a: a.friction.z_ba_backward, 1e6, "z_ba_backward", "a value in µm (×1e6)"),
])
def test_each_unit_slip_is_named(path, factor, name, slip):
    act = ss.lu2015_slc1720()
    (finding,) = implausible_parameters(eqx.tree_at(path, act, path(act) * factor))
    assert finding.name == name and slip in str(finding), str(finding)
    assert finding.above == (factor > 1) and "plausible: " in str(finding)


def _both_zba(a):
    return a.friction.z_ba_forward, a.friction.z_ba_backward


def test_an_alias_stands_for_its_targets_when_they_agree():
    both = _both_zba
    (finding,) = implausible_parameters(_with(both, (0.4, 0.4)))
    assert finding.name == "z_ba" and "a value in µm (×1e6)" in str(finding)
    found = implausible_parameters(_with(both, (0.4, 0.45)))
    assert [f.name for f in found] == ["z_ba_forward", "z_ba_backward"]


def test_a_friction_laws_parameters_come_from_its_records():
    # LuGre's names are not written anywhere in the plausibility module.
    lugre = LuGre(1e5, 0.0, 0.0, 0.1, 0.12, 1e-3)
    act = eqx.tree_at(lambda a: a.friction, ss.lu2015_slc1720(), lugre)
    assert implausible_parameters(act) == []
    slipped = eqx.tree_at(lambda a: (a.friction.sigma0, a.friction.v_s), act, (1e11, 1e3))
    found = {f.name: f for f in implausible_parameters(slipped)}
    assert set(found) == {"sigma0", "v_s"}
    assert found["sigma0"].unit == "N/m" and "mm/s (×1e3)" in str(found["v_s"])


# --------------------------------------------------- the commands, warned or refused


def _stub_simulation(monkeypatch):
    monkeypatch.setattr(simulate_module, "simulate_recording",
                        lambda actuator, rec, **kw: np.zeros(rec.n))


def test_a_slipped_parameter_that_can_run_is_a_warning(params_with, tmp_path, monkeypatch):
    # Kp 1e10 N/m on the reference's 3 g piezo: a 290 kHz mode, steppable.
    path = params_with(Kp=1e10, z_ba=1.1, z_ba_forward=1.1, z_ba_backward=1.1)
    _stub_simulation(monkeypatch)
    source = path.read_bytes()
    (_, warns) = run(tmp_path, "simulate", "--params", path, "--duration", 0.01, "--out",
                     tmp_path / "o.csv", code=0, errors=0, warnings=2, writes=True)
    assert warns[0].startswith(f"warning: {path}: Kp 1e+10 N/m is 10x above the stiffest "
                               f"piezo stacks (plausible: 100..1e9 N/m)")
    assert warns[1].startswith(f"warning: {path}: z_ba 1.1 m is ") and "µm (×1e6)" in warns[1]
    assert path.read_bytes() == source and (tmp_path / "o.csv").exists()


def test_a_slip_the_simulator_cannot_run_is_refused_naming_it(params_with, tmp_path,
                                                              no_simulation):
    path = params_with(Kp=2.2e12)
    (errs, _) = run(tmp_path, "simulate", "--params", path, "--duration", 0.01, "--out",
                    tmp_path / "o.csv", code=2, errors=1)
    assert errs[0].startswith(f"error: {path}: Kp 2.2e+12 N/m is 2,200x above the stiffest "
                              f"piezo stacks")
    assert "MHz, beyond the 1 MHz the simulator steps on its own" in errs[0]
    assert "as if from N/µm (×1e6)?" in errs[0] and errs[0].endswith("Fix: write Kp in N/m.")


@pytest.mark.parametrize("command", [
    ("sweep", "--out", "OUT"),
    ("drive", "--velocity", "50um/s", "--out", "OUT/c.json"),
    ("contacts", "--out", "OUT"),
    ("zba-surface", "DATA", "--out", "OUT"),
])
def test_every_command_refuses_the_slip_and_warns_of_the_rest(command, params_with,
                                                              tmp_path, fixtures_dir,
                                                              no_simulation):
    path = params_with(Kp=2.2e12, Ms=30.0)
    args = [fixtures_dir / "identification" if a == "DATA" else
            tmp_path / a.replace("OUT", "out") if a.startswith("OUT") else a
            for a in command]
    (errs, warns) = run(tmp_path, *args, "--params", path, code=2, errors=1, warnings=1)
    assert "Kp 2.2e+12 N/m" in errs[0] and "N/µm" in errs[0]
    assert "Ms 30 kg" in warns[0] and "a value in g (×1e3)" in warns[0]
    assert not (tmp_path / "out").exists()

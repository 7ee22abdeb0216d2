"""Issue #65, fail safe: the identification's verdicts (a step superseded by a later
one that converged, a misspecified fit, no standard error on what was held), staged
outputs and output locks, and Ctrl-C at any point of a command."""

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import stickslip_jax as ss
from stickslip_jax.cli.main import app
from stickslip_jax.files import OutputExistsError
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.model_check import MODEL_ERROR_OVER_NOISE, check_model
from stickslip_jax.identify.regime_spread import jackknife_spread, regime_spread
from stickslip_jax.identify.solve import SolveResult, SolveStatus
from stickslip_jax.identify.steps import Identification, StepReport
from stickslip_jax.staging import (
    MANIFEST,
    STAGING_PREFIX,
    OutputLock,
    OutputLockedError,
    StageAborted,
    abort_active,
    staged_files,
    staged_folder,
)

runner = CliRunner()
REPO = Path(__file__).resolve().parent.parent


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def snapshot(paths) -> dict[Path, bytes]:
    """Every input file's bytes (to assert that inputs stay byte-for-byte unchanged)."""
    return {Path(p): Path(p).read_bytes() for p in paths}


def leftovers(folder: Path) -> list[str]:
    """Staging folders left in ``folder`` (there must never be any)."""
    return [p.name for p in folder.iterdir() if p.name.startswith(STAGING_PREFIX)]


# ------------------------------------------------------------------ the verdicts


def _solve(converged: bool, message: str) -> SolveResult:
    status = SolveStatus.CONVERGED if converged else SolveStatus.STEP_CAP
    return SolveResult(np.zeros(1), status, message, 60 if not converged else 4, 0.0,
                       1.0, 0.5)


def _identification(steps) -> Identification:
    return Identification(ss.lu2015_slc1720(), steps, None, np.zeros(1), None)


def test_a_capped_early_step_does_not_veto_a_joint_step_that_refitted_it():
    capped = StepReport("dynamics", ["step"], ["Mp", "Kp"], _solve(False, "not converged: "
                        "hit max_steps=60"), 1.0, 0.5)
    hysteresis = StepReport("hysteresis", ["sine"], ["pi_weights"], _solve(True, "ok"), 1, 1)
    joint = StepReport("joint", ["step", "sine"], ["Mp", "Kp", "pi_weights"],
                       _solve(True, "converged"), 1.0, 0.4)
    assert _identification([capped, hysteresis, joint]).converged
    assert _identification([capped, hysteresis, joint]).unconverged_steps == []
    # The joint step's own cap stands, and so does a step that no later step refitted.
    capped_joint = dataclasses.replace(joint, result=_solve(False, "hit max_steps=60"))
    assert not _identification([capped, capped_joint]).converged
    partial = dataclasses.replace(joint, free=["Kp", "pi_weights"])
    assert [s.name for s in _identification([capped, partial]).unconverged_steps] == \
        ["dynamics"]
    # Without a later step, the cap stands.
    assert not _identification([capped, hysteresis]).converged


NAMES = ["saw_40V_500Hz_fwd", "saw_40V_50Hz_bwd", "sine_40V_50Hz"]


def _noisy_fit(fixtures_dir, chi2: dict[str, float], seed: int = 3):
    """Three fixture recordings and 'simulated' outputs that differ from each by white
    noise of ``chi2[name]`` (default 1) times its noise variance: mean (e/σ)² ≈ chi2."""
    from stickslip_jax.identify.residuals import recording_noise

    recs = [ss.load_recording(fixtures_dir / "identification" / f"{n}.csv") for n in NAMES]
    data = Dataset.from_recordings(recs)
    sig = np.asarray(recording_noise(data))
    rng = np.random.default_rng(seed)
    q = np.asarray(data.measured).copy()
    for b, rec in enumerate(recs):
        q[b, :rec.n] += rng.normal(0.0, sig[b] * np.sqrt(chi2.get(rec.name, 1.0)), rec.n)
    return data, q


def test_model_check_says_adequate_mismatch_or_misspecified(fixtures_dir):
    check = check_model(*_noisy_fit(fixtures_dir, {}), None)
    assert check.chi2_overall == pytest.approx(1.0, abs=0.05)
    assert check.verdict == "adequate" and check.adequate and not check.misspecified
    half = check_model(*_noisy_fit(fixtures_dir, dict.fromkeys(NAMES, 1.5)), None)
    assert half.verdict == "mismatch" and "smaller than the noise" in half.statement()
    much = 1.0 + 2 * MODEL_ERROR_OVER_NOISE
    bad = check_model(*_noisy_fit(fixtures_dir, dict.fromkeys(NAMES, much)), None)
    assert bad.misspecified and bad.statement().startswith(
        "the model does not describe these recordings")
    assert set(bad.misspecified_recordings) == set(NAMES)
    # One recording far off is enough, and it is the one named.
    one = check_model(*_noisy_fit(fixtures_dir, {"sine_40V_50Hz": 9.0}), None)
    assert one.misspecified and one.misspecified_recordings == ("sine_40V_50Hz",)
    assert one.as_dict()["per_recording"]["sine_40V_50Hz"]["chi2"] == pytest.approx(9, rel=0.1)


def test_jackknife_spread_and_the_regime_out_fits(fixtures_dir):
    assert jackknife_spread([1.0]) is None
    # √((K−1)/K Σ(θ−θ̄)²) with K = 4: values ±1 around 0 → √(3/4 · 4) = √3.
    assert jackknife_spread([1.0, -1.0, 1.0, -1.0]) == pytest.approx(np.sqrt(3.0))
    folder = fixtures_dir / "identification"
    recs = [ss.load_recording(folder / f"{n}.csv") for n in
            ("step_40V", "sine_40V_50Hz", "saw_40V_50Hz_fwd", "saw_60V_100Hz_fwd")]
    calls = []

    def refit(rows, names):
        calls.append((rows, names))
        return {n: float(len(rows) + len(calls)) for n in names}, True, "converged"

    out = regime_spread(recs, ["Mp", "pi_weights[0]"], refit,
                        lambda subset: [] if any(r.drive.waveform == "step" for r in subset)
                        else ["Mp"])
    left_out = [f.regime for f in out.fits]
    assert sorted(left_out) == sorted({"step", "sine", "scanning", "stepping_forward"}
                                      & set(left_out)) and len(left_out) >= 3
    # Without the step response, Mp is held (not a value of that fit).
    without_step = next(f for f in out.fits if f.regime == "step")
    assert "Mp" not in without_step.values and "pi_weights[0]" in without_step.values
    assert out.spread["Mp"] == pytest.approx(jackknife_spread(
        [f.values["Mp"] for f in out.fits if "Mp" in f.values]))
    assert regime_spread(recs[:1], ["Mp"], refit, lambda s: []) is None


STEPS = ("--steps", "hysteresis,friction")
"""The PI weights and the break-away (two steps, so that an interrupt finds a fit)."""


def _sawtooths(fixtures_dir, tmp_path, gain: float = 1.0):
    """The two 500 Hz sawtooths and the sine of the identification fixtures, the
    forward sawtooth's position scaled by ``gain`` (a sensor gain the model does not
    have), and a start whose break-away is off (``STEPS`` fits it)."""
    folder = fixtures_dir / "identification"
    truth = json.loads((folder / "truth.json").read_text())
    init = tmp_path / "init.json"
    init.write_text(json.dumps({**truth, "z_ba_forward": truth["z_ba_forward"] * 1.3,
                                "z_ba_backward": truth["z_ba_backward"] * 0.7}))
    data = tmp_path / "data"
    data.mkdir()
    for name in ("saw_40V_500Hz_fwd", "saw_40V_500Hz_bwd", "sine_40V_50Hz"):
        rec = ss.load_recording(folder / f"{name}.csv")
        if name.endswith("fwd"):
            rec = dataclasses.replace(rec, position=rec.position * gain)
        ss.save_recording(rec, data / f"{name}.csv")
    return data, init


def test_misspecified_fit_exits_4_says_so_first_and_marks_its_params(fixtures_dir, tmp_path):
    data, init = _sawtooths(fixtures_dir, tmp_path, gain=1.25)
    before = snapshot([*data.iterdir(), init])
    out = tmp_path / "id"
    res = run("identify", data, "--out", out, "--init", init, "--fix", "Ms=0.0247",
              *STEPS, "--no-figures")
    assert res.exit_code == 4, res.output
    lines = res.stdout.splitlines()
    assert lines[0].startswith("MISSPECIFIED: the model does not describe these recordings")
    assert [ln for ln in res.stderr.splitlines() if ln.startswith("error:")] == \
        [ln for ln in res.stderr.splitlines()[-1:]]
    assert "Traceback" not in res.output
    params = json.loads((out / "params.json").read_text())
    assert params["fit_status"].startswith("misspecified: ")
    ss.load_params(out / "params.json")  # still a parameter file
    fit = json.loads((out / "fit.json").read_text())
    assert fit["status"] == "misspecified" and fit["misspecified"] is True
    assert "saw_40V_500Hz_fwd" in fit["model_check"]["misspecified_recordings"]
    # What the friction step did not fit is printed without a standard error.
    held = [ln for ln in lines if ln.strip().startswith(("Mp ", "Kp ", "Dp "))]
    assert held and all("±" not in ln and "held" in ln for ln in held)
    assert snapshot(before) == before
    # A command that loads the marked file says so.
    sim = run("simulate", "--params", out / "params.json", "--waveform", "sine",
              "--amplitude", 10, "--frequency", 50, "--duration", 0.01, "--out",
              tmp_path / "s.csv")
    assert sim.exit_code == 0, sim.output
    assert "warning:" in sim.stderr and "misspecified" in sim.stderr


def test_a_fit_within_the_noise_is_not_called_misspecified(fixtures_dir, tmp_path):
    data, init = _sawtooths(fixtures_dir, tmp_path)
    out = tmp_path / "id"
    res = run("identify", data, "--out", out, "--init", init, "--fix", "Ms=0.0247",
              *STEPS, "--no-figures")
    assert res.exit_code == 0, res.output
    assert "MISSPECIFIED" not in res.output and "fit_status" not in \
        (out / "params.json").read_text()
    assert json.loads((out / "fit.json").read_text())["status"] == "converged"


def test_a_held_hysteresis_is_held_as_given(fixtures_dir, tmp_path):
    # The start's 35 thresholds span 0-58 V, the recordings 0-40 V: re-gridded to the
    # recorded range (as when the weights are fitted), the held loop would be another
    # model, 2 nm off (misspecified). Held, it is the truth's, and the fit adequate.
    data, init = _sawtooths(fixtures_dir, tmp_path)
    (data / "sine_40V_50Hz.csv").unlink()
    out = tmp_path / "id"
    res = run("identify", data, "--out", out, "--init", init, "--fix", "Ms=0.0247",
              "--steps", "friction", "--no-figures")
    assert res.exit_code == 0, res.output
    params = json.loads((out / "params.json").read_text())
    start = json.loads(init.read_text())
    assert params["pi_thresholds"] == start["pi_thresholds"]
    assert params["pi_weights"] == start["pi_weights"]
    assert json.loads((out / "fit.json").read_text())["model_check"]["verdict"] == "adequate"


# ------------------------------------------------------------- staged outputs


def test_staged_folder_writes_whole_or_not_at_all(tmp_path):
    out = tmp_path / "deep" / "out"
    with pytest.raises(RuntimeError), staged_folder(out, "identify", force=False) as stage:
        (stage / "params.json").write_text("{}")
        raise RuntimeError("the fit failed")
    assert not out.exists() and not (tmp_path / "deep").exists()
    assert leftovers(tmp_path) == []
    with staged_folder(out, "identify", force=False) as stage:
        (stage / "figures").mkdir()
        (stage / "figures" / "overlay_a.png").write_bytes(b"a")
        (stage / "figures" / "overlay_b.png").write_bytes(b"b")
        assert not out.exists()  # nothing in place before the end
    assert sorted(p.name for p in (out / "figures").iterdir()) == ["overlay_a.png",
                                                                   "overlay_b.png"]
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest == {"identify": ["figures/overlay_a.png", "figures/overlay_b.png"]}
    (out / "notes.txt").write_text("mine")  # the user's own file
    # Without force an earlier run's outputs are refused at once, before any work.
    with pytest.raises(OutputExistsError), staged_folder(out, "identify", force=False):
        pytest.fail("the block must not run")
    # With force the earlier outputs are replaced, stale ones included; nothing else.
    with staged_folder(out, "identify", force=True) as stage:
        (stage / "figures").mkdir()
        (stage / "figures" / "overlay_a.png").write_bytes(b"A")
    assert sorted(p.name for p in (out / "figures").iterdir()) == ["overlay_a.png"]
    assert (out / "figures" / "overlay_a.png").read_bytes() == b"A"
    assert (out / "notes.txt").read_text() == "mine"
    # Another command's outputs in the same folder are not its to remove.
    with staged_folder(out, "diagnose", force=False) as stage:
        (stage / "report.md").write_text("r")
    with staged_folder(out, "identify", force=True) as stage:
        (stage / "fit.json").write_text("{}")
    assert (out / "report.md").exists() and not (out / "figures" / "overlay_a.png").exists()
    assert leftovers(out.parent) == []


def test_staged_files_and_the_lock(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "sub" / "b.png"
    with staged_files([a, None, b], force=False) as staged:
        staged[a].write_text("A")
        with pytest.raises(OutputLockedError, match="another stickslip command"):
            OutputLock(a).acquire()
        assert not a.exists()
    assert a.read_text() == "A" and not b.exists()  # b was never written
    with pytest.raises(OutputExistsError), staged_files([a], force=False):
        pass
    with staged_files([a], force=True) as staged:
        staged[a].write_text("A2")
    assert a.read_text() == "A2"
    lock = OutputLock(tmp_path / "out").acquire()
    try:
        with pytest.raises(OutputLockedError), staged_folder(tmp_path / "out", "x",
                                                             force=False):
            pass
    finally:
        lock.release()
    assert leftovers(tmp_path) == []


def test_abort_active_removes_what_was_staged(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(StageAborted), staged_folder(out, "identify", force=False) as stage:
        (stage / "params.json").write_text("{}")
        assert abort_active() == 1  # what an interrupt handler does
        assert not stage.exists()
        OutputLock(out).acquire().release()  # the lock is free again
    assert not out.exists() and leftovers(tmp_path) == []


# ------------------------------------------------------------- Ctrl-C and locks


def _start(args, cwd: Path, **env_changes):
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONUNBUFFERED": "1", **env_changes}
    return subprocess.Popen([sys.executable, "-m", "stickslip_cli", *map(str, args)],
                            cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_for(proc, marker: str, timeout: float = 300.0) -> list[str]:
    """Read ``proc``'s stderr until a line holds ``marker``; the lines read."""
    lines, end = [], time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if not line:
            break
        lines.append(line)
        if marker in line:
            return lines
    raise AssertionError(f"{marker!r} never came: {''.join(lines)[-2000:]}")


@pytest.mark.slow
@pytest.mark.parametrize("point", ["import", "start", "fit", "figures", "figures helper"])
def test_ctrl_c_stops_within_a_second_and_leaves_nothing(fixtures_dir, tmp_path, point):
    data, init = _sawtooths(fixtures_dir, tmp_path)
    before = snapshot([*data.iterdir(), init])
    out = tmp_path / "id"
    # "figures helper": drawn beside a helper process, which shares the command's
    # stderr, so communicate() below also waits for the helper to be gone.
    proc = _start(["identify", data, "--out", out, "--init", init, "--fix", "Ms=0.0247",
                   *STEPS, "--force"], tmp_path,
                  STICKSLIP_FIGURE_HELPER="1" if point == "figures helper" else "0")
    seen = []
    if point == "import":
        time.sleep(0.3)
    else:
        marker = {"start": "recording(s); start", "fit": "hysteresis: step   1",
                  "figures": "[check]", "figures helper": "[check]"}[point]
        seen = _wait_for(proc, marker)
        if point == "start":
            # A second command aimed at the same --out is refused at once.
            second = run("identify", data, "--out", out, "--init", init, "--force")
            assert second.exit_code == 2, second.output
            assert "another stickslip command is writing there" in second.stderr
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=30)
    stopped = time.monotonic() - t0
    stderr = "".join(seen) + stderr
    assert proc.returncode == 130, stderr
    assert stopped < 1.5, stopped
    assert stderr.splitlines()[-1].startswith("error: interrupted (Ctrl-C)")
    assert sum(ln.startswith("error:") for ln in stderr.splitlines()) == 1
    assert "Traceback" not in stderr + stdout and "Exception ignored" not in stderr
    assert not out.exists() and leftovers(tmp_path) == []
    assert snapshot(before) == before
    if point == "start":  # the lock went with the process: the command now runs
        done = run("identify", data, "--out", out, "--init", init, "--fix", "Ms=0.0247",
                   *STEPS, "--no-figures")
        assert done.exit_code == 0, done.output

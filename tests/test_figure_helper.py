"""The figure helper process (stickslip_jax.figure_helper): what it draws is the same
file to the byte as what this process draws, a job that fails there is drawn (or
raised) here, a dead helper loses nothing, and Ctrl-C does not reach it."""

import signal
import time

import matplotlib
import numpy as np
import pytest

from stickslip_jax.figure_helper import (
    FigureHelper,
    FigureJob,
    draw_figures,
    figure_helper,
    helper_enabled,
)
from stickslip_jax.plots import plot_trace

pytestmark = pytest.mark.xdist_group("figure_helper")  # one helper process at a time


def trace_jobs(folder, n=4):
    """``n`` overlays of distinct sine traces, to be written into ``folder``."""
    t = np.linspace(0.0, 0.02, 500)
    u = 40 * np.sin(2 * np.pi * 50 * t)
    return [FigureJob(f"trace_{i}", plot_trace, (t, u, 1e-6 * np.sin(2 * np.pi * (i + 1) * 50 * t)),
                      {"title": f"trace {i}", "path": folder / f"trace_{i}.png"})
            for i in range(n)]


def test_the_helper_draws_the_files_this_process_draws(tmp_path):
    alone, shared = tmp_path / "alone", tmp_path / "shared"
    alone.mkdir()
    shared.mkdir()
    here = draw_figures(trace_jobs(alone))
    jobs = trace_jobs(shared)
    with FigureHelper() as helper:
        done, taken = {}, iter(range(10))
        helper.feed(jobs, lambda: next(taken), done)  # every job to the helper
    assert sorted(done) == sorted(here) == [f"trace_{i}" for i in range(4)]
    for key, path in done.items():
        assert path == shared / f"{key}.png"
        assert path.read_bytes() == here[key].read_bytes(), key


def test_shared_drawing_writes_every_figure_in_order_with_in_process_jobs(tmp_path):
    jobs = trace_jobs(tmp_path, 6)
    t = np.linspace(0.0, 1.0, 50)
    # not picklable: drawn here only
    jobs.insert(2, FigureJob("local", lambda path: plot_trace(t, t, 1e-6 * t, path=path),
                             kwargs={"path": tmp_path / "local.png"}, in_process=True))
    with FigureHelper() as helper:
        paths = draw_figures(jobs, helper)
    assert list(paths) == [j.key for j in jobs]
    for job in jobs:
        assert paths[job.key] == tmp_path / f"{job.key}.png"
        assert paths[job.key].stat().st_size > 1000


class _IdleHelper:
    """A helper that draws nothing: every shared job is drawn here, in the order
    draw_figures hands them out."""

    def feed(self, jobs, take, done):
        return None

    def close(self):
        return None


def test_shared_jobs_are_handed_out_heaviest_first(tmp_path):
    drawn = []

    def draw(key, path):
        drawn.append(key)
        return path

    weights = {"a": 1.0, "b": 3.0, "c": 1.0, "d": 6.0, "e": 1.0}
    jobs = [FigureJob(k, draw, (k,), {"path": tmp_path / f"{k}.png"}, weight=w)
            for k, w in weights.items()]
    paths = draw_figures(jobs, _IdleHelper())
    assert drawn == ["d", "b", "a", "c", "e"]  # heaviest first, equals in their order
    assert list(paths) == list(weights)  # returned in the jobs' order
    drawn.clear()
    draw_figures(jobs)  # without a helper: in order
    assert drawn == list(weights)


def test_the_helper_draws_with_this_process_settings(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with matplotlib.rc_context({"font.size": 13.0, "axes.facecolor": "0.9"}):
        here = draw_figures(trace_jobs(tmp_path / "a", 1))
        with FigureHelper() as helper:
            done, taken = {}, iter(range(3))
            helper.feed(trace_jobs(tmp_path / "b", 1), lambda: next(taken), done)
    plain = draw_figures(trace_jobs(tmp_path, 1))
    assert done["trace_0"].read_bytes() == here["trace_0"].read_bytes()
    assert plain["trace_0"].read_bytes() != here["trace_0"].read_bytes()


def test_a_job_that_fails_in_the_helper_raises_here(tmp_path):
    bad = FigureJob("bad", plot_trace, (np.arange(5.0), np.arange(4.0), np.arange(3.0)),
                    {"path": tmp_path / "bad.png"})
    with FigureHelper() as helper:
        done, taken = {}, iter(range(3))
        helper.feed([bad], lambda: next(taken), done)
        assert done == {}  # reported failed, not drawn
        with pytest.raises(ValueError):
            draw_figures([bad, *trace_jobs(tmp_path, 2)], helper)


def test_a_dead_helper_loses_no_figure(tmp_path):
    with FigureHelper() as helper:
        helper._process.kill()
        helper._process.wait()
        paths = draw_figures(trace_jobs(tmp_path), helper)
    assert sorted(p.name for p in paths.values()) == [f"trace_{i}.png" for i in range(4)]
    assert all(p.is_file() for p in paths.values())


def test_ctrl_c_does_not_reach_the_helper_and_closing_stops_it_at_once():
    import os

    helper = FigureHelper()
    process = helper._process
    # A terminal's Ctrl-C goes to its foreground process group: not the helper's.
    assert os.getpgid(process.pid) != os.getpgid(0)
    deadline = time.monotonic() + 60
    while not _ignores_sigint(process.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)  # and a SIGINT sent to it anyway is ignored
    time.sleep(0.5)
    assert process.poll() is None, "SIGINT stopped the helper"
    t0 = time.monotonic()
    helper.close()
    assert time.monotonic() - t0 < 1.5
    assert process.poll() is not None


def _ignores_sigint(pid: int) -> bool:
    """Whether process ``pid`` ignores SIGINT (its SigIgn mask in /proc)."""
    with open(f"/proc/{pid}/status") as fh:
        ignored = next(int(line.split()[1], 16) for line in fh if line.startswith("SigIgn"))
    return bool(ignored & (1 << (signal.SIGINT - 1)))


def test_the_environment_turns_the_helper_off(monkeypatch):
    monkeypatch.setenv("STICKSLIP_FIGURE_HELPER", "0")
    assert not helper_enabled()
    with figure_helper() as helper:
        assert helper is None
    monkeypatch.setenv("STICKSLIP_FIGURE_HELPER", "yes")
    with pytest.raises(ValueError, match="STICKSLIP_FIGURE_HELPER"):
        helper_enabled()
    monkeypatch.setenv("STICKSLIP_FIGURE_HELPER", "1")
    with figure_helper(enabled=False) as helper:
        assert helper is None


def test_stop_all_kills_every_helper_at_once():
    from stickslip_jax.figure_helper import stop_all

    helpers = [FigureHelper(), FigureHelper()]
    processes = [h._process for h in helpers]
    t0 = time.monotonic()
    assert stop_all() == 2
    assert time.monotonic() - t0 < 1.0
    assert all(p.poll() is not None for p in processes)
    assert stop_all() == 0
    for helper in helpers:
        helper.close()  # nothing left to stop


def test_a_job_that_cannot_go_to_the_helper_is_drawn_here(tmp_path):
    t = np.linspace(0.0, 1.0, 50)
    local = FigureJob("local", lambda path: plot_trace(t, t, 1e-6 * t, path=path),
                      kwargs={"path": tmp_path / "local.png"})  # not marked in_process
    with FigureHelper() as helper:
        paths = draw_figures([local, *trace_jobs(tmp_path, 3)], helper)
    assert list(paths) == ["local", "trace_0", "trace_1", "trace_2"]
    assert all(p.is_file() for p in paths.values())


def plot_from_this_test_module(path):
    """A module-level job the helper cannot unpickle: it imports the package, not the
    test modules."""
    t = np.linspace(0.0, 1.0, 50)
    return plot_trace(t, t, 1e-6 * t, path=path)


def test_a_job_the_helper_cannot_unpickle_is_reported_and_the_helper_goes_on(tmp_path, capfd):
    job = FigureJob("here_only", plot_from_this_test_module,
                    kwargs={"path": tmp_path / "here_only.png"})
    with FigureHelper() as helper:
        done, taken = {}, iter(range(3))
        helper.feed([job], lambda: next(taken), done)
        assert done == {}  # reported, not drawn there
        good = trace_jobs(tmp_path, 1)
        taken = iter(range(3))
        helper.feed(good, lambda: next(taken), done)  # the same helper, still in step
        assert list(done) == ["trace_0"] and done["trace_0"].is_file()
        paths = draw_figures([job, *trace_jobs(tmp_path, 2)], helper)
    assert paths["here_only"].is_file()
    assert "Traceback" not in capfd.readouterr().err  # the helper did not die loudly

"""A second process that draws figures beside this one.

Drawing is matplotlib's work on one core: a command that writes twenty figures after
its fit leaves the machine's other core idle for seconds. :class:`FigureHelper` starts
a helper process early (its imports then overlap the fit), and :func:`draw_figures`
shares a list of figure jobs between it and this process: each takes the next job
until none is left, so neither waits while the other has work.

Who draws which figure changes nothing in it: every job is a module-level function of
plain data (numpy arrays, recordings, paths) that writes its file atomically, and both
processes run the same matplotlib with the same settings (this process's rcParams go
to the helper with each list of jobs), so the files are the same to the byte
whichever draws them (``tests/test_figure_helper.py``). A job that needs
this process's state (a compiled model) is marked ``in_process`` and never shipped.

Failure is safe: a terminal's Ctrl-C reaches this process only (the helper runs in a
session of its own and ignores SIGINT); leaving :class:`FigureHelper` stops the helper
within a second (a draw interrupted here stops it at once), and any job it did not
report drawn (it failed or the helper died) is drawn here, so an error surfaces as it
would without the helper. Nothing is timed: which
process draws a figure depends on the machine's load, but what is written does not.
``STICKSLIP_FIGURE_HELPER=0`` draws everything in this process.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import pickle
import signal
import subprocess
import sys
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class FigureJob:
    """One figure to write: ``draw(*args, **kwargs)`` writes it and returns its path.

    ``draw`` must be importable by name (a module-level function) and its arguments
    picklable, unless ``in_process``: then it is drawn in this process only (for
    figures that evaluate the model)."""

    key: str
    draw: Callable[..., Path]
    args: tuple = ()
    kwargs: dict = field(default_factory=dict)
    in_process: bool = False
    weight: float = 1.0
    """Its drawing time relative to the others' [-]: :func:`draw_figures` hands out
    the heaviest first, so that the two processes end together (a heavy figure last
    keeps one drawing while the other waits). It orders the drawing, never what is
    drawn."""

    def run(self) -> Path:
        return Path(self.draw(*self.args, **self.kwargs))


def helper_enabled() -> bool:
    """Whether commands start a figure helper (``STICKSLIP_FIGURE_HELPER``, default on;
    ``0`` turns it off)."""
    value = os.environ.get("STICKSLIP_FIGURE_HELPER", "1").strip()
    if value not in ("0", "1"):
        raise ValueError(f"STICKSLIP_FIGURE_HELPER must be 0 or 1, got {value!r}")
    return value == "1"


def _send(stream, message) -> None:
    pickle.dump(message, stream, protocol=pickle.HIGHEST_PROTOCOL)
    stream.flush()


def warm_up_drawing() -> None:
    """Draw a first, throw-away figure: matplotlib's imports, its fonts and the Agg
    canvas loaded, which a process's first figure otherwise waits for (0.8 s: its first
    overlay took 1.17 s, the next 0.38 s). The helper does it at its start. In the
    command's own process a thread doing it during the fit gained nothing (identify on
    the fixtures, 4 pairs: 21.3/22.0, 19.9/19.9, 21.5/21.5 s without/with): it took
    the GIL from the fit for as long as it saved at the end."""
    from .plots import subplots

    fig, ax = subplots()
    ax.plot([0, 1])
    fig.canvas.draw()


def serve() -> None:
    """The helper process: draw each job it is sent on stdin (a :class:`FigureJob`
    pickled into bytes) and report it on stdout (``("ok", key, path)`` or
    ``("error", key, traceback)``, key None when the job would not unpickle), until None
    or the end of its input (its parent is gone)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which stops it
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything a library prints goes to stderr, not into the replies
    requests = sys.stdin.buffer
    warm_up_drawing()
    while True:
        try:
            job = pickle.load(requests)
        except EOFError:
            return
        if job is None:
            return
        if isinstance(job, dict):  # the parent's matplotlib settings, before its jobs
            _apply_settings(job)
            continue
        key = None
        try:
            # Each job comes pickled inside its message, so that one this process cannot
            # unpickle (its function not importable here) is reported like a failed draw
            # and leaves the stream in step for the next.
            job = pickle.loads(job)
            key = job.key
            reply = ("ok", key, str(job.run()))
        except Exception:  # reported; the parent draws it again and raises there
            reply = ("error", key, traceback.format_exc())
        try:
            _send(replies, reply)
        except OSError:  # the parent is gone
            return


_ACTIVE: set[FigureHelper] = set()
_ACTIVE_LOCK = threading.Lock()


def stop_all() -> int:
    """Kill every helper process now and wait for each; the number killed. For an
    interrupt handler that ends the process without unwinding (``stickslip_cli``): it
    runs before the staged outputs are removed, so no helper writes into them after."""
    with _ACTIVE_LOCK:
        helpers = list(_ACTIVE)
    for helper in helpers:
        helper.kill()
    return len(helpers)


def _settings() -> dict:
    """This process's matplotlib settings (a notebook may have changed them), for the
    helper to draw with; none while matplotlib is not imported here."""
    if "matplotlib" not in sys.modules:
        return {}
    import matplotlib

    return {k: v for k, v in matplotlib.rcParams.items() if k != "backend"}


def _apply_settings(settings: dict) -> None:
    import warnings

    import matplotlib

    with warnings.catch_warnings():  # deprecated names copied along with the rest
        warnings.simplefilter("ignore")
        matplotlib.rcParams.update(settings)


class FigureHelper:
    """A helper process for :func:`draw_figures`. Use as a context manager, entered
    well before the figures (its start-up, about as long as importing this package,
    then overlaps other work); leaving it stops the helper."""

    def __init__(self) -> None:
        self._process = subprocess.Popen(
            [sys.executable, "-c", "from stickslip_jax.figure_helper import serve; serve()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=_helper_environment(),
            start_new_session=True)  # a terminal's Ctrl-C reaches this process only
        with _ACTIVE_LOCK:
            _ACTIVE.add(self)

    def __enter__(self) -> FigureHelper:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def kill(self) -> None:
        """Stop the helper at once, whatever it is drawing."""
        process = self._process
        if process is not None:
            with contextlib.suppress(OSError):
                process.kill()
            self.close()

    def close(self) -> None:
        """Stop the helper: ask it to end, and kill it if it does not at once."""
        process, self._process = self._process, None
        if process is None:
            return
        with _ACTIVE_LOCK:
            _ACTIVE.discard(self)
        with contextlib.suppress(OSError, ValueError):
            _send(process.stdin, None)
            process.stdin.close()
        try:
            process.wait(timeout=0.3)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        process.stdout.close()

    def feed(self, jobs: Sequence[FigureJob], take: Callable[[], int],
             done: dict[str, Path]) -> None:
        """Give the helper ``jobs[take()]`` one at a time until ``take`` runs past the
        end, putting each path it reports drawn into ``done``. Returns at the end of
        the jobs or when the helper fails (what it had not drawn stays out of
        ``done``). Runs on a thread of this process beside its own drawing."""
        process = self._process
        if process is None:
            return
        try:
            _send(process.stdin, _settings())
            while (i := take()) < len(jobs):
                _send(process.stdin, pickle.dumps(jobs[i], protocol=pickle.HIGHEST_PROTOCOL))
                status, key, value = pickle.load(process.stdout)
                if status != "ok":
                    return
                done[key] = Path(value)
        except Exception:  # a broken pipe, a job that would not pickle, a lost reply:
            self.close()  # no later job goes to this helper; this process draws them


def _helper_environment() -> dict[str, str]:
    """The helper's environment: this one, with this package importable as it is
    here (a checkout run without installing)."""
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    return env


@contextlib.contextmanager
def figure_helper(enabled: bool = True) -> Iterator[FigureHelper | None]:
    """A :class:`FigureHelper` for the block, or None when ``enabled`` is false, the
    environment turns it off (:func:`helper_enabled`) or a process cannot start."""
    if not (enabled and helper_enabled()):
        yield None
        return
    try:
        helper = FigureHelper()
    except OSError:  # no processes here (a sandbox): draw everything in this one
        yield None
        return
    with helper:
        yield helper


def draw_figures(jobs: Sequence[FigureJob], helper: FigureHelper | None = None
                 ) -> dict[str, Path]:
    """Write every job's figure; returns ``{key: path}`` in the jobs' order.

    With a ``helper``, the jobs not ``in_process`` are shared with it: this process
    draws its own jobs first, then each process takes the next shared job as it comes
    free, the heaviest first (:attr:`FigureJob.weight`). Without one, everything is
    drawn here, in order."""
    if len({j.key for j in jobs}) != len(jobs):
        raise ValueError("figure jobs need distinct keys")
    shared = sorted((j for j in jobs if not j.in_process), key=lambda j: -j.weight)
    if helper is None or not shared:
        return {j.key: j.run() for j in jobs}
    counter, lock = itertools.count(), threading.Lock()

    def take() -> int:
        with lock:
            return next(counter)

    by_helper: dict[str, Path] = {}
    feeder = threading.Thread(target=helper.feed, args=(shared, take, by_helper),
                              name="stickslip-figure-feeder", daemon=True)
    feeder.start()
    try:
        paths = {j.key: j.run() for j in jobs if j.in_process}
        while (i := take()) < len(shared):
            paths[shared[i].key] = shared[i].run()
        feeder.join()
    except BaseException:  # Ctrl-C or an error here: the helper stops drawing at once
        helper.close()
        raise
    paths.update(by_helper)
    for job in shared:  # what the helper failed or died on: drawn (or raised) here
        if job.key not in paths:
            paths[job.key] = job.run()
    return {j.key: paths[j.key] for j in jobs}

"""``one_blas_thread``: identify, diagnose and design_experiment run OpenBLAS on one
thread and put the process's counts back afterwards (stickslip_jax/blas_threads.py)."""

import threading

import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.blas_threads import blas_thread_counts, limit_blas_threads, one_blas_thread


@pytest.fixture
def two_blas_threads(monkeypatch):
    """Every loaded OpenBLAS on two threads, no ``OPENBLAS_NUM_THREADS``; the counts
    found are put back after the test."""
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    np.ones((4, 4)) @ np.ones((4, 4))  # numpy's OpenBLAS loaded
    before = blas_thread_counts()
    if not before:
        pytest.skip("no OpenBLAS loaded in this process")
    limit_blas_threads(2)
    counts = blas_thread_counts()
    if set(counts.values()) != {2}:
        limit_blas_threads(1)
        pytest.skip(f"OpenBLAS here runs at most {counts} threads")
    yield counts
    for threads in set(before.values()):
        limit_blas_threads(threads)


def test_a_decorated_call_runs_one_thread_and_puts_the_counts_back(two_blas_threads):
    seen = []

    @one_blas_thread
    def inner():
        seen.append(("inner", blas_thread_counts()))

    @one_blas_thread
    def outer():
        seen.append(("outer before", blas_thread_counts()))
        inner()
        seen.append(("outer after", blas_thread_counts()))  # the nested call restored nothing
        return 7

    assert outer() == 7
    for where, counts in seen:
        assert set(counts.values()) == {1}, (where, counts)
    assert blas_thread_counts() == two_blas_threads


def test_calls_side_by_side_restore_only_when_the_last_returns(two_blas_threads):
    first_in, second_done = threading.Event(), threading.Event()
    seen = {}

    @one_blas_thread
    def first():
        first_in.set()
        second_done.wait(10)
        seen["first after the second returned"] = blas_thread_counts()

    @one_blas_thread
    def second():
        pass

    t = threading.Thread(target=first)
    t.start()
    first_in.wait(10)
    second()
    second_done.set()
    t.join(10)
    assert set(seen["first after the second returned"].values()) == {1}
    assert blas_thread_counts() == two_blas_threads


def test_an_exception_still_restores_and_the_users_setting_stands(two_blas_threads,
                                                                  monkeypatch):
    @one_blas_thread
    def fails():
        raise RuntimeError("inside")

    with pytest.raises(RuntimeError, match="inside"):
        fails()
    assert blas_thread_counts() == two_blas_threads

    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    seen = []
    one_blas_thread(lambda: seen.append(blas_thread_counts()))()
    assert seen == [two_blas_threads]


def test_the_entry_points_are_wrapped():
    for fn in (ss.identify, ss.diagnose, ss.design_experiment):
        assert getattr(fn, "__wrapped__", None) is not None, fn.__name__

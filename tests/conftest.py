"""Strict numerics for every test: float64 and no silent rank promotion; XLA's small
loops compiled as the command line compiles them (``fast_cpu_loops``); OpenBLAS on one
thread, as the command line runs it (``stickslip_jax/blas_threads.py``: beside another
worker, up to a tenth of a reduced diagnosis's time went to spinning BLAS threads), here and in the
notebooks' kernels and the commands the tests start. Where
``$STICKSLIP_CACHE_DIR`` names a folder (``make test`` names one in its environment's
folder), the workers share compiled programs through JAX's persistent cache
(:mod:`stickslip_jax.compilation_cache`); unset or ``off``, each compiles its own."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# Commands run in-process here draw their figures without a helper process: two test
# workers already keep both cores busy (tests/test_figure_helper.py tests the helper).
os.environ.setdefault("STICKSLIP_FIGURE_HELPER", "0")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import pytest  # noqa: E402

import stickslip_jax  # noqa: E402
from stickslip_jax.blas_threads import limit_blas_threads  # noqa: E402
from stickslip_jax.compilation_cache import (  # noqa: E402
    cache_dir_from_env,
    use_compilation_cache,
)

stickslip_jax.fast_cpu_loops()  # before any JAX computation, as the CLI does
if os.environ["OPENBLAS_NUM_THREADS"] == "1":  # (a library loaded before this line)
    limit_blas_threads(1)

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
use_compilation_cache(cache_dir_from_env(default=None))

from pathlib import Path  # noqa: E402

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"


@pytest.fixture(scope="session")
def fixtures_dir() -> Path:
    """The repository's fixtures/ folder (tests never read outside the repo)."""
    return FIXTURES

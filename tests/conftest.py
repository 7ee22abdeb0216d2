"""Strict numerics for every test: float64 and no silent rank promotion; XLA's small
loops compiled as the command line compiles them (``fast_cpu_loops``). Where
``$STICKSLIP_CACHE_DIR`` names a folder (``make test`` names one in its environment's
folder), the workers share compiled programs through JAX's persistent cache
(:mod:`stickslip_jax.compilation_cache`); unset or ``off``, each compiles its own."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# Commands run in-process here draw their figures without a helper process: two test
# workers already keep both cores busy (tests/test_figure_helper.py tests the helper).
os.environ.setdefault("STICKSLIP_FIGURE_HELPER", "0")

import jax  # noqa: E402
import pytest  # noqa: E402

import stickslip_jax  # noqa: E402
from stickslip_jax.compilation_cache import (  # noqa: E402
    cache_dir_from_env,
    use_compilation_cache,
)

stickslip_jax.fast_cpu_loops()  # before any JAX computation, as the CLI does

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
use_compilation_cache(cache_dir_from_env(default=None))

from pathlib import Path  # noqa: E402

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"


@pytest.fixture(scope="session")
def fixtures_dir() -> Path:
    """The repository's fixtures/ folder (tests never read outside the repo)."""
    return FIXTURES

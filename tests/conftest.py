"""Strict numerics for every test: float64 and no silent rank promotion; XLA's small
loops compiled as the command line compiles them (``fast_cpu_loops``)."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402
import pytest  # noqa: E402

import stickslip_jax  # noqa: E402

stickslip_jax.fast_cpu_loops()  # before any JAX computation, as the CLI does

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

from pathlib import Path  # noqa: E402

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"


@pytest.fixture(scope="session")
def fixtures_dir() -> Path:
    """The repository's fixtures/ folder (tests never read outside the repo)."""
    return FIXTURES

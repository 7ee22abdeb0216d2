"""The fits refuse single precision at once (stickslip_jax.precision)."""

import jax.numpy as jnp
import pytest

import stickslip_jax as ss


def test_a_fit_in_single_precision_is_refused_before_any_work():
    """Float32 residuals sit at the rounding level of nanometres on micrometres: the
    fits say so at once instead of failing minutes later (stickslip_jax.precision)."""
    import jax

    from stickslip_jax.diagnose import diagnose

    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(RuntimeError, match="diagnose needs double precision"):
            diagnose([], init=ss.lu2015_slc1720())
        with pytest.raises(RuntimeError, match="identify needs double precision"):
            ss.identify([], init=ss.lu2015_slc1720())
    finally:
        jax.config.update("jax_enable_x64", True)
    assert jnp.asarray(1.0).dtype == jnp.float64

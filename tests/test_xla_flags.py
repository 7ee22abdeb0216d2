"""XLA_FLAGS helpers: what they add, when they refuse, and that the native-loop
compilation gives the same numbers as XLA's default."""

import json
import os
import subprocess
import sys

import pytest

from stickslip_jax import xla_flags

_SIMULATE = """
import json, jax
jax.config.update("jax_enable_x64", True)
import stickslip_jax as ss
ss.fast_cpu_loops() if {fast} else None
act = ss.lu2015_slc1720()
t, u = ss.sawtooth(40.0, 500.0, direction="backward", duration_s=0.02)
q = ss.simulate(act, u, dt=float(t[1] - t[0]), drive=ss.DriveContext.make(backward=True))
print(json.dumps([float(x) for x in q]))
"""


def _run(fast: bool, flags: str = "") -> list[float]:
    env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", _SIMULATE.format(fast=fast)], env=env,
                         capture_output=True, text=True, timeout=300, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_native_loops_give_the_default_compilations_numbers():
    default, fast = _run(False), _run(True)
    assert len(default) == len(fast) == 500
    span = max(default) - min(default)
    assert span > 1e-7  # a stepping trace, not a flat one
    # Same scheme, compiled differently: equal to rounding (FMA contraction may differ).
    assert max(abs(a - b) for a, b in zip(default, fast, strict=True)) < 1e-9 * span


def test_add_xla_flag_keeps_a_users_value_and_refuses_once_jax_has_started(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=3")
    assert xla_flags.add_xla_flag("xla_force_host_platform_device_count", 8)
    assert os.environ["XLA_FLAGS"] == "--xla_force_host_platform_device_count=3"
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()  # JAX has started: a new flag now comes too late
    assert xla_flags.backends_started()
    assert not xla_flags.add_xla_flag("xla_cpu_enable_fast_math", "false")
    assert "fast_math" not in os.environ["XLA_FLAGS"]


def test_fast_cpu_loops_warns_when_late_and_leaves_a_users_backend_options(monkeypatch):
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()  # make sure JAX has started
    monkeypatch.setenv("XLA_FLAGS", "")
    with pytest.warns(UserWarning, match="came after JAX's first computation"):
        assert xla_flags.fast_cpu_loops() is False
    assert os.environ["XLA_FLAGS"] == ""
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_extra_options=xla_cpu_fold_all_constants")
    assert xla_flags.fast_cpu_loops() is False  # the user's own options: not ours to merge
    monkeypatch.setenv("XLA_FLAGS",
                       "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5")
    assert xla_flags.fast_cpu_loops() is True
    with pytest.raises(ValueError, match="threshold_bytes"):
        xla_flags.fast_cpu_loops(-1)


def _flags_after(call: str, flags: str) -> str:
    """What ``ss.<call>`` returns and leaves in XLA_FLAGS, in a fresh process that starts
    with ``flags``."""
    code = f"import os, stickslip_jax as ss; ok = ss.{call}; print(ok, os.environ['XLA_FLAGS'])"
    env = {**os.environ, "XLA_FLAGS": flags}
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=120, check=True).stdout.strip()


def test_fast_cpu_loops_sets_the_threshold_in_a_fresh_process():
    out = _flags_after("fast_cpu_loops(2048)", "--xla_force_host_platform_device_count=2")
    assert out == ("True --xla_force_host_platform_device_count=2 "
                   "--xla_cpu_experimental_ynn_fusion_type= "
                   "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=2048")


def test_device_side_gpu_loops_adds_both_options_and_keeps_a_users_own():
    out = _flags_after("device_side_gpu_loops()", "--xla_gpu_graph_min_graph_size=5")
    assert out == ("True --xla_gpu_graph_min_graph_size=5 --xla_gpu_enable_command_buffer="
                   "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,CONDITIONAL,WHILE")


def test_batching_and_adjoint_defaults_on_a_cpu(monkeypatch):
    # With the default stepping's refinement and event conds, mapping rows wins on a CPU
    # whatever the loop setting (vmap turns every cond into a select), and forward
    # sensitivities are the default up to 128 parameters
    # (benchmarks/bench_gradient_modes.py).
    import jax

    from stickslip_jax.adjoint import default_max_directions
    from stickslip_jax.simulate import default_batching

    if jax.default_backend() != "cpu":
        pytest.skip("the rule concerns the CPU backend")
    for flags in ("--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=100000",
                  "--xla_force_host_platform_device_count=2"):
        monkeypatch.setenv("XLA_FLAGS", flags)
        assert default_batching() == "map" and default_max_directions() == 128

"""The persistent compilation cache: where it lives, that ``off`` turns it off, and
that it is the locked, bounded cache (JAX keeps a lock file beside the entries only
when the cache has a size limit): several processes share it safely."""

import os
import subprocess
import sys

from stickslip_jax.compilation_cache import (
    CACHE_ENV,
    DEFAULT_CACHE_DIR,
    cache_dir_from_env,
    use_compilation_cache,
)

_COMPILE = """
import sys, jax, jax.numpy as jnp
from pathlib import Path
from stickslip_jax.compilation_cache import use_compilation_cache
print(use_compilation_cache(Path(sys.argv[1])))
jax.jit(lambda x: jnp.sin(x) * 2.0)(jnp.arange(3.0)).block_until_ready()
"""


def test_the_folder_comes_from_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv(CACHE_ENV, raising=False)
    assert cache_dir_from_env() == DEFAULT_CACHE_DIR
    assert cache_dir_from_env(default=None) is None
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    assert cache_dir_from_env(default=None) == tmp_path
    monkeypatch.setenv(CACHE_ENV, " OFF ")
    assert cache_dir_from_env() is None
    assert use_compilation_cache(None) is False
    assert use_compilation_cache() is False  # the default asks the environment


def test_by_default_the_cache_is_the_environments_folder(tmp_path):
    """A notebook's ``ss.use_compilation_cache()`` keeps its programs where the command
    line keeps them: ``$STICKSLIP_CACHE_DIR``."""
    cache = tmp_path / "cache"
    env = {**os.environ, CACHE_ENV: str(cache)}
    script = _COMPILE.replace("use_compilation_cache(Path(sys.argv[1]))",
                              "use_compilation_cache()")
    done = subprocess.run([sys.executable, "-c", script], env=env,
                          capture_output=True, text=True, timeout=300, check=True)
    assert done.stdout.split()[0] == "True"
    assert any(p.name.endswith("-cache") for p in cache.iterdir())


def test_a_folder_that_cannot_be_made_leaves_the_cache_off(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    assert use_compilation_cache(blocker / "cache") is False


def test_compiled_programs_are_kept_locked_and_read_back(tmp_path):
    cache = tmp_path / "cache"
    env = {k: v for k, v in os.environ.items() if k != CACHE_ENV}
    first = subprocess.run([sys.executable, "-c", _COMPILE, str(cache)], env=env,
                           capture_output=True, text=True, timeout=300, check=True)
    assert first.stdout.split()[0] == "True"
    entries = sorted(p.name for p in cache.iterdir())
    assert ".lockfile" in entries  # the size limit is set, so JAX locks its reads/writes
    assert any(n.endswith("-cache") for n in entries), entries
    # A second process finds the program: nothing new is written.
    subprocess.run([sys.executable, "-c", _COMPILE, str(cache)], env=env,
                   capture_output=True, text=True, timeout=300, check=True)
    assert sorted(p.name for p in cache.iterdir() if not p.name.endswith("-atime")) == \
        sorted(n for n in entries if not n.endswith("-atime"))


def test_a_cache_written_without_zstandard_is_left_alone(tmp_path):
    """A cache from before ``zstandard`` was installed (zlib entries): the compressor is
    part of an entry's key, so the program is compiled again into a zstandard entry
    beside the old one, with no warning about the old one."""
    cache = tmp_path / "cache"
    env = {k: v for k, v in os.environ.items() if k != CACHE_ENV}
    env["PYTHONWARNINGS"] = "always"
    zlib_run = "import sys; sys.modules['zstandard'] = None\n" + _COMPILE
    subprocess.run([sys.executable, "-c", zlib_run, str(cache)], env=env,
                   capture_output=True, text=True, timeout=300, check=True)
    old = {p.name: p.read_bytes() for p in cache.iterdir() if p.name.endswith("-cache")}
    assert old and all(b[:2] == b"\x78\x9c" for b in old.values())  # zlib's header
    again = subprocess.run([sys.executable, "-c", _COMPILE, str(cache)], env=env,
                           capture_output=True, text=True, timeout=300, check=True)
    assert "persistent compilation cache" not in again.stderr, again.stderr
    now = {p.name: p.read_bytes() for p in cache.iterdir() if p.name.endswith("-cache")}
    new = {n: b for n, b in now.items() if n not in old}
    assert len(new) == len(old) and all(now[n] == b for n, b in old.items())
    assert all(b[:4] == b"\x28\xb5\x2f\xfd" for b in new.values())  # a zstandard frame

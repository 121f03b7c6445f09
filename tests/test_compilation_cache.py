"""`fj.use_compilation_cache`: the library's explicit, opt-in persistent compilation cache.

What it changes is JAX's process-wide configuration, so the checks that start from an
unconfigured JAX run in one child process (a fresh JAX, a clean environment)."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import pytest

import fleshing_jax as fj

_CHILD = textwrap.dedent(
    """
    import os, sys
    from pathlib import Path
    import jax
    settings = lambda: (jax.config.jax_compilation_cache_dir,
                        jax.config.jax_persistent_cache_min_compile_time_secs,
                        jax.config.jax_enable_x64)  # x64 is the caller's choice, never set
    before = settings()
    import fleshing_jax as fj
    fj.Line(1.0)  # importing and using the library changes nothing
    assert settings() == before and before[0] is None, settings()
    os.environ["FLESHING_JAX_CACHE"] = "off"
    assert fj.use_compilation_cache() is None and settings() == before
    jax.jit(lambda x: x * 2 + 1)(1.0)  # compiled before the call: not stored anywhere
    mine = Path(sys.argv[1]) / "mine"
    os.environ["FLESHING_JAX_CACHE"] = str(mine)
    assert fj.use_compilation_cache(min_compile_seconds=0) == mine and mine.is_dir()
    assert settings() == (str(mine), 0.0, False)
    assert not os.listdir(mine)
    jax.jit(lambda x: x * 3 - 1)(2.0)  # compiled after: stored, although JAX had compiled
    assert len(os.listdir(mine)) == 1, os.listdir(mine)
    explicit = Path(sys.argv[1]) / "explicit"
    assert fj.use_compilation_cache(explicit) == explicit
    jax.jit(lambda x: x * 5 - 1)(2.0)
    assert len(os.listdir(explicit)) == 1 and len(os.listdir(mine)) == 1
    # Once a folder is configured, the default call keeps it (and its settings).
    os.environ["FLESHING_JAX_CACHE"] = str(mine)
    assert fj.use_compilation_cache() == explicit
    print("ok")
    """
)


def test_use_compilation_cache_is_explicit_and_stores_programs(tmp_path):
    environment = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    checkout = str(Path(__file__).resolve().parents[1])  # this checkout, not an installed copy
    environment["PYTHONPATH"] = os.pathsep.join(
        filter(None, [checkout, os.environ.get("PYTHONPATH")])
    )
    child = subprocess.run([sys.executable, "-c", _CHILD, str(tmp_path)], env=environment,
                           capture_output=True, text=True, timeout=120)  # fmt: skip
    assert child.returncode == 0 and child.stdout.strip() == "ok", child.stderr[-2000:]


def test_use_compilation_cache_keeps_a_configured_cache():
    # This session's cache (conftest.py) is configured: the default call leaves it alone.
    configured = jax.config.jax_compilation_cache_dir
    seconds = jax.config.jax_persistent_cache_min_compile_time_secs
    assert str(fj.use_compilation_cache()) == configured
    assert jax.config.jax_compilation_cache_dir == configured
    assert jax.config.jax_persistent_cache_min_compile_time_secs == seconds


def test_use_compilation_cache_bad_arguments():
    with pytest.raises(TypeError, match="path"):
        fj.use_compilation_cache(3)
    for seconds in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="min_compile_seconds"):
            fj.use_compilation_cache("unused", min_compile_seconds=seconds)

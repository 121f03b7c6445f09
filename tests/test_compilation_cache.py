"""`fj.compilation_cache_settings`: the options of an opt-in persistent compilation cache, which
the caller applies (the library never changes JAX's configuration).

The checks that start from an unconfigured JAX run in one child process (a fresh JAX, a clean
environment)."""

import ast
import os
import subprocess
import sys
import textwrap
from pathlib import Path

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
    assert fj.compilation_cache_settings() == {} and settings() == before
    mine = Path(sys.argv[1]) / "mine"
    os.environ["FLESHING_JAX_CACHE"] = str(mine)
    options = fj.compilation_cache_settings(min_compile_seconds=0)
    assert mine.is_dir() and not os.listdir(mine) and settings() == before  # asked, not set
    for name, value in options.items():
        jax.config.update(name, value)
    assert settings() == (str(mine), 0.0, False)
    jax.jit(lambda x: x * 3 - 1)(2.0)  # stored by JAX with the options applied
    assert len(os.listdir(mine)) == 1, os.listdir(mine)
    # Once a folder is configured, the default call asks for nothing; an explicit one does.
    assert fj.compilation_cache_settings() == {}
    explicit = Path(sys.argv[1]) / "explicit"
    assert fj.compilation_cache_settings(explicit)["jax_compilation_cache_dir"] == str(explicit)
    print("ok")
    """
)


def test_settings_are_only_asked_for_and_store_programs(tmp_path):
    environment = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    checkout = str(Path(__file__).resolve().parents[1])  # this checkout, not an installed copy
    environment["PYTHONPATH"] = os.pathsep.join(
        filter(None, [checkout, os.environ.get("PYTHONPATH")])
    )
    child = subprocess.run([sys.executable, "-c", _CHILD, str(tmp_path)], env=environment,
                           capture_output=True, text=True, timeout=120)  # fmt: skip
    assert child.returncode == 0 and child.stdout.strip() == "ok", child.stderr[-2000:]


def test_a_configured_cache_is_kept():
    # This session's cache (conftest.py) is configured: the default call asks for nothing.
    assert fj.compilation_cache_settings() == {}


def test_compilation_cache_settings_bad_arguments():
    with pytest.raises(TypeError, match="path"):
        fj.compilation_cache_settings(3)
    for seconds in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="min_compile_seconds"):
            fj.compilation_cache_settings("unused", min_compile_seconds=seconds)


def test_the_library_never_sets_jax_s_configuration():
    # No call of `….config.update(…)` anywhere in the package (docstrings may show one).
    for source in Path(fj.__file__).parent.rglob("*.py"):
        for node in ast.walk(ast.parse(source.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                owner = node.func.value
                called = node.func.attr == "update" and getattr(owner, "attr", "") == "config"
                assert not called, f"{source}:{node.lineno}"

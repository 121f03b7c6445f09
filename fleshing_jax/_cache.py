"""JAX's persistent compilation cache for the command line, the demo and library users.

Compiling the batched paths takes seconds; the work on a typical mesh takes milliseconds. The
command line therefore keeps XLA's compiled programs in the user's cache folder, so that every
call after the first starts from them. The library never changes JAX's configuration on its
own: `fleshing-jax` commands call `enable_compilation_cache`, which sets JAX's environment
variables for the command's own process before JAX is imported, and a script or notebook
applies the options `fleshing_jax.compilation_cache_settings()` returns for the same cache.

`FLESHING_JAX_CACHE` moves the cache (a folder) or turns it off (`0`, `off`, `false`, `none` or
empty).
"""

from __future__ import annotations

import os
import sys
from os import PathLike
from pathlib import Path

ENVIRONMENT_VARIABLE = "FLESHING_JAX_CACHE"
_OFF = ("", "0", "off", "false", "none", "no")


def default_cache_folder() -> Path:
    """The platform's per-user cache folder for fleshing-jax's compiled programs."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA", Path.home() / "AppData" / "Local"))
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "fleshing-jax" / "jax-compilation-cache"


def cache_folder() -> Path | None:
    """The folder `FLESHING_JAX_CACHE` names, the default one, or `None` when turned off."""
    setting = os.environ.get(ENVIRONMENT_VARIABLE)
    if setting is None:
        return default_cache_folder()
    if setting.strip().lower() in _OFF:
        return None
    return Path(setting).expanduser()


def enable_compilation_cache() -> Path | None:
    """Asks JAX for its persistent compilation cache in `cache_folder()`; returns the folder.

    Through JAX's own environment variables, set before JAX is imported (the command line
    imports it only once a command runs), never through `jax.config`: a JAX already
    configured by the process, or variables the user set, win. Every program is cached,
    however fast it compiled: the command line's programs are few, and the small ones add up
    over a call. A folder that cannot be created leaves the cache off.
    """
    folder = cache_folder()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(folder))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
    return folder


def compilation_cache_settings(
    path: str | PathLike | None = None, *, min_compile_seconds: float = 0.0
) -> dict[str, object]:
    """JAX's options for keeping compiled programs on disk, so that a new Python process or
    notebook kernel loads them instead of compiling again (seconds to minutes for a B-spline
    fit or a medial pose, see `benchmarks/README.md`).

    The library never changes JAX's configuration: this returns the options, and the caller
    applies each `(name, value)` with JAX's own configuration call, first thing (notebooks do
    so in their first cell; the README shows the two lines).

    **Arguments:**

    - `path`: the cache folder (created if needed). `None` (default): the folder
      `FLESHING_JAX_CACHE` names, or the command line's default
      (`~/.cache/fleshing-jax/jax-compilation-cache` on Linux): the command line and the
      library then share their programs. If JAX already has a cache folder
      (`JAX_COMPILATION_CACHE_DIR`, or `jax.config`), `None` asks for nothing: it is kept.
    - `min_compile_seconds`: programs that compiled faster than this are not stored (JAX's own
      default is 1 s; 0 stores every program: a notebook's many small programs add up).

    **Returns:** a dict of `jax.config` option names and values (the folder, and which
    programs to store); empty when there is nothing to change (a cache already configured) or
    the cache stays off (`FLESHING_JAX_CACHE=off`).

    The library's largest programs (the medial pose: `arap_medial`, `MedialRig.pose`; a
    skeleton pose's fit, `fit_skeleton_pose`) also keep their traced programs in that folder
    (`jax.export`, a `fleshing-jax-exported` subfolder), so that a new process's first call
    neither traces nor compiles them.

    The cache is trusted code: never point it at a folder that others can write to.
    """
    if path is not None and not isinstance(path, str | PathLike):
        raise TypeError(f"path must be a folder (str or os.PathLike) or None, got {type(path)}")
    seconds = float(min_compile_seconds)
    if not seconds >= 0:  # also refuses NaN
        raise ValueError(f"min_compile_seconds must be ≥ 0, got {min_compile_seconds!r}")
    import jax

    if path is None and jax.config.jax_compilation_cache_dir:
        return {}
    folder = cache_folder() if path is None else Path(path).expanduser()
    if folder is None:
        return {}
    folder.mkdir(parents=True, exist_ok=True)
    return {
        "jax_compilation_cache_dir": str(folder),
        "jax_persistent_cache_min_compile_time_secs": seconds,
        "jax_persistent_cache_min_entry_size_bytes": 0,
    }

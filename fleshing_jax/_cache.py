"""JAX's persistent compilation cache for the command line and the demo.

Compiling the batched paths takes seconds; the work on a typical mesh takes milliseconds. The
command line therefore keeps XLA's compiled programs in the user's cache folder, so that every
call after the first starts from them. The library never changes JAX's configuration: only
`fleshing-jax` commands call `enable_compilation_cache`, which sets JAX's environment
variables for the command's own process before JAX is imported.

`FLESHING_JAX_CACHE` moves the cache (a folder) or turns it off (`0`, `off`, `false`, `none` or
empty).
"""

from __future__ import annotations

import os
import sys
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

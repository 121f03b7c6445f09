"""Traced programs kept on disk next to the compiled ones (`jax.export`), so that a first call
in a new process neither traces nor lowers them.

JAX's persistent compilation cache (`compilation_cache_settings`) keys a compiled program on its
lowered module, so every new process still traces and lowers a program before it can find it:
most of a warm first `deform_medial` (`benchmarks/README.md`). `persistent` compiles like
`eqx.filter_jit` and, when JAX's cache is on and the arguments are concrete, also keeps the
exported program (`jax.export`: traced and lowered) in a subfolder of JAX's cache folder. A
later call with the same key loads it and runs it; XLA's compilation of it then comes from
JAX's own cache. The key is everything that decides the trace: the function, the library's
source, the versions of JAX, jaxlib and equinox, the backend, the dtype of Python floats (x64
on or off), the arguments' pytree structure (with the static fields of equinox modules), their
shapes and dtypes, and the values of the static (non-array) arguments. Traced arguments (a call
under `jit`, `grad` or `vmap`), `jax.disable_jit` or no cache folder: `eqx.filter_jit`, as
without this module. The library's source stands for the constants its code reads while
tracing: a test that patches one (`monkeypatch.setattr`) must call the function traced.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import tempfile
from collections import OrderedDict
from pathlib import Path

import equinox as eqx
import jax
import jaxlib
import numpy as np
from jax.dtypes import canonicalize_dtype

FOLDER = "fleshing-jax-exported"  # inside JAX's cache folder (JAX reads only its own files)
LOADED = 32  # programs kept in memory per process (each holds its serialized module)

_loaded: OrderedDict = OrderedDict()
_source: list[str] = []


def _source_fingerprint() -> str:
    """A digest of the library's Python source, read once per process."""
    if not _source:
        root = Path(__file__).parent
        digest = hashlib.blake2b(digest_size=16)
        for path in sorted(root.rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
        _source.append(digest.hexdigest())
    return _source[0]


@functools.cache
def _serialisable() -> bool:
    """Whether `jax.export` can serialise here (it needs `flatbuffers`, which JAX does not
    install itself; a dependency of this library, but an environment may lack it)."""
    return importlib.util.find_spec("flatbuffers") is not None


def _folder() -> Path | None:
    """The folder of exported programs, or `None` where JAX keeps no local cache."""
    configured = jax.config.jax_compilation_cache_dir
    if (not configured or "://" in str(configured) or jax.config.jax_disable_jit
            or not jax.config.jax_enable_compilation_cache or not _serialisable()):  # fmt: skip
        return None
    return Path(configured) / FOLDER


def _key(name: str, signature: tuple) -> str:
    """The file name of a program: a digest of the function, the library and the call's
    `signature` (see `persistent`)."""
    digest = hashlib.blake2b(digest_size=20)
    for part in (name, _source_fingerprint(), jax.__version__, jaxlib.__version__,
                 eqx.__version__, jax.default_backend(), repr(signature)):  # fmt: skip
        digest.update(part.encode())
        digest.update(b"\0")
    return digest.hexdigest()


def _write(path: Path, data: bytes) -> None:
    """Writes `data` to `path` through a temporary file and a rename (never a partial file);
    a folder that cannot be written leaves the program unsaved."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(handle, "wb") as file:
            file.write(data)
        os.replace(temporary, path)
    except OSError:
        pass


def _program(folder: Path, key: str, flat, avals):
    """The exported program of `flat` at `avals`: read from `folder`, else exported and saved."""
    path = folder / f"{key}.exported"
    try:
        return jax.export.deserialize(bytearray(path.read_bytes()))
    except FileNotFoundError:
        pass
    except Exception:  # noqa: BLE001 (a damaged or foreign file is exported again)
        pass
    exported = jax.export.export(jax.jit(flat))(*avals)
    _write(path, bytes(exported.serialize()))
    return exported


def persistent(fun):
    """`eqx.filter_jit(fun)`, with its traced program kept on disk for concrete calls (see the
    module docstring). `fun` takes positional arguments (arrays are traced, everything else
    static, as `eqx.filter_jit`) and returns a tuple of arrays."""
    jitted = eqx.filter_jit(fun)
    name = f"{fun.__module__}.{fun.__qualname__}"

    @functools.wraps(fun)
    def call(*args):
        folder = _folder()
        dynamic, static = eqx.partition(args, eqx.is_array)
        leaves, treedef = jax.tree.flatten(dynamic)
        if folder is None or any(isinstance(a, jax.core.Tracer) for a in leaves):
            return jitted(*args)
        # What decides the trace, hashable: compared in memory on every call (a few
        # microseconds), written out as the file's key only for a program not loaded yet.
        constants, constants_def = jax.tree.flatten(static)
        signature = (str(folder), canonicalize_dtype(float).name, treedef, tuple(constants),
                     constants_def, tuple((np.shape(a), np.dtype(a.dtype).name,
                                           bool(getattr(a, "weak_type", False))) for a in leaves))
        program = _loaded.pop(signature, None)
        if program is None:
            avals = [jax.ShapeDtypeStruct(shape, dtype, weak_type=weak)
                     for shape, dtype, weak in signature[-1]]

            def flat(*leaves):
                return fun(*eqx.combine(jax.tree.unflatten(treedef, leaves), static))

            program = jax.jit(_program(folder, _key(name, signature), flat, avals).call)
        _loaded[signature] = program  # the most recent last
        while len(_loaded) > LOADED:
            _loaded.popitem(last=False)
        return program(*leaves)

    return call

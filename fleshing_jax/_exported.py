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

Outputs may be any pytree (equinox modules with static fields: a registrar, a prepared
spine): the program returns their arrays, and the file keeps, beside it, the output with a
`_Leaf` in place of each array (pickled), from which a loaded program's output is rebuilt.
An output that cannot be pickled leaves its program in memory only.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import pickle
import re
import sys
import tempfile
import threading
import types
from collections import OrderedDict
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax
import jaxlib
import numpy as np
from jax.dtypes import canonicalize_dtype

FOLDER = "fleshing-jax-exported"  # inside JAX's cache folder (JAX reads only its own files)
LOADED = 32  # programs kept in memory per process (each holds its serialized module)

_loaded: OrderedDict = OrderedDict()
_unkept: set = set()  # the calls whose program JAX could not export: jitted as they are
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


def _by_name(value):
    """`value`, or for a function defined at a module's top level (a solver's `norm`:
    `optimistix.max_norm`), its module and name: what it is in every process (the library's
    and its dependencies' versions are in the key), where it prints by its address."""
    if not isinstance(value, types.FunctionType) or "<" in value.__qualname__:
        return value
    module = sys.modules.get(value.__module__)
    if getattr(module, value.__qualname__, None) is not value:
        return value
    return ("function", value.__module__, value.__qualname__)


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


def _exported(jitted, avals):
    """`jax.export`'s program of `jitted` at `avals`, or `None` where JAX cannot export it (a
    host callback in it). Custom calls without JAX's compatibility guarantee across versions
    (LAPACK's QR in a Levenberg–Marquardt step's linear solve) are allowed: a kept program
    is only loaded by the versions of JAX and jaxlib that exported it (`_key`)."""
    try:
        return jax.export.export(jitted)(*avals)
    except ValueError as error:  # (the message names every such call: `@target(`)
        targets = set(re.findall(r"custom_call @(\w+)\(", str(error)))
        if not targets:
            return None
    except Exception:  # noqa: BLE001
        return None
    checks = [jax.export.DisabledSafetyCheck.custom_call(t) for t in sorted(targets)]
    try:  # (the trace is jit's cached one: only lowered again)
        return jax.export.export(jitted, disabled_checks=checks)(*avals)
    except Exception:  # noqa: BLE001
        return None


class _Leaf:
    """Where an output's array goes, in the pickled outline of a program's output."""


def _outline(out):
    """`(arrays, outline)`: `out`'s arrays, in order, and `out` with a `_Leaf` for each."""
    dynamic, static = eqx.partition(out, eqx.is_array)
    arrays, treedef = jax.tree.flatten(dynamic)
    return arrays, eqx.combine(jax.tree.unflatten(treedef, [_Leaf() for _ in arrays]), static)


def _filled(outline, arrays):
    """`outline` (`_outline`) with its `_Leaf`s replaced by `arrays`, in order."""
    parts, treedef = jax.tree.flatten(outline, is_leaf=lambda x: isinstance(x, _Leaf))
    arrays = iter(arrays)
    return jax.tree.unflatten(treedef, [next(arrays) if isinstance(x, _Leaf) else x
                                        for x in parts])


def _program(folder: Path, key: str, fun, avals):
    """`(exported, outline)`: the exported program of `fun` (arrays → its output's arrays) at
    `avals` and its output's outline, read from `folder`, else exported and saved (when the
    outline pickles); `None` where JAX cannot export it."""
    path = folder / f"{key}.program"
    try:
        outline, data = pickle.loads(path.read_bytes())
        return jax.export.deserialize(bytearray(data)), outline
    except FileNotFoundError:
        pass
    except Exception:  # noqa: BLE001 (a damaged or foreign file is exported again)
        pass
    outlines = []

    def flat(*leaves):
        arrays, outline = _outline(fun(*leaves))
        outlines.append(outline)
        return arrays

    exported = _exported(jax.jit(flat), avals)
    if exported is None:
        return None
    try:
        data = pickle.dumps((outlines[0], bytes(exported.serialize())))
    except Exception:  # noqa: BLE001 (an output that does not pickle: kept in memory only)
        return exported, outlines[0]
    _write(path, data)
    return exported, outlines[0]


class _Loaded(NamedTuple):
    """A kept program in memory: `exported` (`jax.export`'s), `jitted` (its call, jitted),
    the `outline` of its output (`_outline`), and the thread `prepare` compiles it in (`None`
    where none was started; joined by every call, at once when it is done)."""

    exported: jax.export.Exported
    jitted: object
    outline: object
    compiling: threading.Thread | None


def _uncommitted(array):
    """`array` not committed to its device, as `jit` returns from uncommitted arguments (a
    loaded program's outputs are committed: mixed with uncommitted arrays in eager operations,
    each such operation compiled again, once). The same buffer; as it is where JAX's array
    type takes no such flag."""
    try:
        from jax._src.array import ArrayImpl

        return ArrayImpl(array.aval, array.sharding, [array.addressable_data(0)],
                         committed=False)
    except Exception:  # noqa: BLE001 (another JAX: committed)
        return array


def persistent(fun=None, *, compiler_options: dict | None = None):
    """`eqx.filter_jit(fun)`, with its traced program kept on disk for concrete calls (see the
    module docstring). `fun` takes positional arguments (arrays are traced, everything else
    static, as `eqx.filter_jit`) and returns a pytree. `compiler_options`: XLA's, as
    `eqx.filter_jit`'s (a loaded program is compiled with them too). Usable as `@persistent`
    or `persistent(fun, compiler_options=…)`."""
    if fun is None:
        return functools.partial(persistent, compiler_options=compiler_options)
    jitted = eqx.filter_jit(fun, compiler_options=compiler_options)
    name = f"{fun.__module__}.{fun.__qualname__}"

    def program(args, arrays):
        """`(key, leaves, loaded)` of a call on `args` (`arrays` tells its traced leaves):
        `loaded` a `_Loaded`, `None` where the program is not kept (`jitted` then; without a
        cache folder, at once: a shape fit's solve has thousands of leaves)."""
        folder = _folder()
        if folder is None:  # (before the arguments are split: `jitted` splits them itself)
            return None, None, None
        dynamic, static = eqx.partition(args, arrays)
        leaves, treedef = jax.tree.flatten(dynamic)
        if any(isinstance(a, jax.core.Tracer) for a in leaves):
            return None, leaves, None
        # What decides the trace, hashable: compared in memory on every call (a few
        # microseconds), written out as the file's key only for a program not loaded yet.
        constants, constants_def = jax.tree.flatten(static)
        constants = [_by_name(c) for c in constants]
        signature = (str(folder), canonicalize_dtype(float).name, treedef, tuple(constants),
                     constants_def, tuple((np.shape(a), np.dtype(a.dtype).name,
                                           bool(getattr(a, "weak_type", False))) for a in leaves))
        key = (signature, name, repr(compiler_options))
        loaded = _loaded.pop(key, None)
        if loaded is None and (key in _unkept or " at 0x" in repr(signature)):
            # (An object printed by its address, another in each process: no key on disk.)
            return key, leaves, None
        if loaded is None:
            avals = [jax.ShapeDtypeStruct(shape, dtype, weak_type=weak)
                     for shape, dtype, weak in signature[-1]]

            def flat(*leaves):
                return fun(*eqx.combine(jax.tree.unflatten(treedef, leaves), static))

            exported = _program(folder, _key(name, signature), flat, avals)
            if exported is None:
                _unkept.add(key)
                return key, leaves, None
            loaded = _Loaded(exported[0], jax.jit(exported[0].call,
                                                  compiler_options=compiler_options),
                             exported[1], None)
        _loaded[key] = loaded  # the most recent last
        while len(_loaded) > LOADED:
            _loaded.popitem(last=False)
        return key, leaves, loaded

    @functools.wraps(fun)
    def call(*args):
        key, leaves, loaded = program(args, eqx.is_array)
        if loaded is None:
            return jitted(*args)
        if loaded.compiling is not None:  # (`prepare` compiles it: waited for, not twice)
            loaded.compiling.join()
        outputs = loaded.jitted(*leaves)
        if not any(getattr(a, "committed", False) for a in leaves):
            outputs = [_uncommitted(a) for a in outputs]
        return _filled(loaded.outline, outputs)

    def prepare(*args):
        """Starts compiling the program of a later `call(*args)` in a thread of its own
        (XLA's compile runs outside Python's lock, so another program is traced meanwhile);
        `args` may hold `jax.ShapeDtypeStruct`s for arrays. Returns the call's output with a
        `jax.ShapeDtypeStruct` for each array (what the next program's `prepare` takes), or
        `None` where the program is not kept (no cache folder: the call compiles it)."""
        key, leaves, loaded = program(args, _abstract_or_array)
        if loaded is None:
            return None
        if loaded.compiling is None:
            avals = [_abstract(a) for a in leaves]  # (weak types as the call's: its key)
            # (Not a daemon: a process ending while XLA compiles waits for it, as a daemon
            # thread stopped inside the compiler aborts the process.)
            compiling = threading.Thread(target=_compile, args=(loaded.jitted, avals))
            compiling.start()
            _loaded[key] = loaded._replace(compiling=compiling)
        return _filled(loaded.outline, [_abstract(a) for a in loaded.exported.out_avals])

    call.prepare = prepare
    return call


def _abstract_or_array(x) -> bool:
    return isinstance(x, jax.ShapeDtypeStruct) or eqx.is_array(x)


def _abstract(x) -> jax.ShapeDtypeStruct:
    """`x`'s shape, dtype and weak type."""
    return jax.ShapeDtypeStruct(np.shape(x), x.dtype, weak_type=bool(getattr(x, "weak_type",
                                                                             False)))


def _compile(jitted, avals) -> None:
    """`jitted` compiled for `avals` (JAX keeps it for the call); a failure is left to the
    call, which compiles it again and raises there."""
    try:
        jitted.lower(*avals).compile()
    except Exception:  # noqa: BLE001 (the call compiles it again and raises there)
        pass

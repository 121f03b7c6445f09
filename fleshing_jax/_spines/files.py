"""Spine files: JSON objects `{"type": "<lowercase class name>", <constructor arguments>}`.

For example `{"type": "bspline", "control_points": [[0, 0, 0], …], "degree": 5}` or
`{"type": "arc", "radius": 2.0, "length": 3.0, "origin": [0, 0, 0], "tangent": [1, 0, 0],
"normal": [0, 1, 0]}`. Every spine type is supported; `save_spine` writes all the arguments that
define the spine (so that `load_spine` rebuilds it exactly), `load_spine` accepts any valid
subset (missing optional arguments take their defaults).
"""

from __future__ import annotations

import glob
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from .analytic import Arc, Helix, Line
from .bspline import BSpline
from .polyline import Polyline
from .polynomial import InterpolatingPolynomial
from .spine import AbstractSpine

# type name → (class, {field: (kind, required)}); kinds: "scalar", "vector", "points", "int",
# "vector_or_none" (knots), "scalar_or_none" (step). Positional arguments are listed first.
_SCHEMA = {
    "line": (Line, {"length": ("scalar", True), "origin": ("vector", False),
                    "tangent": ("vector", False)}),
    "arc": (Arc, {"radius": ("scalar", True), "length": ("scalar", True),
                  "origin": ("vector", False), "tangent": ("vector", False),
                  "normal": ("vector", False)}),
    "helix": (Helix, {"radius": ("scalar", True), "pitch": ("scalar", True),
                      "length": ("scalar", True)}),
    "bspline": (BSpline, {"control_points": ("points", True), "degree": ("int", False),
                          "knots": ("array_or_none", False), "subdivisions": ("int", False)}),
    "interpolatingpolynomial": (InterpolatingPolynomial, {"points": ("points", True),
                                                          "subdivisions": ("int", False)}),
    "polyline": (Polyline, {"points": ("points", True), "step": ("scalar_or_none", False)}),
}  # fmt: skip
MAX_FILE_BYTES = 16 * 2**20  # resource bounds on untrusted files (and inside the spines)
MAX_ROWS = 10_000  # points or control points
_POSITIONAL = {"line": 1, "arc": 2, "helix": 3, "bspline": 1, "interpolatingpolynomial": 1,
               "polyline": 1}  # fmt: skip


def _arguments(spine: AbstractSpine) -> dict:
    """The constructor arguments that rebuild `spine`, as JSON-ready Python values."""

    def tolist(value):
        return np.asarray(value, dtype=np.float64).tolist()

    if isinstance(spine, Line):
        return {"length": tolist(spine.length), "origin": tolist(spine.origin),
                "tangent": tolist(spine.direction)}  # fmt: skip
    if isinstance(spine, Arc):
        return {"radius": tolist(spine.radius), "length": tolist(spine.length),
                "origin": tolist(spine.origin), "tangent": tolist(spine.start_tangent),
                "normal": tolist(spine.start_normal)}  # fmt: skip
    if isinstance(spine, Helix):
        return {"radius": tolist(spine.radius), "pitch": tolist(spine.pitch),
                "length": tolist(spine.length)}  # fmt: skip
    if isinstance(spine, BSpline):
        return {"control_points": tolist(spine.control_points), "degree": spine.degree,
                "knots": tolist(spine.knots), "subdivisions": spine.subdivisions}  # fmt: skip
    if isinstance(spine, InterpolatingPolynomial):
        return {"points": tolist(spine.points), "subdivisions": spine.subdivisions}
    if isinstance(spine, Polyline):
        return {"points": tolist(spine.points), "step": spine.step}
    raise TypeError(f"`spine` must be one of {[c.__name__ for c, _ in _SCHEMA.values()]}, "
                    f"got {type(spine)}.")  # fmt: skip


def spine_json(spine: AbstractSpine) -> str:
    """`spine` as the JSON text `save_spine` writes (one line; `load_spine` reads it back)."""
    return json.dumps({"type": type(spine).__name__.lower(), **_arguments(spine)})


def save_spine(spine: AbstractSpine, path: str | os.PathLike) -> None:
    """Writes `spine` to the JSON file `path` (`{"type": "<lowercase class name>", …}`),
    atomically: written to a temporary file in the same folder, then renamed over `path`, so
    that a save killed midway never leaves `path` half-written (the previous file there stays
    intact). Temporary files left by killed saves of the same name are removed.

    **Arguments:** `spine`: a `Line`, `Arc`, `Helix`, `BSpline`, `InterpolatingPolynomial` or
    `Polyline` with concrete values; `path`: file name.
    """
    data = {"type": type(spine).__name__.lower(), **_arguments(spine)}
    text = json.dumps(data, indent=1) + "\n"
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    _remove_stale_temporaries(directory, path.name)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "w") as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


STALE_SECONDS = 60.0  # a temporary file this old belongs to a save that was killed


def _remove_stale_temporaries(directory: Path, name: str) -> None:
    """Removes the temporary files that killed saves of `name` left in `directory` (a save
    takes milliseconds: older ones are not being written)."""
    now = time.time()
    for stale in directory.glob(f".{glob.escape(name)}.*.tmp"):
        try:
            if now - stale.stat().st_mtime > STALE_SECONDS:
                stale.unlink()
        except OSError:  # removed meanwhile, or not ours to remove
            pass


def _umask() -> int:
    mask = os.umask(0)  # the only way to read it: set and restore
    os.umask(mask)
    return mask


def _check_field(path, kind: str, name: str, value):
    def fail(expected):
        raise ValueError(f"{path}: field '{name}' must be {expected}, got {value!r}.")

    def is_number(v):
        return isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v)

    if kind == "int":
        if not isinstance(value, int) or isinstance(value, bool):
            fail("an integer")
    elif kind in ("scalar", "scalar_or_none"):
        if not (is_number(value) or (value is None and kind == "scalar_or_none")):
            fail("a number" + (" or null" if kind == "scalar_or_none" else ""))
    elif kind == "vector":
        if not (isinstance(value, list) and len(value) == 3 and all(map(is_number, value))):
            fail("a list of 3 numbers")
    elif kind == "array_or_none":
        if value is not None and not (isinstance(value, list) and all(map(is_number, value))):
            fail("a list of numbers or null")
    elif kind == "points":
        rows = isinstance(value, list) and all(
            isinstance(r, list) and len(r) == 3 and all(map(is_number, r)) for r in value
        )
        if not rows:
            fail("a list of [x, y, z] rows")
        if len(value) > MAX_ROWS:
            raise ValueError(
                f"{path}: field '{name}' must have at most {MAX_ROWS} rows, got {len(value)}."
            )
    return value


def load_spine(path: str | os.PathLike) -> AbstractSpine:
    """Reads a spine written by `save_spine` (or by hand) from the JSON file `path`.

    Raises `FileNotFoundError` if `path` does not exist, and `ValueError` naming the file and the
    offending field for malformed files (invalid JSON, unknown `type`, missing, unknown or
    ill-typed fields, or values the spine rejects, including sizes beyond the spines' resource
    bounds: `subdivisions`, `degree`, a polyline `step` giving too many edges; files over
    `MAX_FILE_BYTES`).
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such spine file")
    size = os.path.getsize(path)
    if size > MAX_FILE_BYTES:
        raise ValueError(
            f"{path}: {size} bytes, more than a spine file may hold ({MAX_FILE_BYTES} bytes)."
        )
    try:
        with open(path) as file:
            data = json.load(file)
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as error:
        raise ValueError(f"{path}: not valid JSON ({error}).") from error
    if not isinstance(data, dict):
        raise ValueError(f"{path}: must hold a JSON object, got {type(data).__name__}.")
    kind = data.get("type")
    if kind not in _SCHEMA:
        raise ValueError(f"{path}: field 'type' must be one of {sorted(_SCHEMA)}, got {kind!r}.")
    cls, fields = _SCHEMA[kind]
    unknown = sorted(set(data) - set(fields) - {"type"})
    if unknown:
        raise ValueError(f"{path}: unknown field '{unknown[0]}' for type {kind!r} "
                         f"(expected some of {sorted(fields)}).")  # fmt: skip
    arguments = {}
    for name, (field_kind, required) in fields.items():
        if name not in data:
            if required:
                raise ValueError(f"{path}: missing field '{name}' for type {kind!r}.")
            continue
        arguments[name] = _check_field(path, field_kind, name, data[name])
    names = list(fields)[: _POSITIONAL[kind]]
    positional = [arguments.pop(name) for name in names]
    try:
        return cls(*positional, **arguments)
    except (ValueError, TypeError) as error:
        raise ValueError(f"{path}: {error}") from error

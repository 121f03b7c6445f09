"""Spine files: JSON objects `{"type": "<lowercase class name>", <constructor arguments>}`.

For example `{"type": "bspline", "control_points": [[0, 0, 0], …], "degree": 5}` or
`{"type": "arc", "radius": 2.0, "length": 3.0, "origin": [0, 0, 0], "tangent": [1, 0, 0],
"normal": [0, 1, 0]}`. Every spine type is supported; `save_spine` writes all the arguments that
define the spine (so that `load_spine` rebuilds it exactly), `load_spine` accepts any valid
subset (missing optional arguments take their defaults).
"""

from __future__ import annotations

import json
import os

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
    """Writes `spine` to the JSON file `path` (`{"type": "<lowercase class name>", …}`).

    **Arguments:** `spine`: a `Line`, `Arc`, `Helix`, `BSpline`, `InterpolatingPolynomial` or
    `Polyline` with concrete values; `path`: file name.
    """
    data = {"type": type(spine).__name__.lower(), **_arguments(spine)}
    with open(path, "w") as file:
        json.dump(data, file, indent=1)
        file.write("\n")


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
    return value


def load_spine(path: str | os.PathLike) -> AbstractSpine:
    """Reads a spine written by `save_spine` (or by hand) from the JSON file `path`.

    Raises `FileNotFoundError` if `path` does not exist, and `ValueError` naming the file and the
    offending field for malformed files (invalid JSON, unknown `type`, missing, unknown or
    ill-typed fields, or values the spine rejects).
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such spine file")
    try:
        with open(path) as file:
            data = json.load(file)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
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

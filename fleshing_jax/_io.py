"""Spines as JSON files: `{"type": "<lowercase class name>", <constructor arguments>}`.

For example `{"type": "arc", "radius": 2.0, "length": 3.0, "origin": [0, 0, 0],
"tangent": [1, 0, 0], "normal": [0, 1, 0]}`. Supported here: `line`, `arc`, `helix`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ._analytic import Arc, Helix, Line
from ._spine import AbstractSpine

# type name → (class, required fields, optional vector fields (3,))
_SPINES = {
    "line": (Line, ("length",), ("origin", "tangent")),
    "arc": (Arc, ("radius", "length"), ("origin", "tangent", "normal")),
    "helix": (Helix, ("radius", "pitch", "length"), ()),
}


def _fields(spine: AbstractSpine) -> dict:
    def number(x):
        return float(np.asarray(x))

    def vector(x):
        return [float(v) for v in np.asarray(x)]

    if isinstance(spine, Line):
        return {
            "type": "line",
            "length": number(spine.length),
            "origin": vector(spine.origin),
            "tangent": vector(spine.direction),
        }
    if isinstance(spine, Arc):
        return {
            "type": "arc",
            "radius": number(spine.radius),
            "length": number(spine.length),
            "origin": vector(spine.origin),
            "tangent": vector(spine.start_tangent),
            "normal": vector(spine.start_normal),
        }
    if isinstance(spine, Helix):
        return {
            "type": "helix",
            "radius": number(spine.radius),
            "pitch": number(spine.pitch),
            "length": number(spine.length),
        }
    name = type(spine).__name__
    raise TypeError(f"cannot save a spine of type {name} (supported: line, arc, helix)")


def save_spine(spine: AbstractSpine, path: str | os.PathLike) -> None:
    """Writes `spine` (a `Line`, `Arc` or `Helix`) to `path` as JSON (see the module docs)."""
    Path(path).write_text(json.dumps(_fields(spine), indent=2) + "\n")


def load_spine(path: str | os.PathLike) -> AbstractSpine:
    """Reads a spine written by `save_spine` (or by hand, in the same format).

    **Raises:** `FileNotFoundError` if `path` does not exist; `ValueError` naming the file and
    the field when the JSON is malformed, the type unknown, or a field missing or invalid.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such spine file")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from error
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object with a 'type' field")
    kind = data.get("type")
    if kind not in _SPINES:
        raise ValueError(f"{path}: field 'type' must be one of {sorted(_SPINES)}, got {kind!r}")
    cls, required, vectors = _SPINES[kind]
    known = {"type", *required, *vectors}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"{path}: unknown field {unknown[0]!r} for a {kind} spine")
    args, kwargs = [], {}
    for name in required:
        if name not in data:
            raise ValueError(f"{path}: missing field {name!r} for a {kind} spine")
        args.append(_number(data[name], path, name))
    for name in vectors:
        if name in data:
            kwargs[name] = _vector(data[name], path, name)
    try:
        return cls(*args, **kwargs)
    except (ValueError, TypeError) as error:
        raise ValueError(f"{path}: invalid {kind} spine ({error})") from error


def _number(value, path: Path, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ValueError(f"{path}: field {name!r} must be a finite number, got {value!r}")
    return float(value)


def _vector(value, path: Path, name: str) -> list[float]:
    if not isinstance(value, list) or len(value) != 3:
        raise ValueError(f"{path}: field {name!r} must be a list of 3 numbers, got {value!r}")
    return [_number(v, path, f"{name}[{i}]") for i, v in enumerate(value)]

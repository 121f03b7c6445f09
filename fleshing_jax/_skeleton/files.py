"""Skeleton files: JSON, written atomically, read with bounds on their size.

`{"type": "skeleton", "limbs": [{"spine": <spine object>, "joint": s, "parent": i}, …],
"region": [i, …], "vertices": [[x, y, z], …]}`; each spine is the object `fj.save_spine` writes
(a `"bspline"` with its control points, degree, knots and subdivisions). Numbers are written
with Python's shortest exact repr, so a skeleton loads back bit for bit.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .._checks import check_readable_file
from .._medial_axis.files import check_medial_path, write_atomic
from .._spines.bspline import BSpline
from .._spines.files import _check_field, spine_json
from .skeleton import Limb, Skeleton

MAX_FILE_BYTES = 1 << 30  # 1 GiB: a 10-million-vertex mesh's skeleton fits
MAX_LIMBS = 10_000
MAX_VERTICES = 20_000_000
MAX_NAME = 1000  # characters of a limb's name
_SPINE_FIELDS = {"control_points": "points", "degree": "int", "knots": "array_or_none",
                 "subdivisions": "int"}  # fmt: skip


def save_skeleton(skeleton: Skeleton, path: str | os.PathLike) -> None:
    """Writes `skeleton` to the JSON file `path`, atomically (a temporary file beside it,
    then renamed over it: a killed save leaves the previous file whole).

    **Raises:** `TypeError` unless `skeleton` is a `Skeleton` of `fj.BSpline` limbs;
    `ValueError` naming `path` when its folder does not exist or is not writable, or it is a
    folder.
    """
    if not isinstance(skeleton, Skeleton):
        raise TypeError(f"`skeleton` must be a Skeleton, got {type(skeleton).__name__}.")
    for i, limb in enumerate(skeleton.limbs):
        if not isinstance(limb.spine, BSpline):
            raise TypeError(
                f"`skeleton.limbs[{i}].spine` must be a BSpline to be saved, got "
                f"{type(limb.spine).__name__}."
            )
    target = check_medial_path(path)
    limbs = [
        {"spine": json.loads(spine_json(limb.spine)), "joint": float(limb.joint),
         "parent": limb.parent} | ({"name": limb.name} if limb.name else {})
        for limb in skeleton.limbs
    ]  # fmt: skip
    data = {
        "type": "skeleton",
        "limbs": limbs,
        "region": np.asarray(skeleton.region).tolist(),
        "vertices": np.asarray(skeleton.vertices, np.float64).tolist(),
    }
    write_atomic(target, json.dumps(data) + "\n")


def load_skeleton(path: str | os.PathLike) -> Skeleton:
    """Reads a skeleton written by `save_skeleton` from the JSON file `path`.

    **Raises:** `FileNotFoundError` for a missing file; `ValueError` naming the file and the
    field for a folder, a file over `MAX_FILE_BYTES`, invalid JSON, a missing, unknown or
    ill-typed field, more than `MAX_LIMBS` limbs or `MAX_VERTICES` vertices, or values a
    `Skeleton` rejects (a parent after its child, a region index out of range, a joint off its
    spine).
    """
    path = Path(path)
    check_readable_file(path, "a skeleton file", MAX_FILE_BYTES)
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as error:
        raise ValueError(f"{path}: not valid JSON ({error}).") from error
    if not isinstance(data, dict) or data.get("type") != "skeleton":
        raise ValueError(f'{path}: must hold a JSON object with "type": "skeleton".')
    unknown = sorted(set(data) - {"type", "limbs", "region", "vertices"})
    if unknown:
        raise ValueError(f"{path}: unknown field '{unknown[0]}'.")
    limbs, region, vertices = (_field(path, data, k) for k in ("limbs", "region", "vertices"))
    if not isinstance(limbs, list) or len(limbs) > MAX_LIMBS:
        raise ValueError(f"{path}: field 'limbs' must be a list of at most {MAX_LIMBS} limbs.")
    if not isinstance(region, list) or len(region) > MAX_VERTICES:
        raise ValueError(f"{path}: field 'region' must be a list of at most {MAX_VERTICES} "
                         "limb indices.")  # fmt: skip
    if not all(isinstance(i, int) and not isinstance(i, bool) for i in region):
        raise ValueError(f"{path}: field 'region' must hold integers.")
    # (Checked as Python integers: one past int64, 2**70, overflowed NumPy's conversion.)
    out = next((i for i in region if not -1 <= i < len(limbs)), None)
    if out is not None:
        raise ValueError(f"{path}: field 'region' must hold limb indices in [-1, {len(limbs)}) "
                         f"(-1: the body), got {out}.")
    if not isinstance(vertices, list) or len(vertices) != len(region):
        raise ValueError(f"{path}: field 'vertices' must be a list of {len(region)} points, "
                         "one per region entry.")  # fmt: skip
    try:
        points = np.asarray(vertices, np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        points = np.full((len(region), 3), np.nan)
    if len(points) != len(region) or not np.isfinite(points).all():
        raise ValueError(f"{path}: field 'vertices' must be a list of finite [x, y, z] rows.")
    try:
        return Skeleton(
            tuple(_limb(path, i, limb) for i, limb in enumerate(limbs)),
            np.asarray(region, np.int64),
            points,
        )
    except (ValueError, TypeError) as error:
        raise ValueError(f"{path}: {error}") from error


def _field(path, data: dict, name: str):
    if name not in data:
        raise ValueError(f"{path}: missing field '{name}'.")
    return data[name]


def _limb(path, i: int, data) -> Limb:
    """Limb `i` of the file `path` from its JSON object."""
    where = f"limbs[{i}]"
    if not isinstance(data, dict) or not (
            {"spine", "joint", "parent"} <= set(data) <= {"spine", "joint", "parent", "name"}):
        raise ValueError(f"{path}: {where} must be an object with fields 'spine', 'joint' and "
                         "'parent' (and optionally 'name').")  # fmt: skip
    spine, joint, parent = data["spine"], data["joint"], data["parent"]
    name = data.get("name", "")
    if not isinstance(name, str) or len(name) > MAX_NAME:
        raise ValueError(f"{path}: {where}.name must be a string of at most {MAX_NAME} "
                         "characters.")  # fmt: skip
    _check_field(path, "scalar", f"{where}.joint", joint)
    _check_field(path, "int", f"{where}.parent", parent)
    if not isinstance(spine, dict) or spine.get("type") != "bspline":
        raise ValueError(f'{path}: {where}.spine must be a "bspline" spine object.')
    unknown = sorted(set(spine) - set(_SPINE_FIELDS) - {"type"})
    if unknown or "control_points" not in spine:
        raise ValueError(f"{path}: {where}.spine must have 'control_points' and some of "
                         f"{sorted(_SPINE_FIELDS)}, got {sorted(spine)}.")  # fmt: skip
    arguments = {name: _check_field(path, kind, f"{where}.spine.{name}", spine[name])
                 for name, kind in _SPINE_FIELDS.items() if name in spine}  # fmt: skip
    control_points = np.asarray(arguments.pop("control_points"), np.float64)
    if arguments.get("knots") is not None:
        arguments["knots"] = np.asarray(arguments["knots"], np.float64)
    return Limb(BSpline(control_points, **arguments), joint, parent, name)

"""Handle files: which medial spheres move where, as JSON, for the command line.

    {"handles": [0, 1, {"at": [x, y, z]}], "targets": [[x, y, z], [x, y, z], [x, y, z]],
     "rotations": [[[1, 0, 0], [0, 1, 0], [0, 0, 1]], ...]}      (rotations: optional)

A handle is a sphere index, or `{"at": [x, y, z]}`: the sphere whose centre is nearest to
that point (`MedialMesh.nearest`), so that a handle can be chosen without knowing indices.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # (not imported: the command line's help reads this module without JAX)
    from .._medial_axis.medial_mesh import MedialMesh

HANDLES_FORMAT = (
    '{"handles": [i or {"at": [x, y, z]}, ...], "targets": [[x, y, z], ...]} (one target per '
    'handle), optionally with "rotations": [[[3 x 3]], ...]'
)
MAXIMUM_HANDLES = 100_000  # a bound on the file's size, checked before any array is built
MAX_FILE_BYTES = 16 * 2**20
MAXIMUM_INDEX = 2**62  # beyond it an index cannot be an int64 sphere index


def load_handles(path, medial: MedialMesh | None = None):
    """Reads a handle file: `(handles (h,) int, targets (h, 3), rotations (h, 3, 3) or None)`.

    **Arguments:** `path`; `medial`: the medial mesh that handles given by a point
    (`{"at": [x, y, z]}`) are looked up in (required only for those).

    Raises `FileNotFoundError` when `path` is not a file, `ValueError` naming the file and the
    field for a folder, a file over `MAX_FILE_BYTES`, text that is not UTF-8 JSON (a byte-order
    mark is accepted), missing, unknown or mistyped fields (strings, booleans and non-integer
    indices are refused), non-finite numbers and mismatched counts (values are checked further
    by `arap_medial`).
    """
    data = _read_json(Path(path))
    if not isinstance(data, dict) or "handles" not in data or "targets" not in data:
        raise ValueError(f"{path}: expected {HANDLES_FORMAT}")
    unknown = set(data) - {"handles", "targets", "rotations"}
    if unknown:
        raise ValueError(f"{path}: unknown fields {sorted(unknown)}; expected {HANDLES_FORMAT}")
    entries = data["handles"]
    if not isinstance(entries, list):
        raise ValueError(f"{path}: `handles` must be a list of sphere indices or "
                         f'{{"at": [x, y, z]}}, got {_short(entries)}')
    if len(entries) > MAXIMUM_HANDLES:
        raise ValueError(f"{path}: at most {MAXIMUM_HANDLES} handles, got {len(entries)}")
    handles = np.array([_handle(path, entry, k, medial) for k, entry in enumerate(entries)],
                       dtype=np.int64).reshape(-1)
    h = len(handles)
    targets = _numbers(path, data["targets"], "targets", (h, 3))
    rotations = None
    if data.get("rotations") is not None:
        rotations = _numbers(path, data["rotations"], "rotations", (h, 3, 3))
    return handles, targets, rotations


def _read_json(path: Path):
    from .._checks import check_readable_file  # (here: the help text reads this module, no JAX)

    check_readable_file(path, "a handle file", MAX_FILE_BYTES)
    try:
        with open(path, encoding="utf-8-sig") as file:  # a byte-order mark is harmless
            return json.load(file)
    except (ValueError, RecursionError) as error:  # decoding errors, huge integers too
        what = "too deeply nested" if isinstance(error, RecursionError) else str(error)
        raise ValueError(f"{path}: not valid JSON ({what}); expected {HANDLES_FORMAT}") from None


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, float) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _handle(path, entry, k: int, medial: MedialMesh | None) -> int:
    """Handle `k` of the file: an index, or the sphere nearest to `{"at": [x, y, z]}`."""
    if isinstance(entry, dict):
        if set(entry) != {"at"}:
            raise ValueError(f"{path}: handle {k} must be an index or {{\"at\": [x, y, z]}}, "
                             f"got {_short(entry)}")
        point = _numbers(path, entry["at"], f"handles[{k}].at", (3,))
        if medial is None:
            raise ValueError(f"{path}: handle {k} is given by a point; the medial mesh is "
                             "needed to find its sphere")
        return int(medial.nearest(point))
    if not isinstance(entry, int) or isinstance(entry, bool) or abs(entry) > MAXIMUM_INDEX:
        raise ValueError(f"{path}: `handles` must be integers (sphere indices, in range) or "
                         f'{{"at": [x, y, z]}}; handle {k} is {_short(entry)}')
    return entry


def _numbers(path, value, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """`value` as a float64 array of `shape`, every element a finite JSON number."""

    def walk(item, depth):
        if depth == len(shape):
            if not _is_number(item):
                raise ValueError(f"{path}: `{name}` must hold numbers, got {_short(item)}")
            return
        if not isinstance(item, list) or len(item) != shape[depth]:
            expected = " × ".join(map(str, shape))
            raise ValueError(f"{path}: `{name}` must have shape ({expected}), got "
                             f"{_short(item)}")
        for x in item:
            walk(x, depth + 1)

    walk(value, 0)
    try:
        array = np.array(value, dtype=np.float64).reshape(shape)
    except OverflowError:  # an integer beyond float64
        array = np.full(shape, np.inf)
    if not np.isfinite(array).all():
        raise ValueError(f"{path}: `{name}` must be finite numbers (found NaN, inf, or a "
                         "number beyond float64)")
    return array



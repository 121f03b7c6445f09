"""Handle files: which medial spheres move where, as JSON, for the command line.

    {"handles": [0, 1, 17], "targets": [[x, y, z], [x, y, z], [x, y, z]],
     "rotations": [[[1, 0, 0], [0, 1, 0], [0, 0, 1]], ...]}      (rotations: optional)
"""

from __future__ import annotations

import json

import numpy as np

HANDLES_FORMAT = (
    '{"handles": [i, ...], "targets": [[x, y, z], ...]} (one target per handle), optionally '
    'with "rotations": [[[3 x 3]], ...]'
)
MAXIMUM_HANDLES = 100_000  # a bound on the file's size, checked before any array is built


def load_handles(path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Reads a handle file: `(handles (h,) int, targets (h, 3), rotations (h, 3, 3) or None)`.

    Raises `ValueError` naming the file and the field for malformed JSON, missing or
    mistyped fields and mismatched counts (values are checked further by `arap_medial`).
    """
    try:
        with open(path) as file:
            data = json.load(file)
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error}); expected {HANDLES_FORMAT}") from None
    if not isinstance(data, dict) or "handles" not in data or "targets" not in data:
        raise ValueError(f"{path}: expected {HANDLES_FORMAT}")
    unknown = set(data) - {"handles", "targets", "rotations"}
    if unknown:
        raise ValueError(f"{path}: unknown fields {sorted(unknown)}; expected {HANDLES_FORMAT}")
    handles = _array(path, data, "handles", (-1,), np.int64)
    if len(handles) > MAXIMUM_HANDLES:
        raise ValueError(f"{path}: at most {MAXIMUM_HANDLES} handles, got {len(handles)}")
    h = len(handles)
    targets = _array(path, data, "targets", (h, 3), np.float64)
    rotations = None
    if data.get("rotations") is not None:
        rotations = _array(path, data, "rotations", (h, 3, 3), np.float64)
    return handles, targets, rotations


def _array(path, data, name, shape, dtype) -> np.ndarray:
    value = data[name]
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: `{name}` must be an array of numbers, got "
                         f"{json.dumps(value)[:60]}") from None
    if array.ndim != len(shape) or any(n != -1 and n != m for n, m in zip(shape, array.shape)):
        expected = " × ".join("any" if n == -1 else str(n) for n in shape)
        raise ValueError(f"{path}: `{name}` must have shape ({expected}), got {array.shape}")
    if dtype == np.int64:
        if not np.all(array == np.round(array)):
            raise ValueError(f"{path}: `{name}` must be integers (sphere indices)")
        return array.astype(np.int64)
    return array

"""Welding coincident vertices: one point per position (NumPy).

Meshes read with `process=False` keep a copy of a vertex for each texture coordinate or
normal it has (spot has 277 such copies), and STL files one per face corner: the copies are
one point of the surface, so they are bound, posed and checked for closedness as one.
"""

from __future__ import annotations

import numpy as np


def weld(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coincident vertices as one: `(points (m, 3), index (n,))` with `vertices[i]` at
    `points[index[i]]`, the points in order of first occurrence (no copy: `index` is
    `arange(n)`). Copies of a vertex at a texture or normal seam (meshes read with
    `process=False`) are then bound and posed as one, so the seam cannot open. Rows with a
    non-finite value share one last point, NaN (invalid)."""
    finite = np.isfinite(vertices).all(axis=1)
    rows = vertices[finite] + 0.0  # −0.0 → 0.0: equal coordinates, equal bytes
    _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    index = np.full(len(vertices), len(order), np.int64)
    index[finite] = rank[inverse.reshape(-1)]
    points = rows[first[order]]
    if not finite.all():
        points = np.concatenate([points, np.full((1, 3), np.nan)])
    return points, index


def weld_faces(vertices: np.ndarray, faces: np.ndarray):
    """`(points, faces on points, copies)`: the welded mesh, faces that collapsed (two corners
    at one position) dropped, and `copies`, the number of vertices that were copies."""
    points, index = weld(vertices)
    f = index[faces]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return points, f[keep], len(vertices) - len(points)

"""A procedural table: a thick top on four cylindrical legs, the skeleton's test shape.

Built like the animal (`animal.py`), as the envelope of a hand-made medial mesh: a slab of
four spheres for the top (a box with rounded edges) and one cone per leg, so that it is closed
and manifold at any resolution, with no mesh boolean, and its limbs are known.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .medial_mesh import MedialMesh


def table_medial(top: float = 0.14, leg: float = 0.07, height: float = 0.8) -> MedialMesh:
    """The table's own medial mesh: a top of half-thickness `top` over the square
    [−0.5, 0.5]² at height `height`, four legs of radius `leg` from under its corners (at
    ±0.4) down to the floor (z = 0, their rounded ends included)."""
    corners = np.array([[x, y] for x in (-0.4, 0.4) for y in (-0.4, 0.4)])
    top_centres = np.column_stack([corners, np.full(4, height)])
    feet = np.column_stack([corners, np.full(4, leg)])
    centers = np.concatenate([top_centres, top_centres, feet])
    radii = np.r_[np.full(4, top), np.full(4, leg), np.full(4, leg)]
    slab = np.array([[0, 1, 3], [0, 3, 2]])
    edges = np.array([[0, 1], [1, 3], [3, 2], [2, 0], [0, 3], *[[4 + i, 8 + i] for i in range(4)]])
    return MedialMesh(centers, radii, edges, slab)


def table(resolution: int = 16, **sizes) -> trimesh.Trimesh:
    """The table's closed, manifold surface: the envelope of `table_medial(**sizes)` at
    `resolution` grid cells along its longest side (3,700 vertices at the default 16)."""
    return table_medial(**sizes).envelope(resolution)

"""Procedural closed shapes for demos, tests and the paper's experiments (NumPy, no data files).

Every shape is closed and outward oriented, built along the x axis from `x = 0` to its length,
so that `Line(length)` (the default line: origin 0, tangent x) is its natural source spine.
"""

from __future__ import annotations

import numpy as np
import trimesh


def extrusion(contour, length: float, segments: int) -> trimesh.Trimesh:
    """A straight prism: the closed planar `contour` (y, z) swept along x over `[0, length]`.

    **Arguments:** `contour`: (M, 2) counter-clockwise polygon in the (y, z) plane (no repeated
    end point); `length`; `segments`: number of slices along x.

    **Returns:** a closed triangle `Trimesh` (caps are fans around the contour's first point's
    opposite: a centre vertex at the polygon's vertex mean, so the contour must be star-shaped
    about it).
    """
    contour = np.asarray(contour, dtype=float)
    m, n = len(contour), int(segments)
    x = np.linspace(0.0, length, n + 1)
    ring = np.arange(m)
    vertices = np.concatenate(
        [np.column_stack([np.full(m, xi), contour]) for xi in x]
        + [[[0.0, *contour.mean(0)], [length, *contour.mean(0)]]]
    )
    faces = []
    for i in range(n):
        a, b = i * m + ring, i * m + np.roll(ring, -1)
        c, d = a + m, b + m
        faces += [np.column_stack([a, b, d]), np.column_stack([a, d, c])]
    start, end = (n + 1) * m, (n + 1) * m + 1
    faces.append(np.column_stack([np.roll(ring, -1), ring, np.full(m, start)]))
    faces.append(np.column_stack([n * m + ring, n * m + np.roll(ring, -1), np.full(m, end)]))
    return trimesh.Trimesh(vertices, np.concatenate(faces), process=False)


def creature(length: float = 4.0, segments: int = 64, around: int = 32) -> trimesh.Trimesh:
    """An elongated, fish-like body along x: a swollen head, a tapering tail, a dorsal hump.

    Its cross-sections are ellipses centred above the x axis (off-centre, so that bending it
    by skinning changes its volume). Closed by one vertex at each end.

    **Returns:** a closed triangle `Trimesh` with `2 + (segments − 1) · around` vertices.
    """
    t = np.linspace(0.0, 1.0, segments + 1)[1:-1]
    profile = np.sin(np.pi * t) ** 0.7 * (1 + 0.6 * np.exp(-(((t - 0.25) / 0.15) ** 2)))
    width, height = 0.32 * profile, 0.42 * profile
    lift = 0.12 * np.sin(np.pi * t) + 0.08 * np.exp(-(((t - 0.5) / 0.2) ** 2))
    angle = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    y = width[:, None] * np.cos(angle)
    z = lift[:, None] + height[:, None] * np.sin(angle)
    x = np.broadcast_to(length * t[:, None], y.shape)
    rings = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    vertices = np.concatenate([[[0.0, 0.0, 0.0]], rings, [[length, 0.0, 0.0]]])
    ring, k = np.arange(around), len(t)
    faces = [np.column_stack([np.zeros(around, int), 1 + np.roll(ring, -1), 1 + ring])]
    for i in range(k - 1):
        a, b = 1 + i * around + ring, 1 + i * around + np.roll(ring, -1)
        faces += [np.column_stack([a, b, b + around]), np.column_stack([a, b + around, a + around])]
    last, tip = 1 + (k - 1) * around, len(vertices) - 1
    faces.append(np.column_stack([last + ring, last + np.roll(ring, -1), np.full(around, tip)]))
    return trimesh.Trimesh(vertices, np.concatenate(faces), process=False)


def box_grid(bounds, divisions: int, quads: bool = False):
    """The surface of an axis-aligned box, each face a `divisions × divisions` grid.

    Each edge of the box is cut into `divisions` equal parts: `6 d² + 2` vertices (d = 1, 2, 4,
    … give 8, 26, 98, … vertices: the levels of a subdivision hierarchy).

    **Arguments:** `bounds`: (2, 3) min and max corners; `divisions`: d ≥ 1; `quads`: return quad
    faces instead of triangles.

    **Returns:** `(vertices (V, 3), faces (F, 4) or (2F, 3))`, closed and outward oriented.
    """
    lo, hi = np.asarray(bounds, dtype=float)
    d = int(divisions)
    grid = np.linspace(0.0, 1.0, d + 1)
    u, v = np.meshgrid(grid, grid, indexing="ij")
    points, quads_list = [], []
    for axis in range(3):
        for side in (0.0, 1.0):
            p, q = [a for a in range(3) if a != axis]
            unit = np.zeros((d + 1, d + 1, 3))
            unit[..., axis], unit[..., p], unit[..., q] = side, u, v
            base = sum(len(x) for x in points)
            idx = base + np.arange((d + 1) ** 2).reshape(d + 1, d + 1)
            cell = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1)
            cell = cell.reshape(-1, 4)
            # (p, q, axis) right-handed ⇔ axis == 1 is the odd one out; flip to face outward.
            outward = (side == 1.0) != (axis == 1)
            quads_list.append(cell if outward else cell[:, ::-1])
            points.append(unit.reshape(-1, 3))
    points = np.concatenate(points)
    faces = np.concatenate(quads_list)
    keys = np.round(points * d).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)  # keep vertices in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vertices = lo + points[first[order]] * (hi - lo)
    faces = rank[inverse.reshape(-1)][faces]
    if not quads:
        faces = np.stack([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]], 1).reshape(-1, 3)
    return vertices, faces


CUBE_FACES = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
     [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]]
)  # fmt: skip
"""(12, 3) outward triangles of the cube whose corners are `CUBE_CORNERS`."""

CUBE_CORNERS = np.array(
    [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
    dtype=float,
)


def cube_cloud(bounds, size: float, gap: float = 0.5):
    """A lattice of equal cubes filling a box: the paper's "cloud of cubes" (Fig. 9).

    **Arguments:** `bounds`: (2, 3) corners of the region; `size`: cube edge; `gap`: spacing
    between cubes as a fraction of `size`.

    **Returns:** `(vertices (K, 8, 3), faces (12, 3))`: every cube uses `CUBE_FACES`, so that
    `volume(vertices, faces)` gives the K volumes at once.
    """
    lo, hi = np.asarray(bounds, dtype=float)
    step = size * (1 + gap)
    axes = []
    for a in range(3):
        count = max(1, int(np.floor((hi[a] - lo[a] - size) / step)) + 1)
        start = lo[a] + 0.5 * (hi[a] - lo[a] - size - (count - 1) * step)
        axes.append(start + step * np.arange(count))
    corners = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 1, 3)
    return corners + size * CUBE_CORNERS, CUBE_FACES.copy()


def voxel_surface(occupied, size: float, origin=(0.0, 0.0, 0.0)):
    """The boundary of a set of voxels, as outward quads with shared vertices.

    **Arguments:** `occupied`: (X, Y, Z) bool array; `size`: voxel edge; `origin`: (3,) corner of
    voxel (0, 0, 0). The set must be a manifold solid (no voxels touching along an edge only).

    **Returns:** `(vertices (V, 3), quads (F, 4))`.
    """
    occupied = np.pad(np.asarray(occupied, dtype=bool), 1)
    shape = np.array(occupied.shape) + 1
    faces = []
    for axis in range(3):
        p, q = [a for a in range(3) if a != axis]
        for side in (-1, 1):
            neighbour = np.roll(occupied, -side, axis=axis)
            cells = np.argwhere(occupied & ~neighbour)
            corner = cells.copy()
            corner[:, axis] += side > 0
            offsets = np.zeros((4, 3), int)
            offsets[[1, 2], p] = 1
            offsets[[2, 3], q] = 1
            quad = corner[:, None, :] + offsets  # counter-clockwise about +axis if (p,q,axis) rh
            right_handed = axis != 1
            if (side > 0) != right_handed:
                quad = quad[:, ::-1]
            faces.append(quad)
    corners = np.concatenate(faces)  # (F, 4, 3) integer grid corners
    keys = np.ravel_multi_index(corners.reshape(-1, 3).T, shape)
    unique, inverse = np.unique(keys, return_inverse=True)
    grid = np.stack(np.unravel_index(unique, shape), -1) - 1  # undo the padding
    vertices = np.asarray(origin, dtype=float) + size * grid
    return vertices, inverse.reshape(-1, 4)


def genus2_slab(width=2.0, height=1.0, thickness=0.3, size=0.05):
    """A rectangular slab in the (x, y) plane with two square holes: a genus-2 quad mesh.

    It spans `[0, width] × [−height/2, height/2] × [−thickness/2, thickness/2]`.

    **Returns:** `(vertices (V, 3), quads (F, 4))` (see `voxel_surface`).
    """
    nx, ny, nz = (int(round(v / size)) for v in (width, height, thickness))
    occupied = np.ones((nx, ny, nz), dtype=bool)
    hx, hy = nx // 5, ny // 3
    for cx in (nx // 4, 3 * nx // 4):
        occupied[cx - hx // 2 : cx - hx // 2 + hx, ny // 2 - hy // 2 : ny // 2 - hy // 2 + hy] = 0
    return voxel_surface(occupied, size, origin=(0.0, -ny * size / 2, -nz * size / 2))

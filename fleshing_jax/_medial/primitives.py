"""Signed distances to the primitives of a medial mesh and to their union.

A medial mesh's volume is the union of its spheres, its *cones* (the convex hull of the two
spheres of an edge) and its *slabs* (the convex hull of the three spheres of a face), as in
Sun et al. 2013 and Q-MAT (Li et al. 2015). Each primitive is the union of the spheres
interpolated linearly (centre and radius) over its edge or face, so its signed distance is
`min_t |p − c(t)| − r(t)`, a convex problem with closed-form solutions (derived here):

- cone, spheres `(c0, r0)`, `(c1, r1)` at distance `L`, axis `u`, `s = (r0 − r1)/L`: with
  `x = (p − c0)·u` and `y` the distance to the axis, the minimiser lies on the axis at
  `x − y s/√(1 − s²)`; inside `[0, L]` the distance is `x s + y √(1 − s²) − r0`, otherwise
  that of the nearer end sphere. Nested spheres (`L ≤ |r0 − r1|`) are the larger sphere.
- slab: the two planes tangent to the three spheres have normals `a ± γ m` (`m` the normal
  of the centres' plane, `a` in that plane with `a·(ci − c0) = r0 − ri`, `γ = √(1 − |a|²)`);
  where `p` projects along the normal of its side into the triangle of centres, the
  distance is `n·(p − c0) − r0`; elsewhere the minimum lies on an edge (a cone).

The union's signed distance is the minimum over primitives: exact outside the union, and
inside it a lower bound of the distance to the boundary (enough for signs and for the narrow
band the envelope needs).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def cone_distance(p, c0, r0, c1, r1):
    """Signed distance of points `p` (M, 3) to cones `(c0 (M, 3), r0 (M,), c1, r1)`: (M,)."""
    end0 = np.linalg.norm(p - c0, axis=1) - r0
    end1 = np.linalg.norm(p - c1, axis=1) - r1
    axis = c1 - c0
    length = np.linalg.norm(axis, axis=1)
    proper = length > np.abs(r0 - r1) * (1 + 1e-12)
    safe = np.where(proper, length, 1.0)
    u = axis / safe[:, None]
    x = _dot(p - c0, u)
    y = np.linalg.norm(p - c0 - x[:, None] * u, axis=1)
    s = np.where(proper, (r0 - r1) / safe, 0.0)
    co = np.sqrt(np.maximum(1 - s * s, 1e-300))
    t = (x - y * s / co) / safe
    lateral = np.where(proper & (t >= 0) & (t <= 1), x * s + y * co - r0, np.inf)
    return np.minimum(np.minimum(end0, end1), lateral)


def slab_tangent_normals(c0, r0, c1, r1, c2, r2):
    """The in-plane part `a` (M, 3), plane normal `m` (M, 3) and `γ` (M,; NaN where the slab
    has no tangent planes) of the two tangent-plane normals `a ± γ m` of slabs."""
    e1, e2 = c1 - c0, c2 - c0
    m = np.cross(e1, e2)
    norm = np.linalg.norm(m, axis=1)
    m = m / np.where(norm > 0, norm, 1.0)[:, None]
    g11, g12, g22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    det = g11 * g22 - g12 * g12
    ok = det > 1e-14 * np.maximum(g11 * g22, 1e-300)
    det = np.where(ok, det, 1.0)
    h1, h2 = r0 - r1, r0 - r2
    alpha = (g22 * h1 - g12 * h2) / det
    beta = (g11 * h2 - g12 * h1) / det
    a = alpha[:, None] * e1 + beta[:, None] * e2
    gamma2 = 1 - _dot(a, a)
    gamma = np.where(ok & (gamma2 > 1e-12), np.sqrt(np.maximum(gamma2, 0)), np.nan)
    return a, m, gamma


def slab_plane_distance(p, c0, r0, c1, r1, c2, r2):
    """Signed distance of `p` (M, 3) to the tangent-plane part of slabs, `inf` where the
    minimiser is not inside the triangle (there a cone of the slab's edges gives it): (M,)."""
    a, m, gamma = slab_tangent_normals(c0, r0, c1, r1, c2, r2)
    height = _dot(p - c0, m)
    side = np.where(height >= 0, 1.0, -1.0)
    g = np.nan_to_num(gamma, nan=1.0)
    n = a + (side * g)[:, None] * m
    foot = p - (np.abs(height) / g)[:, None] * n
    # Barycentric coordinates of the foot in the triangle of centres.
    e1, e2, w = c1 - c0, c2 - c0, foot - c0
    g11, g12, g22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    det = g11 * g22 - g12 * g12
    det = np.where(det > 0, det, 1.0)
    b1 = (g22 * _dot(w, e1) - g12 * _dot(w, e2)) / det
    b2 = (g11 * _dot(w, e2) - g12 * _dot(w, e1)) / det
    inside = np.isfinite(gamma) & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1)
    return np.where(inside, _dot(n, p - c0) - r0, np.inf)


def bounding_spheres(centers, radii, edges, faces):
    """Bounding spheres of the primitives that `union_distance` evaluates: the spheres not on
    any edge, every cone, every slab. Returns `(kind (P,), index (P,), centre (P, 3),
    radius (P,))`, kind 0/1/2 for sphere/cone/slab."""
    lone = np.setdiff1d(np.arange(len(centers)), edges.reshape(-1))
    c0, c1 = centers[edges[:, 0]], centers[edges[:, 1]]
    mid = (c0 + c1) / 2
    cone_r = np.linalg.norm(c1 - c0, axis=1) / 2 + np.maximum(radii[edges[:, 0]],
                                                              radii[edges[:, 1]])
    tri = centers[faces]
    cen = tri.mean(axis=1) if len(faces) else np.zeros((0, 3))
    slab_r = (np.linalg.norm(tri - cen[:, None], axis=2) + radii[faces]).max(axis=1) \
        if len(faces) else np.zeros(0)
    kind = np.concatenate([np.zeros(len(lone)), np.ones(len(edges)), np.full(len(faces), 2)])
    index = np.concatenate([lone, np.arange(len(edges)), np.arange(len(faces))])
    centre = np.concatenate([centers[lone], mid, cen])
    radius = np.concatenate([radii[lone], cone_r, slab_r])
    return kind.astype(np.int8), index.astype(np.int64), centre, radius


def union_distance(points, centers, radii, edges, faces, *, cutoff: float, group: int = 256):
    """Signed distance of `points` (N, 3) to the union of a medial mesh's primitives.

    Only primitives whose bounding sphere comes within `cutoff` of a point are evaluated
    there; a point with none gets `cutoff` (it is at least that far outside).

    **Returns:** `(N,)` array, clipped above at `cutoff`.
    """
    points = np.asarray(points, dtype=np.float64)
    out = np.full(len(points), float(cutoff))
    if len(points) == 0:
        return out
    kind, index, centre, radius = bounding_spheres(centers, radii, edges, faces)
    tree = cKDTree(points)
    # Primitives in groups, so that the (point, primitive) pairs of a group stay small.
    for start in range(0, len(kind), group):
        sl = slice(start, start + group)
        lists = tree.query_ball_point(centre[sl], radius[sl] + cutoff)
        sizes = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
        if sizes.sum() == 0:
            continue
        pts = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists])
        prim = np.repeat(np.arange(start, start + len(lists)), sizes)
        value = np.full(len(pts), np.inf)
        p = points[pts]
        k, i = kind[prim], index[prim]
        sel = k == 0
        value[sel] = np.linalg.norm(p[sel] - centers[i[sel]], axis=1) - radii[i[sel]]
        sel = k == 1
        e = edges[i[sel]]
        value[sel] = cone_distance(p[sel], centers[e[:, 0]], radii[e[:, 0]],
                                   centers[e[:, 1]], radii[e[:, 1]])
        sel = k == 2
        f = faces[i[sel]]
        value[sel] = slab_plane_distance(p[sel], centers[f[:, 0]], radii[f[:, 0]],
                                         centers[f[:, 1]], radii[f[:, 1]],
                                         centers[f[:, 2]], radii[f[:, 2]])
        np.minimum.at(out, pts, value)
    return out

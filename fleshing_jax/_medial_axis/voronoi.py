"""The initial medial axis: the inner part of the Voronoi diagram of dense surface samples.

As in Q-MAT (Li et al. 2015, section 5) and Amenta & Bern's poles: the Voronoi vertices of
surface samples that lie inside the shape are centres of maximal empty spheres, so they
approximate medial spheres; Voronoi edges and faces between inside vertices connect them
into a 2-complex that converges to the medial axis (with spikes, removed later by the
simplification). The Voronoi diagram is taken as the dual of SciPy's Delaunay tetrahedra:

- Voronoi vertex = circumcentre of a tetrahedron, kept where it lies inside the mesh; its
  radius is the distance to the mesh (`surface.SurfaceQuery`), its contacts are the
  tetrahedron's four samples (whose tangent planes seed the sphere quadrics);
- Voronoi edge = a triangle shared by two kept tetrahedra;
- Voronoi face = a Delaunay edge, not on the hull, all of whose tetrahedra are kept: a
  convex polygon in the edge's bisector plane, ordered by angle and fanned into triangles
  (the fan's diagonals become edges too, so every face's edges are edges).

Every inside vertex is kept, with or without a kept neighbour, and the pieces of each volume
are joined into one connected graph (`connect`): in thin parts the inside vertices are
scattered, and they are the only spheres there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy.spatial import Delaunay

from .connect import distinct, join_pieces, unique_rows, volumes
from .rows import cross, norm, sorted_order
from .shells import shells
from .surface import SurfaceQuery

_PAIRS = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])


@dataclass
class InitialAxis:
    """The inner Voronoi complex. `centers (n, 3)`, `radii (n,)`, `edges (e, 2)`, `faces
    (f, 3)`, `contacts (n, 4)`: indices into `points (s, 3)` / `normals (s, 3)` of the samples
    on each sphere, `weights (s,)`: each sample's share of the surface area."""

    centers: np.ndarray
    radii: np.ndarray
    edges: np.ndarray
    faces: np.ndarray
    contacts: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    volume: np.ndarray
    volumes: int


def circumcentres(a, b, c, d):
    """Circumcentres `(T, 3)` of tetrahedra and a validity mask `(T,)` (False when flat)."""
    u, v, w = b - a, c - a, d - a
    vw, wu, uv = cross(v, w), cross(w, u), cross(u, v)
    det = 2 * np.einsum("ij,ij->i", u, vw)
    num = ((u * u).sum(1)[:, None] * vw + (v * v).sum(1)[:, None] * wu
           + (w * w).sum(1)[:, None] * uv)
    scale = np.maximum.reduce([norm(x) for x in (u, v, w)]) ** 3
    ok = np.abs(det) > 1e-12 * scale
    return a + num / np.where(ok, det, 1.0)[:, None], ok


@numba.njit(cache=True, error_model="numpy")
def _before(a, b):
    """Whether `a` sorts before `b` in NumPy's order of floats (NaN last)."""
    return a < b or (b != b and a == a)


@numba.njit(cache=True, error_model="numpy")
def around_order(group, angle):
    """`np.lexsort((angle, group))` `(m,)` for `group (m,)` ascending: each group's
    positions by `angle (m,)` (NaN last), equal angles in their order. An insertion sort
    within each group (a Voronoi face has a handful of vertices): NumPy's two merge sorts
    over spot's 270k face vertices took 35 ms."""
    order = np.arange(len(group))
    start = 0
    for k in range(1, len(group) + 1):
        if k == len(group) or group[k] != group[start]:
            for i in range(start + 1, k):
                j = i
                while j > start and _before(angle[order[j]], angle[order[j - 1]]):
                    order[j], order[j - 1] = order[j - 1], order[j]
                    j -= 1
            start = k
    return order


def initial_medial_axis(query: SurfaceQuery, points, normals, weights, sample_faces
                        ) -> InitialAxis:
    """The inner Voronoi complex of surface samples `points (s, 3)` with outward `normals`
    on the closed mesh of `query`, `weights (s,)` their area shares and `sample_faces (s, k)`
    the faces each lies on (-1 padded; see `InitialAxis`)."""
    delaunay = Delaunay(points)
    tets = delaunay.simplices.astype(np.int64)
    # (`np.take`, not `points[...]`: the same rows, several times faster in NumPy 2.4.)
    a, b, c, d = (np.take(points, tets[:, k], axis=0) for k in range(4))
    centre, ok = circumcentres(a, b, c, d)
    lo, hi = query.vertices.min(axis=0), query.vertices.max(axis=0)
    ok &= ((centre >= lo) & (centre <= hi)).all(axis=1)
    candidates = np.flatnonzero(ok)
    # The closest point of an empty sphere lies near its contact samples: search the faces
    # around the faces of the tetrahedron's four samples.
    near = query.around(sample_faces[tets[candidates]].reshape(len(candidates), -1))
    poles = np.take(centre, candidates, axis=0)
    distance, _, inside = query.query_candidates(poles, near)
    # The closest face is not always among those: an outer pole beyond a part thinner than
    # its sphere, its samples on the part's rim or far side, took its sign from their faces,
    # behind which it lies, and was kept as inside (the coarse animal's tail, a sliver 0.005
    # thick: radii up to 0.07 sticking out of it, 6 % of the diagonal after the fit). A
    # centre inside the shape lies behind the tangent plane of each of its samples (its
    # sphere is tangent there from inside); the few that lie in front of one (on the
    # animal 400 of 77,000, most of them inside, where the surface is concave) take their
    # side from a certified query. Their radius stays that of the faces searched, as for
    # every other vertex: certified, two of spot's 79,000 radii shrank by 2e-4 of the
    # diagonal, and the collapses and the fit took spot at 200 spheres from 0.72 to 0.89 %.
    contact = tets[candidates]
    front = np.einsum("ijk,ijk->ij", poles[:, None] - np.take(points, contact, axis=0),
                      np.take(normals, contact, axis=0)).max(axis=1) > 0
    doubt = np.flatnonzero(front & inside)
    if len(doubt):
        inside[doubt] = query.query(centre[candidates[doubt]])[2]
    keep = np.zeros(len(tets), dtype=bool)
    keep[candidates[inside & (distance > 0)]] = True
    radius = np.zeros(len(tets))
    # The circumradius is a distance to a surface point, so it bounds the distance from above
    # where the closest face was not certified (see `SurfaceQuery.query`).
    radius[candidates] = np.minimum(distance, norm(poles - np.take(a, candidates, axis=0)))

    # Voronoi edges: Delaunay neighbours that are both kept.
    neighbours = delaunay.neighbors.astype(np.int64)
    t = np.repeat(np.arange(len(tets)), 4)
    nb = neighbours.reshape(-1)
    sel = (nb > t) & keep[t] & keep[np.maximum(nb, 0)]
    edges = [np.stack([t[sel], nb[sel]], 1)]

    # Voronoi faces: Delaunay edges whose whole ring of tetrahedra is kept, off the hull.
    n_points = len(points)
    ends = tets[:, _PAIRS]  # (T, 6, 2); min and max, not a sort of millions of pairs
    key = (np.minimum(ends[..., 0], ends[..., 1]) * n_points
           + np.maximum(ends[..., 0], ends[..., 1])).reshape(-1)
    owner = np.repeat(np.arange(len(tets)), 6)
    on_hull = neighbours < 0
    hull_keys = []
    for k in range(4):  # facet opposite vertex k of the tetrahedra on the hull
        facet = np.delete(tets[on_hull[:, k]], k, axis=1)
        for p, q in ((0, 1), (0, 2), (1, 2)):
            lo_, hi_ = np.minimum(facet[:, p], facet[:, q]), np.maximum(facet[:, p], facet[:, q])
            hull_keys.append(lo_ * n_points + hi_)
    hull_keys = distinct(np.concatenate(hull_keys))
    key, order = sorted_order(key, n_points * n_points)
    owner = owner.take(order)
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    size = np.diff(np.r_[start, len(key)])
    ring_kept = np.minimum.reduceat(keep[owner].astype(np.int8), start).astype(bool)
    good = ring_kept & (size >= 3) & ~np.isin(key[start], hull_keys)
    group = np.repeat(np.arange(len(start)), size)
    member = good[group]
    rings = key[start[good]]  # the Delaunay edge of each face kept
    owner, group = owner[member], group[member]
    faces = np.zeros((0, 3), dtype=np.int64)
    if len(rings):
        # Each face's frame once, not once per vertex (spot: 56k frames, not 270k).
        i, j = np.divmod(rings, n_points)
        pi, pj = np.take(points, i, axis=0), np.take(points, j, axis=0)
        axis = pj - pi
        axis /= norm(axis)[:, None]
        # A reference direction perpendicular to the axis, then the angle of each circumcentre
        # around the axis (the polygon is convex and perpendicular to it).
        helper = np.where((np.abs(axis[:, 0]) < 0.9)[:, None], [1.0, 0, 0], [0, 1.0, 0])
        e1 = cross(axis, helper)
        e1 /= norm(e1)[:, None]
        e2 = cross(axis, e1)
        ring = np.repeat(np.arange(len(rings)), size[good])  # each vertex's face
        offset = np.take(centre, owner, axis=0) - np.take((pi + pj) / 2, ring, axis=0)
        angle = np.arctan2(np.einsum("ij,ij->i", offset, np.take(e2, ring, axis=0)),
                           np.einsum("ij,ij->i", offset, np.take(e1, ring, axis=0)))
        order = around_order(group, angle)  # (`group` ascends)
        owner, group = owner[order], group[order]
        first = np.r_[True, group[1:] != group[:-1]]
        rank = np.arange(len(group)) - np.maximum.accumulate(np.where(first, np.arange(len(group)),
                                                                      0))
        head = owner[np.maximum.accumulate(np.where(first, np.arange(len(group)), 0))]
        fan = np.flatnonzero(rank >= 2)
        faces = np.stack([head[fan], owner[fan - 1], owner[fan]], 1)
        edges += [faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [0, 2]]]
    edges = unique_rows(np.concatenate(edges), len(tets))
    faces = unique_rows(faces, len(tets))

    # Every kept sphere, renumbered; then the pieces of each volume joined.
    used = np.flatnonzero(keep)
    new = np.full(len(tets), -1, dtype=np.int64)
    new[used] = np.arange(len(used))
    count, volume = volumes(*shells(query.faces)[::-1], sample_faces[tets[used], 0])
    edges = join_pieces(centre[used], new[edges], volume,
                        inside=lambda p: query.query(p, exact=False)[2])
    return InitialAxis(centre[used], radius[used], edges, new[faces], tets[used],
                       points, normals, weights, volume, count)

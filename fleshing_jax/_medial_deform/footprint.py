"""Footprint binding of surface vertices to a medial mesh (NumPy preprocessing).

Follows Lan et al. 2017 (appendix): a vertex `p` is bound to the medial primitive (sphere,
cone = edge, slab = face) whose envelope is nearest, and on it to its *footprint sphere*, the
sphere `(c(β), r(β))` interpolated linearly over the primitive that minimises the power
distance `E_m(β) = |p − c(β)|² − r(β)²`. Its Hessian is the Gram matrix of the Minkowski
products of `(c_a − c_k, r_a − r_k)`, positive definite for a slab whose spheres are not
nested or collinear, so `β` solves a 2×2 linear system on a slab (1×1 on a cone); when the
minimiser is outside the primitive (or the Hessian is not positive definite) the minimum lies
on its boundary: the best of the edges' clamped 1D minima (a convex problem's constrained
minimum; for a non-convex one the boundary holds it anyway).

Our own choices: candidates are pruned with the primitives' bounding spheres (a primitive
whose bounding sphere is farther than the nearest sphere's envelope cannot be nearest); the
primitives the implicit field later uses are chosen here too (`field_cones` nearest cones,
lone spheres counted as cones of length 0, and `field_slabs` nearest slabs), with the rest
iso-values of that field.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from .._medial_axis.primitives import _Cones, _Slabs, in_blocks

CHUNK = 1024  # points per block of the (point, primitive) bound matrix


class Binding(NamedTuple):
    """Per-vertex footprint data (NumPy). `spheres`, `beta`: (N, 3) the footprint's spheres
    and barycentric weights (a cone as `(i, j, j)`, a lone sphere as `(i, i, i)`, unused
    weights 0); `offset`: (N, 3) `p − c(β)`; `distance`: (N,) signed distance to the nearest
    primitive's envelope; `valid`: (N,); `cones`: (C, 2) the segment table (edges, then lone
    spheres as `(i, i)`); `field_cones` (N, kc) and `field_slabs` (N, ks): each vertex's
    field candidates (indices into `cones` and the medial faces); `edge_cones` (N, e) and
    `edge_slots` (N, ks, 3): the cones its slabs need as edges beyond its cone candidates,
    and where each slab's edges are in `field_cones ++ edge_cones` (`distinct_edges`);
    `iso`: (N,) the field of the rest envelope at the rest vertex over those candidates;
    `width`: (N,) the smooth union's width there (`blend` times the footprint radius)."""

    spheres: np.ndarray
    beta: np.ndarray
    offset: np.ndarray
    distance: np.ndarray
    valid: np.ndarray
    cones: np.ndarray
    field_cones: np.ndarray
    field_slabs: np.ndarray
    edge_cones: np.ndarray
    edge_slots: np.ndarray
    iso: np.ndarray
    width: np.ndarray


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def segment_footprint(p, ca, ra, cb, rb):
    """Minimiser `t ∈ [0, 1]` of `E(t) = |p − c(t)|² − r(t)²` on segments `(ca, ra)–(cb, rb)`
    (all (M, ·)), with `E` there: `(t (M,), E (M,))`."""
    d, dr, w = cb - ca, rb - ra, p - ca
    h = _dot(d, d) - dr * dr  # the 1×1 Hessian (halved): a Minkowski norm
    convex = h > 1e-14 * np.maximum(_dot(d, d), 1e-300)
    t = np.clip((_dot(w, d) + ra * dr) / np.where(convex, h, 1.0), 0.0, 1.0)

    def energy(t):
        q = w - t[:, None] * d
        return _dot(q, q) - (ra + t * dr) ** 2

    e0, e1 = energy(np.zeros_like(t)), energy(np.ones_like(t))
    t = np.where(convex, t, np.where(e1 < e0, 1.0, 0.0))
    return t, energy(t)


def slab_footprint(p, c, r):
    """Footprint weights on slabs of spheres `c (M, 3, 3)`, `r (M, 3)` for points `p (M, 3)`:
    `β (M, 3)` over the three spheres, summing to 1, all >= 0."""
    ck, rk = c[:, 2], r[:, 2]
    e = c[:, :2] - ck[:, None]  # (M, 2, 3)
    dr = r[:, :2] - rk[:, None]
    w = p - ck
    h11 = _dot(e[:, 0], e[:, 0]) - dr[:, 0] ** 2
    h12 = _dot(e[:, 0], e[:, 1]) - dr[:, 0] * dr[:, 1]
    h22 = _dot(e[:, 1], e[:, 1]) - dr[:, 1] ** 2
    g1 = _dot(e[:, 0], w) + dr[:, 0] * rk
    g2 = _dot(e[:, 1], w) + dr[:, 1] * rk
    det = h11 * h22 - h12 * h12
    scale = np.maximum(_dot(e[:, 0], e[:, 0]) * _dot(e[:, 1], e[:, 1]), 1e-300)
    definite = (h11 > 0) & (det > 1e-12 * scale)
    safe = np.where(definite, det, 1.0)
    bi, bj = (h22 * g1 - h12 * g2) / safe, (h11 * g2 - h12 * g1) / safe
    inside = definite & (bi >= 0) & (bj >= 0) & (bi + bj <= 1)
    beta = np.stack([bi, bj, 1 - bi - bj], axis=1)
    # Boundary: the three edges' clamped minima, the best one kept.
    best = np.full(len(p), np.inf)
    edge_beta = np.zeros_like(beta)
    for a, b in ((0, 1), (1, 2), (0, 2)):
        t, energy = segment_footprint(p, c[:, a], r[:, a], c[:, b], r[:, b])
        better = energy < best
        best = np.where(better, energy, best)
        candidate = np.zeros_like(beta)
        candidate[:, a], candidate[:, b] = 1 - t, t
        edge_beta = np.where(better[:, None], candidate, edge_beta)
    return np.where(inside[:, None], beta, edge_beta)


class _SlabEdges:
    """The three edge cones of every slab, `(i, j), (j, k), (i, k)`, as one `_Cones`."""

    def __init__(self, centers, radii, faces):
        pairs = faces[:, [[0, 1], [1, 2], [0, 2]]].reshape(-1, 2)
        self.cones = _Cones(centers[pairs[:, 0]], radii[pairs[:, 0]], centers[pairs[:, 1]],
                            radii[pairs[:, 1]])

    def distance(self, p, i):
        """Distance of `p` (M, 3) to the nearest edge cone of slabs `i` (M,)."""
        return np.minimum.reduce([self.cones.distance(p, 3 * i + a) for a in range(3)])


def slab_distance(p, slabs, edges, i):
    """Signed distance of `p` (M, 3) to the whole slabs `i` (M,): the tangent-plane part
    where the foot is in the triangle, else the nearest edge cone."""
    plane = slabs.distance(p, i)
    return np.where(np.isfinite(plane), plane, edges.distance(p, i))


def smooth_union(values, width):
    """The smooth union of `implicit.smooth_union`, folded over the last axis of `values`
    (M, k) in order, `width` (M,)."""
    out = values[:, 0]
    for k in range(1, values.shape[1]):
        b = values[:, k]
        h = np.clip(0.5 + 0.5 * (b - out) / width, 0, 1)
        out = b + h * (out - b) - width * h * (1 - h)
    return out


def _rank(points):
    """Rank of each pair within its point's group, for pairs sorted by point."""
    starts = np.r_[0, np.flatnonzero(np.diff(points)) + 1]
    sizes = np.diff(np.r_[starts, len(points)])
    return np.arange(len(points)) - np.repeat(starts, sizes)


def _nearest_k(pts, prim, dist, n_points, k, fallback, bound):
    """The `k` nearest primitives per point from pairs `(pts, prim, dist)`, each pair once
    (ties: the lower primitive index), and their distances: `(n_points,
    k)` each; rows with fewer repeat their nearest (duplicates do not change a minimum),
    `fallback` (at distance `inf`) for none. `bound (n_points,)`: a distance that at least
    `k` of each point's pairs do not exceed (pairs beyond it are skipped)."""
    out = np.full((n_points, k), fallback, dtype=np.int64)
    out_d = np.full((n_points, k), np.inf)
    if k == 0 or len(pts) == 0:
        return out, out_d
    near = dist <= bound[pts]
    pts, prim, dist = pts[near], prim[near], dist[near]
    order = np.lexsort((prim, dist, pts))
    pts, prim, dist = pts[order], prim[order], dist[order]
    rank = _rank(pts)
    first = rank == 0
    out[pts[first]] = prim[first][:, None]
    out_d[pts[first]] = dist[first][:, None]
    keep = rank < k
    out[pts[keep], rank[keep]] = prim[keep]
    out_d[pts[keep], rank[keep]] = dist[keep]
    return out, out_d


def _reachable(points, upper, near, b_centre, b_square, b_radius, margin):
    """The (point, primitive) pairs `(i (P,), j (P,))`, in order of point then primitive,
    whose bounding sphere (`b_centre`, `b_square = |b_centre|²`, `b_radius`) comes within
    `upper (M,)` of `points (M, 3)`, except each point's `near (M, k)` primitives.

    `|p − b| ≤ upper + radius` compared squared, `|p − b|²` expanded as a matrix product
    (the (points, primitives, 3) differences would cost several times more), in place (the
    same operations in the same order as the plain expression); `margin` covers its
    rounding."""
    square = points @ b_centre.T
    square *= -2
    square += (points * points).sum(1)[:, None]
    square += b_square[None]
    reach = upper[:, None] + b_radius[None]
    reach += margin
    np.maximum(reach, 0, out=reach)
    reach *= reach
    reach[np.arange(len(points))[:, None], near] = -1
    return np.nonzero(square <= reach)


def bind(points, centers, radii, edges, faces, *, field_cones=4, field_slabs=1,
         max_distance=None, blend=0.1) -> Binding:
    """Binds `points` (N, 3) to the medial mesh `(centers, radii, edges, faces)` (NumPy
    float64 / int64). See the module docstring; **returns** a `Binding`."""
    n, m = len(centers), len(points)
    lone = np.setdiff1d(np.arange(n), edges.reshape(-1))
    cones = np.concatenate([edges, np.stack([lone, lone], 1)]).astype(np.int64)
    finite = np.isfinite(points).all(axis=1)
    p_all = np.where(finite[:, None], points, 0.0)
    if max_distance is None:
        lo, hi = (centers - radii[:, None]).min(0), (centers + radii[:, None]).max(0)
        max_distance = float(np.linalg.norm(hi - lo))

    seg = _Cones(centers[cones[:, 0]], radii[cones[:, 0]], centers[cones[:, 1]],
                 radii[cones[:, 1]])
    slabs = _Slabs(*(x for k in range(3) for x in (centers[faces[:, k]], radii[faces[:, k]])))
    slab_edges = _SlabEdges(centers, radii, faces)

    # Bounding spheres: cones (segments), then slabs.
    c0, c1 = centers[cones[:, 0]], centers[cones[:, 1]]
    b_centre = [(c0 + c1) / 2]
    b_radius = [np.linalg.norm(c1 - c0, axis=1) / 2 + np.maximum(radii[cones[:, 0]],
                                                                 radii[cones[:, 1]])]
    if len(faces):
        tri = centers[faces]
        mid = tri.mean(axis=1)
        b_centre.append(mid)
        b_radius.append((np.linalg.norm(tri - mid[:, None], axis=2) + radii[faces]).max(1))
    b_centre, b_radius = np.concatenate(b_centre), np.concatenate(b_radius)
    n_cones = len(cones)

    # Candidates: the k primitives of each kind with the nearest bounding-sphere centres
    # (their distances computed), plus every primitive whose bounding sphere is within the
    # smallest of those distances (none farther can be the nearest). The field's candidates
    # are the nearest of these.
    n_slabs = len(faces)
    kc, ks = min(field_cones, n_cones), min(max(field_slabs, 1), n_slabs)
    _, near_c = cKDTree(b_centre[:n_cones]).query(p_all, k=kc)
    near_c = near_c.reshape(m, kc)
    d_near_c = seg.distance(np.repeat(p_all, kc, 0), near_c.reshape(-1)).reshape(m, kc)
    upper = d_near_c.min(1)
    near_s = np.zeros((m, 0), np.int64)
    d_near_s = np.zeros((m, 0))
    if n_slabs:
        _, near_s = cKDTree(b_centre[n_cones:]).query(p_all, k=ks)
        near_s = near_s.reshape(m, ks)
        d_near_s = slab_distance(np.repeat(p_all, ks, 0), slabs, slab_edges,
                                 near_s.reshape(-1)).reshape(m, ks)
        upper = np.minimum(upper, d_near_s.min(1))

    # Per block of points (everything per pair stays in cache, nothing as long as all pairs
    # is built): the pairs within reach, their distances, and the nearest cones and slabs of
    # each point (ties: the lower index). Pairs farther than a distance already known `k`
    # times over (the near candidates') cannot be among the `k` nearest: dropped before the
    # sort. Every point has its near candidates among its pairs, so every row is filled.
    b_square = (b_centre * b_centre).sum(1)
    margin = 1e-7 * float(np.abs(b_centre).max() + np.abs(p_all).max())
    near = np.concatenate([near_c, near_s + n_cones], 1)  # their distances known
    fc, dfc = np.zeros((m, kc), np.int64), np.zeros((m, kc))
    fs, dfs = np.zeros((m, ks), np.int64), np.zeros((m, ks))
    for start in range(0, m, CHUNK):
        rows = slice(start, start + CHUNK)
        block = p_all[rows]
        i, j = _reachable(block, upper[rows], near[rows], b_centre, b_square, b_radius, margin)
        local = np.arange(len(block))
        cone = j < n_cones
        d = in_blocks(seg.distance, block, i[cone], j[cone])
        fc[rows], dfc[rows] = _nearest_k(
            np.r_[i[cone], np.repeat(local, kc)], np.r_[j[cone], near_c[rows].reshape(-1)],
            np.r_[d, d_near_c[rows].reshape(-1)], len(block), kc, 0, d_near_c[rows].max(1))
        if n_slabs:
            d = in_blocks(lambda p, k: slab_distance(p, slabs, slab_edges, k), block,
                           i[~cone], j[~cone] - n_cones)
            fs[rows], dfs[rows] = _nearest_k(
                np.r_[i[~cone], np.repeat(local, ks)],
                np.r_[j[~cone] - n_cones, near_s[rows].reshape(-1)],
                np.r_[d, d_near_s[rows].reshape(-1)], len(block), ks, 0, d_near_s[rows].max(1))
    # The nearest primitive (ties: the cone).
    on_slab = dfs[:, 0] < dfc[:, 0] if n_slabs else np.zeros(m, bool)
    nearest = np.where(on_slab, fs[:, 0] + n_cones if n_slabs else 0, fc[:, 0])
    distance = np.where(on_slab, dfs[:, 0] if n_slabs else 0, dfc[:, 0])
    # No more candidates than primitives: repeats would cost field evaluations for nothing.
    fs = fs[:, :min(field_slabs, n_slabs)]

    spheres = np.zeros((m, 3), np.int64)
    beta = np.zeros((m, 3))
    on_cone = nearest < n_cones
    ic = nearest[on_cone]
    a, b = cones[ic, 0], cones[ic, 1]
    t, _ = segment_footprint(p_all[on_cone], centers[a], radii[a], centers[b], radii[b])
    spheres[on_cone] = np.stack([a, b, b], 1)
    beta[on_cone] = np.stack([1 - t, t, np.zeros_like(t)], 1)
    on_slab = ~on_cone
    f = faces[nearest[on_slab] - n_cones] if on_slab.any() else np.zeros((0, 3), np.int64)
    spheres[on_slab] = f
    beta[on_slab] = slab_footprint(p_all[on_slab], centers[f], radii[f])
    # Lone spheres (cones (i, i)) and weights that vanish: first slot only.
    offset = p_all - np.einsum("mk,mkd->md", beta, centers[spheres])

    valid = finite & np.isfinite(distance) & (distance <= max_distance)
    width = blend * np.maximum((beta * radii[spheres]).sum(1), 1e-3 * float(radii.max()) + 1e-12)
    iso = rest_field(p_all, seg, slabs, slab_edges, fc, fs, width)
    edge_cones, edge_slots = distinct_edges(fc, fs, faces, cones)
    return Binding(spheres, beta, offset, np.where(valid, distance, 0.0), valid, cones,
                   fc, fs, edge_cones, edge_slots, np.where(valid, iso, 0.0), width)


def distinct_edges(field_cones, field_slabs, faces, cones):
    """The cones each point's slab candidates need as edges and are not among its cone
    candidates, so that the field evaluates each distinct cone once per point.

    **Arguments:** `field_cones (M, kc)`, `field_slabs (M, ks)` the candidates; `faces (F,
    3)` the medial faces, whose edges `(i, j), (j, k), (i, k)` are all in `cones (C, 2)`
    (either orientation; `MedialMesh` checks it).

    **Returns:** `(edge_cones (M, e), edge_slots (M, ks, 3))`: the further cones (in order of
    first need, rows padded with their first cone candidate, `e` the most any point needs)
    and, for each slab edge, its column in `field_cones ++ edge_cones`."""
    m, kc = field_cones.shape
    ks = field_slabs.shape[1]
    if ks == 0:
        return np.zeros((m, 0), np.int64), np.zeros((m, 0, 3), np.int64)
    n = np.int64(max(faces.max(), cones.max()) + 1)
    keys = np.sort(cones, axis=1) @ np.array([n, 1])
    order = np.argsort(keys)
    pairs = np.sort(faces[:, [[0, 1], [1, 2], [0, 2]]], axis=2) @ np.array([n, 1])
    face_cones = order[np.searchsorted(keys, pairs, sorter=order)]  # (F, 3)
    need = np.concatenate([field_cones, face_cones[field_slabs].reshape(m, 3 * ks)], 1)
    # Each entry's first occurrence in its row; the entries past the cone candidates that
    # are their own first occurrence are the further cones, numbered in order.
    first = np.argmax(need[:, :, None] == need[:, None, :], axis=2)
    new = first == np.arange(need.shape[1])
    new[:, :kc] = False
    rank = np.cumsum(new, axis=1) - 1
    e = int(new.sum(1).max())
    edge_cones = np.repeat(field_cones[:, :1], e, axis=1)
    rows, cols = np.nonzero(new)
    edge_cones[rows, rank[rows, cols]] = need[rows, cols]
    at = np.take_along_axis(rank, first, axis=1)
    slots = np.where(first < kc, first, kc + at)
    return edge_cones, slots[:, kc:].reshape(m, ks, 3)


def rest_field(points, seg, slabs, slab_edges, field_cones, field_slabs, width):
    """The rest envelope's field over each point's candidates, as `implicit.field` computes
    it: the smooth union (`width`) of the cones' and whole slabs' distances."""
    m, kc = field_cones.shape
    values = [seg.distance(np.repeat(points, kc, 0), field_cones.reshape(-1)).reshape(m, kc)]
    ks = field_slabs.shape[1]
    if ks:
        values.append(slab_distance(np.repeat(points, ks, 0), slabs, slab_edges,
                                    field_slabs.reshape(-1)).reshape(m, ks))
    return smooth_union(np.concatenate(values, axis=1), width)

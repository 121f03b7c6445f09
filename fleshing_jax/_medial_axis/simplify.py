"""Simplification of a medial mesh by edge collapses in order of Q-MAT's sphere-quadric error.

Follows Q-MAT (Li et al. 2015): a sphere `m = (c, r)` is a point of R⁴; a tangent plane of
the surface through `p` with outward normal `n` is touched from inside by `m` when
`d(m) = n·p − n·c − r = 0`, and `d(m)²` is a quadric in `m`. Each sphere carries the sum `Q`
of its planes' quadrics; collapsing an edge `(i, j)` replaces both spheres by the sphere
minimising `Q_i + Q_j`, at the cost of that minimum. Q-MAT's *stability ratio*
`s = (|c_i − c_j| − |r_i − r_j|) / |c_i − c_j|` (0 when one sphere is inside the other: a
spike) multiplies the cost, `(E + k) s²`, so that spikes collapse first (`k` small: it only
orders collapses whose error is zero).

Our own choices, where Q-MAT is sequential or leaves room:

- The planes seeding a sphere are the tangent planes at its contact samples (the four
  samples of its Delaunay tetrahedron), each weighted by its share of the surface area, so
  `E` is a mean squared distance (Q-MAT seeds from the slabs of the initial medial mesh).
- Errors and lengths are measured in units of the mesh's bounding-box diagonal, and the
  cost is `(E + k + w |c_i − c_j|²) s²`: where the error is zero for many collapses (a
  cylinder is tangent to every sphere on its axis), the shortest edges go first, which
  keeps the spheres evenly spread (`w = length_weight`).
- The minimiser is regularised towards the edge's midpoint (`1e-6` of the quadric's trace)
  for the directions a quadric leaves free, and compared with both end spheres and the
  midpoint; spheres of negative radius are never chosen.
- The stability ratio saturates: `min(1, s / stable)` with `stable = 0.3`. A sheet running
  into a sharp 90° edge shrinks at `|Δr| = L sin 45°`, so Q-MAT's `s = 1 − sin 45° ≈ 0.29`
  discounted its collapses 12× as if it were a spike, and the sheets reaching a box's edges
  went first; saturated, only nearly nested spheres (`s` well below 0.3: spikes) are
  discounted, and by less. Measured in benchmarks/README.md (box 3.6 → 2.9 % at 200 spheres
  before the fit of `refine`).
- Late in the collapses (from `min(late × target, below)` spheres down: 4 × the target,
  at most 200), an edge's cost also counts `hausdorff (H / scale)²`, `H` the farthest that
  a contact sample of its two spheres would lie outside what remains around them (the
  merged sphere, its cones to both spheres' neighbours, the slabs of their faces;
  `_uncovered`). The quadric error is a mean over the contacts, blind to the single worst
  point that the Hausdorff distance measures: without this term the capped bunny's thin,
  flat left ear collapsed into a chain of cones at 50 spheres (2.12 % of the diagonal both
  ways after the fit, 1.80 % / 1.45 % with it). Earlier, the term weighed on the 200-sphere
  meshes too (from 800 spheres down) and took the bunny at 200 from 0.95 to 1.32 % (1.06 %
  at a tenth of the weight): hence `below`. Every second sample is used (`sparse`): all of
  them took the bunny's collapses from 4.9 to 9.8 s for 1.65 % / 1.69 %; every fourth lost
  the gain (2.13 % / 1.73 %).
- Collapses run in batches: in each round, the edges that are among the cheapest `batch`
  fraction of all edges and the cheapest at both of their spheres (an independent set) are
  collapsed together, never more than needed. This replaces Q-MAT's priority queue (Python
  would be too slow for it on 10⁵ spheres) and keeps its order closely: a batch is a part of
  the head of the queue with no two collapses touching the same sphere.
"""

from __future__ import annotations

import functools

import numpy as np

from .connect import components, distinct, unique_rows
from .primitives import _Cones, _Slabs
from .rows import norm, sorted_order, sorted_rows


def contact_quadrics(axis, slide: float = 1.0):
    """Quadrics `(A (n, 4, 4), b (n, 4), c (n,))` of the contacts of an `InitialAxis`.

    Per contact `(p, n)` with weight `w`: the tangent-plane term `w (n·p − n·c − r)²` (Q-MAT)
    plus `slide · w |c + r n − p|²`, the squared distance from the sample to the point where
    the sphere would touch a plane of normal `n` (our own addition). A plane alone is
    infinite: every sphere on the bisector of two faces of a box is tangent to both, so a
    whole sheet running into a sharp edge would collapse into its root at no cost; the
    second term keeps contacts near where the sphere touches.
    """
    # (A numba loop, `quadric_loops`: NumPy's einsums' sums, bit for bit, 30× faster.)
    from .quadric_loops import contact_quadrics as sums

    return sums(np.ascontiguousarray(axis.normals, np.float64),
                np.ascontiguousarray(axis.points, np.float64),
                np.ascontiguousarray(axis.weights, np.float64),
                np.ascontiguousarray(axis.contacts, np.int64), float(slide))


def _error(A, b, c, m):
    return np.einsum("ij,ijk,ik->i", m, A, m) + 2 * np.einsum("ij,ij->i", b, m) + c


def _edge_costs(spheres, A, b, c, edges, k, length_weight, scale, stable, hausdorff=0.0,
                uncovered=None):
    # (Numba loops, `quadric_loops`: the quadrics summed and the options priced in one pass.)
    from .quadric_loops import cheapest, edge_systems

    # The minimiser regularised towards the midpoint by `eps = 1e-6 trace(A) / 4`: the
    # system `(A + eps I) m = eps mid − b`, made in the sums' loop (as NumPy passes over
    # (e, 4, 4) arrays, the costs took twice as long on spot).
    i, j = np.ascontiguousarray(edges[:, 0]), np.ascontiguousarray(edges[:, 1])
    reg, rhs, length, dr = edge_systems(spheres, A, b, i, j)
    best = np.linalg.solve(reg, rhs[..., None])[..., 0]
    # The cheapest of the four options (`_error`, a negative radius never chosen).
    error, chosen = cheapest(spheres, A, b, c, i, j, best)
    stability = np.clip((length - dr) / np.where(length > 0, length, 1.0), 0, 1)
    # Saturated: ratios above `stable` count as 1 (see the module's notes).
    stability = np.minimum(stability / stable, 1.0) if stable > 0 else stability
    cost = error / scale**2 + k + length_weight * (length / scale) ** 2
    if uncovered is not None:  # see `simplify`'s `hausdorff`
        cost = cost + hausdorff * (uncovered(edges, chosen) / scale) ** 2
    return cost * stability**2, chosen


def _groups(labels, n):
    """Start offsets `(n + 1,)` of the groups of sorted `labels` in `[0, n)` (a CSR index)."""
    return np.searchsorted(labels, np.arange(n + 1))


def _gather(start, ids):
    """Positions in a CSR array of the members of groups `ids (m,)`, and for each its row in
    `ids`: `(rows (M,), positions (M,))`."""
    count = start[ids + 1] - start[ids]
    rows = np.repeat(np.arange(len(ids)), count)
    first = np.repeat(start[ids] - np.cumsum(count) + count, count)
    return rows, first + np.arange(len(rows))


def _pairs_by_row(rows_a, rows_b, m):
    """Every `(a, b)` index pair with `rows_a[a] == rows_b[b]`, both sorted by row `< m`."""
    return _gather(_groups(rows_b, m), rows_a)


BUDGET = 500_000  # about the most (sample, cone or slab) pairs `_uncovered` takes at once

TOP = 8  # samples of each edge measured exactly first by `_uncovered` (see there)


def _uncovered(spheres, edges, faces, pairs, optimum, samples, points):
    """The farthest that a contact sample of an edge's two spheres lies outside what would
    remain around them after collapsing it: `(e,)`, for edges `pairs (e, 2)` whose merged
    sphere is `optimum (e, 4)`. `samples = (start (n + 1,), ids)`: each sphere's contact
    samples in `points`. What remains: the merged sphere, its cones to the neighbours of
    both spheres, and the slabs (with their outer edges) of their faces.

    The edges are taken in blocks of about `BUDGET` (sample, primitive) pairs (one edge
    may exceed it alone): all at once, a sphere-like shape's spheres, each with thousands of
    samples and dozens of neighbours, took 2.5–6.6 GB (issue 30)."""
    n = len(spheres)
    start = samples[0]
    count = np.diff(start)
    around = np.bincount(edges.reshape(-1), minlength=n) + np.bincount(faces.reshape(-1),
                                                                         minlength=n) + 1
    size = np.cumsum(count[pairs].sum(1) * around[pairs].sum(1))
    cuts = np.searchsorted(size, np.arange(1, int(size[-1] // BUDGET) + 2) * BUDGET) \
        if len(size) else np.zeros(0, np.int64)
    cuts = np.unique(np.r_[0, np.maximum(cuts, 1), len(pairs)].clip(0, len(pairs)))
    return np.concatenate([np.zeros(0)] + [
        _uncovered_block(spheres, edges, faces, pairs[a:b], optimum[a:b], samples, points)
        for a, b in zip(cuts[:-1], cuts[1:]) if b > a])


def _uncovered_block(spheres, edges, faces, pairs, optimum, samples, points):
    """`_uncovered` for one block of edges."""
    n, m = len(spheres), len(pairs)
    both = np.concatenate([edges, edges[:, ::-1]])
    both = both[np.argsort(both[:, 0], kind="stable")]
    nbr_start = _groups(both[:, 0], n)
    face_of = np.repeat(np.arange(len(faces)), 3)
    corner = faces.reshape(-1)
    order = np.argsort(corner, kind="stable")
    face_of, face_start = face_of[order], _groups(corner[order], n)

    def of_both(start, data):  # rows (ascending) and data of the members of both spheres
        rows, pos = _gather(start, pairs.reshape(-1))
        return rows // 2, data[pos]

    p_row, p_id = of_both(samples[0], samples[1])
    c_row, nbr = of_both(nbr_start, both[:, 1])
    keep = (nbr != pairs[c_row, 0]) & (nbr != pairs[c_row, 1])
    # Cones from the merged sphere; the sphere itself as a cone to itself (degree 0).
    c_row = np.concatenate([c_row[keep], np.arange(m)])
    c_row, order = np.sort(c_row, kind="stable"), np.argsort(c_row, kind="stable")
    ends = np.concatenate([spheres[nbr[keep]], optimum])[order]
    f_row, face = of_both(face_start, face_of)
    tri = faces[face]
    outer = (tri != pairs[f_row, :1]) & (tri != pairs[f_row, 1:])
    keep = outer.sum(axis=1) == 2  # faces with both spheres become cones: already there
    f_row, tri, outer = f_row[keep], tri[keep], outer[keep]
    rest = tri[outer].reshape(-1, 2)

    # Only samples outside the merged sphere can be uncovered (most of the pairs' cost).
    centre = optimum[p_row]
    best = norm(points[p_id] - centre[:, :3]) - centre[:, 3]
    out = np.flatnonzero(best > 0)
    p_row, p_id, best = p_row[out], p_id[out], best[out]
    cones = _Cones(optimum[c_row, :3], optimum[c_row, 3], ends[:, :3], ends[:, 3])
    if len(f_row):
        s1, s2, merged = spheres[rest[:, 0]], spheres[rest[:, 1]], optimum[f_row]
        slabs = _Slabs(merged[:, :3], merged[:, 3], s1[:, :3], s1[:, 3], s2[:, :3], s2[:, 3])
        sides = _Cones(s1[:, :3], s1[:, 3], s2[:, :3], s2[:, 3])

    def exact(sub):
        """The distances `(len(sub),)` of the samples `sub` (positions among the outside
        ones) to what remains: cones, then slabs for those the cones leave outside."""
        value = best[sub].copy()
        a, k = _pairs_by_row(p_row[sub], c_row, m)
        np.minimum.at(value, a, cones.distance(points[p_id[sub[a]]], k))
        if len(f_row):
            left = np.flatnonzero(value > 0)
            a, k = _pairs_by_row(p_row[sub[left]], f_row, m)
            q = points[p_id[sub[left[a]]]]
            np.minimum.at(value, left[a], np.minimum(slabs.distance(q, k), sides.distance(q, k)))
        return value

    # The worst sample only counts: an upper bound of each sample's distance (the nearest
    # sphere at the far ends of the cones, which the cones contain) ranks them; the
    # `TOP` highest of each edge are measured exactly, and then only the samples whose
    # bound exceeds the worst found. The others cannot raise it, so the result is that of
    # measuring every sample (a sphere-like shape's samples, thousands per sphere, each
    # against dozens of cones, took 2.5–6.6 GB and minutes; issue 30).
    # (`a` ascends and every sample has a cone, the merged sphere's own: a reduction by
    # sample, not `np.minimum.at`, from its points gathered once: 3× faster on a sphere.)
    a, k = _pairs_by_row(p_row, c_row, m)
    far = points[p_id][a] - ends[k, :3]
    first = np.searchsorted(a, np.arange(len(best)))
    bound = np.minimum(best, np.minimum.reduceat(np.sqrt(np.einsum("ij,ij->i", far, far))
                                                 - ends[k, 3], first)) if len(a) else best
    order = np.lexsort((-bound, p_row))
    rank = np.arange(len(order)) - np.searchsorted(p_row[order], p_row[order])
    top = np.sort(order[rank < TOP])
    worst = np.zeros(m)
    np.maximum.at(worst, p_row[top], np.maximum(exact(top), 0.0))
    # (A hair below the worst: the bound and the exact value round alike where they tie.)
    rest_ = np.setdiff1d(np.flatnonzero(bound > worst[p_row] * (1 - 1e-9)), top,
                         assume_unique=True)
    if len(rest_):
        np.maximum.at(worst, p_row[rest_], np.maximum(exact(rest_), 0.0))
    return worst


def _star_optimum(current, A, b, c):
    """Sphere minimising a summed quadric, regularised towards the `current` sphere (kept
    when it is better or the optimum has a negative radius)."""
    eps = 1e-6 * np.trace(A, axis1=1, axis2=2) / 4 + 1e-300
    best = np.linalg.solve(A + eps[:, None, None] * np.eye(4),
                           (eps[:, None] * current - b)[..., None])[..., 0]
    better = (best[:, 3] >= 0) & (_error(A, b, c, best) <= _error(A, b, c, current))
    return np.where(better[:, None], best, current)


def simplify(centers, radii, edges, faces, quadrics, target: int, *, scale: float,
             k: float = 1e-8, length_weight: float = 1e-5, batch: float = 0.1,
             stable: float = 0.3, contacts=None, hausdorff: float = 10.0, late: float = 4.0,
             below: int = 200, sparse: int = 2, progress=None):
    """Collapses edges of a medial mesh until `target` spheres remain (or no edge does).

    **Arguments:** `centers (n, 3)`, `radii (n,)`, `edges (e, 2)`, `faces (f, 3)`,
    `quadrics = (A (n, 4, 4), b (n, 4), c (n,))` with weights summing to about 1; `target`
    spheres; `scale`: the mesh's bounding-box diagonal (errors and lengths are measured in
    it); `k`: Q-MAT's constant; `length_weight`: the tie-breaking weight of the squared edge
    length; `batch`: largest fraction of the spheres collapsed per round; `stable`: the
    stability ratio from which an edge counts as fully stable (0: Q-MAT's ratio);
    `contacts = (points (s, 3), ids (n, k))`: the surface samples and each sphere's contact
    samples, for `hausdorff`, the weight of the worst uncovered contact sample in the cost
    from `min(late × target, below)` spheres down (0 or no `contacts`: none; see the module's
    notes), counted on every `sparse`-th sample; `progress`: a tqdm bar (or None), advanced
    per collapse.

    **Returns:** `(centers, radii, edges, faces)` of the simplified mesh.
    """
    from .quadric_loops import renumbered_edges  # (numba's import where it is used)

    spheres = np.concatenate([centers, radii[:, None]], axis=1)
    A, b, c = (x.copy() for x in quadrics)
    edges, faces = np.asarray(edges, np.int64), np.asarray(faces, np.int64).reshape(-1, 3)
    # The faces are carried by `member`, not renumbered round by round: only the late
    # collapses and the result need them (a tenth of spot's collapses went to renumbering
    # and deduplicating them every round; the same faces, in the same order).
    initial_faces = faces
    cost = np.full(len(edges), np.nan)
    optimum = np.zeros((len(edges), 4))
    member = np.arange(len(spheres))  # the sphere each initial sphere has gone into
    # The pieces of the graph: a collapse merges two spheres of one piece, so they never
    # split or join, and the labels are found once (not once per round).
    piece = components(len(spheres), edges)[1]
    late_phase = False
    while len(spheres) > target and len(edges):
        n = len(spheres)
        uncovered = None
        if hausdorff and contacts is not None and n <= min(late * target, below):
            if not late_phase:  # every cost is stale for the new term
                late_phase, cost = True, np.full(len(edges), np.nan)
            points, initial = contacts
            # Each sphere's contact samples: those of the initial spheres gone into it (every
            # `sparse`-th sample only: enough for the worst one, at a fraction of the cost).
            key = distinct(member[:, None] * len(points) + initial)
            key = key[key % len(points) % sparse == 0]
            samples = (_groups(key // len(points), n), key % len(points))
            faces = _merged_faces(initial_faces, member, n)
            uncovered = functools.partial(_uncovered, spheres, edges, faces, samples=samples,
                                          points=points)
        # Only edges next to a collapse need new costs (NaN); the others keep theirs.
        stale = np.flatnonzero(np.isnan(cost))
        if len(stale):
            cost[stale], optimum[stale] = _edge_costs(spheres, A, b, c,
                                                      np.take(edges, stale, axis=0), k,
                                                      length_weight, scale, stable, hausdorff,
                                                      uncovered)
        # No collapse leaves a piece of the graph with one sphere (in no edge): the edges of
        # two-sphere pieces are out of the queue, and a piece of `s` spheres loses at most
        # `s - 2` in a round (below).
        spare = np.bincount(piece, minlength=n) - 2
        queued = np.where(spare[piece[edges[:, 0]]] > 0, cost, np.inf)
        # The head of the queue: the `limit` cheapest edges, in order of cost.
        limit = min(n - target, max(1, int(batch * n)))
        head = np.argpartition(queued, limit - 1)[:limit] if limit < len(cost) else \
            np.arange(len(cost))
        head = head[np.argsort(queued[head], kind="stable")]
        head = head[np.isfinite(queued[head])]
        if not len(head):
            break
        # Each collapse drops its smaller sphere into the other. A sphere is dropped by its
        # cheapest head edge only, and a sphere that is dropped keeps nothing: the collapses
        # of a round form stars (spikes around one hub all go in one round).
        e = edges[head]
        small_first = spheres[e[:, 0], 3] <= spheres[e[:, 1], 3]
        drop = np.where(small_first, e[:, 0], e[:, 1])
        keep = np.where(small_first, e[:, 1], e[:, 0])
        # (`np.unique(drop, return_index=True)` and `~np.isin(keep, drop)`: the same
        # arrays, without a stable sort of the drops in no order or a sort for `isin`.)
        drop, first = sorted_order(drop, n)  # (`head` is not empty)
        new = np.r_[True, drop[1:] != drop[:-1]]
        drop, first = drop[new], first[new]
        chosen, keep = head[first], keep[first]
        dropped = np.zeros(n, dtype=bool)
        dropped[drop] = True
        ok = ~dropped[keep]
        chosen, keep, drop = chosen[ok], keep[ok], drop[ok]
        # Within each piece, the cheapest `spare` drops only.
        order = np.lexsort((cost[chosen], piece[drop]))
        rank = np.arange(len(order)) - np.searchsorted(piece[drop][order], piece[drop][order])
        ok = np.sort(order[rank < spare[piece[drop][order]]])
        chosen, keep, drop = chosen[ok], keep[ok], drop[ok]
        count = np.bincount(keep, minlength=n)  # (each hub's collapses: no sort)
        single = count[keep] == 1
        spheres[keep[single]] = optimum[chosen[single]]
        np.add.at(A, keep, np.take(A, drop, axis=0))
        np.add.at(b, keep, np.take(b, drop, axis=0))
        np.add.at(c, keep, c[drop])
        stars = np.flatnonzero(count > 1)
        if len(stars):
            spheres[stars] = _star_optimum(spheres[stars], A[stars], b[stars], c[stars])
        # Renumber: dropped spheres become their partners, then the survivors are compacted.
        target_of = np.arange(n)
        target_of[drop] = keep
        alive = np.ones(n, dtype=bool)
        alive[drop] = False
        changed = np.zeros(n, dtype=bool)
        changed[keep] = True
        relabel = (np.cumsum(alive) - 1)[target_of]
        member = relabel[member]
        survivors = np.flatnonzero(alive)  # (positions and `np.take`: see `_edge_costs`)
        spheres, A, b, c, piece = (np.take(x, survivors, axis=0)
                                   for x in (spheres, A, b, c, piece))
        # The edges renumbered and keyed in one compiled loop (`quadric_loops`; as NumPy's
        # gathers, `sorted_rows` and masks over all edges, a quarter of the collapses), then
        # each distinct row once at its first position, by key: `np.unique`'s stable sort.
        m = len(spheres)
        edges, touched, live, key = renumbered_edges(edges, relabel, changed, alive, m)
        order = np.argsort(key, kind="stable")
        key = key.take(order)
        first = live.take(order[np.r_[True, key[1:] != key[:-1]]]) if len(key) else live
        edges, cost, optimum = (np.take(x, first, axis=0) for x in (edges, cost, optimum))
        cost[touched[first]] = np.nan
        if progress is not None:
            progress.update(len(chosen))
    order = np.lexsort(edges.T[::-1])
    return (spheres[:, :3], spheres[:, 3], edges[order],
            _merged_faces(initial_faces, member, len(spheres)))


def _merged_faces(faces, member, n: int):
    """The faces `(f, 3)` once the collapses have taken each initial sphere into `member`
    (`(n0,)`, indices below `n`): those still on three spheres, each once, sorted within
    and across rows (as renumbering them after every collapse and dropping the repeats and
    the degenerate ones gives: a face on two spheres stays on two)."""
    faces = sorted_rows(member[faces])
    live = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])
    return unique_rows(faces[live], n)


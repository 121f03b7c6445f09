"""The fit's candidate (sample, primitive) pairs: found, pruned, and read for the closest.

A sample's distance to a medial mesh's union is that of its closest primitive, and moving
every sphere by at most `δ` (centre plus radius) changes every primitive's distance by at
most `δ` (`refine`'s notes). So the fit searches, now and then, for the pairs within
`2 margin` of each sample's best (`search`), valid while no sphere moves more than `margin`
from where they were found (the *anchor*), and evaluates only those.

Both steps cost in proportion to their pairs (millions: spot at 200 spheres searches 3.1M
and keeps 1.2M, for 25,000 samples), so each does less than all of them:

- the search tests the primitives' bounding spheres against all samples in blocks of
  `BUDGET` (sample, primitive) pairs, a matrix product and a comparison, instead of a k-d
  tree's ball queries, whose Python lists of millions of integers were most of its time;
- an evaluation at spheres moved by `Δ_k` from the anchor (`prune`) skips the pairs that
  cannot attain a sample's best: a pair's distance is now at least its distance at the
  anchor minus the largest `Δ_k` of its spheres, and a cone's (or lone sphere's) at most
  that plus it, so a pair whose lower bound exceeds the least upper bound of its sample's
  cones is never the closest (a slab's closed form is `inf` where its foot leaves the
  triangle, so slabs give lower bounds only). The pairs kept keep their order, so the
  closest pair chosen, and every distance, are those of all the candidates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .primitives import UnionPrimitives

BUDGET = 1 << 19  # (sample, primitive) distances that `ball_pairs` computes at once


def ball_pairs(points, centre, radius, extra=None):
    """Every pair `(pts, prim)` with `|points[pts] − centre[prim]| <= radius[prim]` (plus
    `extra[pts]` when given), the primitives ascending (and the samples ascending within
    each), for `points (N, 3)`, `centre (P, 3)`, `radius (P,)`, `extra (N,)` (see
    `ball_blocks`)."""
    blocks = list(ball_blocks(points, centre, radius, extra))
    return tuple(np.concatenate([np.zeros(0, np.int64)] + [block[k] for block in blocks])
                 for k in range(2))


PAD = 2e-6  # the round-off allowance of `ball_blocks`'s float32 test, relative (see there)


def ball_blocks(points, centre, radius, extra=None):
    """`ball_pairs` in blocks of about `BUDGET` tested pairs (a few MB: they stay in the
    cache), primitives ascending from block to block. With `extra`, a block may also hold
    pairs beyond `radius + extra` where that sum is negative, and pairs whose squared
    distance exceeds `(radius + extra)²` by up to `PAD K` (`K`: see `float32_pad`): a
    superset, never fewer."""
    origin = points.mean(axis=0) if len(points) else np.zeros(3)
    p, c = points - origin, centre - origin  # near the origin: little cancellation below
    pp = np.einsum("ij,ij->i", p, p)
    minus_2p = np.ascontiguousarray(-2 * p.T)
    limit = radius**2 - np.einsum("ij,ij->i", c, c)
    if extra is not None:
        # A superset serves (the search measures every pair it gets): the squares in
        # float32, half the bytes of each pass of this memory-bound test (3× faster), their
        # round-off covered by a pad on the limit.
        limit = (limit + float32_pad(p, c, radius, extra)).astype(np.float32)
        pp, minus_2p, c, radius, extra = (x.astype(np.float32) for x in (pp, minus_2p, c,
                                                                         radius, extra))
    rows = max(1, BUDGET // max(len(p), 1))
    for start in range(0, len(c), rows):
        # |p − c|² <= r²  ⇔  |p|² − 2 c·p <= r² − |c|², by coordinates: a matrix product
        # with 3 columns gains nothing from BLAS, whose threads slowed it on a busy machine.
        block = c[start:start + rows]
        square = block[:, :1] * minus_2p[0]
        square += block[:, 1:2] * minus_2p[1]
        square += block[:, 2:] * minus_2p[2]
        if extra is None:
            square += pp
        else:
            # |p − c| <= r + e  ⇐  |p|² − e² − 2 c·p − 2 r e <= r² − |c|² where r + e >= 0:
            # one more term per pair. `e` is raised to −r of the block's smallest `r`, so that
            # the squares do not admit points far inside a small primitive (a superset).
            e = np.maximum(extra, -radius[start:start + rows].min())
            square += radius[start:start + rows, None] * (-2 * e)
            square += pp - e * e
        prim, pts = np.divmod(np.flatnonzero(square <= limit[start:start + rows, None]),
                              len(p))
        yield pts, prim + start


def float32_pad(p, c, radius, extra) -> float:
    """The pad `PAD K` on the squares of `ball_blocks`'s float32 test, `K = (A + B)² +
    (R + E)²` for the largest `|p|` (A), `|c|` (B), radius (R) and `|e|` (E, `e` the
    extra margin, at least −R): every term of the test and of its partial sums is below `K`,
    and a dozen float32 roundings (2⁻²⁴ each, relative) of such terms stay below `PAD K`."""
    if not len(p) or not len(c):
        return 0.0
    a = np.sqrt(np.einsum("ij,ij->i", p, p).max())
    b = np.sqrt(np.einsum("ij,ij->i", c, c).max())
    r = float(np.abs(radius).max())
    # (Over the finite margins: one NaN would take every pair out, not just its point's.)
    e = max(float(np.abs(extra[np.isfinite(extra)]).max(initial=0.0)), r)
    return PAD * ((a + b) ** 2 + (r + e) ** 2)


PAIRS = 4_000_000  # the most candidate pairs `search` keeps (about 100 MB; see there)


@dataclass
class Candidates:
    """Candidate pairs `pts (M,)`, `prim (M,)` (primitives ascending), their distances
    `value (M,)` at the spheres `anchor (n, 4)` where they were found, valid while no sphere
    moves by more than `margin` from there."""

    pts: np.ndarray
    prim: np.ndarray
    value: np.ndarray
    anchor: np.ndarray
    margin: float


def search(points, union: UnionPrimitives, params, margin: float,
           upper=None) -> Candidates:
    """The pairs within `2 margin` of each sample's smallest distance to the `union` of
    the spheres `params (n, 4)`, given `upper (N,)`: an upper bound of each sample's
    distance to the union (by default, from its nearest sphere centres: `upper_bound`). Only
    the primitives whose bounding sphere comes within `upper + 2 margin` of a sample can be
    in its band, so only those are evaluated: the closer the bound, the fewer (a point deep
    inside tests only the primitives around it).

    At most about `PAIRS` pairs are kept: beyond, the margin is narrowed until they fit
    (down to an eighth; the fit's steps shorten with it). On a sphere nearly every
    primitive lies within `2 margin` of every sample (9.2M pairs, 358 a sample, at 100
    spheres: 1.4 GB and 42 s for the fit); on spot at 200 spheres they are 1.2M."""
    if upper is None:
        upper = upper_bound(points, union)
    best = np.full(len(points), np.inf)
    found_pts, found_prim, found_val = [], [], []
    floor, held = margin / 8, 0
    blocks = ball_blocks(points, union.centre, union.radius, upper + 2 * margin)
    for pts, prim, value in _measured(blocks, points, union):
        np.minimum.at(best, pts, value)
        # Only the pairs within the band of the best so far (a superset of the final band):
        # on a sphere, all pairs at once took 1.5 GB.
        # (Positions and `take`, not a boolean mask per array: 5× faster, the same pairs.)
        near = np.flatnonzero(value <= best[pts] + 2 * margin)
        pts, prim, value = pts.take(near), prim.take(near), value.take(near)
        found_pts.append(pts), found_prim.append(prim), found_val.append(value)
        held += len(pts)
        if held > 2 * PAIRS and margin > floor:  # narrowed early: memory stays capped
            pts, prim, value = (np.concatenate(x) for x in (found_pts, found_prim, found_val))
            margin = _narrowed(value - best[pts], margin, floor)
            near = value <= best[pts] + 2 * margin
            found_pts, found_prim, found_val = [pts[near]], [prim[near]], [value[near]]
            held = near.sum()
    pts, prim, value = (np.concatenate(x) for x in (found_pts, found_prim, found_val))
    gap = value - best[pts]
    keep = np.flatnonzero(gap <= 2 * margin)
    if len(keep) > PAIRS:
        margin = _narrowed(gap[keep], margin, floor)
        keep = keep[gap[keep] <= 2 * margin]
    return Candidates(pts.take(keep), prim.take(keep), value.take(keep), params, margin)


MEASURED = 1 << 18  # about the pairs whose distances `_measured` takes at once


def _measured(blocks, points, union: UnionPrimitives):
    """The blocks `(pts, prim)` of `ball_blocks`, each with its pairs' distances to the
    `union` `(pts, prim, value)`: measured over several blocks at once (about `MEASURED`
    pairs; the same values): one block's pairs fill its last `in_blocks` part only partly,
    and measured block by block, spot's eight searches took 1.89 s instead of 1.51 s."""
    batch, size = [], 0
    for block in blocks:
        batch.append(block)
        size += len(block[0])
        if size >= MEASURED:
            yield from _split(batch, points, union)
            batch, size = [], 0
    yield from _split(batch, points, union)


def _split(batch, points, union: UnionPrimitives):
    """The blocks of `batch` with their distances, measured at once (see `_measured`)."""
    if not batch:
        return
    value = union.distance(points, *(np.concatenate(x) for x in zip(*batch)))
    cuts = np.cumsum([len(pts) for pts, _ in batch])[:-1]
    for (pts, prim), part in zip(batch, np.split(value, cuts)):
        yield pts, prim, part


def upper_bound(points, union: UnionPrimitives, neighbours: int = 8):
    """An upper bound `(N,)` of the distance of `points (N, 3)` to the `union`: the least
    `|p − c| − r` over the spheres of its `neighbours` nearest centres (every sphere is part
    of the union, alone or as the end of a cone)."""
    k = min(neighbours, len(union.centers))
    distance, index = cKDTree(union.centers).query(points, k=k)
    distance, index = distance.reshape(len(points), k), index.reshape(len(points), k)
    return (distance - union.radii[index]).min(axis=1)


def _narrowed(gap, margin: float, floor: float) -> float:
    """The margin, at most `margin` and at least `floor`, that keeps about `PAIRS` of the
    pairs at `gap` (M,) above their samples' best within twice it."""
    gap = gap[gap <= 2 * margin]
    if len(gap) <= PAIRS:
        return margin
    return min(margin, max(float(np.partition(gap, PAIRS)[PAIRS]) / 2 * (1 - 1e-9), floor))


def _primitive_moves(union: UnionPrimitives, moved):
    """The largest move `(P,)` of the spheres of each primitive, from the spheres'
    `moved (n,)`."""
    out = np.empty(len(union.kind))
    for kind, spheres in ((0, None), (1, union.edges), (2, union.faces)):
        sel = union.kind == kind
        index = union.index[sel]
        out[sel] = moved[index] if spheres is None else moved[spheres[index]].max(axis=1)
    return out


def prune(candidates: Candidates, union: UnionPrimitives, params, n_points: int,
          tolerance: float, upper=None):
    """`(pts, prim)`: the candidates that may attain a sample's distance to the `union` of
    the spheres `params (n, 4)` (see the module's notes; `tolerance` absorbs round-off).
    `upper (N,)`: known upper bounds of the samples' distances (e.g. the sphere that
    attained a sample's distance at spheres near `params`, interpolated at `params`: on
    spot at 200 spheres it keeps 0.35M pairs a step after a search where the cones' bounds
    alone kept 0.55M; the same pairs attain, so the same result)."""
    moved = np.linalg.norm(params[:, :3] - candidates.anchor[:, :3], axis=1) + np.abs(
        params[:, 3] - candidates.anchor[:, 3])
    pts, prim, value = candidates.pts, candidates.prim, candidates.value
    change = _primitive_moves(union, moved)[prim]
    upper = np.full(n_points, np.inf) if upper is None else upper.copy()
    # The spheres and cones: the pairs before the first slab's (the primitives ascend, kinds
    # in order), a slice rather than a selection (the same pairs, no copies).
    solid = np.searchsorted(prim, np.searchsorted(union.kind, 2))
    np.minimum.at(upper, pts[:solid], value[:solid] + change[:solid])
    keep = np.flatnonzero(value - change <= upper[pts] + tolerance)
    return pts.take(keep), prim.take(keep)


def closest(points, pts, prim, union: UnionPrimitives):
    """Each sample's distance to the union `(N,)`, and its closest primitive's spheres and
    weights `(N, 3)`, from candidate pairs (every sample has one)."""
    value = union.distance(points, pts, prim)
    best = np.full(len(points), np.inf)
    np.minimum.at(best, pts, value)
    # One attaining pair per sample: of several, the last in the pairs' order (NumPy's
    # assignment with repeated indices keeps the last write), i.e. the one of the largest
    # primitive (a sample meets a primitive in at most one pair, or in equal duplicates),
    # whatever the order of the samples within a primitive.
    hit = np.flatnonzero(value == best[pts])
    pick = np.empty(len(points), dtype=np.int64)
    pick[pts[hit]] = hit
    # Spheres and weights of the attaining pairs only (evaluated again: cheaper than filling
    # them for every pair). `pick` follows the pairs' order, so its primitives ascend.
    pick.sort()
    _, spheres, weights = union.closest(points, pts[pick], prim[pick])
    order = np.empty(len(points), dtype=np.int64)
    order[pts[pick]] = np.arange(len(points))
    return best, spheres[order], weights[order]

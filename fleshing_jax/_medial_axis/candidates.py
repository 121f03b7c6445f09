"""The fit's candidate (sample, primitive) pairs: found, pruned, and read for the closest.

A sample's distance to a medial mesh's union is that of its closest primitive, and moving
every sphere by at most `δ` (centre plus radius) changes every primitive's distance by at
most `δ` (`refine`'s notes). So the fit searches, now and then, for the pairs within
`2 margin` of each sample's best (`search`), valid while no sphere moves more than `margin`
from where they were found (the *anchor*), and evaluates only those.

Both steps cost in proportion to their pairs (millions: spot at 200 spheres searches 3.1M
and keeps 1.2M, for 25,000 samples), so each does less than all of them:

- the search tests the primitives' bounding spheres against tiles of nearby samples, then
  against the samples of the tiles they reach (`ball_blocks`), instead of a k-d tree's
  ball queries, whose Python lists of millions of integers were most of its time; a slab
  skips the tiles where no sample's foot falls in its triangle (its distance `inf`, never
  in the band: `UnionPrimitives.in_tiles`), two thirds of its pairs on spot;
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

from .pairs import (
    attaining,
    attaining_spheres,
    in_band_count,
    in_band_into,
    lowered_band,
    near_tiles,
    pruned,
    tile_pairs,
)
from .primitives import UnionPrimitives
from .rows import norm

BUDGET = 1 << 19  # (sample, primitive) pairs a block of `ball_blocks` spans


def ball_pairs(points, centre, radius, extra=None):
    """Every pair `(pts, prim)` with `|points[pts] − centre[prim]| <= radius[prim]` (plus
    `extra[pts]` when given), the primitives ascending, for `points (N, 3)`, `centre
    (P, 3)`, `radius (P,)`, `extra (N,)` (see `ball_blocks`)."""
    blocks = list(ball_blocks(points, centre, radius, extra))
    return tuple(np.concatenate([np.zeros(0, np.int64)] + [block[k] for block in blocks])
                 for k in range(2))


TILE = 32  # samples per tile of `ball_blocks` (consecutive in a spatial order; 2^k)

SLACK = 1e-5  # `ball_blocks`'s allowance on the reach, relative to the points' extent


def ball_blocks(points, centre, radius, extra=None, boxes=None):
    """`ball_pairs` in blocks of about `BUDGET // N` primitives, primitives ascending (the
    samples within a primitive in no particular order). A block may also hold pairs up to
    `SLACK` (relative to the extent of the points and centres) beyond the reach: a
    superset, never fewer.

    The samples are grouped in tiles of `TILE`, consecutive in a spatial (Morton) order,
    and each primitive tests only the samples of the tiles that its bounding sphere
    reaches: on spot at 200 spheres 5.5M of the 24M (sample, primitive) pairs. The test in
    float32 (half the bytes of each pass), its round-off (about 1e-7 of the extent, in
    the coordinates relative to their mean) well within `SLACK`. `boxes(near, low, high,
    origin)` (e.g. `UnionPrimitives.in_tiles`) may clear more of the primitives' tiles
    `near (P, tiles)`, given the tiles' boxes `low + origin` to `high + origin`."""
    n, tiles = len(points), -(-len(points) // TILE)
    extra = np.zeros(n) if extra is None else extra
    rows = max(1, BUDGET // max(n, 1))
    origin = points.mean(axis=0) if n else np.zeros(3)
    p, c = points - origin, centre - origin
    slack = SLACK * max(float(np.abs(p).max(initial=0.0)), float(np.abs(c).max(initial=0.0)))
    # Coordinates and margins by tile `(tiles, TILE)`, the last tile padded with NaN (no
    # pair: every comparison with NaN fails).
    order = _spatial_order(p)
    padded = np.full((4, tiles * TILE), np.nan)
    padded[:3, :n], padded[3, :n] = p.take(order, axis=0).T, extra.take(order)
    padded = padded.reshape(4, tiles, TILE)
    if not n:  # (no tiles: nothing to reduce)
        padded = np.zeros((4, 0, TILE))
    # A primitive farther from a tile's bounding box than its radius plus the tile's
    # largest margin (its NaNs left out: `fmax`) takes none of its samples.
    low, high = np.nanmin(padded[:3], axis=2), np.nanmax(padded[:3], axis=2)  # (3, tiles)
    largest = np.fmax.reduce(padded[3], axis=1)
    near = near_tiles(c, low, high, (radius, largest + 2 * slack))  # (P, tiles), compiled
    if boxes is not None:
        boxes(near, low, high, origin)
    lanes = tuple(np.ascontiguousarray(x) for x in padded.astype(np.float32))
    c, radius = c.astype(np.float32), (radius + slack).astype(np.float32)
    for start in range(0, len(centre), rows):  # (a compiled loop: primitives ascending)
        yield tile_pairs(near, start, min(start + rows, len(centre)), lanes, c, radius, order)


def _spread_bits(bits: int):
    """`(2^bits,)`: each integer's bits spread three apart (bit `k` to bit `3k`)."""
    value, out = np.arange(1 << bits), np.zeros(1 << bits, np.int64)
    for bit in range(bits):
        out |= ((value >> bit) & 1) << (3 * bit)
    return out


_SPREAD = _spread_bits(10)


def _spatial_order(points):
    """A permutation `(N,)` of `points (N, 3)` in Morton order on a 1024³ grid over their
    box: consecutive points lie close together (tiles)."""
    if not len(points):
        return np.zeros(0, np.int64)
    low = points.min(axis=0)
    span = max(float(np.ptp(points, axis=0).max()), 1e-300)
    cell = np.minimum(((points - low) * (1024 / span)).astype(np.int64), 1023)
    return np.argsort(_SPREAD[cell[:, 0]] | (_SPREAD[cell[:, 1]] << 1)
                      | (_SPREAD[cell[:, 2]] << 2), kind="stable")


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
    # (Without the tiles where no sample has a slab's foot in its triangle: that slab's
    # distance is `inf` there, never in the band.)
    blocks = ball_blocks(points, union.centre, union.radius, upper + 2 * margin,
                         union.in_tiles)
    for pts, prim in blocks:
        # Only the pairs within the band of the best so far (a superset of the final band):
        # on a sphere, all pairs at once took 1.5 GB. (One compiled loop: `best` lowered by
        # the block's pairs, then theirs kept.)
        pts, prim, value = lowered_band(best, pts, prim, union.distance(points, pts, prim),
                                        2 * margin)
        found_pts.append(pts), found_prim.append(prim), found_val.append(value)
        held += len(pts)
        if held > 2 * PAIRS and margin > floor:  # narrowed early: memory stays capped
            pts, prim, value = (np.concatenate(x) for x in (found_pts, found_prim, found_val))
            margin = _narrowed(value - best[pts], margin, floor)
            near = value <= best[pts] + 2 * margin
            found_pts, found_prim, found_val = [pts[near]], [prim[near]], [value[near]]
            held = near.sum()
    kept = _in_band(best, list(zip(found_pts, found_prim, found_val)), 2 * margin)
    if len(kept[0]) > PAIRS:
        pts, prim, value = (np.concatenate(x) for x in (found_pts, found_prim, found_val))
        gap = value - best[pts]
        keep = np.flatnonzero(gap <= 2 * margin)
        margin = _narrowed(gap[keep], margin, floor)
        keep = keep[gap[keep] <= 2 * margin]
        kept = pts.take(keep), prim.take(keep), value.take(keep)
    return Candidates(*kept, params, margin)


def _in_band(best, blocks, band: float):
    """The pairs `(pts, prim, value)` of `blocks` (a list of such triples) with `value −
    best[pts] <= band`, in their order, concatenated.

    Counted, then written into arrays that NumPy allocates: spot's searches keep 1.1–1.9M
    pairs, and the filter of their concatenation (an array of positions, then three arrays
    taken at them, allocated by numba) took three times as long, most of it the first
    writes to fresh memory (NumPy asks the kernel for huge pages where it can)."""
    counts = [in_band_count(best, pts, value, band) for pts, _, value in blocks]
    out = (np.empty(sum(counts), np.int64), np.empty(sum(counts), np.int64),
           np.empty(sum(counts)))
    for (pts, prim, value), start in zip(blocks, np.cumsum([0, *counts[:-1]])):
        in_band_into(best, pts, prim, value, band, *out, int(start))
    return out


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
    moved = norm(params[:, :3] - candidates.anchor[:, :3]) + np.abs(
        params[:, 3] - candidates.anchor[:, 3])
    pts, prim, value = candidates.pts, candidates.prim, candidates.value
    change = _primitive_moves(union, moved)
    upper = np.full(n_points, np.inf) if upper is None else upper.copy()
    # The spheres and cones: the pairs before the first slab's (the primitives ascend, kinds
    # in order). One compiled loop (`pairs.pruned`).
    solid = int(np.searchsorted(prim, np.searchsorted(union.kind, 2)))
    # (Written into arrays NumPy allocates, as `_in_band`'s; spot keeps 0.35–0.55M of 1.1M.)
    out = np.empty(len(pts), np.int64), np.empty(len(pts), np.int64)
    count = pruned(pts, prim, value, change, solid, upper, tolerance, *out)
    return out[0][:count], out[1][:count]


def closest(points, pts, prim, union: UnionPrimitives):
    """Each sample's distance to the union `(N,)`, and its closest primitive's spheres and
    weights `(N, 3)`, from candidate pairs (every sample has one)."""
    value = union.distance(points, pts, prim)
    # One attaining pair per sample: of several, the last in the pairs' order, i.e. the one
    # of the largest primitive (a sample meets a primitive in at most one pair, or in equal
    # duplicates), whatever the order of the samples within a primitive.
    best, pick = attaining(pts, value, len(points))
    # Spheres and weights of the attaining pairs only (evaluated again: cheaper than filling
    # them for every pair), each sample's in one compiled loop: `UnionPrimitives.closest`'s
    # arithmetic, without its NumPy passes over the kinds' slices and the reordering.
    spheres, weights = attaining_spheres(
        np.ascontiguousarray(points, np.float64), pts, prim, pick, union.kind,
        np.ascontiguousarray(union.index, np.int64), union.cones.columns, union.slabs.table,
        *(np.ascontiguousarray(x, np.int64).reshape(-1, k)
          for x, k in ((union.edges, 2), (union.faces, 3))))
    return best, spheres, weights

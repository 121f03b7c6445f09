"""Loops over (point, primitive) pairs of a medial mesh, compiled by numba.

`UnionPrimitives.distance` measures millions of pairs (spot at 200 spheres: 1.7–2.6M in each
of the fit's candidate searches, and its evaluations, the envelope and `medial_distance`
besides). In NumPy every operation of the closed forms is a pass over the pairs, after
gathering each pair's primitive quantities; here one loop reads them in place: 85 → 18 ms
for the 1.7M pairs of one of spot's searches (4.7×). The candidate search's tests (tiles,
samples, slabs' boxes) and filters, `prune`'s bounds and `closest`'s choice are loops too.

The arithmetic is that of `primitives` (the lone sphere's `norm`, `_Cones._parts`,
`_Slabs.distance` and `_Slabs._parts`), each operation in the same order on the same float64
numbers: the same values, bit for bit (IEEE operations and square roots; numba contracts no
multiply-add into a fused one without `fastmath`), which the fit's ties need (see
`_Slabs._parts`). `np.minimum`'s and `np.maximum`'s NaN and signed-zero rules are written
out (`_least`, and the cone's `max(·, 0)`), and division as NumPy's (`error_model="numpy"`:
infinities and NaN, never an exception).

Compiled on first use (about 5 s of CPU with `triangles`) and cached beside this file
(`cache=True`): a later process loads them in 0.1–0.3 s, plus numba's import (0.2 s).
"""

from __future__ import annotations

import numba
import numpy as np

from .primitives import FOOT


@numba.njit(cache=True, error_model="numpy")
def _least(a, b):
    """`np.minimum(a, b)` of two floats (NaN if either is NaN; `a` on a tie); no branch."""
    return a if (a <= b) | (a != a) else b


@numba.njit(cache=True, error_model="numpy", inline="always")
def _column(table, i):
    """Column `i` of a table of 15 rows (`_Cones.columns`, `_Slabs.test`), as a tuple of
    floats: read once for all the samples of one primitive."""
    return (table[0, i], table[1, i], table[2, i], table[3, i], table[4, i], table[5, i],
            table[6, i], table[7, i], table[8, i], table[9, i], table[10, i], table[11, i],
            table[12, i], table[13, i], table[14, i])


@numba.njit(cache=True, error_model="numpy", inline="always")
def _cone_parts(px, py, pz, row):
    """`_Cones._parts` of one point and the cone of `row` (its column of `_Cones.columns`,
    `_column`): the distances to the end spheres and to the lateral surface, and the
    minimiser's position `t`. Without branches (every quantity computed, then chosen), so
    that a loop over the samples of one cone compiles into vector instructions: the same
    values."""
    d0x, d0y, d0z = px - row[0], py - row[1], pz - row[2]
    dd = (d0x * d0x + d0z * d0z) + d0y * d0y
    end0 = np.sqrt(dd) - row[9]
    d1x, d1y, d1z = px - row[6], py - row[7], pz - row[8]
    end1 = np.sqrt((d1x * d1x + d1z * d1z) + d1y * d1y) - row[10]
    x = (d0x * row[3] + d0z * row[5]) + d0y * row[4]
    across = dd - x * x
    across = across if (across >= 0.0) | (across != across) else 0.0  # np.maximum(·, 0)
    y = np.sqrt(across)
    s, co = row[11], row[12]
    t = x - y * s / co
    lateral = x * s + y * co - row[9]
    lateral = lateral if (row[14] > 0) & (t >= 0) & (t <= row[13]) else np.inf
    return end0, end1, lateral, t


@numba.njit(cache=True, error_model="numpy", inline="always")
def _slab_parts(px, py, pz, table, i):
    """`_Slabs._parts` of one point and slab `i` (`table`: `_Slabs.table`): the distance
    (`inf` where the foot is off the triangle) and the foot's coordinates `b1`, `b2`."""
    row = table[i]
    dx, dy, dz = px - row[0], py - row[1], pz - row[2]
    height = (dx * row[3] + dz * row[5]) + dy * row[4]
    side = (1.0 if height >= 0 else -1.0) * row[19]
    nx, ny, nz = row[6] + side * row[3], row[7] + side * row[4], row[8] + side * row[5]
    lift = np.abs(height) / row[19]
    wx, wy, wz = dx - lift * nx, dy - lift * ny, dz - lift * nz
    w1 = (wx * row[9] + wz * row[11]) + wy * row[10]
    w2 = (wx * row[12] + wz * row[14]) + wy * row[13]
    b1 = row[15] * w1 + row[16] * w2
    b2 = row[16] * w1 + row[17] * w2
    if row[20] > 0 and b1 >= 0 and b2 >= 0 and b1 + b2 <= 1:
        return ((nx * dx + nz * dz) + ny * dy) - row[18], b1, b2
    return np.inf, b1, b2


@numba.njit(cache=True, error_model="numpy", inline="always")
def _slab_near(px, py, pz, row):
    """Whether `_Slabs.distance` of one point to the slab of `row` (its column of
    `_Slabs.test`, `_column`) may be finite: the foot's coordinates on or near the
    triangle (`FOOT`). Without branches, as `_cone_parts`."""
    dx, dy, dz = px - row[0], py - row[1], pz - row[2]
    lift = np.abs((dx * row[3] + dz * row[5]) + dy * row[4])
    b1 = ((dx * row[6] + dz * row[8]) + dy * row[7]) - lift * row[12]
    b2 = ((dx * row[9] + dz * row[11]) + dy * row[10]) - lift * row[13]
    return (row[14] > 0) & (b1 >= -FOOT) & (b2 >= -FOOT) & (b1 + b2 <= 1 + FOOT)


CHUNK = 256  # samples of one primitive gathered at a time by `pair_distances` (a few kB)


@numba.njit(cache=True, error_model="numpy")
def pair_distances(points, pts, prim, kind, index, centers, radii, cone, test, table, out):
    """`out[k]`: the signed distance of `points[pts[k]]` to primitive `prim[k]` (`kind` 0, 1,
    2: lone sphere, cone, slab, number `index` among its kind; the tables of `_Cones` and
    `_Slabs`). Every array float64 or int64 and contiguous (one compiled version).

    By runs of pairs of one primitive (the searches' and the fit's pairs come sorted by
    primitive, thousands a cone on spot; any order gives the same values): a cone's samples
    are gathered `CHUNK` at a time and measured in a loop without branches, which compiles
    into vector instructions (spot's fit: 0.5 → 0.2 s; the same values, bit for bit)."""
    gx, gy, gz = np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK)
    near = np.empty(CHUNK, np.bool_)
    start = 0
    while start < len(pts):
        q = prim[start]
        stop = start + 1
        while stop < len(pts) and prim[stop] == q:
            stop += 1
        i = index[q]
        if kind[q] == 0:
            cx, cy, cz, r = centers[i, 0], centers[i, 1], centers[i, 2], radii[i]
            for k in range(start, stop):
                j = pts[k]
                x, y, z = points[j, 0] - cx, points[j, 1] - cy, points[j, 2] - cz
                out[k] = np.sqrt((x * x + y * y) + z * z) - r
        else:
            row = _column(cone, i) if kind[q] == 1 else _column(test, i)
            for first in range(start, stop, CHUNK):
                size = min(CHUNK, stop - first)
                for k in range(size):
                    j = pts[first + k]
                    gx[k], gy[k], gz[k] = points[j, 0], points[j, 1], points[j, 2]
                if kind[q] == 1:
                    for k in range(size):
                        end0, end1, lateral, _ = _cone_parts(gx[k], gy[k], gz[k], row)
                        out[first + k] = _least(_least(end0, end1), lateral)
                    continue
                for k in range(size):
                    near[k] = _slab_near(gx[k], gy[k], gz[k], row)
                for k in range(size):  # (few are near: 7k of the fit's 1.3M slab pairs)
                    out[first + k] = (_slab_parts(gx[k], gy[k], gz[k], table, i)[0] if near[k]
                                      else np.inf)
        start = stop


@numba.njit(cache=True, error_model="numpy")
def _kept(pts, prim, value, keep, count: int):
    """The pairs at positions `keep[:count]`: `(pts, prim, value)`."""
    keep = keep[:count]
    return pts[keep], prim[keep], value[keep]


@numba.njit(cache=True, error_model="numpy")
def lowered_band(best, pts, prim, value, band: float):
    """`candidates.search`'s step per block: `best[pts] = min(best[pts], value)` in the pairs'
    order (as `np.minimum.at`), then the pairs `(pts, prim, value)` with `value <= best[pts]
    + band`, in their order."""
    for k in range(len(pts)):
        best[pts[k]] = _least(best[pts[k]], value[k])
    keep = np.empty(len(pts), np.int64)
    count = 0
    for k in range(len(pts)):
        if value[k] <= best[pts[k]] + band:
            keep[count] = k
            count += 1
    return _kept(pts, prim, value, keep, count)


@numba.njit(cache=True, error_model="numpy")
def in_band_count(best, pts, value, band: float) -> int:
    """How many pairs `(pts, value)` have `value − best[pts] <= band` (`candidates.search`'s
    last filter, `in_band_into`)."""
    count = 0
    for k in range(len(pts)):
        count += value[k] - best[pts[k]] <= band
    return count


@numba.njit(cache=True, error_model="numpy")
def in_band_into(best, pts, prim, value, band: float, out_pts, out_prim, out_value,
                 start: int) -> None:
    """The pairs `(pts, prim, value)` with `value − best[pts] <= band`, in their order,
    written to the outputs from position `start` (`candidates.search`'s last filter)."""
    count = start
    for k in range(len(pts)):
        if value[k] - best[pts[k]] <= band:
            out_pts[count], out_prim[count], out_value[count] = pts[k], prim[k], value[k]
            count += 1


@numba.njit(cache=True, error_model="numpy")
def pruned(pts, prim, value, change, solid: int, upper, tolerance: float, out_pts,
           out_prim) -> int:
    """`candidates.prune`'s selection: `upper[pts] = min(upper[pts], value + change[prim])`
    over the first `solid` pairs (spheres and cones) in order, then the pairs `(pts, prim)`
    with `value − change[prim] <= upper[pts] + tolerance`, in their order, written to the
    outputs (as long as the pairs); returns how many."""
    for k in range(solid):
        upper[pts[k]] = _least(upper[pts[k]], value[k] + change[prim[k]])
    count = 0
    for k in range(len(pts)):
        if value[k] - change[prim[k]] <= upper[pts[k]] + tolerance:
            out_pts[count], out_prim[count] = pts[k], prim[k]
            count += 1
    return count


@numba.njit(cache=True, error_model="numpy")
def attaining(pts, value, points: int):
    """`candidates.closest`'s choice: each sample's least `value` `(points,)` (as
    `np.minimum.at`) and the position `(points,)` of its last pair attaining it (as NumPy's
    assignment with repeated indices: the last write stays)."""
    best = np.full(points, np.inf)
    for k in range(len(pts)):
        best[pts[k]] = _least(best[pts[k]], value[k])
    pick = np.zeros(points, np.int64)
    for k in range(len(pts)):
        if value[k] == best[pts[k]]:
            pick[pts[k]] = k
    return best, pick


@numba.njit(cache=True, error_model="numpy")
def attaining_spheres(points, pts, prim, pick, kind, index, cone, table, edges, faces):
    """`candidates.closest`'s spheres and weights `(N, 3)` each: for every sample `s`, those
    of `UnionPrimitives.closest` at its attaining pair `pick[s]` (a lone sphere `j`: `(j, j,
    j)`, weights `(1, 0, 0)`; a cone: its spheres `(i, j, j)`, `(1 − f, f, 0)` with `f` the
    fraction of `_Cones.closest`; a slab: its spheres, `(1 − b1 − b2, b1, b2)`)."""
    n = len(pick)
    spheres, weights = np.empty((n, 3), np.int64), np.zeros((n, 3))
    for s in range(n):
        k = pick[s]
        q = prim[k]
        i = index[q]
        px, py, pz = points[pts[k], 0], points[pts[k], 1], points[pts[k], 2]
        if kind[q] == 0:
            spheres[s, 0] = spheres[s, 1] = spheres[s, 2] = i
            weights[s, 0] = 1.0
        elif kind[q] == 1:
            end0, end1, lateral, t = _cone_parts(px, py, pz, _column(cone, i))
            ends = _least(end0, end1)
            if lateral < ends:  # np.clip(t / length, 0, 1)
                fraction = t / cone[13, i]
                if fraction == fraction:
                    fraction = fraction if fraction > 0 else 0.0
                    fraction = fraction if fraction < 1 else 1.0
            else:
                fraction = 0.0 if end0 <= end1 else 1.0
            spheres[s, 0], spheres[s, 1], spheres[s, 2] = edges[i, 0], edges[i, 1], edges[i, 1]
            weights[s, 0], weights[s, 1] = 1 - fraction, fraction
        else:
            _, b1, b2 = _slab_parts(px, py, pz, table, i)
            spheres[s, 0], spheres[s, 1], spheres[s, 2] = faces[i, 0], faces[i, 1], faces[i, 2]
            weights[s, 0], weights[s, 1], weights[s, 2] = 1 - b1 - b2, b1, b2
    return spheres, weights


@numba.njit(cache=True, error_model="numpy")
def _largest(a, b):
    """`np.maximum(a, b)` of two floats (NaN if `a` is NaN; `a` on a tie)."""
    return a if (a >= b or a != a) else b


@numba.njit(cache=True, error_model="numpy")
def near_tiles(centre, low, high, reach):
    """`candidates.ball_blocks`'s first test `(P, tiles)`: whether the distance of
    `centre[i]` to tile `t`'s box `low[:, t]`–`high[:, t]`, summed and rooted as
    `np.sqrt(sum(np.square(np.maximum(np.maximum(low − c, c − high), 0))))`, is at most
    `reach[i, t]`, given as `(radius (P,), bound (tiles,))`: `radius[i] + bound[t]`."""
    radius, bound = reach
    near = np.empty((len(centre), low.shape[1]), np.bool_)
    for i in range(len(centre)):
        for t in range(low.shape[1]):
            total = 0.0
            for k in range(3):
                side = _largest(_largest(low[k, t] - centre[i, k], centre[i, k] - high[k, t]),
                                0.0)
                total = total + side * side
            near[i, t] = np.sqrt(total) <= radius[i] + bound[t]
    return near


@numba.njit(cache=True, error_model="numpy")
def _inside(x, y, z, reach, centre, radius, i, t, lane):
    """`candidates.ball_blocks`'s float32 test of sample `lane` of tile `t` against
    primitive `i`."""
    dx = x[t, lane] - centre[i, 0]
    dy = y[t, lane] - centre[i, 1]
    dz = z[t, lane] - centre[i, 2]
    square = dx * dx
    square += dy * dy
    square += dz * dz
    limit = radius[i] + reach[t, lane]
    return (square <= limit * limit) & (limit >= 0)


@numba.njit(cache=True, error_model="numpy")
def tile_pairs(near, start: int, stop: int, tiles, centre, radius, order):
    """`candidates.ball_blocks`' pairs `(pts, prim)` of primitives `start` to `stop`: the
    samples of their `near` tiles (`tiles = (x, y, z, reach)`, each `(tiles, TILE)` float32,
    the samples' positions in `order`) within reach, primitives then tiles then lanes
    ascending (as `np.nonzero` and `np.flatnonzero` give them)."""
    x, y, z, reach = tiles
    width = x.shape[1]
    # Room for every sample of the near tiles, then one pass (not a pass to count the pairs
    # and a second to write them: the same pairs, each test made once).
    count = 0
    for i in range(start, stop):
        for t in range(near.shape[1]):
            count += near[i, t]
    pts, prim = np.empty(count * width, np.int64), np.empty(count * width, np.int64)
    inside = np.empty(width, np.bool_)
    count = 0
    for i in range(start, stop):
        for t in range(near.shape[1]):
            if near[i, t]:
                # A tile's tests first (one loop without branches: vector instructions),
                # then its pairs.
                for lane in range(width):
                    inside[lane] = _inside(x, y, z, reach, centre, radius, i, t, lane)
                for lane in range(width):
                    if inside[lane]:
                        pts[count], prim[count] = order[t * width + lane], i
                        count += 1
    return pts[:count], prim[:count]


@numba.njit(cache=True, error_model="numpy")
def _span(v, d, half, size):
    """`_Slabs.in_boxes`'s `span`: `v·d`, `|v|·half`, `|v|·size` (each `v` a 3-tuple)."""
    return ((v[0] * d[0] + v[2] * d[2]) + v[1] * d[1],
            (abs(v[0]) * half[0] + abs(v[2]) * half[2]) + abs(v[1]) * half[1],
            (abs(v[0]) * size[0] + abs(v[2]) * size[2]) + abs(v[1]) * size[1])


@numba.njit(cache=True, error_model="numpy")
def _slab_box(test, s, low, high):
    """`_Slabs.in_boxes` for slab `s` and the box `low` to `high` (3-tuples)."""
    middle = ((low[0] + high[0]) / 2, (low[1] + high[1]) / 2, (low[2] + high[2]) / 2)
    half = ((high[0] - low[0]) / 2, (high[1] - low[1]) / 2, (high[2] - low[2]) / 2)
    d = (middle[0] - test[0, s], middle[1] - test[1, s], middle[2] - test[2, s])
    size = ((abs(middle[0]) + abs(test[0, s])) + half[0],
            (abs(middle[1]) + abs(test[1, s])) + half[1],
            (abs(middle[2]) + abs(test[2, s])) + half[2])
    centre, width, magnitude = _span((test[3, s], test[4, s], test[5, s]), d, half, size)
    lift_low = _largest(abs(centre) - width, 0.0)
    lift_high = abs(centre) + width
    p1 = (test[6, s], test[7, s], test[8, s])
    p2 = (test[9, s], test[10, s], test[11, s])
    k1, k2 = test[12, s], test[13, s]
    inside = test[14, s] > 0
    for v, slope, bound in ((p1, k1, -FOOT), (p2, k2, -FOOT),
                            ((-(p1[0] + p2[0]), -(p1[1] + p2[1]), -(p1[2] + p2[2])),
                             -(k1 + k2), -1 - FOOT)):
        centre, width, size_v = _span(v, d, half, size)
        lift = slope * lift_low if slope >= 0 else slope * lift_high
        largest = centre + width - lift
        allowance = 1e-8 * (size_v + abs(slope) * (lift_high + magnitude))
        inside = inside and largest >= bound - allowance
    return inside


@numba.njit(cache=True, error_model="numpy")
def slab_boxes(test, i, low, high):
    """`_Slabs.in_boxes` `(M,)` for slabs `i (M,)` (`test`: `_Slabs.test`) and boxes `low
    (3, M)` to `high (3, M)`: the same bounds, operation for operation."""
    keep = np.empty(len(i), np.bool_)
    for k in range(len(i)):
        keep[k] = _slab_box(test, i[k], (low[0, k], low[1, k], low[2, k]),
                            (high[0, k], high[1, k], high[2, k]))
    return keep


@numba.njit(cache=True, error_model="numpy")
def slab_tiles(near, kind, index, test, low, high, origin):
    """`candidates.ball_blocks`'s slab test, in place: `near[p, t]` (primitives by tiles)
    cleared where primitive `p` is a slab (`kind` 2, number `index[p]`) that no point of
    tile `t`'s box, `low[:, t] + origin` to `high[:, t] + origin`, has a finite distance to
    (`_Slabs.in_boxes`)."""
    for p in range(near.shape[0]):
        if kind[p] != 2:
            continue
        for t in range(near.shape[1]):
            if near[p, t]:
                near[p, t] = _slab_box(
                    test, index[p],
                    (low[0, t] + origin[0], low[1, t] + origin[1], low[2, t] + origin[2]),
                    (high[0, t] + origin[0], high[1, t] + origin[1], high[2, t] + origin[2]))


@numba.njit(cache=True, error_model="numpy")
def jacobian_rows(spheres, weights, u):
    """`refine._jacobian`'s CSR arrays `(data, indices (int32), indptr (int32))` for samples
    whose closest primitive interpolates `spheres (N, 3)` with `weights (N, 3)`, `u (N, 3)`
    the unit vectors to them: in row `i`, `−w_k (u_i, 1)` in the four columns of each sphere
    `k`, the columns ascending and a repeated sphere's entries summed, as SciPy's
    `sum_duplicates` leaves them (its sums of two terms, or of a term and zeros of one
    sign, do not depend on their order)."""
    n = len(spheres)
    data, indices = np.empty(12 * n), np.empty(12 * n, np.int32)
    indptr = np.empty(n + 1, np.int32)
    order = np.empty(3, np.int64)
    count = 0
    for i in range(n):
        indptr[i] = count
        for k in range(3):  # the row's three spheres by index (an insertion sort)
            order[k] = k
            m = k
            while m > 0 and spheres[i, order[m - 1]] > spheres[i, order[m]]:
                order[m - 1], order[m] = order[m], order[m - 1]
                m -= 1
        k = 0
        while k < 3:
            sphere = spheres[i, order[k]]
            last = k
            while last + 1 < 3 and spheres[i, order[last + 1]] == sphere:
                last += 1
            for c in range(4):
                du = u[i, c] if c < 3 else 1.0
                value = -(weights[i, order[k]] * du)
                for m in range(k + 1, last + 1):
                    value += -(weights[i, order[m]] * du)
                data[count], indices[count] = value, 4 * sphere + c
                count += 1
            k = last + 1
    indptr[n] = count
    return data[:count], indices[:count], indptr

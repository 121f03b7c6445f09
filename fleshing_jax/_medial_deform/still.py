"""Where the implicit correction has nothing to do: groups of vertices whose spheres all move
as one rigid body.

The correction (`implicit.correct`) moves each skinned vertex back to its rest iso-value of
the posed envelope's field and relaxes it towards its rest one-ring. Where every sphere that
a vertex reads (its footprint's and rotation weights' spheres, the spheres of its field's
candidate cones and slabs) and every sphere its one-ring neighbours read move by the same
rigid motion, the skinned vertex, its field and its neighbours move by that motion too, so
the Newton step and the relaxation move it by round-off only: the correction can be skipped.

Our own shortcut (not in Vaillant et al. 2013 or Lan et al. 2017): a pose that turns a head
and holds the body (spot's cases in `benchmarks/medial_deform.py`) leaves most of the
surface rigid. The test is per group of `GROUP` consecutive vertices in a spatial (Morton)
order, so that a group's vertices share most of their spheres (on spot, 2,930 vertices and
200 spheres, a block of 512 reads 83 spheres on average, 155 in the vertices' own order).
Per frame the test compares the spheres' rotations and translations, `(groups, spheres a
group reads)` numbers, where the field's evaluation costs `(vertices, candidates)` closed
forms. The correction then evaluates only the vertices of the groups that are not still,
gathered into chunks of `block_size` (`implicit.correct`). Spot with its head turned 30°
about the neck and its core held: groups of 64 leave 31 % of its vertices to correct (2
chunks of 512), groups of 512 (the skip's first form, a `lax.cond` per block) 52 % (3 of 6
blocks); groups of 32 / 16: 25 / 21 %, in as many chunks, the test's table wider (53 / 45
spheres against 65 for 64: measured slower). Its skin: CPU 0.90–0.92 → 0.69–0.82 ms a pose
(load 8–10); with the body free (2 % of the vertices still at 64, none at 512) unchanged.

The rig keeps its welded points in this order (`rig.py` permutes them at binding), so that a
group is a slice of every per-point array. Only rigs of at most `VERTICES` vertices skip: on
the 107,786-vertex capsule bent 90° (no block still) the blocks' `lax.cond`s made its skin
46 → 53 ms of CPU (load 10).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

SIZE = 256  # the fewest vertices a block (see `block_size`)
MOST = 1024  # the most (`implicit.BLOCK`: larger blocks' temporaries leave the cache)
VERTICES = 16_384  # the most vertices a rig skips still blocks for (see below)
GROUP = 64  # vertices a group of the still test (see the module docstring)
TOLERANCE = 16  # how far from one rigid motion a still block's spheres may be, in eps


def morton_order(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """A permutation `(m,)` of `points (m, 3)` along a Morton (Z-order) curve over their
    bounding box, `2^bits` cells a side: consecutive points are near each other."""
    if not len(points):
        return np.zeros(0, np.int64)
    lo, size = points.min(axis=0), max(float(np.ptp(points, axis=0).max()), 1e-300)
    cell = np.clip(((points - lo) / size * (2**bits - 1)).astype(np.int64), 0, 2**bits - 1)
    code = np.zeros(len(points), np.int64)
    for bit in range(bits):
        for axis in range(3):
            code |= ((cell[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(code, kind="stable")


def block_size(m: int) -> int:
    """Vertices a block for `m` vertices: an eighth of them, as a power of two in
    `[SIZE, MOST]`. Each block is one iteration of the correction's loop (and a `lax.cond`),
    whose overhead (tens of µs) made blocks of 256 a third slower than 1024 on 107,786
    vertices (59 against 41 ms of CPU a pose). Spot's 2,930 vertices make 6 blocks of 512,
    the same still vertices as 12 of 256 (head turned, core held) and a faster skin: its
    fastest 0.92 → 0.76 ms, with the body free (no block still) 1.29 → 1.23 ms (medians
    over rounds of the fastest of 50: 1.03 → 0.98, 1.58 → 1.37 ms; load 9)."""
    return int(min(max(SIZE, 2 ** int(np.ceil(np.log2(max(m / 8, 1))))), MOST))


def block_spheres(spheres: np.ndarray, ring: np.ndarray | None, size: int) -> np.ndarray:
    """The spheres each block of `size` consecutive points reads: `(blocks, s)` int array,
    each row the distinct spheres of the block's points and of their one-ring neighbours,
    padded by its first.

    **Arguments:** `spheres (m, k)` the spheres each point reads (the points in block order,
    `morton_order`); `ring (m, w)` their one-ring neighbours (itself as padding), or None."""
    rows = []
    for start in range(0, len(spheres), size):
        block = slice(start, start + size)
        reads = spheres[block] if ring is None else np.r_[spheres[block].ravel(),
                                                          spheres[ring[block]].ravel()]
        rows.append(np.unique(reads))
    width = max(len(row) for row in rows)
    return np.stack([np.r_[row, np.full(width - len(row), row[0])] for row in rows])


def still_blocks(table: Int[Array, "b s"], rest_centers: Float[Array, "n 3"],
                 centers: Float[Array, "n 3"], rotations: Float[Array, "n 3 3"]
                 ) -> Bool[Array, " b"]:
    """Whether each block's spheres (`table`, `block_spheres`) move by one rigid motion: their
    rotations and translations `c̃ − R c` within `TOLERANCE` eps of the block's first sphere's
    (translations relative to the rest centres' extent: conservative for a pose far from
    them, whose translations round off more, and never at the scale of a pose beyond the
    dtype's range, where the correction must flag its overflowing vertices)."""
    eps = TOLERANCE * jnp.finfo(centers.dtype).eps
    translations = centers - jnp.einsum("nab,nb->na", rotations, rest_centers)
    extent = jnp.max(jnp.abs(rest_centers))
    r, t = rotations[table], translations[table]  # (b, s, 3, 3), (b, s, 3)
    turn = jnp.max(jnp.abs(r - r[:, :1]), axis=(1, 2, 3))
    shift = jnp.max(jnp.abs(t - t[:, :1]), axis=(1, 2))
    return (turn <= eps) & (shift <= eps * extent)

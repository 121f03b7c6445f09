"""Batch sizes rounded up to a few buckets, so that eager calls compile once per bucket.

Every distinct batch size compiles new XLA programs: seconds each on a CPU, and memory maps
that a long session eventually runs out of (about 130 sizes end the process in `LLVM ERROR:
Unable to allocate section memory`). The eager entry points (`register`, `pose`, `flesh`,
`jacobian_determinant`) therefore pad a batch to the next bucket, `64·2^k` or `96·2^k` points,
run that bucket's programs and drop the padding: at most two programs per doubling of the size,
and at most a third of the work spent on padding (a sixth on average).

Batches of more than `PAD_LIMIT` points run at their own size: padding copies the inputs,
which at those sizes costs a visible part of a pose (a few nanoseconds per point against about
fifteen), while so large a batch is rarely resized within a session.

Spines too: a spine's sizes are static (its control points or vertices, and the counts that
follow its turning), so every new spine compiled new programs. The same ladder, from a smaller
`minimum`, rounds them up:

- B-splines and polylines are padded by `_bucketed` to `8·2^k` or `12·2^k` control points
  (polylines: input points and resampled edges) before the eager entry points compile: copies
  of the last control point, knot and knot span (polylines: of the last vertex, zero-length
  edges). How many pieces or edges are the curve's is then an array, not a shape: the padding
  has zero length, is never located, and its frames stand still, so values are those of the
  unpadded spine to round-off and gradients reach only the real control points.
- Arc-length sub-intervals per piece (`8·2^k` or `12·2^k`) and closest-point samples
  (`128·2^k` or `192·2^k`) are rounded up where they are chosen from the turning: more is only
  more accurate (and the search's sample levels, what a float64 search depends on, do not
  change). A B-spline's and a polyline's sample floor counts the padded pieces or edges.
- `InterpolatingPolynomial` is not padded: its degree is its point count (at most 26).

So a session that bends onto ever new spines compiles about two programs per doubling of
their size or turning (20 B-splines of 6 … 25 control points: 9; 20 polylines of 10 … 200
points: 9), not one per spine.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PyTree

MINIMUM = 64
PAD_LIMIT = 1 << 19


def bucket(n: int, minimum: int = MINIMUM) -> int:
    """The padded size of a batch of `n` points: the smallest `m·2^k` or `1.5·m·2^k` that is
    at least `n`, `m = minimum` (a power of two: 64 for points); `n` itself beyond `PAD_LIMIT`
    (and for an empty batch)."""
    if n == 0 or n > PAD_LIMIT:
        return n
    size = minimum
    while size < n:
        # 64 → 96 → 128 → 192 → …: alternately ×3/2 and ×4/3.
        size = size * 3 // 2 if size & (size - 1) == 0 else size * 4 // 3
    return size


def pad_batch(tree: PyTree, size: int) -> PyTree:
    """The per-point arrays of `tree` (leading axis `n`; scalars are shared and kept) padded
    to `size` with copies of their last point: finite wherever the inputs are, so the padding
    computes harmlessly. `tree` itself when `size` is its size.

    Concrete arrays are padded on the host and put on the device as they are: a device
    operation on the `n`-point arrays (`jnp.pad`, and even `jnp.asarray`) would itself compile
    once per size. Traced ones (a spine's parameters under `grad`) are padded in their trace
    (a padded spine never reads the copies: no gradient flows through them)."""

    def pad(a):
        if jnp.ndim(a) == 0 or a.shape[0] == size:
            return a
        if isinstance(a, jax.core.Tracer):
            return jnp.pad(a, [(0, size - a.shape[0])] + [(0, 0)] * (a.ndim - 1), mode="edge")
        host = np.asarray(a)
        padded = np.pad(host, [(0, size - len(host))] + [(0, 0)] * (host.ndim - 1), mode="edge")
        return jax.device_put(padded)

    if any(isinstance(a, jax.Array) and not isinstance(a, jax.core.Tracer)
           and len(a.sharding.device_set) > 1 for a in jax.tree.leaves(tree)):
        return tree  # sharded over devices: kept as laid out (padding would gather it)
    return jax.tree.map(pad, tree)


def unpad_batch(tree: PyTree, n: int) -> PyTree:
    """The first `n` points of the per-point arrays of `tree` (scalars kept), sliced on the
    host as `pad_batch` pads (in their trace if they are traced)."""

    def unpad(a):
        if jnp.ndim(a) == 0 or a.shape[0] == n:
            return a
        if isinstance(a, jax.core.Tracer):  # outputs traced through other arguments (a spine
            return a[:n]  # under `grad`): sliced in that trace
        return jax.device_put(np.asarray(a)[:n])

    return jax.tree.map(unpad, tree)

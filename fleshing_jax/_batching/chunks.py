"""Batched work in fixed-size chunks under `jit`, so that memory follows the chunk, not the batch.

A batch function materialises its intermediates for every point at once: tens to hundreds of
bytes per point, several times the inputs and outputs. `map_chunks` runs it on `CHUNK_POINTS`
points at a time with `lax.map` (one compiled chunk, looped), so the intermediates are those
of one chunk and the peak memory is the inputs and outputs plus a fixed amount.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import PyTree

CHUNK_POINTS = 8192


def map_chunks(
    function: Callable, inputs: PyTree, chunk: int | None = None, whole: bool = False
) -> PyTree:
    """`function(inputs)` for a batch function, evaluated `chunk` points at a time.

    **Arguments:** `function`: a batch of inputs (leading axis `n`) → a batch of outputs (same
    leading axis); it must treat points independently. `inputs`: pytree of arrays with leading
    axis N, and scalars shared by all points (passed to every chunk as they are). `chunk`:
    points per chunk (default `CHUNK_POINTS`). `whole`: evaluate the whole batch at once, for
    functions that fuse into a few kernels with few intermediates per point (the tabulated
    paths, `_spines.table`): for them chunking saves little memory and costs time, the loop body
    running ~2.5× slower on XLA's CPU backend than the same kernels on the whole batch.

    **Returns:** the outputs, leading axis N, equal to `function(inputs)`. Batches of at most
    one chunk call `function` directly. Otherwise the batch is padded to whole chunks with
    copies of its last point (finite wherever the inputs are, so no spurious NaN) and the
    padding dropped from the outputs. Differentiable (`lax.map` is a `scan`).
    """
    chunk = CHUNK_POINTS if chunk is None else int(chunk)
    inputs, shared = per_point(inputs)
    n = jax.tree.leaves(inputs)[0].shape[0]
    if whole or n <= chunk:
        return function(eqx.combine(inputs, shared))
    count = -(-n // chunk)

    # Chunk `j` holds the points `j, j + count, j + 2 count, …`: strided, so that points sharded
    # across devices in contiguous blocks give chunks spread over all the devices (each works on
    # its own part of every chunk) rather than whole chunks on one device, run one at a time.
    def split(a):
        padding = [(0, count * chunk - n)] + [(0, 0)] * (a.ndim - 1)
        return jnp.swapaxes(
            jnp.pad(a, padding, mode="edge").reshape(chunk, count, *a.shape[1:]), 0, 1
        )

    def join(a):
        return jnp.swapaxes(a, 0, 1).reshape(count * chunk, *a.shape[2:])[:n]

    outputs = jax.lax.map(lambda c: function(eqx.combine(c, shared)), jax.tree.map(split, inputs))
    return jax.tree.map(join, outputs)


def per_point(tree: PyTree) -> tuple[PyTree, PyTree]:
    """`tree` split into its per-point arrays and its scalars (shared by all points), as by
    `eqx.partition`; `eqx.combine` joins them again."""
    return eqx.partition(tree, lambda leaf: jnp.ndim(leaf) > 0)


def batch_axes(tree: PyTree) -> PyTree:
    """`vmap` axes for `tree`: 0 for per-point arrays, `None` for shared scalars."""
    return jax.tree.map(lambda leaf: 0 if jnp.ndim(leaf) > 0 else None, tree)

"""Numerics with safe gradients, shared by every subsystem.

Everything here is written so that values *and* derivatives stay finite at the degenerate
points the library meets all the time (zero curvature, zero offsets): the "double `where`"
pattern feeds a harmless argument to the unsafe function and then selects the result. The
explicit dot products keep XLA's CPU kernels fused (see `dot`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array


def dot(a: Array, b: Array) -> Array:
    """`a·b` over the last axis (leading axes broadcast), as an explicit sum of products.

    Not `jnp.dot`: batched by `vmap`, that becomes a reduction over a minor axis of length 3,
    which XLA's CPU backend runs about 7× slower than these fused multiply-adds
    (`benchmarks/README.md`). The per-point code of the batched paths uses this throughout.
    """
    return sum(a[..., i] * b[..., i] for i in range(a.shape[-1]))


def norm(a: Array) -> Array:
    """`|a|` over the last axis (see `dot`)."""
    return jnp.sqrt(dot(a, a))


def safe_sqrt(x: Array) -> Array:
    """`sqrt(x)` for `x > 0`, and 0 (with zero derivative) for `x <= 0`."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1)), 0)


def safe_divide(numerator: Array, denominator: Array) -> Array:
    """`numerator / denominator`, and 0 where the denominator is 0 (finite derivatives)."""
    nonzero = denominator != 0
    return jnp.where(nonzero, numerator / jnp.where(nonzero, denominator, 1), 0)


def cast_floats(tree, dtype):
    """Casts every floating array leaf of `tree` to `dtype` (so float32 points stay float32)."""

    def cast(leaf):
        if isinstance(leaf, jax.Array | np.ndarray) and jnp.issubdtype(leaf.dtype, jnp.floating):
            return leaf.astype(dtype)
        return leaf

    return jax.tree.map(cast, tree)


def relative_tolerance(dtype) -> float:
    """A tolerance for "converged" checks: the square root of the dtype's epsilon."""
    return float(np.sqrt(np.finfo(dtype).eps))

"""Small numerical helpers shared by the other modules.

Everything here is written so that values *and* derivatives stay finite at the degenerate
points the library meets all the time (zero curvature, zero offsets): the "double `where`"
pattern feeds a harmless argument to the unsafe function and then selects the result.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike


def as_float_array(value: ArrayLike, name: str, shape: tuple[int, ...] | None = None) -> Array:
    """Converts `value` to a floating JAX array, checking its shape.

    Integers become the default float type; floating inputs keep their dtype.
    Raises `ValueError` naming `name` when the shape is not `shape`.
    """
    if isinstance(value, jax.Array) and jnp.issubdtype(value.dtype, jnp.floating):
        array = value
    else:
        array = jnp.asarray(value)
        if not jnp.issubdtype(array.dtype, jnp.floating):
            array = array.astype(jnp.result_type(float))
    if shape is not None and array.shape != shape:
        raise ValueError(f"`{name}` must have shape {shape}, got shape {array.shape}.")
    return array


def is_concrete(*values) -> bool:
    """Whether all `values` are known at trace time (so that value checks can run)."""
    return not any(isinstance(v, jax.core.Tracer) for v in jax.tree.leaves(values))


def check_positive(value: Array, name: str) -> None:
    """Raises `ValueError` if a concrete `value` is not finite and strictly positive."""
    if is_concrete(value):
        v = np.asarray(value)
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ValueError(f"`{name}` must be finite and positive, got {v}.")


def unit(vector: Array, name: str) -> Array:
    """Normalises `vector`, raising `ValueError` when a concrete vector is zero or not finite."""
    if is_concrete(vector):
        v = np.asarray(vector)
        if not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
            raise ValueError(f"`{name}` must be a finite non-zero vector, got {v}.")
    return vector / jnp.linalg.norm(vector)


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


def check_points(points: ArrayLike, name: str, minimum: int, why: str) -> Array:
    """Converts `points` to a float (N, 3) array and checks it is usable as spine data.

    Raises `ValueError` naming `name` unless `N ≥ minimum` (`why` says where the minimum comes
    from), and, when concrete, unless all values are finite and no two consecutive points
    coincide. Traced inputs are checked for finiteness with `eqx.error_if`.
    """
    points = as_float_array(points, name)
    if points.ndim != 2 or points.shape[-1] != 3:
        raise ValueError(f"`{name}` must have shape (N, 3), got shape {points.shape}.")
    if points.shape[0] < minimum:
        raise ValueError(
            f"`{name}` must have at least {why} = {minimum} rows, got {points.shape[0]}."
        )
    if not is_concrete(points):
        return eqx.error_if(
            points, ~jnp.all(jnp.isfinite(points)), f"`{name}` must be finite (found NaN or inf)."
        )
    p = np.asarray(points, dtype=np.float64)
    bad = np.argwhere(~np.isfinite(p))
    if bad.size:
        raise ValueError(f"`{name}` must be finite, got {p[bad[0, 0]]} in row {bad[0, 0]}.")
    gaps = np.linalg.norm(np.diff(p, axis=0), axis=-1)
    scale = np.max(np.abs(p)) + np.max(gaps)
    repeated = np.flatnonzero(gaps <= 16 * np.finfo(points.dtype).eps * scale)
    if repeated.size:
        i = int(repeated[0])
        raise ValueError(
            f"`{name}` has repeated consecutive points: rows {i} and {i + 1} coincide ({p[i]})."
        )
    return points

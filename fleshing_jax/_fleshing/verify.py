"""Verification of local volume preservation with automatic differentiation."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._batching.buckets import bucket, pad_batch, unpad_batch
from .._checks import is_concrete
from .pipeline import Fleshing, _check_points, apply_point


def jacobian_determinant(fleshing: Fleshing, points: ArrayLike) -> Float[Array, " N"]:
    """`det ∂M/∂X` at each point, by forward-mode autodiff (`jax.jacfwd`).

    Equal to 1 (to round-off) for the three fleshings wherever the points are valid; skinning
    is the baseline that is not volume preserving.

    **Arguments:** `fleshing`: a `Fleshing`; `points`: (N, 3) array.

    **Returns:** (N,) array of determinants; NaN marks the points that are not valid
    (`fleshing.is_valid` is False there), where the map has no meaningful Jacobian.
    """
    if not isinstance(fleshing, Fleshing):
        raise TypeError(f"`fleshing` must be a `Fleshing`, got {type(fleshing)}.")
    points = _check_points(points, "points")
    fleshing = Fleshing(  # spines padded to a bucket of sizes (`AbstractSpine._bucketed`)
        fleshing.source._bucketed(),
        fleshing.target._bucketed(),
        method=fleshing.method,
        twist=fleshing.twist,
        check_projection=fleshing.check_projection,
    )
    if not is_concrete(points):
        return _determinants(fleshing, points)
    n = points.shape[0]  # called eagerly: one program per bucket of sizes (`_batching.buckets`)
    return unpad_batch(_determinants(fleshing, pad_batch(points, bucket(n))), n)


@eqx.filter_jit
def _determinants(fleshing, points):
    def one(x):
        jacobian, valid = jax.jacfwd(lambda x: apply_point(fleshing, x), has_aux=True)(x)
        return jnp.where(valid, jnp.linalg.det(jacobian), jnp.nan)

    return jax.vmap(one)(points)

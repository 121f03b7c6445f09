"""Input checks shared by every subsystem: conversion to float arrays and value checks.

Shape and type problems raise `ValueError` at trace time with a message naming the argument;
value checks run where the values are concrete (outside `jit`), and traced inputs are checked
with `eqx.error_if` where a check matters.
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

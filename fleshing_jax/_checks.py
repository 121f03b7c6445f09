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

from ._numerics import on_device


def as_float_array(value: ArrayLike, name: str, shape: tuple[int, ...] | None = None, *,
                   host: bool = False) -> Array:
    """Converts `value` to a floating JAX array, checking its shape.

    Integers (and booleans) become the default float type; floating inputs keep their dtype.
    Raises `TypeError` naming `name` for values that are not real numbers (`None`, strings,
    objects, complex numbers: an imaginary part is never dropped silently), and `ValueError`
    naming `name` when the shape is not `shape`. `host`: a value that is not a JAX array is
    returned as a NumPy array of that dtype, not put on the device: for a per-frame argument
    that a jitted call transfers with its others (a device transfer is about 25 µs a value).
    """
    if isinstance(value, jax.Array) and jnp.issubdtype(value.dtype, jnp.floating):
        array = value
    else:
        if value is None or isinstance(value, str | bytes):
            raise TypeError(f"`{name}` must be a real number or an array of them, got {value!r}.")
        array = _as_float(value, name)
        if not host and isinstance(array, np.ndarray):
            # (Put on the device as it is: `jnp.asarray` would compile a program per shape.)
            array = jax.device_put(array)
    if shape is not None and array.shape != shape:
        expected = "a scalar" if shape == () else f"shape {shape}"
        raise ValueError(f"`{name}` must be {expected}, got shape {array.shape}.")
    return array


def _as_float(value, name: str) -> Array | np.ndarray:
    """`value` (not a floating JAX array) as floating: a NumPy array, converted on the host, or
    a JAX array of another dtype converted on the device."""
    if isinstance(value, jax.Array):
        host = value
    else:
        try:
            host = np.asarray(value)
        except (TypeError, ValueError) as error:
            raise TypeError(
                f"`{name}` must be a real number or an array of them, got {_short(value)} "
                f"({error})."
            ) from None
        if host.dtype.kind not in "biufc":
            raise TypeError(
                f"`{name}` must be a real number or an array of them, got {_short(value)} "
                f"(dtype {host.dtype})."
            )
    if jnp.issubdtype(host.dtype, jnp.complexfloating):
        raise TypeError(f"`{name}` must be real, got complex values (dtype {host.dtype}).")
    if not jnp.issubdtype(host.dtype, jnp.floating):
        if isinstance(host, np.ndarray):
            return host.astype(jnp.result_type(float))
        return jnp.asarray(host, jnp.result_type(float))
    if isinstance(host, np.ndarray) and host.dtype == np.float64 != jnp.result_type(float):
        host = host.astype(np.float32)  # what `jnp.asarray` gives without float64
    return host if isinstance(host, np.ndarray) else jnp.asarray(host)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def as_points(points: ArrayLike, name: str, single: bool = False) -> Array:
    """Converts `points` to a float (N, 3) array (or (3,) when `single`), checking its type.

    Raises `TypeError` naming `name` for non-real values and for half precision (float16,
    bfloat16: three significant digits cannot resolve a bend; use float32), and `ValueError`
    for a wrong shape. Values are not checked: non-finite points are flagged per point.
    """
    points = as_float_array(points, name)
    if jnp.finfo(points.dtype).bits < 32:
        raise TypeError(
            f"`{name}` must be float32 or float64, got {points.dtype} (too coarse to bend "
            "with volume preserved: convert it with `.astype(np.float32)`)."
        )
    expected = (3,) if single else ("N", 3)
    if points.ndim != len(expected) or points.shape[-1] != 3:
        raise ValueError(f"`{name}` must have shape {expected}, got shape {points.shape}.")
    return points


def as_twist(twist: ArrayLike, dtype=None) -> Array:
    """The twist angle as a scalar float array (in `dtype` if given).

    Raises `TypeError` for a value that is not a real number, `ValueError` for a non-scalar one
    or, when concrete, a non-finite one (which would make every point invalid). A traced twist
    is not checked: a non-finite one then flags every point invalid.
    """
    twist = as_float_array(twist, "twist", ())
    if is_concrete(twist) and not np.isfinite(np.asarray(twist)):
        raise ValueError(f"`twist` must be a finite angle in radians, got {np.asarray(twist)}.")
    return twist if dtype is None else twist.astype(dtype)


def as_margin(margin: ArrayLike, dtype=None) -> Array:
    """The margin of the valid region (`_fleshing.region`) as a scalar float array: `TypeError`
    for a value that is not a real number, `ValueError` for a non-scalar, negative or (when
    concrete) non-finite one."""
    margin = as_float_array(margin, "margin", ())
    if not is_concrete(margin):
        return margin if dtype is None else margin.astype(dtype)
    value = np.asarray(margin)  # (checked and cast on the host: on the device, programs)
    if not (np.isfinite(value) and value >= 0):
        raise ValueError(
            f"`margin` must be a finite distance ≥ 0 (from the cut locus), got {value}."
        )
    return margin if dtype is None else on_device(value, dtype)


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


def check_number(value, name: str, low: float, high: float, *, integer: bool = False,
                 above: bool = False) -> float | int:
    """A numeric option `value` as a Python float (or int when `integer`), checked before work.

    Raises `TypeError` naming `name` unless `value` is a real number (an integer when
    `integer`; booleans, strings, `None` and arrays are refused), and `ValueError` naming it
    unless it is finite and in `[low, high]` (`(low, high]` when `above`). Bounds keep every
    option where the algorithm means something and its cost stays bounded (unrolled loops,
    grids).
    """
    kinds = (int, np.integer) if integer else (int, float, np.integer, np.floating)
    if isinstance(value, bool | np.bool_) or not isinstance(value, kinds):
        kind = "an integer" if integer else "a real number"
        raise TypeError(f"`{name}` must be {kind}, got {_short(value)} "
                        f"({type(value).__name__}).")
    number = int(value) if integer else float(value)
    below = number <= low if above else number < low
    if not (integer or np.isfinite(number)) or below or number > high:
        interval = f"{'(' if above else '['}{low:g}, {high:g}]"
        raise ValueError(f"`{name}` must be {'an integer' if integer else 'a finite number'} in "
                         f"{interval}, got {value!r}.")
    return number


def check_vertex_ids(vertex_ids, count: int, name: str = "vertex_ids") -> np.ndarray:
    """`vertex_ids` as a non-empty (k,) int64 array of indices into `count` vertices: a
    `TypeError` naming `name` for values that are not integers, a `ValueError` for none, another
    shape or an index out of range (an empty list, read as floats, was said to be of the
    wrong dtype)."""
    ids = np.asarray(vertex_ids)
    if ids.size == 0:
        raise ValueError(f"`{name}` must name at least one vertex, got none.")
    if ids.dtype == bool or not np.issubdtype(ids.dtype, np.integer):
        raise TypeError(f"`{name}` must be integer vertex indices, got dtype {ids.dtype}.")
    if ids.ndim != 1:
        raise ValueError(f"`{name}` must be a (k,) array of vertex indices, got shape "
                         f"{ids.shape}.")
    out = ids[(ids < 0) | (ids >= count)]
    if out.size:
        raise ValueError(f"`{name}` must index the mesh's {count} vertices (0 to {count - 1}), "
                         f"got {out[:10].tolist()}.")
    return ids.astype(np.int64)


def check_finite_points(points: ArrayLike, name: str) -> np.ndarray:
    """`points` as a float64 NumPy array of shape `(k, 3)` or `(3,)`, all finite.

    Raises `TypeError` naming `name` for values that are not real numbers (strings, `None`,
    complex), `ValueError` for another shape or a non-finite value.
    """
    array = as_real_array(points, name, "an array")
    if array.shape[-1:] != (3,) or array.ndim not in (1, 2):
        raise ValueError(f"`{name}` must have shape (k, 3) or (3,), got shape {array.shape}.")
    array = array.astype(np.float64)
    if not np.isfinite(array).all():
        raise ValueError(f"`{name}` must be finite (found NaN or inf).")
    return array


def check_readable_file(path, kind: str, limit: int) -> None:
    """Raises for a `path` that is a folder (`ValueError`), missing (`FileNotFoundError`) or
    larger than `limit` bytes (`ValueError`), each naming the file and its `kind` (e.g. "a
    handle file"): the checks on an input file that need no reading."""
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not {kind}")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file ({kind})")
    size = path.stat().st_size
    if size > limit:
        raise ValueError(f"{path}: {size} bytes, more than {kind} may hold ({limit} bytes)")


def as_real_array(value, name: str, expected: str) -> np.ndarray:
    """`value` as a NumPy array of real numbers (integers or floats), else a `TypeError` naming
    `name` and the `expected` array (strings would be parsed, complex numbers lose their
    imaginary part)."""
    if value is None or isinstance(value, str | bytes):
        raise TypeError(f"`{name}` must be {expected} of real numbers, got {_short(value)}.")
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as error:
        raise TypeError(f"`{name}` must be {expected} of real numbers ({error}).") from None
    if array.dtype.kind not in "iuf":
        raise TypeError(f"`{name}` must be {expected} of real numbers, got dtype {array.dtype}.")
    return array

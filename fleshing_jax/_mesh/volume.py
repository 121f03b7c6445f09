"""Signed volumes of closed polygon meshes, as differentiable JAX functions.

By the divergence theorem the volume enclosed by a closed, consistently (outward) oriented
surface is the sum over its faces of the signed volumes of the cones from a reference point.
A triangle `(a, b, c)` contributes `a · (b × c) / 6` (coordinates relative to the reference).
A quad `(a, b, c, d)` is the average of its two splits into triangles: this is exact for the
bilinear patch through its four corners and does not depend on which diagonal one picks.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._checks import as_float_array, is_concrete


def _check(vertices: ArrayLike, faces: ArrayLike) -> tuple[Array, Array]:
    vertices = as_float_array(vertices, "vertices")
    if vertices.ndim < 2 or vertices.shape[-1] != 3:
        raise ValueError(f"`vertices` must have shape (..., V, 3), got shape {vertices.shape}.")
    faces = jnp.asarray(faces)
    if faces.ndim != 2 or faces.shape[-1] not in (3, 4):
        raise ValueError(f"`faces` must have shape (F, 3) or (F, 4), got shape {faces.shape}.")
    if not jnp.issubdtype(faces.dtype, jnp.integer):
        raise TypeError(f"`faces` must hold integer vertex indices, got dtype {faces.dtype}.")
    count = vertices.shape[-2]
    outside = (faces < 0) | (faces >= count)  # a gather would wrap −1 and give NaN past V
    if is_concrete(faces):
        bad = np.argwhere(np.asarray(outside))
        if bad.size:
            i, j = bad[0]
            raise ValueError(
                f"`faces` must index the {count} vertices (0 to {count - 1}), got "
                f"faces[{i}, {j}] = {int(faces[i, j])}."
            )
    elif faces.size:
        vertices = eqx.error_if(vertices, jnp.any(outside), "`faces` must index the vertices.")
    return vertices, faces


def _cone(a: Array, b: Array, c: Array) -> Array:
    return jnp.sum(a * jnp.cross(b, c), axis=-1) / 6


def face_volumes(vertices: ArrayLike, faces: ArrayLike) -> Float[Array, "... F"]:
    """The signed volume contributed by each face (cone from the vertices' centroid).

    Their sum is `volume(vertices, faces)`. Per face they depend on the reference point, so
    compare them only between two poses of the same mesh (or sum them over closed parts).

    **Arguments:**

    - `vertices`: (..., V, 3) array; leading axes batch several poses of the same mesh.
    - `faces`: (F, 3) triangles or (F, 4) quads, integer indices, outward orientation.

    **Returns:** (..., F) array, in the dtype of `vertices`.
    """
    vertices, faces = _check(vertices, faces)
    # Relative to the centroid: exact for closed meshes, and accurate in float32.
    local = vertices - jnp.mean(vertices, axis=-2, keepdims=True)
    corners = [jnp.take(local, faces[:, i], axis=-2) for i in range(faces.shape[-1])]
    if len(corners) == 3:
        return _cone(*corners)
    a, b, c, d = corners
    return 0.5 * (_cone(a, b, c) + _cone(a, c, d) + _cone(a, b, d) + _cone(b, c, d))


def volume(vertices: ArrayLike, faces: ArrayLike) -> Float[Array, ...]:
    """Signed volume enclosed by a closed mesh; differentiable in `vertices`.

    Positive for outward-oriented faces; agrees with `trimesh.Trimesh.volume` on closed meshes.
    Works under `jit`, `vmap` and `grad`. (On an open mesh the result is that of the mesh closed
    by the cones to the centroid of its vertices: close holes first, e.g. with `cap_holes`.)

    **Arguments:**

    - `vertices`: (..., V, 3) array; leading axes batch several poses (e.g. one per frame) or
      several copies of one element (e.g. a cloud of cubes, (K, 8, 3)).
    - `faces`: (F, 3) triangles or (F, 4) quads.

    **Returns:** (...) array of volumes.
    """
    return jnp.sum(face_volumes(vertices, faces), axis=-1)


def volume_change(before: ArrayLike, after: ArrayLike, faces: ArrayLike) -> Float[Array, ...]:
    """Relative volume change `(vol(after) − vol(before)) / vol(before)`.

    **Arguments:** `before`, `after`: (..., V, 3) vertices of two poses of one mesh; `faces`:
    (F, 3) or (F, 4). **Returns:** (...) array (e.g. per cube of a cloud of cubes).
    """
    v0, v1 = volume(before, faces), volume(after, faces)
    return (v1 - v0) / v0


def triangulate(faces: ArrayLike) -> np.ndarray:
    """Splits (F, 4) quads into (2F, 3) triangles along the diagonal `a–c`; triangles pass.

    Triangle `2i` is `(a, b, c)` and `2i + 1` is `(a, c, d)` for quad `i`.
    """
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[-1] not in (3, 4):
        raise ValueError(f"`faces` must have shape (F, 3) or (F, 4), got shape {faces.shape}.")
    if faces.shape[-1] == 3:
        return faces
    return np.stack([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]], axis=1).reshape(-1, 3)

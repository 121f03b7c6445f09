"""Frames along a spine: Frenet (where defined) and twist-compensated (rotation minimising)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from ._misc import safe_sqrt
from ._spine import AbstractSpine


def twist_normals(normals: tuple[Array, Array], twist: ArrayLike) -> tuple[Array, Array]:
    """Rotates the normals `(I, J)` by `twist` radians about `T = I × J` (right-hand rule)."""
    i, j = normals
    cos, sin = jnp.cos(twist), jnp.sin(twist)
    return cos * i + sin * j, cos * j - sin * i


def rotation_minimizing_frame(spine: AbstractSpine, s: ArrayLike, *, twist: ArrayLike = 0.0):
    """The twist-compensated frame of `spine` at arc length `s`.

    The first normal starts as `initial_normal(T(0))` (a fixed rule of the start tangent),
    rotated by `twist` radians about `T(0)` (right-hand rule), and is transported along the
    spine without rotation about the tangent.

    **Arguments:**

    - `spine`: an `AbstractSpine`.
    - `s`: scalar arc length (beyond the ends, the spine's circular continuation).
    - `twist`: scalar angle in radians.

    **Returns:** (3, 3) array whose rows are `(T, I, J)`, with `J = T × I`.
    """
    _, tangent, _ = spine.jet(s)
    i, j = twist_normals(spine.jet_and_normals(s)[1], jnp.asarray(twist, tangent.dtype))
    return jnp.stack([tangent, i, j])


def frenet_frame(spine: AbstractSpine, s: ArrayLike) -> tuple[Array, Array]:
    """The Frenet frame `(T, N, B)` of `spine` at `s`, where it is defined.

    **Returns:** `(frame, defined)`: a (3, 3) array with rows `(T, N, B)`, and a boolean that is
    `False` where the curvature is zero. There `N` and `B` do not exist; the rows returned are
    the rotation-minimising normals instead, so that the array never holds NaN.
    """
    _, tangent, k = spine.jet(s)
    kappa = safe_sqrt(jnp.dot(k, k))
    defined = kappa > 0
    i, j = spine.jet_and_normals(s)[1]
    normal = jnp.where(defined, k / jnp.where(defined, kappa, 1), i)
    binormal = jnp.where(defined, jnp.cross(tangent, normal), j)
    return jnp.stack([tangent, normal, binormal]), defined

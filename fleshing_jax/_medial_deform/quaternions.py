"""Unit quaternions `(w, x, y, z)` and rotation matrices, both ways, with finite derivatives.

Shared by the ARAP solver (its first-guess rotations are interpolated as quaternions) and the
skins (rotations blended as quaternions, dual quaternions for DQS).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._numerics import dot


def quaternion_from_matrix(r: Float[Array, "3 3"]) -> Float[Array, " 4"]:
    """A unit quaternion `(w, x, y, z)` of the rotation `r` (either sign), differentiable.

    Of the four ways to recover it (Shepperd's method), takes the one dividing by the largest
    component (`4 q_k² ≥ 1`), so the clamped square root below is exact on the branch that is
    used and every branch has finite derivatives."""
    t = jnp.trace(r)
    squares = jnp.stack([1 + t, 1 + 2 * r[0, 0] - t, 1 + 2 * r[1, 1] - t, 1 + 2 * r[2, 2] - t])
    half = 0.5 * jnp.sqrt(jnp.maximum(squares, 1))  # |q_k| on the branch used
    a, b, c = r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]
    d, e, f = r[0, 1] + r[1, 0], r[0, 2] + r[2, 0], r[1, 2] + r[2, 1]
    branches = jnp.stack([
        jnp.stack([half[0], a / (4 * half[0]), b / (4 * half[0]), c / (4 * half[0])]),
        jnp.stack([a / (4 * half[1]), half[1], d / (4 * half[1]), e / (4 * half[1])]),
        jnp.stack([b / (4 * half[2]), d / (4 * half[2]), half[2], f / (4 * half[2])]),
        jnp.stack([c / (4 * half[3]), e / (4 * half[3]), f / (4 * half[3]), half[3]]),
    ])
    return branches[jnp.argmax(squares)]


def matrix_from_quaternion(q: Float[Array, " 4"]) -> Float[Array, "3 3"]:
    """The rotation of a quaternion `q` (normalised here; the identity for `q = 0`)."""
    size = jnp.sqrt(dot(q, q))
    ok = size > 0
    w, x, y, z = jnp.where(ok, q / jnp.where(ok, size, 1), jnp.eye(4, dtype=q.dtype)[0])
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
        jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
        jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
    ])

"""Skinning a surface from the per-sphere rigid motions of a posed medial mesh (JAX).

Each sphere `i` carries the rigid motion `x ↦ c̃_i + R_i (x − c_i)` (`MedialPose`). A bound
vertex has its footprint `β` over (up to) three spheres of its primitive and *rotation
weights* `w` over `K` spheres (the footprint's weights smoothed over the mesh, `rig.py`):

- `medial` (Lan et al. 2017): `p' = c̃(β) + R(w) · (p − c(β))`: the footprint centre on the
  posed primitive, plus the rest offset turned by the blended rotation. The blend `R(w)` is a
  normalised quaternion blend (nlerp, signs aligned with the heaviest sphere's quaternion) —
  our choice over a matrix blend with polar projection, whose SVD has no finite derivative at
  repeated singular values (every rotation's).
- `lbs`: linear blend of the spheres' rigid transforms with weights `w`
  (Magnenat-Thalmann et al. 1988).
- `dqs`: dual-quaternion blend of the same transforms with weights `w` (Kavan et al. 2008).

Functions are for one vertex (batched with `vmap` in `rig.py`); per-sphere quantities
(quaternions, translations) are computed once per pose.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._numerics import dot, safe_divide, safe_sqrt, weighted_sum
from .quaternions import matrix_from_quaternion, quaternion_from_matrix


def _rotate(r: Array, v: Array) -> Array:
    return jnp.stack([dot(r[i], v) for i in range(3)])


def _aligned(quats: Float[Array, "K 4"], weights: Float[Array, " K"]) -> Array:
    """Weights times the sign that puts each quaternion on the first one's hemisphere."""
    sign = jnp.where(dot(quats, quats[0]) < 0, -1.0, 1.0).astype(quats.dtype)
    return weights * sign


def blend_quaternion(quats: Float[Array, "K 4"], weights: Float[Array, " K"]) -> Array:
    """Normalised blend of quaternions (nlerp), signs aligned with the first (heaviest)."""
    q = weighted_sum(_aligned(quats, weights), quats)
    length = safe_sqrt(dot(q, q))
    identity = jnp.zeros(4, q.dtype).at[0].set(1)
    return jnp.where(length > 0, safe_divide(q, length), identity)


def medial_vertex(
    centers: Float[Array, "3 3"],
    beta: Float[Array, " 3"],
    offset: Float[Array, " 3"],
    quats: Float[Array, "K 4"],
    weights: Float[Array, " K"],
) -> tuple[Array, Array]:
    """The medial skin of one vertex: `c̃(β) + R(w) · offset`. **Arguments:** the posed
    centres of its footprint's spheres, `β`, the rest offset, the quaternions and weights of
    its rotation spheres. **Returns:** `(position (3,), R (3, 3))`."""
    r = matrix_from_quaternion(blend_quaternion(quats, weights))
    centre = weighted_sum(beta, centers)
    return centre + _rotate(r, offset), r


def lbs_vertex(
    rotations: Float[Array, "K 3 3"],
    translations: Float[Array, "K 3"],
    weights: Float[Array, " K"],
    point: Float[Array, " 3"],
) -> Array:
    """Linear blend skinning of one rest vertex with sphere transforms `x ↦ R x + t`."""
    moved = jax.vmap(_rotate, (0, None))(rotations, point) + translations
    return weighted_sum(weights, moved)


def _multiply(a: Array, b: Array) -> Array:
    """Quaternion product `a ⊗ b`, `(w, x, y, z)`."""
    aw, av, bw, bv = a[0], a[1:], b[0], b[1:]
    return jnp.concatenate([(aw * bw - dot(av, bv))[None], aw * bv + bw * av + jnp.cross(av, bv)])


def dual_quaternion(q: Float[Array, " 4"], t: Float[Array, " 3"]) -> Float[Array, " 8"]:
    """Unit dual quaternion `(q, ½ (0, t) ⊗ q)` of the rigid motion `x ↦ R(q) x + t`."""
    pure = jnp.concatenate([jnp.zeros(1, t.dtype), t])
    return jnp.concatenate([q, 0.5 * _multiply(pure, q)])


def dqs_vertex(dual: Float[Array, "K 8"], weights: Float[Array, " K"], point: Array) -> Array:
    """Dual-quaternion skinning of one rest vertex (Kavan et al. 2008: blend, divide by the
    real part's norm, apply)."""
    w = _aligned(dual[:, :4], weights)
    b = weighted_sum(w, dual)
    length = safe_sqrt(dot(b[:4], b[:4]))
    b = jnp.where(length > 0, safe_divide(b, length), jnp.zeros(8, b.dtype).at[0].set(1))
    real, d = b[:4], b[4:]
    r0, rv, d0, dv = real[0], real[1:], d[0], d[1:]
    translation = 2 * (r0 * dv - d0 * rv + jnp.cross(rv, dv))
    return _rotate(matrix_from_quaternion(real), point) + translation


def sphere_motions(rest_centers: Array, centers: Array, rotations: Array):
    """Per-sphere quantities of a pose: quaternions (n, 4), translations `t_i = c̃_i − R_i c_i`
    (n, 3) and dual quaternions (n, 8)."""
    quats = jax.vmap(quaternion_from_matrix)(rotations)
    translations = centers - jax.vmap(_rotate)(rotations, rest_centers)
    dual = jax.vmap(dual_quaternion)(quats, translations)
    return quats, translations, dual


"""The volume a pose past its exact range loses, given back where it was carried.

Past a joint's exact range (`fj.joint_range`) the vertices past the joint are blended towards
their cross-sections' rigid motion (`posing._sections_carried`): the limb stays whole, but
the sections fan out on the convex side and pile up on the concave one, and the volume is
no longer kept (spot's head turned 45° sideways: −4.2 %; cheburashka's tilted 30°: −1.5 %).
Implicit skinning corrects the concave side of a joint by moving the skin along its normals
(Vaillant et al. 2013); here the blended vertices move along the volume's gradient (their
area-weighted normals), by one scalar `λ` for the whole pose, so that the mesh encloses
its rest volume again in proportion to the blend:

    vol(x + λ d) = vol(x) + b · (vol(rest) − vol(x)),   d_i = w_i ∂vol/∂x_i,

with `w_i` the blend of vertex `i` (0 wherever the map is exact: those vertices do not move)
and `b` the largest. Continuous in the angles (as `b → 0`, `λ d → 0`), differentiable (a few
Newton steps on a cubic in `λ`), and the vertices stay flagged: inexact, with the volume
kept.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

NEWTON_STEPS = 4  # the volume is a cubic in `λ`, near-linear here: 1e-12 relative in 3


def _signed_volume(vertices: Array, triangles: Array) -> Array:
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return jnp.sum(a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1])
                   + a[:, 1] * (b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2])
                   + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0])) / 6


def restored_volume(
    vertices: Float[Array, "n 3"], rest: Float[Array, "n 3"], triangles: Int[Array, "t 3"],
    blend: Float[Array, " n"],
) -> Float[Array, "n 3"]:
    """`vertices` with those of nonzero `blend` moved along the volume's gradient until the
    mesh `(vertices, triangles)` has given back the fraction `max(blend)` of the volume it
    lost from `rest` (see the module's docstring); `vertices` as they are where no blend is
    positive."""
    centre = jnp.mean(rest, axis=0)  # (relative to it: accurate in float32)
    x, x0 = vertices - centre, rest - centre
    grad = jax.grad(_signed_volume)(x, triangles)
    b = jnp.max(blend)
    direction = blend[:, None] * grad
    now = _signed_volume(x, triangles)
    goal = now + b * (_signed_volume(x0, triangles) - now)

    def step(lam, _):
        value, slope = jax.jvp(lambda t: _signed_volume(x + t * direction, triangles),
                               (lam,), (jnp.ones_like(lam),))
        safe = jnp.where(slope != 0, slope, 1)
        return lam - jnp.where(slope != 0, (value - goal) / safe, 0), None

    lam, _ = jax.lax.scan(step, jnp.zeros((), x.dtype), None, length=NEWTON_STEPS)
    return vertices + lam * direction

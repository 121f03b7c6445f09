"""Discrete rotation-minimising frames: double reflection (4th order) and projection (1st order).

Both propagate a normal `r` from one sample `(x₀, t₀)` of a spine (position, unit tangent) to the
next `(x₁, t₁)`:

- **double reflection** (Wang, Jüttler, Zheng & Liu 2008): reflect `r` and `t₀` in the plane
  bisecting `x₀x₁`, then in the plane that takes the reflected tangent to `t₁`. The frame error
  is `O(h⁴)` in the step `h`.
- **projection** (the paper, §3.2): project `r` on the normal plane of `t₁` and normalise.
  First order.

A general spine stores its normals at nodes (`propagate`) and evaluates anywhere by one
double-reflection step from the node at or before `s` (`step_from_node`), which is smooth in `s`
between nodes; the result is re-orthogonalised against the exact tangent, so the frame is exactly
orthonormal (all that `det J = 1` needs: the twist rate of the frame does not enter the volume
element).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._numerics import dot, norm, safe_divide, safe_sqrt

METHODS = ("double_reflection", "projection")


def _reflect(v: Array, normal: Array, normal_sq: Array) -> Array:
    """Reflection of `v` in the plane through 0 orthogonal to `normal` (identity if it is 0)."""
    return v - 2 * safe_divide(dot(v, normal), normal_sq) * normal


def orthonormalise(r: Array, tangent: Array) -> Array:
    """`r` made orthogonal to the unit `tangent` and normalised, (3,)."""
    r = r - dot(r, tangent) * tangent
    return r / norm(r)


def reflect_twice(chord: Array, t0: Array, r0: Array, t1: Array) -> Array:
    """The double reflection of `r0`: first in the plane orthogonal to `chord`, then in the one
    that takes the reflected `t0` to `t1`. Returns `r1` (3,), exactly orthogonal to `t1`.

    `chord` only needs the direction of `x₁ − x₀` (its length does not matter); a zero chord
    means a zero step, where the result is `r0` re-orthogonalised.
    """
    c1 = dot(chord, chord)
    r_l = _reflect(r0, chord, c1)
    t_l = _reflect(t0, chord, c1)
    v2 = t1 - t_l
    return orthonormalise(_reflect(r_l, v2, dot(v2, v2)), t1)


def double_reflection(x0, t0, r0, x1, t1, k0=None) -> Array:
    """The normal `r₁` at `(x₁, t₁)` transported from `r₀` at `(x₀, t₀)` by double reflection.

    All arguments are (3,) arrays. Where the step `x₁ − x₀` is so short that its direction is
    lost to round-off (below `∛eps` of the coordinates), its Taylor expansion
    `t₀ + (h/2) k₀` is used instead (`k₀`: curvature vector at `x₀`, optional), which keeps the
    result accurate, and finite with finite derivatives at `x₁ = x₀`.

    **Returns:** the (3,) unit normal at `x₁`, exactly orthogonal to `t₁`.
    """
    chord = x1 - x0
    c1 = dot(chord, chord)
    scale = jnp.max(jnp.abs(x0)) + safe_sqrt(c1)
    short = c1 <= (np.finfo(np.dtype(x0.dtype)).eps ** (1 / 3) * scale) ** 2
    h = safe_sqrt(jnp.where(short, c1, 0))
    taylor = t0 if k0 is None else t0 + 0.5 * h * k0
    return reflect_twice(jnp.where(short, taylor, chord), t0, r0, t1)


def projection(x0, t0, r0, x1, t1, k0=None) -> Array:
    """The paper's rule: `r₀` projected on the normal plane of `t₁`, normalised. (3,)."""
    del x0, t0, x1, k0
    return orthonormalise(r0, t1)


STEPS = {"double_reflection": double_reflection, "projection": projection}


def propagate(positions: Array, tangents: Array, curvatures: Array, r0: Array, method: str):
    """Transports the normal `r0` along samples of a spine.

    **Arguments:** `positions`, `tangents`, `curvatures`: (M, 3) samples in order along the
    spine; `r0`: (3,) unit normal at the first sample; `method`: `"double_reflection"` or
    `"projection"`.

    **Returns:** (M, 3) unit normals, the first one `r0` (made orthogonal to the first tangent).
    """
    step = STEPS[method]

    def body(carry, sample):
        x0, t0, k0, r0 = carry
        x1, t1, k1 = sample
        r1 = step(x0, t0, r0, x1, t1, k0)
        return (x1, t1, k1, r1), r1

    r0 = orthonormalise(r0, tangents[0])
    first = (positions[0], tangents[0], curvatures[0], r0)
    _, rest = jax.lax.scan(body, first, (positions[1:], tangents[1:], curvatures[1:]))
    return jnp.concatenate([r0[None], rest])

"""Closest projection of points on a spine, and the registration pytree.

The search is a coarse nearest sample followed by safeguarded Newton steps on
`f(s) = (C(s) − X)·T(s) = 0`, whose derivative is `f'(s) = 1 − k(s)·d` (positive inside the
reach). Both run on stopped gradients; a last Newton step with live gradients then gives the
implicit-function-theorem derivative `ds = −(∂f)/f'` exactly (`f ≈ 0` makes the rest vanish),
in forward and reverse mode alike.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from ._misc import relative_tolerance, safe_divide
from ._spine import AbstractSpine

NEWTON_STEPS = 8
CANDIDATES = 3  # Newton starts: the best local minima of the sampled distance


def closest_arc_length(spine: AbstractSpine, x: Array, samples: int | None = None):
    """Arc length `s` of the closest projection of one point on the (continued) spine.

    The search covers `[−e₀, length + e₁]` (see `AbstractSpine.extension`). It is global: Newton
    runs from the `CANDIDATES` best local minima of the sampled distance (so that a spine coming
    back near itself — a U-turn, a coil — is projected on its nearest part, not on the part
    whose sample happened to be nearest), and the closest result is kept. A point (nearly)
    equidistant from two separate parts of the spine has no unique projection: it is reported
    as not converged.

    **Arguments:** `spine`; `x`: (3,) point; `samples`: coarse samples (default: the spine's).

    **Returns:** `(s, converged)`: scalar arc length (differentiable with respect to `x` and the
    spine) and whether `s` is a stationary point strictly inside the searched range, and the
    unique closest one.
    """
    samples = spine.default_samples() if samples is None else samples
    spine = spine._prepare()
    fixed = jax.lax.stop_gradient(spine)
    x_fixed = jax.lax.stop_gradient(x)
    e0, e1 = fixed.extension()
    lo, hi = -e0, fixed.length + e1
    grid = jnp.linspace(lo, hi, samples)
    # Sample positions do not depend on x: under vmap they are computed once per spine.
    positions = jax.vmap(fixed)(grid)
    distances = jnp.sum((positions - x_fixed) ** 2, axis=-1)
    inf = jnp.asarray(jnp.inf, distances.dtype)
    before = jnp.concatenate([inf[None], distances[:-1]])
    after = jnp.concatenate([distances[1:], inf[None]])
    minima = jnp.where((distances <= before) & (distances <= after), distances, inf)
    count = min(CANDIDATES, samples)
    _, index = jax.lax.top_k(-minima, count)
    candidate = jnp.isfinite(minima[index]).at[0].set(True)
    h = (hi - lo) / (samples - 1)

    def newton(_, s):
        c, tangent, k = fixed.jet(s)
        d = x_fixed - c
        f, slope = -jnp.dot(d, tangent), 1 - jnp.dot(k, d)
        # Outside the local reach Newton heads for a maximum: step downhill instead.
        step = jnp.where(slope > 0, -f / jnp.where(slope > 0, slope, 1), -jnp.sign(f) * h)
        step = jnp.where(jnp.abs(step) > h, jnp.sign(step) * h, step)
        return jnp.where(s + step < lo, lo, jnp.where(s + step > hi, hi, s + step))

    def solve(s):
        s = jax.lax.fori_loop(0, NEWTON_STEPS, newton, s)
        d = x_fixed - fixed(s)
        return s, jnp.dot(d, d)

    starts, distance = jax.vmap(solve)(grid[index])
    distance = jnp.where(candidate, distance, inf)
    best = jnp.argmin(distance)
    s = jax.lax.stop_gradient(starts[best])
    # Another candidate, elsewhere on the spine, as close as the best one: no unique projection.
    tol = relative_tolerance(distance.dtype)
    elsewhere = jnp.abs(starts - s) > h
    tie = candidate & elsewhere & (distance - distance[best] <= tol * (1 + distance[best]))
    c, tangent, k = spine.jet(s)
    d = x - c
    f, slope = -jnp.dot(d, tangent), 1 - jnp.dot(k, d)
    s = s - safe_divide(f, jnp.where(slope > 0, slope, 0))
    converged = (jnp.abs(f) <= tol * (1 + jnp.linalg.norm(d))) & (s > lo) & (s < hi)
    return s, converged & ~jnp.any(tie)


class Registration(eqx.Module):
    """Points registered on a source spine: everything a new pose needs, per point.

    Produced by `register`; consumed by `pose`. All offsets are in the source spine's
    twist-compensated frame `(I₀, J₀)` at the projection.

    **Fields:**

    - `points`: (N, 3) the input points.
    - `arc_length`: (N,) arc length `s` of the closest projection.
    - `offset`: (N, 2) offset `X − C₀(s)` in `(I₀, J₀)` coordinates.
    - `curvature`: (N, 2) curvature vector `k₀(s)` in `(I₀, J₀)` coordinates.
    - `valid`: (N,) bool: finite, projected, and strictly inside the reach of the source.
    - `length`: scalar length of the source spine.
    """

    points: Float[Array, "*batch 3"]
    arc_length: Float[Array, " *batch"]
    offset: Float[Array, "*batch 2"]
    curvature: Float[Array, "*batch 2"]
    valid: Bool[Array, " *batch"]
    length: Float[Array, ""]


def register_point(spine: AbstractSpine, x: ArrayLike, samples: int | None = None) -> Registration:
    """Registers one point (3,) on `spine`; see `register` for the batched version."""
    x = jnp.asarray(x)
    spine = spine._prepare()
    finite = jnp.all(jnp.isfinite(x))
    s, converged = closest_arc_length(spine, jnp.where(finite, x, 0), samples)
    (c, _, k), (i, j) = spine.jet_and_normals(s)
    d = jnp.where(finite, x, 0) - c
    offset = jnp.stack([jnp.dot(d, i), jnp.dot(d, j)])
    curvature = jnp.stack([jnp.dot(k, i), jnp.dot(k, j)])
    valid = finite & converged & (1 - jnp.dot(curvature, offset) > 0)
    return Registration(x, s, offset, curvature, valid, spine.length)

"""A certified lower bound of a spine's reach, so that most points skip the global search.

Within the reach of a curve, every point has a unique closest point, and a foot of a normal at a
distance below the reach *is* that closest point (Federer 1959, Thm 4.8). So a point whose
Newton-converged foot `s` lies strictly inside the searched range `[lo, hi]` at a distance
`r < ρ`, for a lower bound `ρ` of the reach, is projected correctly without the global
multi-candidate search. The bound is computed once per spine (per pose, per registration), from
`REACH_SAMPLES` samples of the continued spine on `[lo, hi]`, at spacing `h`:

For a window `w`, split the other spine points `t` into near (`|t − s| < w`) and far ones. Near:
`f(t) = ½|X − C(t)|²` has `f'' = 1 − k(t)·(X − C(t)) ≥ 1 − κ̂ (r + |t − s|) > 0` when
`κ̂ (r + w) < 1` (`κ̂ ≥ max κ`), so `s` is the only minimum there. Far: if every pair of spine
points at least `w` apart in arc length is at least `D(w)` apart in space, then
`|X − C(t)| ≥ D(w) − r > r` when `2r < D(w)`. Hence

    ρ = max over w of min(1/κ̂ − w, D(w)/2),

with the sampled `D(w)` lowered by `h` (true points lie within `h/2` of samples) and taken over
sample pairs at least `w − h` apart. `κ̂` is the largest sampled curvature plus the largest jump
between neighbouring samples (a Lipschitz margin for the curvature between samples). Points
that are not certified this way still get the full global search: the bound only saves work.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array

from ._spine import AbstractSpine

REACH_SAMPLES = 384
WINDOWS = 16  # candidate windows w = j/(WINDOWS κ̂), j = 1 … WINDOWS − 1, and the whole range


def search_range(spine: AbstractSpine) -> tuple[Array, Array]:
    """`(lo, hi)`: the arc lengths the closest-point search covers (ends continued)."""
    e0, e1 = spine.extension()
    return -e0, spine.length + e1


def reach_lower_bound(spine: AbstractSpine, samples: int = REACH_SAMPLES) -> Array:
    """A lower bound of the reach of `spine` continued over its search range (scalar, ≥ 0).

    Infinite for a straight spine. Computed without gradients (it only decides which points need
    the global search).
    """
    spine = jax.lax.stop_gradient(spine._prepare())
    lo, hi = search_range(spine)
    grid = jnp.linspace(lo, hi, samples)
    h = (hi - lo) / (samples - 1)
    positions, _, k = jax.vmap(spine.jet)(grid)
    kappa = jnp.linalg.norm(k, axis=-1)
    kappa_hat = jnp.max(kappa) + jnp.max(jnp.abs(jnp.diff(kappa)))
    radius = 1 / kappa_hat  # inf on a straight spine
    chords = jnp.linalg.norm(positions[:, None] - positions[None], axis=-1)
    # The closest chord between samples m apart (m = 0 … S−1), then between samples at least
    # m apart (a suffix minimum): the far distance of every window from one (S, S) pass.
    index = jnp.arange(samples)
    separation = jnp.abs(index[:, None] - index[None])
    closest = jnp.full(samples, jnp.inf, chords.dtype).at[separation].min(chords)
    at_least = jax.lax.cummin(closest, reverse=True)
    fractions = jnp.arange(1, WINDOWS, dtype=h.dtype) / WINDOWS
    windows = jnp.append(jnp.where(jnp.isfinite(radius), fractions * radius, 0), hi - lo + 2 * h)
    # Pairs at least `w − h` apart in arc length: separations m with m·h ≥ w − h (m·h grows
    # with m, so the first such m is the count of those below).
    first = jnp.sum(index * h < (windows - h)[:, None], axis=1)
    far = jnp.append(at_least, jnp.inf)[first] - h
    return jnp.maximum(jnp.max(jnp.minimum(radius - windows, far / 2)), 0)

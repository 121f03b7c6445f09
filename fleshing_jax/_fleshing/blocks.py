"""Runs of the valid region's samples, with bounds in O(1) a run of the two conditions of its
sampled test (`region`): the pruned test `ValidRegion.surely_clear`.

The samples `P_j` (S of them) are cut into runs of `size` consecutive samples (the last run
padded with copies of the last sample: bounds over the same values). For a point `X`:

- **Distances.** A run lies in the capsule of the segment `A B` from its first sample to its
  last, of radius `ε` (its farthest sample from the segment): every `P_j` of it is `Q_j + e_j`
  with `Q_j` on the segment and `|e_j| ≤ ε`, so `|X − P_j| ≥ dist(X, AB) − ε`. (A ball
  around the run would bound the distances only to within its half length; a gently curved
  run's capsule is as thin as its sagitta, `κ L²/8`.) Above, `|X − P_j| ≤ |X − A| + ρ`, with
  `ρ` the largest `|P_j − A|` (the bound multiplies small terms only).
- **Convexity.** The test's `1 − k_j·(X − P_j) − J_j (|X − P_j| + h + δ) − κ̂_j (h + δ)` is
  `b_j + k_j·(A − X) − J_j |X − P_j|` with `b_j = 1 + k_j·(P_j − A) − (J_j + κ̂_j)(h + δ)`
  free of `X`; with `k̄` the run's mean curvature vector and `σ` the largest `|k_j − k̄|`, it is
  at least `min b_j + k̄·(A − X) − (σ + max J_j) |A − X| − max J_j ρ` on the whole run.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._numerics import safe_divide


def _segment_offset(x, start, axis, inverse) -> list[Array]:
    """`X − Q` per coordinate, `Q` the point of the segment `start + t axis`, `0 ≤ t ≤ 1`,
    closest to `X` (`inverse`: `1/|axis|²`, 0 for a point); lists of 3 broadcasting arrays."""
    offsets = [xi - a for xi, a in zip(x, start)]
    t = jnp.clip(sum(o * u for o, u in zip(offsets, axis)) * inverse, 0, 1)
    return [o - t * u for o, u in zip(offsets, axis)]


def _length(vector) -> Array:
    return jnp.sqrt(sum(v * v for v in vector))


class SampleBlocks(eqx.Module):
    """The runs of the valid region's samples and their bounds (see the module's docstring).

    **Fields:** `size` (static): samples a run; `start`, `axis` (3, B): each run's segment
    `A`, `B − A`; `inverse` (B,): `1/|B − A|²` (0 when `A = B`); `spread` (B,): the capsule's
    radius `ε`; `radius` (B,): `ρ`; `base` (B,): `min b_j`; `mean` (3, B): `k̄`; `deviation`
    (B,): `σ`; `wiggle` (B,): `max J_j`.
    """

    size: int = eqx.field(static=True)
    start: Array
    axis: Array
    inverse: Array
    spread: Array
    radius: Array
    base: Array
    mean: Array
    deviation: Array
    wiggle: Array

    def __init__(self, positions, curvature, wiggle, kappa, reach: Array, size: int):
        """`positions`, `curvature` (3, S), `wiggle`, `kappa` (S,): the region's samples `P_j`,
        `k_j`, `J_j`, `κ̂_j`; `reach`: `h + δ`; `size`: samples a run."""
        count = positions.shape[1]
        blocks = -(-count // size)
        index = jnp.minimum(jnp.arange(blocks * size), count - 1).reshape(blocks, size)
        runs, k = positions[:, index], curvature[:, index]  # (3, B, size)
        self.size = size
        self.start = runs[:, :, 0]
        self.axis = runs[:, :, -1] - self.start
        self.inverse = safe_divide(1.0, sum(u * u for u in self.axis))
        column = (self.start[:, :, None], self.axis[:, :, None], self.inverse[:, None])
        self.spread = jnp.max(_length(_segment_offset(runs, *column)), axis=1)
        self.radius = jnp.max(_length([p - a[:, None] for p, a in zip(runs, self.start)]), axis=1)
        along = sum(kc * (p - a[:, None]) for kc, p, a in zip(k, runs, self.start))
        self.base = jnp.min(1 + along - (wiggle[index] + kappa[index]) * reach, axis=1)
        self.mean = jnp.mean(k, axis=2)
        self.deviation = jnp.max(_length([kc - m[:, None] for kc, m in zip(k, self.mean)]), axis=1)
        self.wiggle = jnp.max(wiggle[index], axis=1)

    def nearest(self, x: Array) -> Array:
        """A lower bound of `|X − P_j|` over each run (B,); `x` (3,)."""
        return _length(_segment_offset(x, self.start, self.axis, self.inverse)) - self.spread

    def farthest(self, x: Array) -> Array:
        """An upper bound of `|X − P_j|` over each run (B,); `x` (3,)."""
        return _length([xi - a for xi, a in zip(x, self.start)]) + self.radius

    def convex(self, x: Array) -> Array:
        """A lower bound of the sampled test's convexity term over each run (B,); `x` (3,)."""
        u = [a - xi for a, xi in zip(self.start, x)]  # A − X
        return (self.base + sum(m * ui for m, ui in zip(self.mean, u))
                - (self.deviation + self.wiggle) * _length(u) - self.wiggle * self.radius)

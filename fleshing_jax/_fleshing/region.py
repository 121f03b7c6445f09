"""Where a fleshing is continuous: the valid region of a spine, with a margin.

The map is built on the closest projection onto the spine, which is continuous everywhere but on
the spine's *cut locus* (points with two closest feet on different stretches) and its *focal
set* (where `1 − k·d` reaches 0). A mesh tears where an edge crosses either. A point `X` is
therefore valid only if the whole ball `B(X, δ)` of radius `δ` (the margin) is free of both:
then an edge no longer than `2δ` whose two ends are valid has every point of it within `δ` of
an end, so no point of it on the cut locus or the focal set, and its image is not torn
(`deform_mesh` takes `δ` as half the mesh's longest edge; for a point set, `δ = 0` by default).

Chosen test (direction-aware, so not conservative on the convex side of a bend): for `X` at
offset `d = X − C(s)`, `r = |d|`, every `Y = X + e` with `|e| ≤ δ` has, on the window
`|t − s| ≤ w`, `f_Y(t) = ½|Y − C(t)|²` with

    f_Y''(t) = 1 − k(t)·(Y − C(t)) ≥ 1 − k(s)·d − J(w) r − κ̂(w) δ − ½ κ̂(w)² w² > 0,

(`J(w)`: the largest `|k(t) − k(s)|` in the window, `κ̂(w)` the largest curvature; the last term
bounds `k(t)·(C(s) − C(t))`, of second order since `k(t) ⟂ T(t)`): the window holds one
minimum only. Outside the window, each spine point is within `h/2` of a sample `P_j` at least
`W` samples from the foot's, and `|Y − C(t)| ≥ |X − P_j| − h/2 − δ > r + δ ≥ |Y − C(s)|` when
`|X − P_j| > r + 2δ + h/2`: no far point is closer. Both hold ⇒ `Y` has one closest foot, in
the window, where `f_Y'' > 0`: `B(X, δ)` misses the cut locus and the focal set. The window is
the largest of `W = 1, 2, 4, …` samples whose near condition holds (they tighten as it grows).

The test costs one pass over the `S` samples a point. The batched paths first try the
direction-free certificate of `reach.LocalReach` built with the same margin (O(1) a point,
certifies the inner tube) and run the sampled test on the others only (`update_where`).
Lines (no cut locus) and arcs (the axis, `1 − k·d > δ κ`; wrapping handled in closed form by
`_foot_is_unique`) are tested in closed form (`closed_form_clear`).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._numerics import dot, norm
from .._spines.spine import AbstractSpine
from .reach import REACH_SAMPLES, LocalReach, search_range


def _window_max(values: Array, radius: int) -> Array:
    """The largest of `values` (..., S) within `radius` indices along the last axis."""
    return jax.lax.reduce_window(
        values,
        -jnp.inf,
        jax.lax.max,
        (1,) * (values.ndim - 1) + (2 * radius + 1,),
        (1,) * values.ndim,
        ((0, 0),) * (values.ndim - 1) + ((radius, radius),),
    )


class ValidRegion(eqx.Module):
    """The valid region of a (prepared) spine with a margin `δ`, tested one point at a time.

    **Fields:** `spine` (prepared or its table), `margin` (scalar `δ ≥ 0`), `reach` (the
    direction-free certificate with the same margin), `positions` (3, S) samples over the search
    range `[lo, hi]` at spacing `h`, `spread` and `kappa` (L, S): `J` and `κ̂` of each sample's
    windows of `2^m` samples (`m < L`).
    """

    spine: AbstractSpine
    margin: Array
    reach: LocalReach
    lo: Array
    h: Array
    positions: Array
    spread: Array
    kappa: Array

    def __init__(self, spine: AbstractSpine, margin: Array, samples: int = REACH_SAMPLES):
        spine = jax.lax.stop_gradient(spine._prepare())
        self.spine = spine
        self.margin = jax.lax.stop_gradient(jnp.asarray(margin, spine.length.dtype))
        self.reach = LocalReach(spine, samples, self.margin)
        lo, hi = search_range(spine)
        grid = jnp.linspace(lo, hi, samples)
        self.lo, self.h = lo, (hi - lo) / (samples - 1)
        positions, _, k = jax.vmap(spine.jet)(grid)
        self.positions = positions.T
        # Between samples the curvature vector moves by at most about the largest jump between
        # neighbours (a Lipschitz margin, as in `reach`).
        jumps = norm(jnp.diff(k, axis=0, append=k[-1:]))
        difference = jnp.sqrt(sum((c[None] - c[:, None]) ** 2 for c in k.T))  # (S, S)
        index = jnp.arange(samples)
        apart = jnp.abs(index[None] - index[:, None])
        spread, kappa = [], []
        for m in range(self.levels(samples)):
            radius = 2**m + 1
            jump = _window_max(jumps, radius + 1)
            spread.append(jnp.max(jnp.where(apart <= radius, difference, 0), axis=1) + 2 * jump)
            kappa.append(_window_max(norm(k), radius) + jump)
        self.spread, self.kappa = jnp.stack(spread), jnp.stack(kappa)

    @staticmethod
    def levels(samples: int) -> int:
        """How many windows (`2^m` samples, `m < levels`): the last spans the whole range."""
        return math.ceil(math.log2(samples)) + 1

    def certified(self, s: Array, distance: Array) -> Array:
        """The O(1) direction-free test: a point at `distance` from the spine at its foot `s`
        keeps the margin when it is inside the certified tube (`LocalReach` with `δ`)."""
        return distance < self.reach(s)

    def clear(self, x: Array, s: Array) -> Array:
        """Whether the ball of radius `margin` around `x` (3,), whose foot is at `s`, misses the
        cut locus and the focal set (the sampled test above; one point, scalar bool)."""
        samples = self.positions.shape[1]
        c, _, k = self.spine.jet(s)
        d = x - c
        r = norm(d)
        i = jnp.clip(jnp.round((s - self.lo) / self.h), 0, samples - 1).astype(jnp.int32)
        width = (2.0 ** jnp.arange(self.spread.shape[0]) + 1) * self.h
        spread, kappa = self.spread[:, i], self.kappa[:, i]
        near = 1 - dot(k, d) - spread * r - kappa * self.margin - 0.5 * (kappa * width) ** 2 > 0
        count = jnp.sum(jnp.cumprod(near))  # windows whose near condition holds
        window = jnp.where(count > 0, 2 ** jnp.maximum(count - 1, 0), samples)
        far = jnp.abs(jnp.arange(samples) - i) >= window
        squared = sum((p - xi) ** 2 for p, xi in zip(self.positions, x))
        need = r + 2 * self.margin + 0.5 * self.h
        return (count > 0) & jnp.all(~far | (squared > need * need))


def closed_form_clear(offset: Array, curvature: Array, margin: Array) -> Array:
    """The margin test on a line or an arc, where the only cut set inside the search range is
    the axis of the arc: `1 − k·d > δ |k|` (the distance to the axis is `(1 − k·d)/κ`).
    `offset`, `curvature`: (2,) in the local normals."""
    return 1 - dot(curvature, offset) > margin * norm(curvature)

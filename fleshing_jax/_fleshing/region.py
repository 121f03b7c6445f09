"""Where a fleshing is continuous: the valid region of a spine, with a margin.

The map is built on the closest projection onto the spine, which is continuous everywhere but on
the spine's *cut locus* (points with two closest feet on different stretches) and its *focal
set* (where `1 − k·d` reaches 0). A mesh tears where an edge crosses either. A point `X` is
therefore valid only if the whole ball `B(X, δ)` of radius `δ` (the margin) is free of both:
then an edge no longer than `2δ` whose two ends are valid has every point of it within `δ` of
an end, so no point of it on the cut locus or the focal set, and its image is not torn
(`deform_mesh` takes `δ` as half the mesh's longest edge; for a point set, `δ = 0` by default).

Chosen test (direction-aware, exact at the samples, so not conservative on the convex side
of a bend): with `S` samples `P_j = C(t_j)` at spacing `h` over the search range and
`f_Y(t) = ½|Y − C(t)|²`, every `Y = X + e`, `|e| ≤ δ`, has

    f_Y''(t) = 1 − k(t)·(Y − C(t)) ≥ 1 − k_j·(X − P_j) − J_j (|X − P_j| + h + δ) − κ̂_j (h + δ)

for `t` within `h` of `t_j` (`J_j`, `κ̂_j`: bounds of `|k(t) − k_j|` and `|k(t)|` there, from
the neighbouring samples). The *window* is the run of samples around the foot's where this is
positive: `f_Y` is convex there, so it has one minimum there. Outside the window, a spine point
`C(t)` within `h/2` of a sample `P_j` is farther from `Y` than `C(s)` is when

    (|X − P_j| − h/2)² − r² > 2δ (|P_j − C(s)| + h/2)

(since `|Y − C(t)|² − |Y − C(s)|² = |X − C(t)|² − r² − 2e·(C(t) − C(s))`): then no point outside
the window is as close as the window's minimum. Both hold ⇒ every `Y` in the ball has one
closest foot, inside the window, where `f_Y'' > 0`: the ball misses the cut locus and the
focal set. (With `δ = 0` the test is the projection check, to within `h/2`.)

The test costs one pass over the `S` samples a point. The batched paths first try the
direction-free certificate of `reach.LocalReach` built with the same margin (O(1) a point,
certifies the inner tube), then the *pruned test* on the others (`surely_clear`, O(S/16) a
point), and run the sampled test on the few that neither certifies (`clear_where`). The pruned
test rests on this: the sampled test passes if and only if every sample from the foot's to the
farthest sample, on either side, that is not far (fails the second condition) is convex
(passes the first), since the window is then the whole run and holds every sample that is not
far. `blocks.SampleBlocks` bounds both conditions on runs of 16 samples; the point passes when
every run from the foot's to the farthest run that is not surely far is surely convex. The
bounds beat the samples' own tests by a thousand rounding errors, so that a point passed by
the pruned test is passed by the sampled test too, in float32 as in float64: the two passes
give the sampled test's flags (on spot's head posed, the pruned test passes all the points the
reach bound leaves: 20× faster).
Lines (no cut locus) and arcs (the axis, `1 − k·d > δ κ`; wrapping handled in closed form by
`_foot_is_unique`) are tested in closed form (`closed_form_clear`).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, PyTree

from .._batching.compact import update_where
from .._numerics import dot, norm
from .._spines.spine import AbstractSpine
from .blocks import SampleBlocks
from .reach import REACH_SAMPLES, LocalReach, local_reaches, sampled_jets, search_range

RUN = 16  # samples a run of the pruned test (`blocks`)
SURE_CHUNK = 256  # points a trip of `clear_where`'s pruned test


class ValidRegion(eqx.Module):
    """The valid region of a (prepared) spine with a margin `δ`, tested one point at a time.

    **Fields:** `spine` (prepared or its table), `margin` (scalar `δ ≥ 0`), `reach` (the
    direction-free certificate with the same margin), `lo`, `h` (the first sample and the
    spacing), `positions` and `curvature` (3, S): the samples `P_j` and `k_j` over the search
    range; `wiggle` and `kappa` (S,): `J_j` and `κ̂_j`.
    """

    spine: AbstractSpine
    margin: Array
    reach: LocalReach
    unmargined: LocalReach | None
    lo: Array
    h: Array
    positions: Array
    curvature: Array
    wiggle: Array
    kappa: Array
    blocks: SampleBlocks
    extent: Array
    stiffness: Array

    def __init__(self, spine: AbstractSpine, margin: Array, samples: int = REACH_SAMPLES,
                 certificate: int | None = None, unmargined: bool = False):
        """`certificate`: the samples of the direction-free certificate (`reach`; default
        `samples`, built on the same jets). Any count gives a sound certificate: it only
        decides which points skip the pruned and sampled tests (a posed limb's is smaller:
        `_skeleton.posing.CERTIFICATE_SAMPLES`). `unmargined`: also the spine's `LocalReach`
        without the margin (`self.unmargined`, else `None`; a registration's fast path,
        `projection.Registrar`), computed with the certificate (`reach.local_reaches`)."""
        spine = jax.lax.stop_gradient(spine._prepare())
        self.spine = spine
        self.margin = jax.lax.stop_gradient(jnp.asarray(margin, spine.length.dtype))
        jets = sampled_jets(spine, samples)  # (the reach bounds' samples too: evaluated once)
        own = certificate is None or certificate == samples
        if unmargined and own:
            margins = jnp.stack([jnp.zeros_like(self.margin), self.margin])
            self.unmargined, self.reach = local_reaches(spine, margins, samples, jets)
        else:
            self.unmargined = LocalReach(spine, samples) if unmargined else None
            self.reach = LocalReach(spine, samples if own else certificate, self.margin,
                                    jets if own else None)
        lo, hi = search_range(spine)
        self.lo, self.h = lo, (hi - lo) / (samples - 1)
        positions, _, k = jets
        self.positions, self.curvature = positions.T, k.T
        # Within h of a sample, the curvature vector moves by at most about twice the largest
        # change to a neighbour (a Lipschitz margin for the curvature between samples).
        change = norm(jnp.diff(k, axis=0))
        change = jnp.maximum(jnp.pad(change, (1, 0)), jnp.pad(change, (0, 1)))
        self.wiggle = 2 * change
        self.kappa = norm(k) + self.wiggle
        self.blocks = SampleBlocks(self.positions, self.curvature, self.wiggle, self.kappa,
                                   self.h + self.margin, RUN)
        self.extent = jnp.max(jnp.sum(jnp.abs(positions), axis=1))
        self.stiffness = jnp.max(self.kappa + self.wiggle)

    def certified(self, s: Array, distance: Array) -> Array:
        """The O(1) direction-free test: a point at `distance` from the spine at its foot `s`
        keeps the margin when it is inside the certified tube (`LocalReach` with `δ`)."""
        return distance < self.reach(s)

    def clear(self, x: Array, s: Array) -> Array:
        """Whether the ball of radius `margin` around `x` (3,), whose foot is at `s`, misses the
        cut locus and the focal set (the sampled test above; one point, scalar bool)."""
        h, margin = self.h, self.margin
        samples = self.positions.shape[1]
        c, r, i = self._foot(x, s)
        offsets = [p - xi for p, xi in zip(self.positions, x)]  # P_j − X, per coordinate
        distance = jnp.sqrt(sum(o * o for o in offsets))
        convex = 1 + sum(k * o for k, o in zip(self.curvature, offsets)) - self.wiggle * (
            distance + h + margin
        ) - self.kappa * (h + margin) > 0
        index = jnp.arange(samples)
        left = jnp.max(jnp.where(~convex & (index <= i), index, -1))
        right = jnp.min(jnp.where(~convex & (index >= i), index, samples))
        far = (index <= left) | (index >= right)
        chord = jnp.sqrt(sum((p - ci) ** 2 for p, ci in zip(self.positions, c)))
        gap = jnp.maximum(distance - 0.5 * h, 0) ** 2 - r * r
        return convex[i] & jnp.all(~far | (gap > 2 * margin * (chord + 0.5 * h)))

    def surely_clear(self, x: Array, s: Array) -> Array:
        """The pruned test (above): `True` only where `clear(x, s)` is, in O(runs) (one point,
        scalar bool; `False` says nothing)."""
        h, margin, blocks = self.h, self.margin, self.blocks
        c, r, i = self._foot(x, s)
        # Bounds that beat the samples' own tests by a thousand rounding errors of either.
        size = jnp.sum(jnp.abs(x)) + self.extent + r + h + margin
        rounding = 1000 * jnp.finfo(h.dtype).eps
        near = jnp.maximum(blocks.nearest(x) - 0.5 * h - rounding * size, 0)
        far = near * near > r * r + 2 * margin * (blocks.farthest(c) + 0.5 * h)
        convex = blocks.convex(x) > rounding * (1 + self.stiffness * size)
        # The runs from the foot's to the farthest one that is not far on either side.
        run = jnp.arange(far.shape[0])
        own = i // blocks.size
        first = jnp.minimum(own, jnp.min(jnp.where(far, far.shape[0], run)))
        last = jnp.maximum(own, jnp.max(jnp.where(far, -1, run)))
        inside = (run >= first) & (run <= last)
        return jnp.all(convex | ~inside) & jnp.isfinite(s) & jnp.all(jnp.isfinite(x))

    def _foot(self, x: Array, s: Array) -> tuple[Array, Array, Array]:
        """`(C(s), |x − C(s)|, i)`: the foot, the distance to it and the foot's sample."""
        samples = self.positions.shape[1]
        c = self.spine(s)
        i = jnp.clip(jnp.round((s - self.lo) / self.h), 0, samples - 1).astype(jnp.int32)
        return c, norm(x - c), i


def clear_where(needed: Array, region: ValidRegion, values: Array, inputs: PyTree,
                place: Callable | None = None) -> Array:
    """`values` (n,) bool with entry `i` replaced by `region.clear(*inputs[i])` wherever
    `needed[i]` (`update_where`), `inputs` the points' images and their arc lengths on the
    target (`((n, 3), (n,))`, as they were placed: never bent again here), or with `place`,
    what it makes them of (one point's `inputs` → `(image, s₁)`): the pruned test first, the
    sampled one on the points it does not certify only (on spot's head, none)."""
    place = (lambda one: one) if place is None else place

    def surely(one):
        return region.surely_clear(*place(one))

    # Cheap a point: in larger chunks than the sampled test's, fewer trips of the loop.
    sure = update_where(needed, surely, jnp.zeros_like(needed), inputs, chunk=SURE_CHUNK)
    return update_where(needed & ~sure, lambda one: region.clear(*place(one)), values | sure,
                        inputs)


def clear_all(region: ValidRegion, inputs: PyTree) -> Array:
    """`region.clear(*inputs[i])` for every `i` (n,): `clear_where` on all of them."""
    none = jnp.zeros(jax.tree.leaves(inputs)[0].shape[0], bool)
    return clear_where(~none, region, none, inputs)


def closed_form_clear(offset: Array, curvature: Array, margin: Array) -> Array:
    """The margin test on a line or an arc, where the only cut set inside the search range is
    the axis of the arc: `1 − k·d > δ |k|` (the distance to the axis is `(1 − k·d)/κ`).
    `offset`, `curvature`: (2,) in the local normals."""
    return 1 - dot(curvature, offset) > margin * norm(curvature)

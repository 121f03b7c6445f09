"""Certified lower bounds of a spine's reach, so that most points skip the global search.

Within the reach of a curve, every point has a unique closest point, and a foot of a normal at a
distance below the reach *is* that closest point (Federer 1959, Thm 4.8). The same holds
locally: a point whose Newton-converged foot `s` lies strictly inside the searched range
`[lo, hi]`, at a distance `r` below a lower bound `ρ(s)` of the reach *around `s`*, is projected
correctly without the global multi-candidate search. The bounds are computed once per spine
(per pose, per registration; not for lines and arcs, whose feet have closed forms), from
`REACH_SAMPLES` samples `P_j` of the continued spine on `[lo, hi]` at spacing `h`, one per
sample `t_i`, for the feet nearest to it:

For a window `w`, split the spine points `t` into near (`|t − s| < w`) and far ones. Near:
`f(t) = ½|X − C(t)|²` has `f'' = 1 − k(t)·(X − C(t)) ≥ 1 − κ̂ (r + |t − s|) > 0` when
`κ̂ (r + w) < 1` (`κ̂ ≥ max κ`), so `s` is the only minimum there. Far: with `X = C(s) + r n`,
`n ⟂ T(s)` and `Δ = C(t) − C(s)`, `|X − C(t)|² − r² = |Δ|² − 2r Δ·n ≥ |Δ|² − 2r |Δ⊥|` (`Δ⊥`:
the part of `Δ` across `T(s)`), positive when `r < |Δ|²/(2|Δ⊥|)`; and `|X − C(t)| ≥ |Δ| − r > r`
when `r < |Δ|/2`. For `s` nearest to sample `i`, `t` nearest to sample `j` and `δ = P_j − P_i`
(unit speed: `|Δ − δ| ≤ h`, `|T(s) − T_i| ≤ κ̂h/2`): `|Δ| ≥ a = |δ| − h`, `|Δ⊥| ≤ c =
|δ⊥T_i| + |δ|κ̂h + h` and `|t_j − t_i| ≥ w − h`. With `q_ij = max(a²/(2c), a/2)` (0 if
`a ≤ 0`),

    ρ_i = max over w of min(1/κ̂_i(w) − w, min of q_ij over j at least w − h from i),

over windows `w = m h`, `m = 2, 4, 8, …` up to the whole range.

Along a gently curved stretch `a²/(2c)` is large (`δ⊥` is small): the bound is then set by the
curvature, where the chord test `a/2` alone stops at about a third of `1/κ̂`.
`κ̂_i(w)` is the largest sampled curvature within `w/h + 1` samples of sample `i` plus the largest
jump between neighbouring samples there (a Lipschitz margin for the curvature between samples).
Both parts are local: a tight bend, or a spine coming back near itself (a U-turn, a coil),
lowers the bounds around it only, not along the whole spine. Points that are
not certified still get the full global search: the bounds only save work.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._numerics import norm
from .._spines.spine import AbstractSpine

REACH_SAMPLES = 384


def search_range(spine: AbstractSpine) -> tuple[Array, Array]:
    """`(lo, hi)`: the arc lengths the closest-point search covers (ends continued)."""
    e0, e1 = spine.extension()
    return -e0, spine.length + e1


def held(values, h: Array):
    """`values` (a pytree of arrays), computed once and held in memory, through a conditional
    on `h` (finite: always taken) that XLA cannot fuse across: fused into the reach bound's
    (S, S) kernel, an exact spine's evaluation was repeated for each of its S² pairs (spot's
    leg posed in float64: 40 ms of a frame's 56)."""
    return jax.lax.cond(jnp.isfinite(h), lambda v: v,
                        lambda v: jax.tree.map(jnp.zeros_like, v), values)


def _window_maxima(values: Array, radii) -> list[Array]:
    """For each radius `r` of `radii` (static ints), the largest of `values` (S,) within `r`
    indices of each index: from the maxima over runs of `2^e` values (each level two runs of
    the one below), a window of `2 r + 1` being two overlapping runs of the longest such length
    in it. Exact (a maximum is), in O(S log S): as one `reduce_window` a radius, XLA's CPU
    backend swept the whole window at every index (the radii reach the whole range)."""
    count, widest = values.shape[0], max(radii)
    low = jnp.full(widest, -jnp.inf, values.dtype)
    runs = [jnp.concatenate([low, values, low])]  # runs[e][i]: the largest of 2^e from i
    while 2 ** len(runs) <= 2 * widest + 1:
        half = 2 ** (len(runs) - 1)
        last = runs[-1]
        runs.append(jnp.maximum(last, jnp.concatenate([last[half:], low[:half]])))
    out = []
    for r in radii:
        e = (2 * r + 1).bit_length() - 1  # 2^e ≤ 2r + 1 < 2^(e + 1)
        start, end = widest - r, widest + r + 1 - 2**e  # the two runs' starts at index 0
        out.append(jnp.maximum(runs[e][start: start + count], runs[e][end: end + count]))
    return out


def _running_min(values: Array, reverse: bool = False) -> Array:
    """`jax.lax.cummin(values, axis=1, reverse=reverse)` for an (S, S) array, as a loop over
    the columns, each a vector of the rows: XLA's CPU backend runs `cummin` as a window
    of the whole row at every index (S³ work, 1.4 ms of a pose's 3 ms region at S = 384; the
    loop: 0.25 ms). Same values (a minimum is exact)."""

    def step(smallest, column):
        smallest = jnp.minimum(smallest, column)
        return smallest, smallest

    start = jnp.full(values.shape[0], jnp.inf, values.dtype)
    return jax.lax.scan(step, start, values.T, reverse=reverse)[1].T


def sampled_jets(spine: AbstractSpine, samples: int) -> tuple[Array, Array, Array]:
    """`(C, T, k)` (S, 3) each of a prepared `spine` at `samples` arc lengths evenly spread
    over its search range, `held` (computed once): what `LocalReach` and the valid region
    (`region`) are built from, evaluated once for both (on an exact spine, a bent limb's in
    float64, each evaluation is a quadrature)."""
    lo, hi = search_range(spine)
    return held(jax.vmap(spine.jet)(jnp.linspace(lo, hi, samples)), (hi - lo) / (samples - 1))


class LocalReach(eqx.Module):
    """Lower bounds of a spine's reach around each of its samples, as a function of the arc
    length of a foot (`__call__`, one point).

    **Fields:** `lo`, `h`: the first sample and the spacing; `bounds`: (S,) the bound `ρ_i` for
    feet within `h/2` of sample `i` (`inf` on a straight spine). Argument `jets`: the spine's
    `sampled_jets`, where the caller has them; `margin`: scalar, or (m,) for bounds (m, S),
    one row a margin (`local_reaches`).

    With a `margin` `δ > 0`, the bounds are lowered so that the whole ball of radius `δ` around
    a point inside them has a unique foot near `s` (`region`): the near condition becomes
    `κ̂ (r + δ + w) < 1`, the far one `|X − C(t)| > r + 2δ`, i.e. `r < (a² − 4δ²)/(2c + 4δ)` or
    `r < a/2 − δ`. `δ = 0` gives the bounds above.
    """

    lo: Array
    h: Array
    bounds: Array

    def __init__(self, spine: AbstractSpine, samples: int = REACH_SAMPLES, margin=0.0,
                 jets=None):
        spine = jax.lax.stop_gradient(spine._prepare())
        margin = jnp.asarray(margin, spine.length.dtype)
        lo, hi = search_range(spine)
        h = (hi - lo) / (samples - 1)
        self.lo, self.h = lo, h
        # (`jets`: the caller's `sampled_jets` of the spine, where it has them: `region`.)
        positions, tangents, k = sampled_jets(spine, samples) if jets is None else jets
        kappa = norm(k)
        jumps = jnp.abs(jnp.diff(kappa, append=kappa[-1:]))
        # Windows w = m h, m = 2, 4, …, up to the whole range (no far points).
        windows = [2**e for e in range(1, math.ceil(math.log2(samples + 1)) + 1)]
        # κ̂ over the spine within m + 1 samples of each sample, for m = 1 and each window.
        radii = [m + 1 for m in [1, *windows]]
        kappa_hat = [a + b for a, b in zip(_window_maxima(kappa, radii),
                                            _window_maxima(jumps, radii))]

        # q_ij: far points near sample j stay farther than r from X when r < q_ij (see above).
        # δ_ij = P_j − P_i one coordinate at a time (sums over a minor axis of 3 are slow on
        # XLA's CPU backend, see `_numerics.dot`).
        delta = [p[None] - p[:, None] for p in positions.T]
        along = sum(d * t[:, None] for d, t in zip(delta, tangents.T))
        length = jnp.sqrt(sum(d * d for d in delta))
        across = jnp.sqrt(jnp.maximum(length**2 - along**2, 0))
        a = length - h
        c = across + length * kappa_hat[0][:, None] * h + h

        def bounded(margin):
            # With a margin δ (`region`): far points stay farther than `r + 2δ` from X.
            two = 2 * margin
            q = jnp.where(
                a > two, jnp.maximum((a**2 - two**2) / (2 * c + 2 * two), (a - two) / 2), 0
            )
            # The smallest q_ij over samples j at least w − h away (m − 1 indices) from i, on
            # either side (those after i: the rows reversed, column j read as S − 1 − j).
            # Every window at once, (W, S): the same values as a loop over the windows, in a
            # ninth of the traced operations (compiled in every registration and pose).
            index, last = jnp.arange(samples), samples - 1
            upto, onward = _running_min(q), _running_min(q, reverse=True)
            inf = jnp.asarray(jnp.inf, q.dtype)
            m = np.array(windows)[:, None]
            left, right = index - (m - 1), index + (m - 1)  # far: at least w − h away
            before = jnp.where(left >= 0, upto[index, jnp.maximum(left, 0)], inf)
            after = jnp.where(right <= last, onward[index, jnp.minimum(right, last)], inf)
            hat = jnp.stack(kappa_hat[1:])
            bounds = jnp.minimum(1 / hat - jnp.asarray(m, h.dtype) * h - margin,
                                 jnp.minimum(before, after))
            # A reduction, so that XLA materialises the bounds (their elementwise last steps
            # would otherwise be fused into every point's lookup, 2× slower `pose`).
            return jnp.maximum(jnp.max(bounds, axis=0), 0)

        # (Several margins: what is free of the margin above computed once, the rest batched.)
        self.bounds = jax.vmap(bounded)(margin) if margin.ndim else bounded(margin)

    def __call__(self, s: Array) -> Array:
        """The bound for a foot at `s` (scalar): that of the nearest sample."""
        nearest = jnp.clip(jnp.round((s - self.lo) / self.h), 0, self.bounds.shape[0] - 1)
        return self.bounds.at[nearest.astype(jnp.int32)].get(mode="clip")


def local_reaches(
    spine: AbstractSpine, margins: Array, samples: int = REACH_SAMPLES, jets=None
) -> list[LocalReach]:
    """A `LocalReach` of `spine` for each of `margins` (m,), in one computation: the spine's
    samples, the curvature bounds and the S² distances between samples once, the rest for
    each margin (a registration's fast path and its valid region, `projection.Registrar`:
    traced and compiled once, not twice). The bounds are each margin's own `LocalReach`'s."""
    together = LocalReach(spine, samples, margins, jets)
    return [eqx.tree_at(lambda reach: reach.bounds, together, b) for b in together.bounds]


def reach_lower_bound(spine: AbstractSpine, samples: int = REACH_SAMPLES) -> Array:
    """A lower bound of the reach of `spine` continued over its search range (scalar, ≥ 0): the
    smallest of its `LocalReach` bounds. Infinite for a straight spine. Computed without
    gradients (it only decides which points need the global search)."""
    return jnp.min(LocalReach(spine, samples).bounds)

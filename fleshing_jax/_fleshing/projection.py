"""Closest projection of points on a spine, and the registration pytree.

The search is a coarse nearest sample followed by safeguarded Newton steps on
`f(s) = (C(s) − X)·T(s) = 0`, whose derivative is `f'(s) = 1 − k(s)·d` (positive inside the
reach). Both run on stopped gradients; a last Newton step then carries the
implicit-function-theorem derivative `ds = −(∂f)/f'`, in forward and reverse mode, to every
order (`_numerics.polish_root`).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .._batching.chunks import map_chunks
from .._batching.compact import update_where
from .._numerics import dot, norm, polish_root, relative_tolerance
from .._spines.spine import AbstractSpine
from .._spines.table import SpineTable, fast_evaluator, runs_whole
from .ends import EndFrames
from .reach import LocalReach, search_range
from .region import ValidRegion, clear_all, clear_where, closed_form_clear

NEWTON_STEPS = 8
FAST_STEPS = 3  # Newton steps of the certified fast path (from a sample at most h away)
CANDIDATES = 3  # Newton starts of the global search: the best local minima of the distance
COARSE, BRANCH = 16, 4  # the fast path's coarse-to-fine levels: 16 spans, then 4× finer each


class _Search(eqx.Module):
    """What the closest-point search of one spine needs, computed once for many points."""

    spine: AbstractSpine  # prepared, gradients stopped
    lo: Array
    hi: Array
    grid: Array  # (G,) sample arc lengths on [lo, hi], G = COARSE·BRANCH^levels + 1
    positions: Array  # (G, 3) the spine there
    levels: int = eqx.field(static=True)

    @property
    def h(self):
        return (self.hi - self.lo) / (self.grid.shape[0] - 1)

    def descend(self, x: Array, s: Array, steps: int) -> Array:
        """Safeguarded Newton steps on `f(s) = (C(s) − x)·T(s)` from `s`, each at most `h`."""
        h, tiny = self.h, jnp.finfo(x.dtype).tiny

        def newton(_, s):
            f, slope, _ = self.spine._foot_terms(x, s)
            # Outside the local reach (slope ≤ 0) Newton heads for a maximum: dividing by
            # `tiny` instead makes the clamped step go downhill by `h`. (Clamps rather than
            # `where`s: `f` and `slope` are used once, see `SpineTable._foot_terms`.)
            step = jnp.clip(-f / jnp.maximum(slope, tiny), -h, h)
            return jnp.clip(s + step, self.lo, self.hi)

        # Unrolled on tables, so that XLA fuses the steps into one kernel; a loop on exact
        # spines, whose evaluation is large (unrolled, it would multiply compile time).
        unroll = isinstance(self.spine, SpineTable)
        return jax.lax.fori_loop(0, steps, newton, s, unroll=unroll)

    def global_start(self, x: Array) -> tuple[Array, Array]:
        """Newton from the best local minima of the sampled distance: `(s, unique)`."""
        distances = dot(self.positions - x, self.positions - x)
        inf = jnp.asarray(jnp.inf, distances.dtype)
        before = jnp.concatenate([inf[None], distances[:-1]])
        after = jnp.concatenate([distances[1:], inf[None]])
        minima = jnp.where((distances <= before) & (distances <= after), distances, inf)
        _, index = jax.lax.top_k(-minima, min(CANDIDATES, self.grid.shape[0]))
        candidate = jnp.isfinite(minima[index]).at[0].set(True)

        def solve(s):
            s = self.descend(x, s, NEWTON_STEPS)
            d = x - self.spine(s)
            return s, dot(d, d)

        starts, distance = jax.vmap(solve)(self.grid[index])
        distance = jnp.where(candidate, distance, inf)
        best = jnp.argmin(distance)
        s = starts[best]
        # Another candidate, elsewhere on the spine, as close as the best one: no unique
        # projection.
        tol = relative_tolerance(distance.dtype)
        elsewhere = jnp.abs(starts - s) > self.h
        tie = candidate & elsewhere & (distance - distance[best] <= tol * (1 + distance[best]))
        return s, ~jnp.any(tie)

    def nearby_sample(self, x: Array) -> Array:
        """Index of a sample near `x`, coarse to fine: the nearest of the `COARSE + 1` coarsest
        samples, then at each level the nearest of the `2·BRANCH + 1` finer samples around it
        (logarithmic in the resolution; not always the nearest sample, which is not needed:
        `fast_start` certifies its result independently of where it started)."""
        last = self.grid.shape[0] - 1
        columns = self.positions.T  # gathered one coordinate at a time: fast on XLA's CPU
        strides = [BRANCH ** (self.levels - level) for level in range(self.levels + 1)]
        best = strides[0] * _nearest([column[:: strides[0]] for column in columns], x)
        offsets = jnp.arange(-BRANCH, BRANCH + 1, dtype=jnp.int32)

        def refine(level, best):
            stride = jnp.asarray(strides, jnp.int32)[level]
            around = jnp.clip(best + offsets * stride, 0, last)
            first = best - BRANCH * stride
            samples = [column.at[around].get(mode="promise_in_bounds") for column in columns]
            return jnp.clip(first + _nearest(samples, x) * stride, 0, last)

        # A loop, not unrolled: batched, each level's result is then materialised once, where
        # unrolled XLA would recompute the levels above in each of the next level's gathers.
        return jax.lax.fori_loop(1, self.levels + 1, refine, best)

    def fast_start(self, x: Array, reach: LocalReach) -> tuple[Array, Array]:
        """Newton from a nearby sample: `(s, certified)`, certified when the foot is closer
        than the lower bound of the `reach` around it (then it is the unique closest point, see
        `reach`)."""
        s = self.descend(x, self.grid[self.nearby_sample(x)], FAST_STEPS)
        f, _, distance = self.spine._foot_terms(x, s)
        stationary = jnp.abs(f) <= relative_tolerance(x.dtype) * (1 + distance)
        return s, stationary & (distance < reach(s)) & (s > self.lo) & (s < self.hi)


def _nearest(samples: list[Array], x: Array) -> Array:
    """Index of the sample nearest to `x` (3,) among `samples` (their three coordinates, (m,)
    each), the first on ties.

    The squared distances are non-negative, so their bit patterns as integers order like them:
    each is packed with its index in the low bits and the minimum taken (an argmin's selects
    would use every distance twice, and batched, XLA would split the gathers feeding them into
    separate kernels). Distances equal but in those few low bits count as ties, which a search
    for *a* nearby sample does not mind. (One vector of the m samples, not m scalars: the
    same keys, a tenth of the operations to trace and compile.)
    """
    count = samples[0].shape[0]
    bits = max(1, (count - 1).bit_length())
    squared = sum(jnp.square(column - xi) for column, xi in zip(samples, x))
    integer = jnp.dtype(f"int{8 * squared.dtype.itemsize}")
    packed = jax.lax.bitcast_convert_type(squared, integer) >> bits << bits
    key = jnp.min(packed | jnp.arange(count, dtype=integer))
    return (key & ((1 << bits) - 1)).astype(jnp.int32)


def _search(spine: AbstractSpine, samples: int) -> _Search:
    fixed = jax.lax.stop_gradient(spine)
    lo, hi = search_range(fixed)
    levels = max(0, math.ceil(math.log(max(samples - 1, 1) / COARSE, BRANCH)))
    grid = jnp.linspace(lo, hi, COARSE * BRANCH**levels + 1)
    # Sample positions do not depend on the points: computed once per spine.
    return _Search(fixed, lo, hi, grid, jax.vmap(fixed)(grid), levels)


def _polish(spine: AbstractSpine, search: _Search, x: Array, s: Array) -> tuple[Array, Array]:
    """One more Newton step, differentiable to every order in `x` and the spine (the
    implicit-function derivatives, `_numerics.polish_root`), and whether its result is a
    stationary point strictly inside the searched range."""
    s = polish_root(_foot_residual, s, (spine, x))
    # Checked after the step, from the spine there: the values before it are used once (by the
    # step), see `SpineTable._foot_terms`.
    f, _, distance = spine._foot_terms(x, s)
    tol = relative_tolerance(x.dtype)
    converged = (jnp.abs(f) <= tol * (1 + distance)) & (s > search.lo) & (s < search.hi)
    return s, converged


def _foot_residual(s: Array, params) -> tuple[Array, Array]:
    """`f(s) = (C(s) − x)·T(s)` and `f'(s) = 1 − k·d`, zeroed outside the local reach (where
    Newton would head for a maximum: no step, and no derivative)."""
    spine, x = params
    f, slope, _ = spine._foot_terms(x, s)
    return f, jnp.where(slope > 0, slope, 0)


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
    search = _search(spine, samples)
    s, unique = search.global_start(jax.lax.stop_gradient(x))
    s, converged = _polish(spine, search, x, jax.lax.stop_gradient(s))
    return s, converged & unique


class Registrar(eqx.Module):
    """A spine prepared for batched registration: its search samples and lower bounds of its
    reach around each arc length, computed once for all points, its closed-form foot where
    it has one (lines, arcs; see `closest_arc_lengths`), and its valid region with the margin
    `margin` (`region`: points too close to the cut locus are flagged `discontinuous`)."""

    spine: AbstractSpine | SpineTable  # prepared, or tabulated in single precision
    exact: AbstractSpine  # prepared, gradients stopped: for a closed-form foot, if it has one
    search: _Search
    margin: Array
    # None where the margin has a closed form (lines, arcs); with the fast path's certificate
    # (`reach`).
    region: ValidRegion | None

    def __init__(self, spine: AbstractSpine, samples: int | None = None, margin=0.0,
                 table: SpineTable | None = None):
        samples = spine.default_samples() if samples is None else samples
        spine = spine._prepare()
        # `table`: the spine's `fast_evaluator` where the caller made it already (a skeleton's
        # rest spine, whose table its bent spines read too: `_skeleton.posing`).
        self.spine = fast_evaluator(spine) if table is None else table
        self.exact = jax.lax.stop_gradient(spine)
        self.search = _search(self.spine, samples)
        closed = spine._has_closed_form_foot()
        self.margin = jnp.asarray(margin, spine.length.dtype)
        self.region = None if closed else ValidRegion(self.spine, self.margin, unmargined=True)

    @property
    def reach(self) -> LocalReach | None:
        """The fast path's certificate (the spine's `LocalReach` without the margin, made with
        the valid region's); none where the foot has a closed form (most of the
        preparation's compilation: a line's compiles 2.5× faster, an arc's 1.9×)."""
        return None if self.region is None else self.region.unmargined

    @property
    def fused(self) -> bool:
        """Whether the spine is tabulated or cheap exactly (lines): batches then run whole
        (`map_chunks`)."""
        return runs_whole(self.spine)

    def start(self, x: Array) -> tuple[Array, Array]:
        """`(s, certified)` for one point: the spine's closed-form foot (lines, arcs), else
        Newton from a nearby sample (certified by the reach bound)."""
        closed_form = self.exact._closest_start(x, self.search.lo, self.search.hi)
        return self.search.fast_start(x, self.reach) if closed_form is None else closed_form

    def closest(self, points: Array) -> tuple[Array, Array]:
        """`(s (n,), converged (n,))` for a batch of finite points (n, 3)."""
        fixed = jax.lax.stop_gradient(points)
        s, certified = jax.vmap(self.start)(fixed)
        s, unique = update_where(~certified, self.search.global_start, (s, certified), fixed)
        return self._polished(points, s, unique)

    def closest_global(self, points: Array) -> tuple[Array, Array]:
        """`closest` by the global search for every point (the pending ones, see `eager`)."""
        s, unique = jax.vmap(self.search.global_start)(jax.lax.stop_gradient(points))
        return self._polished(points, s, unique)

    def _polished(self, points: Array, s: Array, unique: Array) -> tuple[Array, Array]:
        s, converged = jax.vmap(lambda x, s: _polish(self.spine, self.search, x, s))(points, s)
        return s, converged & unique

    def register(self, points: Array, closest=None) -> Registration:
        """The registration of a batch of points (n, 3); its `length` is repeated per point.
        `closest`: the search (default `self.closest`; `closest_global` for pending points)."""
        closest = self.closest if closest is None else closest
        s, converged = closest(_finite_or_zero(points))
        registration = jax.vmap(lambda *a: _local_coordinates(self.spine, *a))(points, s, converged)
        return self.cleared(registration)

    def cleared(self, registration: Registration, sampled: bool = True):
        """`registration` with its points closer than the margin to the spine's cut locus or
        focal set flagged `discontinuous` and not valid (`region`): certified in O(1) a point
        where they can be, the sampled test run on the others only.

        `sampled=False` (the eager path, `eager`): the sampled test is not run, and not
        compiled; `(registration, unclear (n,))`, the valid points that the O(1) test does not
        certify flagged as if they failed it, for `clear_pending` to test them."""
        reg, margin = registration, self.margin
        unclear = jnp.zeros_like(reg.valid)
        if self.region is None:
            clear = jax.vmap(closed_form_clear, (0, 0, None))(reg.offset, reg.curvature, margin)
        else:
            region = self.region
            clear = jax.vmap(region.certified)(reg.arc_length, norm(reg.offset))
            if sampled:
                clear = clear_where(reg.valid & ~clear, region, clear, (reg.points, reg.arc_length))
            else:
                unclear = reg.valid & ~clear
        reg = eqx.tree_at(
            lambda r: (r.valid, r.discontinuous), reg, (reg.valid & clear, reg.valid & ~clear)
        )
        return reg if sampled else (reg, unclear)

    def clear_pending(self, registration: Registration, index: Array) -> Registration:
        """`registration` with the sampled test run on the points at `index` (valid before
        `cleared(..., sampled=False)` flagged them)."""
        clear = clear_all(self.region, (registration.points[index], registration.arc_length[index]))
        fields = (registration.valid.at[index].set(clear),
                  registration.discontinuous.at[index].set(~clear))
        return eqx.tree_at(lambda r: (r.valid, r.discontinuous), registration, fields)

    def register_certified(self, points: Array) -> tuple[Registration, Array, Array]:
        """`register` without the global search nor the region's sampled test: `(registration,
        pending (n,), unclear (n,))`, the finite points the fast path does not certify marked
        invalid and pending, those the valid region does not certify unclear (see `eager`)."""
        return self.finish(points, *self.begin(points))

    def begin(self, points: Array) -> tuple[Array, Array]:
        """`register_certified` up to the fast path's start: `(s, certified)`, each (n,)."""
        return jax.vmap(self.start)(jax.lax.stop_gradient(_finite_or_zero(points)))

    def finish(self, points: Array, s: Array, certified: Array):
        """`register_certified` from the start `(s, certified)` of `begin`: Newton's polish
        and the local coordinates."""
        s, converged = self._polished(_finite_or_zero(points), s, certified)
        coordinates = jax.vmap(lambda *a: _local_coordinates(self.spine, *a))
        registration, unclear = self.cleared(coordinates(points, s, converged), sampled=False)
        return registration, ~certified & jnp.all(jnp.isfinite(points), -1), unclear

    def register_all(self, points: Array) -> Registration:
        """`register` for any number of points (N, 3): in chunks (`map_chunks`) on exact
        spines, whole on tables; the `length` a scalar."""
        return self.shared(map_chunks(self.register, points, whole=self.fused))

    def shared(self, registration: Registration) -> Registration:
        """`registration` with the spine's `length` and `ends` as scalars (shared by all
        points) rather than repeated per point."""
        return eqx.tree_at(
            lambda r: (r.length, r.ends), registration, (self.spine.length, EndFrames(self.exact))
        )


def _finite_or_zero(points: Array) -> Array:
    """The points (n, 3), with 0 in place of those that are not finite (flagged invalid by
    the registration; harmless in its search)."""
    finite = jnp.all(jnp.isfinite(points), axis=-1)
    return jnp.where(finite[:, None], points, 0)


def closest_arc_lengths(spine: AbstractSpine, points: Array, samples: int | None = None):
    """`closest_arc_length` for many points (N, 3) at once: `(s (N,), converged (N,))`.

    Same results, less work: each point first runs Newton from a nearby sample, and the result
    is certified global when the point is closer to its foot than a lower bound of the spine's
    reach around that foot (`reach`) — or, on lines and arcs, takes the closed-form foot,
    certified when unique in the search range; only the other points run the global
    multi-candidate search. Exact spines are processed in chunks (`_batching.chunks`), so memory
    does not grow with their intermediates per point; tabulated ones in one batch.
    """
    registrar = Registrar(spine, samples)
    return map_chunks(registrar.closest, points, whole=registrar.fused)


class Registration(eqx.Module):
    """Points registered on a source spine: everything a new pose needs, per point.

    Produced by `register`; consumed by `pose`. All offsets are in the source spine's
    twist-compensated frame `(I₀, J₀)` at the projection.

    **Fields:**

    - `points`: (N, 3) the input points.
    - `arc_length`: (N,) arc length `s` of the closest projection.
    - `offset`: (N, 2) offset `X − C₀(s)` in `(I₀, J₀)` coordinates.
    - `curvature`: (N, 2) curvature vector `k₀(s)` in `(I₀, J₀)` coordinates.
    - `valid`: (N,) bool: finite, projected, strictly inside the reach of the source, and
      farther than the margin from its cut locus and focal set (`region`).
    - `discontinuous`: (N,) bool: projected inside the local reach, but within the margin of
      the cut locus or the focal set, where the map is discontinuous (so not `valid`).
    - `length`: scalar length of the source spine.
    - `ends`: the source's frames at its two ends (`ends.EndFrames`, scalars), for the
      target's first normal and for `beyond="rigid"`.
    """

    points: Float[Array, "*batch 3"]
    arc_length: Float[Array, " *batch"]
    offset: Float[Array, "*batch 2"]
    curvature: Float[Array, "*batch 2"]
    valid: Bool[Array, " *batch"]
    discontinuous: Bool[Array, " *batch"]
    length: Float[Array, ""]
    ends: EndFrames


def invalid_past(registration: Registration, n: int) -> Registration:
    """`registration` with its points from `n` on (a bucket's padding: `pad_batch` copies)
    marked invalid, so that a pose leaves them where they are and runs no check on them."""
    valid = registration.valid
    if valid.shape[0] == n:
        return registration
    if isinstance(valid, jax.core.Tracer):
        valid = valid & (jnp.arange(valid.shape[0]) < n)
    else:  # on the host, as `pad_batch` pads: no device program per size
        valid = np.array(valid)
        valid[n:] = False
        valid = jax.device_put(valid)
    return eqx.tree_at(lambda r: r.valid, registration, valid)


def register_point(
    spine: AbstractSpine, x: ArrayLike, samples: int | None = None, margin=0.0
) -> Registration:
    """Registers one point (3,) on `spine`, with the `margin` of `region`; see
    `register_points` for many."""
    x = jnp.asarray(x)
    spine = spine._prepare()
    finite = jnp.all(jnp.isfinite(x))
    s, converged = closest_arc_length(spine, jnp.where(finite, x, 0), samples)
    reg = _local_coordinates(spine, x, s, converged)
    margin = jnp.asarray(margin, spine.length.dtype)
    if spine._has_closed_form_foot():
        clear = closed_form_clear(reg.offset, reg.curvature, margin)
    else:
        region = ValidRegion(spine, margin)
        fixed = jax.lax.stop_gradient((x, s))
        clear = region.certified(fixed[1], norm(jax.lax.stop_gradient(reg.offset)))
        clear = clear | region.clear(jnp.where(finite, fixed[0], 0), fixed[1])
    return eqx.tree_at(
        lambda r: (r.valid, r.discontinuous), reg, (reg.valid & clear, reg.valid & ~clear)
    )


def register_points(spine: AbstractSpine, points: Array, samples: int | None = None, margin=0.0):
    """Registers points (N, 3) on `spine` (batched projection in chunks, see
    `closest_arc_lengths`), with the `margin` of `region`."""
    return Registrar(spine, samples, margin).register_all(points)


def _local_coordinates(spine: AbstractSpine, x: Array, s: Array, converged: Array):
    """The registration of `x` (3,) at its projection `s`."""
    finite = jnp.all(jnp.isfinite(x))
    offset, curvature, slope = spine._local_terms(jnp.where(finite, x, 0), s)
    valid = finite & converged & (slope > 0)
    ends = EndFrames(spine)
    return Registration(x, s, offset, curvature, valid, jnp.zeros_like(valid), spine.length, ends)

"""Closest projection of points on a spine, and the registration pytree.

The search is a coarse nearest sample followed by safeguarded Newton steps on
`f(s) = (C(s) − X)·T(s) = 0`, whose derivative is `f'(s) = 1 − k(s)·d` (positive inside the
reach). Both run on stopped gradients; a last Newton step with live gradients then gives the
implicit-function-theorem derivative `ds = −(∂f)/f'` exactly (`f ≈ 0` makes the rest vanish),
in forward and reverse mode alike.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from ._chunks import map_chunks
from ._compact import update_where
from ._misc import argmin, dot, norm, relative_tolerance, safe_divide
from ._reach import reach_lower_bound, search_range
from ._spine import AbstractSpine
from ._table import SpineTable, fast_evaluator

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
        """Safeguarded Newton steps on `f(s) = (C(s) − x)·T(s)` from `s`."""
        h = self.h

        def newton(_, s):
            c, tangent, k = self.spine.jet(s)
            d = x - c
            f, slope = -dot(d, tangent), 1 - dot(k, d)
            # Outside the local reach Newton heads for a maximum: step downhill instead.
            step = jnp.where(slope > 0, -f / jnp.where(slope > 0, slope, 1), -jnp.sign(f) * h)
            step = jnp.where(jnp.abs(step) > h, jnp.sign(step) * h, step)
            s = s + step
            return jnp.where(s < self.lo, self.lo, jnp.where(s > self.hi, self.hi, s))

        return jax.lax.fori_loop(0, steps, newton, s)

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
        coarse = self.positions[:: BRANCH**self.levels]
        best = argmin(dot(coarse - x, coarse - x))
        offsets = jnp.arange(-BRANCH, BRANCH + 1)
        columns = self.positions.T  # gathered one coordinate at a time: fast on XLA's CPU
        for level in range(1, self.levels + 1):
            stride = BRANCH ** (self.levels - level)
            index = jnp.clip(best * BRANCH + offsets, 0, last // stride) * stride
            distance = sum((column[index] - xi) ** 2 for column, xi in zip(columns, x))
            best = index[argmin(distance)] // stride
        return best

    def fast_start(self, x: Array, reach: Array) -> tuple[Array, Array]:
        """Newton from a nearby sample: `(s, certified)`, certified when the foot is closer
        than the `reach` lower bound (then it is the unique closest point, see `_reach`)."""
        s = self.descend(x, self.grid[self.nearby_sample(x)], FAST_STEPS)
        c, tangent, _ = self.spine.jet(s)
        d = x - c
        distance = norm(d)
        stationary = jnp.abs(dot(d, tangent)) <= relative_tolerance(x.dtype) * (1 + distance)
        return s, stationary & (distance < reach) & (s > self.lo) & (s < self.hi)


def _search(spine: AbstractSpine, samples: int) -> _Search:
    fixed = jax.lax.stop_gradient(spine)
    lo, hi = search_range(fixed)
    levels = max(0, math.ceil(math.log(max(samples - 1, 1) / COARSE, BRANCH)))
    grid = jnp.linspace(lo, hi, COARSE * BRANCH**levels + 1)
    # Sample positions do not depend on the points: computed once per spine.
    return _Search(fixed, lo, hi, grid, jax.vmap(fixed)(grid), levels)


def _polish(spine: AbstractSpine, search: _Search, x: Array, s: Array) -> tuple[Array, Array]:
    """One Newton step with live gradients (the implicit-function derivative), and whether `s`
    is a stationary point strictly inside the searched range."""
    c, tangent, k = spine.jet(s)
    d = x - c
    f, slope = -dot(d, tangent), 1 - dot(k, d)
    s = s - safe_divide(f, jnp.where(slope > 0, slope, 0))
    tol = relative_tolerance(x.dtype)
    converged = (jnp.abs(f) <= tol * (1 + norm(d))) & (s > search.lo) & (s < search.hi)
    return s, converged


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
    """A spine prepared for batched registration: its search samples and a lower bound of its
    reach, computed once for all points, and its closed-form foot where it has one (lines,
    arcs; see `closest_arc_lengths`)."""

    spine: AbstractSpine | SpineTable  # prepared, or tabulated in single precision
    exact: AbstractSpine  # prepared, gradients stopped: for a closed-form foot, if it has one
    search: _Search
    reach: Array

    def __init__(self, spine: AbstractSpine, samples: int | None = None):
        samples = spine.default_samples() if samples is None else samples
        spine = spine._prepare()
        self.spine = fast_evaluator(spine)
        self.exact = jax.lax.stop_gradient(spine)
        self.search = _search(self.spine, samples)
        self.reach = reach_lower_bound(self.spine)

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
        s, converged = jax.vmap(lambda x, s: _polish(self.spine, self.search, x, s))(points, s)
        return s, converged & unique

    def register(self, points: Array) -> Registration:
        """The registration of a batch of points (n, 3); its `length` is repeated per point."""
        finite = jnp.all(jnp.isfinite(points), axis=-1)
        s, converged = self.closest(jnp.where(finite[:, None], points, 0))
        return jax.vmap(lambda *a: _local_coordinates(self.spine, *a))(points, s, converged)


def closest_arc_lengths(spine: AbstractSpine, points: Array, samples: int | None = None):
    """`closest_arc_length` for many points (N, 3) at once: `(s (N,), converged (N,))`.

    Same results, less work: each point first runs Newton from a nearby sample, and the result
    is certified global when the point is closer to its foot than a lower bound of the spine's
    reach (`_reach`) — or, on lines and arcs, takes the closed-form foot, certified when unique
    in the search range; only the other points run the global multi-candidate search. Points are
    processed in chunks (`_chunks`), so memory does not grow with intermediates per point.
    """
    return map_chunks(Registrar(spine, samples).closest, points)


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
    """Registers one point (3,) on `spine`; see `register_points` for many."""
    x = jnp.asarray(x)
    spine = spine._prepare()
    finite = jnp.all(jnp.isfinite(x))
    s, converged = closest_arc_length(spine, jnp.where(finite, x, 0), samples)
    return _local_coordinates(spine, x, s, converged)


def register_points(spine: AbstractSpine, points: Array, samples: int | None = None):
    """Registers points (N, 3) on `spine` (batched projection in chunks, see
    `closest_arc_lengths`)."""
    registrar = Registrar(spine, samples)
    registration = map_chunks(registrar.register, points)
    return eqx.tree_at(lambda r: r.length, registration, registrar.spine.length)


def _local_coordinates(spine: AbstractSpine, x: Array, s: Array, converged: Array):
    """The registration of `x` (3,) at its projection `s`."""
    finite = jnp.all(jnp.isfinite(x))
    (c, _, k), (i, j) = spine.jet_and_normals(s)
    d = jnp.where(finite, x, 0) - c
    offset = jnp.stack([dot(d, i), dot(d, j)])
    curvature = jnp.stack([dot(k, i), dot(k, j)])
    valid = finite & converged & (1 - dot(curvature, offset) > 0)
    return Registration(x, s, offset, curvature, valid, spine.length)

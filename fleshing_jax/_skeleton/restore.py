"""The volume a pose past its exact range loses, given back where it was carried.

Past a joint's exact range (`fj.joint_range`) the vertices past the joint are blended towards
their cross-sections' rigid motion (`posing._sections_carried`): the limb stays whole, but
the sections fan out on the convex side and pile up on the concave one, and the volume is
no longer kept (spot's head turned 45° sideways: −5.8 %; cheburashka's tilted 30°: −1.5 %).
Implicit skinning corrects the concave side of a joint by moving the skin along its normals
(Vaillant et al. 2013); here the blended vertices move along the volume's gradient (their
area-weighted normals), by one scalar `λ` for the whole pose, so that the mesh encloses
its rest volume again in proportion to the blend:

    vol(x + λ d) = vol(x) + b · (vol(rest) − vol(x)),   d_i = w_i ∂vol/∂x_i,

with `w_i` the blend of vertex `i` (0 wherever the map is exact: those vertices do not move),
rising from 0 at the joint along the limb (no step where the still part meets the moved
one), and `b` the largest. Continuous in the angles (as `b → 0`, `λ d → 0`), differentiable
(a few Newton steps on a cubic in `λ`), and the vertices stay flagged: inexact, with the
volume kept.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

NEWTON_STEPS = 4  # on the cubic in `λ`, near-linear here (tests: to 1e-12 of the volume)


def corner_table(triangles: np.ndarray, count: int) -> np.ndarray:
    """(count, m) int32: for each vertex, the corners `3 t + j` of the triangles `(T, 3)`
    at it (`triangles[t, j]` the vertex), padded with `3 T`: the volume's gradient is then
    gathered per vertex (`volume_gradient`), not scattered from the faces (with XLA's scatter
    on a CPU the restore took 4.7 ms on spot, as long as the rest of its 9-limb frame;
    gathered, 0.6 ms; its corners added column by column and the cubic's coefficients summed
    once, CPU 0.60-0.89 -> 0.47-0.61 ms a call, load 10)."""
    triangles = np.asarray(triangles, np.int64)
    owner = triangles.reshape(-1)
    order = np.argsort(owner, kind="stable")
    counts = np.bincount(owner, minlength=count)
    width = max(int(counts.max(initial=0)), 1)
    table = np.full((count, width), owner.size, np.int32)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    rank = np.arange(owner.size) - np.repeat(starts, counts)
    table[owner[order], rank] = order
    return table


def rest_volume(points, triangles: np.ndarray) -> float:
    """The volume of `(points (n, 3), triangles (T, 3))` in float64, about the points'
    centre (what `restored_volume` gives back towards)."""
    points = np.asarray(points, np.float64)
    a, b, c = (points[triangles[:, k]] - points.mean(axis=0) for k in range(3))
    return float(np.sum(a * np.cross(b, c)) / 6)


def _corners(vertices: Array, triangles: Array) -> tuple[Array, Array, Array]:
    """The triangles' corners (T, 3) each, in one gather."""
    at = vertices[triangles]
    return at[:, 0], at[:, 1], at[:, 2]


def volume_gradient(vertices: Array, triangles: Array, corners: Array) -> Array:
    """(n, 3) the gradient of the volume of `(vertices (n, 3), triangles (T, 3))` (each
    vertex's area-weighted normal, a third of it), gathered at `corners` (`corner_table`)."""
    a, b, c = _corners(vertices, triangles)
    per_corner = jnp.stack([jnp.cross(b, c), jnp.cross(c, a), jnp.cross(a, b)], axis=1) / 6
    per_corner = jnp.concatenate([per_corner.reshape(-1, 3), jnp.zeros((1, 3), a.dtype)])
    # (A vertex's corners added one column at a time: one loop kernel with its gathers, where
    # `jnp.sum(per_corner[corners], axis=1)` materialised the (n, m, 3) gather and reduced it
    # in a kernel of its own.)
    return sum(per_corner[corners[:, j]] for j in range(corners.shape[1]))


def _triple(a: Array, b: Array, c: Array) -> Array:
    """(T,) each triangle's triple product `a · (b × c)` of its rows (T, 3), its three terms
    added as scalars (summed over an axis of 3, XLA's CPU backend ran a reduction kernel)."""
    cross = jnp.cross(b, c)
    return a[:, 0] * cross[:, 0] + a[:, 1] * cross[:, 1] + a[:, 2] * cross[:, 2]


def restored_volume(
    vertices: Float[Array, "n 3"],
    rest: Float[Array, "n 3"],
    volume: Float[Array, ""],
    triangles: Int[Array, "t 3"],
    corners: Int[Array, "n m"],
    blend: Float[Array, " n"],
) -> Float[Array, "n 3"]:
    """`vertices` with those of nonzero `blend` moved along the volume's gradient until the
    mesh `(vertices, triangles)` has given back the fraction `max(blend)` of the volume it
    lost from `volume` (the rest vertices' `rest`; see the module's docstring; `corners`:
    `corner_table`'s); `vertices` as they are where no blend is positive. The volume moved
    by `λ` is a cubic in it, its coefficients gathered once."""
    x = vertices - jnp.mean(rest, axis=0)  # (relative to the rest's centre: float32)
    direction = blend[:, None] * volume_gradient(x, triangles, corners)
    (a, b, c), (da, db, dc) = _corners(x, triangles), _corners(direction, triangles)
    # (Each triangle's four coefficients, then one sum over the triangles: one reduction,
    # not one per triple product.)
    terms = [
        _triple(da, db, dc),
        _triple(da, db, c) + _triple(da, b, dc) + _triple(a, db, dc),
        _triple(da, b, c) + _triple(a, db, c) + _triple(a, b, dc),
        _triple(a, b, c),
    ]
    cubic = jnp.sum(jnp.stack(terms, axis=-1), axis=0) / 6  # (highest power first)
    goal = cubic[3] + jnp.max(blend) * (volume - cubic[3])

    def step(lam, _):
        value, slope = jnp.polyval(cubic, lam), jnp.polyval(jnp.polyder(cubic), lam)
        safe = jnp.where(slope != 0, slope, 1)
        return lam - jnp.where(slope != 0, (value - goal) / safe, 0), None

    # (Unrolled: as a loop, XLA's CPU backend ran each step's few scalar operations as kernels
    # of their own.)
    lam, _ = jax.lax.scan(step, jnp.zeros((), x.dtype), None, length=NEWTON_STEPS, unroll=True)
    return vertices + lam * direction

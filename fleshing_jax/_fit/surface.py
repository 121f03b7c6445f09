"""Distances from points to a triangle mesh's surface, inside a solve (point to triangle).

A posed mesh's vertices sample its surface only every edge length: a target point between
vertices is that far from its nearest vertex however well the pose fits, and a short limb's
small rotation moves its vertices by less than that floor (spot's legs, fitted 7° and 12° off
with a point-to-vertex Chamfer distance as well as at the truth). The distance to the nearest
posed *triangle* is zero at the true pose for every point sampled from the surface.

The nearest triangle is looked for among those around the point's `NEAREST` nearest vertices
(their one-rings, `rings`). The closest point of a surface lies on a triangle incident to the
nearest vertex only where the triangles are small and well shaped: a point inside a large or
obtuse one often lies nearer to a corner of a neighbouring triangle than to its own (33 of 5,000
samples of spot, 21 on its snout, up to 0.05 from the surface at their own pose: with its
head's part of the target unexplained, a shape fit tried other starts for the head for 39
steps, and stopped 0.11° off). With the three nearest, one point is left off, by 0.007.

The choice and the closest point's barycentric weights are made on stopped gradients: the
residual `y − Σ wᵢ vᵢ` then has the derivative of the distance itself in the vertices (the
weights minimise it: their own derivative drops out), and its square sums to the squared
distance.

The nearest vertices are chosen inside the program from a pool of candidates per point,
found outside it by a k-d tree on the host (`pool`: each point's `POOL` nearest vertices of
the surface as it was): the distances to the pool's vertices, and their `NEAREST` smallest
(`nearest_in`, on stopped gradients: nothing differentiates through the choice). While the
surface moves less than the pool's reach, the choice is the k-d tree's own on the moved
surface (`covers` checks it, and a solve finds new pools where it does not). The program
then holds no host callback: JAX's persistent cache keeps it (it stores no program with
one), and the pool's search costs a solve's step less than the callback's round trip did.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Int
from scipy.spatial import cKDTree


def rings(faces: np.ndarray, count: int) -> np.ndarray:
    """Each vertex's incident faces (count, R), padded with -1 (R the largest valence);
    `faces` (F, 3) indices into `count` vertices."""
    faces = np.asarray(faces)
    owner = faces.reshape(-1)
    face = np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(owner, kind="stable")
    owner, face = owner[order], face[order]
    valence = np.bincount(owner, minlength=count)
    out = np.full((count, max(int(valence.max(initial=0)), 1)), -1, np.int64)
    start = np.concatenate([[0], np.cumsum(valence)[:-1]])
    out[owner, np.arange(len(owner)) - start[owner]] = face
    return out


def _dot(p: tuple, q: tuple) -> Array:
    return p[0] * q[0] + p[1] * q[1] + p[2] * q[2]


def _minus(p: tuple, q: tuple) -> tuple:
    return tuple(x - y for x, y in zip(p, q))


def _weights(y: tuple, a: tuple, b: tuple, c: tuple) -> tuple:
    """`closest_weights` on coordinates: each argument a point's three coordinates (arrays of
    one shape, or broadcasting), the result the three weights (arrays). Batched over a target's
    candidate triangles (K, C), each coordinate is a (K, C) array: XLA's CPU backend runs
    these element-wise kernels vectorised, where `vmap` of the (3,)-vector form made (K, C, 3)
    arrays reduced over their minor axis (a shape fit's 1,500 points × 24 candidates on spot:
    `to_surface` 19–23 ms as vectors, 3.7 ms by coordinate, float64, load 6)."""
    e1, e2, d = _minus(b, a), _minus(c, a), _minus(y, a)
    d11, d12, d22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    dtype = d11.dtype
    det = d11 * d22 - d12**2
    tiny = jnp.finfo(dtype).eps * (d11 * d22 + jnp.finfo(dtype).tiny)
    safe = jnp.where(det > tiny, det, 1.0)
    d1, d2 = _dot(d, e1), _dot(d, e2)
    v = (d22 * d1 - d12 * d2) / safe
    w = (d11 * d2 - d12 * d1) / safe
    inside = (det > tiny) & (v >= 0) & (w >= 0) & (v + w <= 1)

    def on_edge(p, q):  # the closest point of segment p q: its parameter t, and its gap
        edge = _minus(q, p)
        length = _dot(edge, edge)
        t = jnp.clip(_dot(_minus(y, p), edge) / jnp.where(length > 0, length, 1.0), 0, 1)
        gap = _minus(y, tuple((1 - t) * pi + t * qi for pi, qi in zip(p, q)))
        return t, _dot(gap, gap)

    (t0, g0), (t1, g1), (t2, g2) = on_edge(a, b), on_edge(b, c), on_edge(c, a)
    zero = jnp.zeros_like(t0)
    # The nearest edge, the first of equals (as `argmin`).
    first = (g0 <= g1) & (g0 <= g2)
    second = ~first & (g1 <= g2)
    edges = [jnp.where(first, e0, jnp.where(second, e1_, e2_))
             for e0, e1_, e2_ in zip((1 - t0, t0, zero), (zero, 1 - t1, t1), (t2, zero, 1 - t2))]
    return tuple(jnp.where(inside, x, edge) for x, edge in zip((1 - v - w, v, w), edges))


def closest_weights(y: Array, a: Array, b: Array, c: Array) -> Array:
    """The barycentric weights (3,) of the point of triangle `(a, b, c)` (each (3,)) closest to
    `y` (3,). Inside, the projection onto the plane; else the nearest of the three edges'
    closest points (the boundary holds the closest point when the projection lies outside).
    Degenerate triangles fall back to their edges."""
    return jnp.stack(_weights(*(jnp.unstack(p) for p in (y, a, b, c))))


NEAREST = 3  # the vertices whose one-rings hold a point's candidate triangles
# Each point's pool of candidate nearest vertices (`pool`): a solve's steps move the surface
# by less than the pool's reach (about twice the vertex spacing) before it is found again.
POOL = 16


def pool(points: np.ndarray, vertices: np.ndarray, count: int = POOL) -> np.ndarray:
    """Each of `points`' (K, 3) `count` nearest of `vertices` (V, 3), as indices (K, count),
    nearest first (a k-d tree, on the host; with fewer vertices than `count`, the nearest
    repeated)."""
    near = cKDTree(vertices).query(points, count)[1].reshape(len(points), -1)
    # (Fewer vertices than `count`: the tree pads with `len(vertices)`; its nearest repeated.)
    return np.where(near < len(vertices), near, near[:, :1]).astype(np.int32)


def covers(candidates: np.ndarray, nearest: np.ndarray) -> bool:
    """Whether each point's `NEAREST` nearest vertices (the first columns of its `pool` row
    found on the surface now, `nearest` (K, ≥ NEAREST), nearest first) lie in its row of
    `candidates` (K, M) (its `pool` where the solve started): then `nearest_in` chooses
    them, as the k-d tree would."""
    near = nearest[:, :NEAREST]
    return bool(np.all(np.any(candidates[:, :, None] == near[:, None, :], axis=1)))


def nearest_in(points: Array, vertices: Array, candidates: Int[Array, "K M"],
               count: int = NEAREST) -> Int[Array, "K c"]:
    """Each of `points`' (K, 3) `count` nearest of its `candidates` (K, M) among `vertices`
    (V, 3), nearest first, as indices (K, count) (on stopped gradients)."""
    points, vertices = jax.lax.stop_gradient(points), jax.lax.stop_gradient(vertices)
    squared = jnp.sum((vertices[candidates] - points[:, None]) ** 2, axis=-1)  # (K, M)
    _, best = jax.lax.top_k(-squared, count)
    return jnp.take_along_axis(candidates, best, axis=1)


def to_surface(points: Array, vertices: Array, faces: Array, ring: Array, candidates: Array,
               along_normal: bool = False) -> Array:
    """The difference vectors (K, 3) from the closest points of the surface `(vertices (V, 3),
    faces (F, 3))` to `points` (K, 3), their squared norms the squared distances; `ring`
    (V, R): `rings(faces, V)`; `candidates` (K, M): each point's `pool` (its nearest vertices
    chosen among them, `nearest_in`). Differentiable in both `points` and `vertices` (the module's
    docstring). With `along_normal`, each vector's part along its triangle's unit normal
    (stopped; a collapsed triangle keeps the whole vector): point to plane, whose derivative
    sees only the surface's motion across itself. (The closest point's weights are stopped,
    so the whole vector's derivative also counts the surface sliding along itself, which moves
    no distance: with noisy points that made the fit rugged and its spread too narrow.)"""
    fixed = jax.lax.stop_gradient(vertices)
    near = nearest_in(points, fixed, candidates)
    candidates = ring[near].reshape(near.shape[0], -1)  # (K, NEAREST·R) faces, -1 padding

    # Each candidate's corners by coordinate (K, C), for `_weights`.
    corners = faces[jnp.maximum(candidates, 0)]  # (K, C, 3)
    coordinates = [tuple(fixed[corners[..., j], i] for i in range(3)) for j in range(3)]
    y = tuple(jax.lax.stop_gradient(points)[:, None, i] for i in range(3))
    weights = _weights(y, *coordinates)
    gap = _minus(y, tuple(sum(w * corner[i] for w, corner in zip(weights, coordinates))
                          for i in range(3)))
    best = jnp.argmin(jnp.where(candidates >= 0, _dot(gap, gap), jnp.inf), axis=1)[:, None]
    face = jnp.take_along_axis(candidates, best, axis=1)[:, 0]
    weights = jnp.stack([jnp.take_along_axis(w, best, axis=1)[:, 0] for w in weights], axis=1)
    weights = jax.lax.stop_gradient(weights)
    difference = points - jnp.einsum("kc,kci->ki", weights, vertices[faces[face]])
    if not along_normal:
        return difference
    a, b, c = jnp.unstack(fixed[faces[face]], axis=1)
    cross = jnp.cross(b - a, c - a)
    size = jnp.linalg.norm(cross, axis=-1, keepdims=True)
    flat = size > jnp.finfo(size.dtype).tiny
    normal = cross / jnp.where(flat, size, 1.0)
    return jnp.where(flat, jnp.sum(difference * normal, -1, keepdims=True) * normal, difference)

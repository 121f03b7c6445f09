"""The paper's discrete spine (§6): a polyline resampled at a constant arc-length step.

Vertices `V_k` are resampled at equal arc length `d` along the input polyline; `C(s)` is the
polyline itself, `C(s) = V_k + a (V_{k+1} − V_k)` on edge `k` (the paper's anchor; `s` is the
arc length along the resampled polyline, `≈ (k + a) d`). A polyline has no curvature, so, as in
the paper, tangent, curvature and frames come from the samples:

- vertex tangents bisect consecutive edges (at the ends: the first/last edge direction reflected
  like a circle through three vertices); `T(s)` is the normalised linear interpolation of the
  vertex tangents along each edge and `k(s) = dT/ds` (exactly orthogonal to `T`);
- the twist-compensated normal is propagated from vertex to vertex by double reflection, and
  on an edge by one more double reflection from the vertex before.

`C'(s)` is the edge direction, not `T(s)`: the volume element is off by `1 − (C'·T)`, which is
second order in the step, so fleshings with polylines preserve volume only up to a
discretisation error that shrinks with `step` (`det J − 1 = O(d²)` where the spines are smooth;
see `benchmarks/README.md`). It exists for comparison with the paper and for rigs that give
polylines; the smooth spines (`BSpline`, `InterpolatingPolynomial`) are exact.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._batching.buckets import bucket, pad_batch
from .._checks import check_points, is_concrete
from .._numerics import dot, norm, safe_divide, safe_sqrt
from .double_reflection import propagate, reflect_twice
from .spine import AbstractTabulatedSpine, Evaluators, PreparedSpine, initial_normal

MAX_EDGES = 1_000_000  # a bound on memory (spine files are untrusted input)
EDGES_BUCKET = 8  # polylines pad to 8, 12, 16, 24, … points and edges (`_bucketed`)


class Polyline(AbstractTabulatedSpine):
    """The paper's discrete spine: `points` resampled at a constant arc-length step.

    **Arguments:**

    - `points`: (N, 3) array, `N ≥ 2`, finite, no two consecutive equal, never turning back
      on itself (consecutive edges less than 179° apart).
    - `step`: optional positive float: the resampling step `d` (rounded so that a whole number
      of steps fits the input's length). Default: the input's mean edge length (as many edges
      as the input). A given step needs concrete `points` (the number of vertices is static).

    Accuracy: position is exact (piecewise linear), tangent and curvature are second-order
    approximations of the smooth curve the points sample; `|det J − 1|` of a fleshing and the
    volume error shrink as `step` does.
    """

    points: Array
    step: float | None = eqx.field(static=True)
    edges: int = eqx.field(static=True)
    samples: int = eqx.field(static=True)

    def __init__(self, points: ArrayLike, *, step: float | None = None):
        points = check_points(points, "points", 2, "2")
        self.points = points
        concrete = is_concrete(points)
        if concrete:
            p = np.asarray(points, np.float64)
            units = np.diff(p, axis=0)
            units /= np.linalg.norm(units, axis=-1, keepdims=True)
            back = np.flatnonzero(np.sum(units[1:] * units[:-1], axis=-1) < -0.9998)
            if back.size:
                raise ValueError(
                    f"`points` turn back on themselves at row {int(back[0]) + 1}: a spine "
                    "cannot reverse its direction."
                )
            length = float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=-1)))
        if step is None:
            self.step, self.edges = None, points.shape[0] - 1
        else:
            if not isinstance(step, int | float | np.number) or not np.isfinite(step) or step <= 0:
                raise ValueError(f"`step` must be a finite positive number, got {step!r}.")
            if not concrete:
                raise ValueError("`step` needs concrete `points` (the vertex count is static).")
            edges = length / step
            if edges > MAX_EDGES:
                raise ValueError(
                    f"`step` = {step!r} would cut the polyline of length {length:.6g} into "
                    f"{edges:.3g} edges, more than {MAX_EDGES}: use a larger step."
                )
            self.step, self.edges = float(step), max(1, int(round(edges)))
        turning = 0.0
        if concrete:
            cosines = np.clip(np.sum(units[1:] * units[:-1], axis=-1), -1, 1)
            turning = float(np.sum(np.arccos(cosines)))
        # (4 per edge of `_bucketed`: polylines padded alike search alike.)
        edges = bucket(self.edges, EDGES_BUCKET)
        self.samples = bucket(int(np.clip(max(128, 4 * edges, 32 * turning), 128, 16384)), 128)

    def _prepare(self) -> PreparedSpine:
        tables = _tables(self.points, self.points.shape[0], self.edges, self.edges)
        return PreparedSpine(tables, EVALUATORS, self.samples, tabulable=False)

    def default_samples(self) -> int:
        return self.samples

    def vertices(self) -> Array:
        """The resampled vertices `C[k]`, (edges + 1, 3)."""
        return _resample(self.points, self.points.shape[0], self.edges, self.edges)

    def _bucketed(self) -> PaddedPolyline:
        """This polyline with its input points and its resampled vertices padded to buckets of
        counts (`8·2^k` or `12·2^k`, `_batching.buckets`): the eager entry points compile once
        per bucket. The padding repeats the last vertex (zero-length edges, never located) and
        leaves results and gradients those of `self`."""
        return PaddedPolyline(self)


class PaddedPolyline(AbstractTabulatedSpine):
    """A `Polyline` whose arrays are padded to bucket sizes (`Polyline._bucketed`); internal.

    **Fields:** `points` (N, 3), the last rows copies; `count`, `edges`: int scalars, the
    polyline's input points and resampled edges; static `total` (≥ `edges`: edges in the
    tables, the last ones of zero length) and `samples`.
    """

    points: Array
    count: Array
    edges: Array
    total: int = eqx.field(static=True)
    samples: int = eqx.field(static=True)

    def __init__(self, polyline: Polyline):
        self.points = pad_batch(polyline.points, bucket(polyline.points.shape[0], EDGES_BUCKET))
        self.count = jax.device_put(np.int32(polyline.points.shape[0]))
        self.edges = jax.device_put(np.int32(polyline.edges))
        self.total, self.samples = bucket(polyline.edges, EDGES_BUCKET), polyline.samples

    def _prepare(self) -> PreparedSpine:
        tables = _tables(self.points, self.count, self.edges, self.total)
        return PreparedSpine(tables, EVALUATORS, self.samples, tabulable=False)

    def default_samples(self) -> int:
        return self.samples


def _resample(points: Array, count, edges, total: int) -> Array:
    """Vertices at `edges` equal steps of arc length along the first `count` of `points`, and
    copies of the last one up to `total` edges: (total + 1, 3). `count` and `edges` are ints
    or int scalars (padded polylines); the rows of `points` after `count` are copies."""
    p = points
    steps = jnp.diff(p, axis=0)
    lengths = safe_sqrt(dot(steps, steps))  # (padding: zero, with a zero derivative)
    cumulative = jnp.concatenate([jnp.zeros((1,), p.dtype), jnp.cumsum(lengths)])
    index = np.arange(1, total)
    inner = index < edges  # the other vertices are padding: any target, then replaced
    fractions = jnp.where(inner, jnp.asarray(index, p.dtype) / jnp.asarray(edges, p.dtype), 0.5)
    targets = fractions * cumulative[-1]
    k = jnp.clip(jnp.searchsorted(cumulative, targets, side="right") - 1, 0, count - 2)
    a = (targets - cumulative[k]) / lengths[k]
    last = p[count - 1]
    middle = jnp.where(inner[:, None], p[k] + a[:, None] * (p[k + 1] - p[k]), last)
    return jnp.concatenate([p[:1], middle, last[None]])


@eqx.filter_jit
def _tables(points, count, edges, total: int):
    """The polyline table: vertices, cumulative arc lengths, edge lengths and directions,
    vertex tangents, the double-reflection normals at the vertices, and `edges`.

    Padded tables (`edges < total`) end in zero-length edges at the last vertex, with its
    tangent: nothing is located on them, and the frames stand still along them."""
    v = _resample(points, count, edges, total)
    steps = jnp.diff(v, axis=0)
    lengths = safe_sqrt(dot(steps, steps))
    real = np.arange(total) < edges
    units = steps / jnp.where(real, lengths, 1)[:, None]  # (padding: zero, never used)
    cumulative = jnp.concatenate([jnp.zeros((1,), v.dtype), jnp.cumsum(lengths)])
    if total == 1:
        tangents = jnp.concatenate([units, units])
    else:  # ends: the next vertex tangent reflected about the end edge (exact on circles)
        bisector = jnp.where(real[1:, None], units[1:] + units[:-1], 1)
        inner = bisector / jnp.linalg.norm(bisector, axis=-1, keepdims=True)
        first = 2 * dot(units[0], inner[0]) * units[0] - inner[0]
        e0, e1 = units[edges - 1], inner[jnp.maximum(edges - 2, 0)]
        last = 2 * dot(e0, e1) * e0 - e1
        # One edge (a padded polyline of one edge): both ends take its direction.
        first, last = (jnp.where(edges == 1, units[0], t) for t in (first, last))
        tangents = jnp.concatenate([first[None], inner, last[None]])
        tangents = jnp.where((np.arange(total + 1) >= edges)[:, None], last, tangents)
    zeros = jnp.zeros_like(v)
    normals = propagate(v, tangents, zeros, initial_normal(tangents[0]), "double_reflection")
    return v, cumulative, lengths, units, tangents, normals, edges


def _on_edge(table, s):
    """Edge index, position, `T(s)` and `k(s) = dT/ds` at `s ∈ [0, length]`."""
    v, cumulative, lengths, units, tangents, _, edges = table
    k = jnp.clip(jnp.searchsorted(cumulative, s, side="right") - 1, 0, edges - 1)
    a = (s - cumulative[k]) / lengths[k]
    position = v[k] + a * lengths[k] * units[k]
    blend = (1 - a) * tangents[k] + a * tangents[k + 1]
    size = norm(blend)
    tangent = blend / size
    slope = (tangents[k + 1] - tangents[k]) / (size * lengths[k])
    curvature = slope - dot(slope, tangent) * tangent
    return k, (position, tangent, curvature)


def _evaluate(tab, s):
    """Jet and normals at `s`, and at both ends (the anchors of the continuations)."""
    v, cumulative, lengths, units, tangents, normals, _ = tab
    out = []
    for e in (s, jnp.zeros_like(s), cumulative[-1]):
        k, jet = _on_edge(tab, e)
        i = reflect_twice(units[k], tangents[k], normals[k], jet[1])
        out.append((jet, (i, jnp.cross(jet[1], i))))
    return out


def _torsion(tab, s):
    """Discrete torsion: the turn of the vertex binormals about the edge, per unit length."""
    v, cumulative, lengths, units, *_, edges = tab
    if units.shape[0] == 1:  # one edge: no interior vertex, no turn
        return jnp.zeros_like(cumulative[0] * s)
    k = jnp.clip(jnp.searchsorted(cumulative, s, side="right") - 1, 0, edges - 1)
    binormals = jnp.cross(units[:-1], units[1:])  # at interior vertices 1 … edges − 1
    inside = (k >= 1) & (k <= edges - 2)
    b0 = binormals[jnp.clip(k - 1, 0, binormals.shape[0] - 1)]
    b1 = binormals[jnp.clip(k, 0, binormals.shape[0] - 1)]
    sin = dot(jnp.cross(b0, b1), units[k])
    cos = dot(b0, b1)
    defined = inside & (safe_sqrt(dot(b0, b0) * dot(b1, b1)) > 0) & (sin**2 + cos**2 > 0)
    angle = jnp.arctan2(jnp.where(defined, sin, 0), jnp.where(defined, cos, 1))
    return jnp.where(defined, safe_divide(angle, lengths[k]), 0)


EVALUATORS = Evaluators(
    length=lambda tab: tab[1][-1],
    jet=lambda tab, s: _on_edge(tab, s)[1],
    jets=lambda tab, s: [jet for jet, _ in _evaluate(tab, s)],
    evaluate=_evaluate,
    torsion=_torsion,
    ends=lambda tab: _evaluate(tab, jnp.zeros_like(tab[1][-1]))[1:],
)

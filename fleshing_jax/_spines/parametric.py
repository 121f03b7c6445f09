"""The shared base of free-form spines made of polynomial pieces (B-spline, polynomial).

A subclass provides its pieces: `_piece_values(x)`, the curve at local parameters `x ∈ (−1, 1)`
of every piece, and the static `piece_degree`. This base fits each piece's monomial coefficients
exactly (Chebyshev nodes), makes the curve an exact arc-length spine (`arclength`), and derives:

- `T = P'/|P'|` and `k = (P'' − (P''·T)T)/|P'|²` (exactly `dT/ds`, orthogonal to `T`, zero at
  inflections without any division by the curvature);
- torsion `τ = (P' × P'')·P‴ / |P' × P''|²` (0 where the curvature vanishes);
- rotation-minimising normals: double-reflection frames at the sub-interval breaks
  (`double_reflection`), evaluated anywhere by one more double-reflection step from the break
  at or before `s`.

Nothing is cached: coefficients and tables are functions of the (differentiable) curve
parameters, computed once per `jit`/`vmap` call (they do not depend on the points being
fleshed), so gradients with respect to control points flow through lengths, parameters and
frames alike.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._batching.buckets import bucket
from .._batching.quick import Program
from .._numerics import dot, norm, safe_divide
from . import arclength
from .double_reflection import double_reflection, propagate
from .spine import AbstractTabulatedSpine, Evaluators, PreparedSpine, initial_normal

RMF_NODES_PER_RADIAN = 96  # double-reflection error < 1e-9 on free-form spines (tests/test_rmf.py)


class AbstractParametricSpine(AbstractTabulatedSpine):
    """A spine made of smooth polynomial pieces, exactly reparameterised by arc length.

    Subclasses implement `_piece_values(x)` and provide three static ints: `piece_degree`,
    `subdivisions` (equal parts per piece for quadrature and frame nodes) and `samples` (for the
    closest-point search); see `static_sizes`.
    """

    piece_degree: eqx.AbstractVar[int]
    subdivisions: eqx.AbstractVar[int]
    samples: eqx.AbstractVar[int]

    @abc.abstractmethod
    def _piece_values(self, x: np.ndarray) -> Array:
        """The curve at local parameters `x` (m,) in `(−1, 1)` of every piece, (S, m, 3)."""

    def _coefficients(self) -> Array:
        """Monomial coefficients of each piece in its local parameter `u ∈ [−1, 1]`, (S, d+1, 3)."""
        x, fit = arclength.fit_matrix(self.piece_degree)
        values = self._piece_values(x)
        return jnp.einsum("kq,sqc->skc", jnp.asarray(fit, values.dtype), values)

    def _piece_count(self) -> Array | None:
        """How many of the pieces are the curve's, the others padding after them (a dynamic
        int: see `_bucketed`); `None` (the default) when every piece is."""
        return None

    def _prepare(self) -> PreparedSpine:
        return PreparedSpine(_tables(self), EVALUATORS, self.samples)

    def default_samples(self) -> int:
        return self.samples


def _jet_of(coefficients: Array, u: Array, order: int = 2):
    """Position, unit tangent and curvature vector of a piece at `u`, and the derivatives in `u`."""
    c, c1, c2, *rest = (arclength.piece_derivative(coefficients, u, m) for m in range(order + 1))
    # (`norm`, `dot`: sums over a minor axis of 3 are slow batched on XLA's CPU backend, and
    # every point posed on an exact spine evaluates a few jets, in double precision.)
    speed = norm(c1)[..., None]
    tangent = c1 / speed
    k = (c2 - dot(c2, tangent)[..., None] * tangent) / speed**2
    return (c, tangent, k), (c1, c2, *rest)


class Tables(eqx.Module):
    """Everything about a parametric spine that does not depend on `s`, computed once.

    **Fields:** `coefficients` (S, d+1, 3) of the pieces; `cumulative` (M+1,) arc length at the
    sub-interval breaks; `nodes`: positions, tangents, curvature vectors and double-reflection
    normals at the breaks, each (M+1, 3); `end`: int scalar, the index of the curve's last
    break (`M`, or less when the last pieces are padding: their sub-intervals have zero length
    and their nodes repeat the last break, so that nothing is ever located in them); `parts`:
    static sub-intervals per piece.
    """

    coefficients: Array
    cumulative: Array
    nodes: tuple[Array, Array, Array, Array]
    end: Array
    parts: int = eqx.field(static=True)


def tables(spine: AbstractParametricSpine) -> Tables:
    """The `Tables` of `spine` (differentiable in its parameters)."""
    coefficients = spine._coefficients()
    parts = spine.subdivisions
    count = spine._piece_count()
    pieces = coefficients.shape[0] if count is None else count
    cumulative = arclength.cumulative_lengths(coefficients, parts, count)
    # Frame nodes: the sub-interval breaks, at static local parameters of every piece.
    x = jnp.asarray(np.linspace(-1.0, 1.0, parts + 1)[:-1], coefficients.dtype)
    (c, t, k), _ = jax.vmap(lambda a: _jet_of(a, x))(coefficients)
    last, _ = _jet_of(coefficients[pieces - 1], jnp.ones((), coefficients.dtype))
    end = jnp.asarray(pieces * parts, jnp.int32)
    beyond = (jnp.arange(c.shape[0] * parts + 1) >= end)[:, None]
    # The last break, and padding's nodes, are the curve's end: zero steps for the frames.
    c, t, k = (
        jnp.where(beyond, e, jnp.concatenate([v.reshape(-1, 3), e[None]]))
        for v, e in zip((c, t, k), last)
    )
    normals = propagate(c, t, k, initial_normal(t[0]), "double_reflection")
    return Tables(coefficients, cumulative, (c, t, k, normals), end, parts)


def locate(tab: Tables, s: Array) -> tuple[Array, Array, Array]:
    """`(i, u, j)` at arc length `s` (scalar): the piece, its local parameter (differentiable)
    and the sub-interval (`arclength.inverse`)."""
    return arclength.inverse(tab.coefficients, tab.cumulative, tab.parts, s, tab.end)


def jet_at(tab: Tables, s):
    i, u, _ = locate(tab, s)
    return _jet_of(tab.coefficients[i], u)[0]


def jets_at(tab: Tables, s):
    """Jets at `s` and at both ends."""
    i, u, _ = locate(tab, s)
    a = tab.coefficients
    ends = [(a[0], -jnp.ones_like(s)), (a[tab.end // tab.parts - 1], jnp.ones_like(s))]
    return [_jet_of(p, v)[0] for p, v in [(a[i], u)] + ends]


def evaluate_at(tab: Tables, s):
    """Jet and normals at `s`, and at both ends (the anchors of the continuations)."""
    return evaluate_located(tab, *locate(tab, s))


def evaluate_located(tab: Tables, i: Array, u: Array, j: Array):
    """`evaluate_at` at the point `locate` found: piece `i`, parameter `u`, sub-interval `j`."""
    jet = _jet_of(tab.coefficients[i], u)[0]
    c, t, k, normals = tab.nodes
    normal = double_reflection(c[j], t[j], normals[j], jet[0], jet[1], k[j])
    return [(jet, (normal, jnp.cross(jet[1], normal)))] + ends_of(tab)


def ends_of(tab: Tables):
    """Jet and normals at both ends: the first and last frame nodes."""
    c, t, k, normals = tab.nodes
    return [((c[e], t[e], k[e]), (normals[e], jnp.cross(t[e], normals[e]))) for e in (0, tab.end)]


def torsion_at(tab: Tables, s):
    i, u, _ = locate(tab, s)
    _, (c1, c2, c3) = _jet_of(tab.coefficients[i], u, order=3)
    b = jnp.cross(c1, c2)
    return safe_divide(dot(b, c3), dot(b, b))


def length_of(tab: Tables):
    return tab.cumulative[-1]


EVALUATORS = Evaluators(length_of, jet_at, jets_at, evaluate_at, torsion_at, ends_of)


@Program  # (a spine's tables: small work, compiled quickly when called on its own)
def _tables(spine):
    return tables(spine)


def static_sizes(
    point_np, span_breaks, spans: int, subdivisions: int | None, name: str, padded: int = 0
):
    """`(subdivisions, samples)` for a parametric spine, and a check that it never stops.

    `point_np` evaluates the curve on a NumPy array of parameters, (G,) → (G, 3), or is `None`
    when the curve is traced (then nothing is checked); `span_breaks`: the (S+1,) span ends
    (`None` if traced); `spans`: S; `padded`: the pieces of the spine padded to its bucket
    (`_bucketed`), when it pads, so that spines padded alike search alike. Frame nodes are
    placed at `RMF_NODES_PER_RADIAN` per radian of the most-turning span (at least 8 per span,
    at most 512), and closest-point samples at 32 per radian of total turning (at least 128, and
    16 per span, padded ones included). Traced curves (built inside `jit` from traced
    parameters) get 16 subdivisions and `max(256, 64 · spans)` samples. Both counts are
    rounded up to the sizes of `_batching.buckets` (`8·2^k` or `12·2^k` subdivisions,
    `128·2^k` or `192·2^k` samples), so that spines of similar turning share their compiled
    programs. Raises `ValueError` naming `name` where a concrete curve stops (zero speed: a
    cusp).
    """
    pieces = max(spans, padded)
    if point_np is None:
        return (16 if subdivisions is None else subdivisions), bucket(max(256, 64 * pieces), 128)
    breaks = np.asarray(span_breaks, dtype=np.float64)
    fractions = np.arange(64) / 64
    grid = (breaks[:-1, None] + np.diff(breaks)[:, None] * fractions).reshape(-1)
    grid = np.append(grid, breaks[-1])
    with np.errstate(all="ignore"):
        positions = np.asarray(point_np(grid), dtype=np.float64)
        h = 1e-6 * (breaks[-1] - breaks[0])
        lo, hi = np.maximum(grid - h, breaks[0]), np.minimum(grid + h, breaks[-1])
        speed = np.linalg.norm(point_np(hi) - point_np(lo), axis=-1) / (hi - lo)
    chords = np.diff(positions, axis=0)
    length = np.sum(np.linalg.norm(chords, axis=-1))
    units = chords / np.maximum(np.linalg.norm(chords, axis=-1, keepdims=True), 1e-300)
    cosines = np.clip(np.sum(units[1:] * units[:-1], axis=-1), -1.0, 1.0)
    # A cusp: the speed vanishes at a sample, or the direction flips between two samples.
    stop = speed <= 1e-6 * length / (breaks[-1] - breaks[0])
    flip = np.concatenate([[False], cosines < -0.5, [False]])
    if not np.all(np.isfinite(speed)) or np.any(stop | flip):
        where = np.argmax(stop | flip | ~np.isfinite(speed))
        raise ValueError(
            f"`{name}` define a curve that stops (zero speed, a cusp) near parameter "
            f"t = {grid[where]:.6g}: a spine needs a tangent everywhere."
        )
    turning = np.concatenate([[0.0], np.arccos(cosines)]).reshape(spans, 64).sum(axis=-1)
    if subdivisions is None:
        subdivisions = int(np.clip(np.ceil(RMF_NODES_PER_RADIAN * turning.max()), 8, 512))
        subdivisions = bucket(subdivisions, 8)  # (more is only more accurate)
    samples = int(np.clip(32 * turning.sum(), max(128, 16 * pieces), 8192))
    return subdivisions, bucket(samples, 128)


MAX_SUBDIVISIONS = 4096  # 8× the most the turning ever asks for: beyond, only memory grows
MAX_DEGREE = 25  # pieces are evaluated by unrolled loops: compile time grows as the degree²


def check_subdivisions(subdivisions) -> None:
    """Raises `ValueError` unless `subdivisions` is `None` or an int in
    `[1, MAX_SUBDIVISIONS]` (a bound on memory: spine files are untrusted input)."""
    if subdivisions is not None and (
        isinstance(subdivisions, bool)
        or not isinstance(subdivisions, int)
        or not 1 <= subdivisions <= MAX_SUBDIVISIONS
    ):
        raise ValueError(
            f"`subdivisions` must be an int from 1 to {MAX_SUBDIVISIONS}, got {subdivisions!r}."
        )

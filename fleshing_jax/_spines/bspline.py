"""Non-uniform B-spline spines (the paper's quintic NUBS), exactly parameterised by arc length."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._batching.buckets import bucket, pad_batch
from .._checks import as_float_array, check_points, is_concrete
from .parametric import MAX_DEGREE, AbstractParametricSpine, check_subdivisions, static_sizes


def clamped_uniform_knots(count: int, degree: int, dtype) -> Array:
    """The clamped uniform knot vector on `[0, 1]` for `count` control points, (count+degree+1,)."""
    inner = np.linspace(0.0, 1.0, count - degree + 1)
    return jnp.asarray(np.concatenate([np.zeros(degree), inner, np.ones(degree)]), dtype)


def _check_knots(knots: Array, count: int, degree: int) -> Array:
    expected = count + degree + 1
    if knots.shape != (expected,):
        raise ValueError(
            f"`knots` must have shape (len(control_points) + degree + 1,) = ({expected},), "
            f"got shape {knots.shape}."
        )
    if not is_concrete(knots):
        steps = jnp.diff(knots)
        bad = ~jnp.all(jnp.isfinite(knots)) | jnp.any(steps < 0)
        bad = bad | (knots[count] <= knots[degree])
        return eqx.error_if(knots, bad, "`knots` must be finite and non-decreasing.")
    u = np.asarray(knots, dtype=np.float64)
    if not np.all(np.isfinite(u)):
        raise ValueError(f"`knots` must be finite, got {u}.")
    decreasing = np.flatnonzero(np.diff(u) < 0)
    if decreasing.size:
        i = int(decreasing[0])
        raise ValueError(
            f"`knots` must be non-decreasing, got knots[{i}] = {u[i]} > "
            f"knots[{i + 1}] = {u[i + 1]}."
        )
    if u[count] <= u[degree]:
        raise ValueError(
            f"`knots` must span a non-empty domain: knots[degree] = {u[degree]} must be below "
            f"knots[len(control_points)] = {u[count]}."
        )
    inner = u[degree + 1 : count]
    values, multiplicity = np.unique(inner, return_counts=True)
    if multiplicity.size and multiplicity.max() > degree:
        raise ValueError(
            f"`knots` has the interior knot {values[multiplicity.argmax()]} repeated "
            f"{multiplicity.max()} times, more than degree = {degree}: the curve would break."
        )
    return knots


class BSpline(AbstractParametricSpine):
    """A non-uniform B-spline spine, exactly reparameterised by arc length.

    `P(t) = Σ Pᵢ Nᵢ,ₚ(t)` on `t ∈ [knots[p], knots[n]]`, `p = degree`, `n = len(control_points)`
    (de Boor's algorithm). The default knots are clamped and uniform, so the spine starts at
    the first control point and ends at the last. Arc length is exact to round-off
    (Gauss–Legendre per sub-interval, Newton inverse), and everything is differentiable with
    respect to `control_points` and `knots`.

    **Arguments:**

    - `control_points`: (n, 3) array, `n ≥ degree + 1`, finite, no two consecutive equal.
    - `degree`: static int ≥ 1 (default 5, the paper's quintic NUBS).
    - `knots`: optional (n + degree + 1,) non-decreasing array; interior knots repeated at most
      `degree` times (at most `degree − 2` for a continuous curvature, which exact volume
      preservation needs).
    - `subdivisions`: optional static int: equal parts per knot span for the arc-length table
      and frame nodes (default: from the curve's turning, see `static_sizes`).
    """

    control_points: Array
    knots: Array
    degree: int = eqx.field(static=True)
    spans: tuple[int, ...] = eqx.field(static=True)
    subdivisions: int = eqx.field(static=True)
    samples: int = eqx.field(static=True)

    def __init__(
        self,
        control_points: ArrayLike,
        *,
        degree: int = 5,
        knots: ArrayLike | None = None,
        subdivisions: int | None = None,
    ):
        if (
            isinstance(degree, bool)
            or not isinstance(degree, int | np.integer)
            or not 1 <= degree <= MAX_DEGREE
        ):
            raise ValueError(f"`degree` must be an integer from 1 to {MAX_DEGREE}, got {degree!r}.")
        self.degree = int(degree)
        points = check_points(control_points, "control_points", degree + 1, "degree + 1")
        count = points.shape[0]
        if knots is None:
            knots = clamped_uniform_knots(count, self.degree, points.dtype)
        knots = as_float_array(knots, "knots").astype(points.dtype)
        self.knots = _check_knots(knots, count, self.degree)
        self.control_points = points
        check_subdivisions(subdivisions)
        # The knot spans of the curve: the non-empty ones when the knots are known.
        self.spans = tuple(range(self.degree, count))
        evaluate, breaks = None, None
        if is_concrete(self.knots):
            u = np.asarray(self.knots, np.float64)
            self.spans = tuple(i for i in self.spans if u[i + 1] > u[i])
            breaks = u[list(self.spans) + [self.spans[-1] + 1]]
            if is_concrete(points):
                p = np.asarray(points, np.float64)
                evaluate = lambda t: _de_boor(p, u, self.degree, t)  # noqa: E731
        padded = bucket(count, CONTROL_POINTS_BUCKET) - self.degree  # pieces of `_bucketed`
        self.subdivisions, self.samples = static_sizes(
            evaluate, breaks, len(self.spans), subdivisions, "control_points", padded
        )

    @property
    def piece_degree(self) -> int:
        return self.degree

    def _piece_values(self, x):
        return _span_values(self, np.asarray(self.spans), x)

    def _bucketed(self) -> PaddedBSpline:
        """This spline with its arrays padded to a bucket of control-point counts
        (`CONTROL_POINTS_BUCKET·2^k` or `1.5·…`, `_batching.buckets`): the eager entry points
        compile once per bucket, not once per count.

        Control points and knots are padded with copies of their last row, and the list of
        knot spans (now an array) with copies of the last span: the padded pieces repeat the
        last one, and the `Tables` mark them as padding (zero length, never located), so the
        padded rows are never read and results and gradients are those of `self`."""
        size = bucket(self.control_points.shape[0], CONTROL_POINTS_BUCKET)
        spans = np.asarray(self.spans + (self.spans[-1],) * (size - self.degree - len(self.spans)))
        return PaddedBSpline(self, size, spans)


CONTROL_POINTS_BUCKET = 8  # B-splines pad to 8, 12, 16, 24, 32, … control points


class PaddedBSpline(AbstractParametricSpine):
    """A `BSpline` whose arrays are padded to a bucket size (`BSpline._bucketed`); internal.

    **Fields:** `control_points` (N, 3) and `knots` (N + degree + 1,), their last rows copies;
    `spans`: (N − degree,) int, the knot span of each piece, the last ones copies; `pieces`:
    int scalar, how many pieces are the curve's; the static `degree`, `subdivisions` and
    `samples` of the spline.
    """

    control_points: Array
    knots: Array
    spans: Array
    pieces: Array
    degree: int = eqx.field(static=True)
    subdivisions: int = eqx.field(static=True)
    samples: int = eqx.field(static=True)

    def __init__(self, spline: BSpline, size: int, spans: np.ndarray):
        self.control_points = pad_batch(spline.control_points, size)
        self.knots = pad_batch(spline.knots, size + spline.degree + 1)
        self.spans = jax.device_put(spans.astype(np.int32))
        self.pieces = jax.device_put(np.int32(len(spline.spans)))
        self.degree, self.subdivisions = spline.degree, spline.subdivisions
        self.samples = spline.samples

    @property
    def piece_degree(self) -> int:
        return self.degree

    def _piece_values(self, x):
        return _span_values(self, self.spans, x)

    def _piece_count(self) -> Array:
        return self.pieces


def _span_values(spline: BSpline | PaddedBSpline, spans, x) -> Array:
    """The curve at local parameters `x` (m,) of the pieces on knot spans `spans` (S,):
    (S, m, 3)."""
    spans = spans[:, None]
    a, b = spline.knots[spans], spline.knots[spans + 1]
    t = a + (b - a) * jnp.asarray((x + 1) / 2, a.dtype)
    return _de_boor(spline.control_points, spline.knots, spline.degree, t, spans)


def _de_boor(points, knots, degree: int, t, span=None):
    """The B-spline at parameters `t` (any shape), (..., 3).

    NumPy or JAX arrays; `span` (int array broadcastable with `t`): the knot span of each `t`
    (found by search when omitted, NumPy only). Evaluates the `degree + 1` non-zero basis
    functions with the Cox–de Boor triangle (The NURBS Book, A2.2) and combines the matching
    control points.
    """
    xp = np if isinstance(t, np.ndarray) and isinstance(points, np.ndarray) else jnp
    count = points.shape[0]
    if span is None:
        span = np.clip(np.searchsorted(knots, t, side="right") - 1, degree, count - 1)
    span = (np if isinstance(span, np.ndarray) else jnp).broadcast_to(span, np.shape(t))[..., None]
    window = knots[span - degree + 1 + np.arange(2 * degree)]
    local = points[span - degree + np.arange(degree + 1)]
    left = [None] + [t - window[..., degree - j] for j in range(1, degree + 1)]
    right = [None] + [window[..., degree - 1 + j] - t for j in range(1, degree + 1)]
    basis = [1.0]
    for j in range(1, degree + 1):
        saved, new = 0.0, []
        for r in range(j):
            width = right[r + 1] + left[j - r]
            temp = xp.where(width > 0, basis[r] / xp.where(width > 0, width, 1), 0)
            new.append(saved + right[r + 1] * temp)
            saved = left[j - r] * temp
        basis = new + [saved]
    return sum(b[..., None] * local[..., i, :] for i, b in enumerate(basis))

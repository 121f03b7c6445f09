"""The interpolating-polynomial spine (the paper's low-degree polynomial, Neville's algorithm)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._checks import check_points, is_concrete
from .parametric import AbstractParametricSpine, check_subdivisions, static_sizes


class InterpolatingPolynomial(AbstractParametricSpine):
    """The polynomial curve through `points`, exactly reparameterised by arc length.

    `P(t)` is the polynomial of degree `N − 1` with `P(i) = points[i]`, `t ∈ [0, N − 1]`,
    evaluated with Neville's algorithm (stable, and differentiable in `t` and the points).
    Meant for a few points (low degree, as in the paper): high degrees oscillate (Runge).

    **Arguments:**

    - `points`: (N, 3) array, `N ≥ 2`, finite, no two consecutive equal.
    - `subdivisions`: optional static int, equal parts per interval `[i, i + 1]` for the
      arc-length table and frame nodes (default: from the curve's turning).
    """

    points: Array
    subdivisions: int = eqx.field(static=True)
    samples: int = eqx.field(static=True)

    def __init__(self, points: ArrayLike, *, subdivisions: int | None = None):
        points = check_points(points, "points", 2, "2 (a polynomial of degree ≥ 1)")
        self.points = points
        check_subdivisions(subdivisions)
        evaluate, breaks = None, None
        if is_concrete(points):
            p = np.asarray(points, np.float64)
            evaluate = lambda t: _neville(p, t)  # noqa: E731
            breaks = np.arange(points.shape[0], dtype=np.float64)
        self.subdivisions, self.samples = static_sizes(
            evaluate, breaks, points.shape[0] - 1, subdivisions, "points"
        )

    @property
    def piece_degree(self) -> int:
        return self.points.shape[0] - 1

    def _piece_values(self, x):
        start = np.arange(self.points.shape[0] - 1)[:, None]
        return _neville(self.points, jnp.asarray(start + (x + 1) / 2, self.points.dtype))


def _neville(points: Array, t: Array) -> Array:
    """Neville's algorithm: the polynomial through `(i, points[i])` at `t` (any shape), (..., 3).

    Works on NumPy and JAX arrays alike.
    """
    nodes = np.arange(points.shape[0])
    p = points
    t = t[..., None]
    for m in range(1, points.shape[0]):
        left, right = nodes[:-m], nodes[m:]
        p = ((t - right)[..., None] * p[..., :-1, :] + (left - t)[..., None] * p[..., 1:, :]) / (
            left - right
        )[:, None]
    return p[..., 0, :]

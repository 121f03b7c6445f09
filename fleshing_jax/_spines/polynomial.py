"""The interpolating-polynomial spine (the paper's low-degree polynomial, Neville's algorithm)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._checks import check_points, is_concrete
from . import arclength
from .parametric import MAX_DEGREE, AbstractParametricSpine, check_subdivisions, static_sizes


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
        if points.shape[0] > MAX_DEGREE + 1:
            raise ValueError(
                f"`points` must have at most {MAX_DEGREE + 1} rows (a polynomial of degree "
                f"≤ {MAX_DEGREE}), got {points.shape[0]}: use a BSpline through many points."
            )
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
        if evaluate is not None:
            _check_conditioning(points)

    @property
    def piece_degree(self) -> int:
        return self.points.shape[0] - 1

    def _piece_values(self, x):
        start = np.arange(self.points.shape[0] - 1)[:, None]
        return _neville(self.points, jnp.asarray(start + (x + 1) / 2, self.points.dtype))


def _check_conditioning(points: Array) -> None:
    """Raises `ValueError` where the pieces of the polynomial through concrete `points`, in
    their dtype, miss the polynomial.

    High degrees are ill-conditioned in monomial form: float32 pieces through 20 points can
    miss the points by percents (and the length by a factor 2). The pieces are computed as the
    spine computes them (NumPy, in the same dtype) and checked at both ends and the middle of
    every piece against Neville's algorithm in float64: to 1e-4 of the curve's extent in single
    precision (about 1000 ulps), 1e-8 in double.
    """
    dtype = np.dtype(points.dtype)
    p = np.asarray(points, dtype)
    x, fit = arclength.fit_matrix(p.shape[0] - 1)
    start = np.arange(p.shape[0] - 1)[:, None]
    values = _neville(p, (start + (x + 1) / 2).astype(dtype))
    coefficients = np.einsum("kq,sqc->skc", fit.astype(dtype), values)
    u = np.array([-1.0, 0.0, 1.0], dtype)
    pieces = np.einsum("ud,sdc->suc", np.vander(u, p.shape[0], increasing=True), coefficients)
    exact = _neville(np.asarray(p, np.float64), start + np.array([0.0, 0.5, 1.0]))
    error = float(np.max(np.abs(pieces - exact)))
    extent = float(np.max(np.ptp(np.asarray(p, np.float64), axis=0)))
    if not error <= (1e-4 if dtype.itemsize <= 4 else 1e-8) * extent:
        raise ValueError(
            f"`points`: the polynomial of degree {p.shape[0] - 1} through them cannot be "
            f"evaluated accurately in {dtype} (its pieces miss it by {error:.2g}): use float64 "
            "(`jax_enable_x64`), fewer points, or a BSpline."
        )


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

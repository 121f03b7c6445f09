"""Piecewise-polynomial curves and their exact arc length: Gauss–Legendre tables, Newton inverse.

A free-form curve is stored as polynomial pieces: on piece `i`, `P(u) = Σ_k a_ik u^k` for a local
parameter `u ∈ [−1, 1]`, coefficients `a` of shape (S, d+1, 3). Each piece is cut in `K` equal
sub-intervals; the length of each is a `GAUSS_NODES`-point Gauss–Legendre sum of the speed
`|P'(u)|` (exact to round-off on these short, smooth sub-intervals), and their cumulative sums
`σ_j` give `s(u) = σ_j + ∫_{u_j}^u |P'|` anywhere. The inverse `u(s)` is a Newton iteration inside
the sub-interval that holds `s`, from the linear guess, clamped to it (the speed is the derivative
of `s(u)`: quadratic convergence), run until its step falls below `√eps` of the sub-interval.

Gradients: the iteration runs on stopped gradients, then one more Newton step
`u ← u − (s(u) − s)/|P'(u)|` whose derivatives are the implicit-function ones,
`∂u/∂s = 1/|P'(u)|` and `∂u/∂θ = −(∂s(u)/∂θ)/|P'(u)|` for the curve's parameters `θ` (control
points, knots), in forward and reverse mode, to every order (`_numerics.polish_root`: the rule
is itself differentiable, so `jax.hessian` and nested `jacfwd` of a spine are exact).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._numerics import dot, norm, polish_root, safe_divide

GAUSS_NODES = 8
NEWTON_STEPS = 5


def monomials(u: Array, degree: int, order: int = 0) -> Array:
    """The `order`-th derivative of `(1, u, …, u^degree)`, shape `u.shape + (degree + 1,)`."""
    u = jnp.asarray(u)
    columns = [jnp.zeros_like(u)] * min(order, degree + 1) + _derived_powers(u, degree, order)
    return jnp.stack(columns, axis=-1)


def _derived_powers(u: Array, degree: int, order: int) -> list[Array]:
    """The `order`-th derivatives of `u^order, …, u^degree` (the lower powers' vanish)."""
    powers = [jnp.ones_like(u)]
    for _ in range(degree - order):
        powers.append(powers[-1] * u)
    factors = [float(np.prod(np.arange(k - order + 1, k + 1))) for k in range(order, degree + 1)]
    return [f * p for f, p in zip(factors, powers)]


def fit_matrix(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Chebyshev nodes `x` (d+1,) in `(−1, 1)` and the matrix taking values there to monomial
    coefficients, (d+1, d+1): well conditioned for the low degrees of spine pieces."""
    m = degree + 1
    x = np.cos(np.pi * (np.arange(m) + 0.5) / m)[::-1]
    return x, np.linalg.inv(np.vander(x, m, increasing=True))


def piece_derivative(coefficients: Array, u: Array, order: int) -> Array:
    """`d^order P/du^order` of one piece (coefficients (d+1, 3)) at `u` (any shape), (..., 3)."""
    degree = coefficients.shape[-2] - 1
    u = jnp.asarray(u)
    # An explicit sum over the powers, not `monomials(…) @ coefficients`: batched, that was a
    # stack and a small matrix product a point, the two costliest kernels of a float64 pose
    # (every Newton step of every point's arc-length inverse evaluates it at 8 nodes).
    terms = [
        p[..., None] * coefficients[..., k, :]
        for k, p in enumerate(_derived_powers(u, degree, order), start=order)
    ]
    return sum(terms[1:], terms[0]) if terms else jnp.zeros(u.shape + (3,), u.dtype)


def _gauss(parts: int, dtype):
    x, w = np.polynomial.legendre.leggauss(GAUSS_NODES)
    # The nodes of sub-interval k of [−1, 1], (K, Q), and the weights for `du`.
    width = 2.0 / parts
    nodes = -1 + width * (np.arange(parts)[:, None] + (x[None, :] + 1) / 2)
    return jnp.asarray(nodes, dtype), jnp.asarray(w * width / 2, dtype)


def cumulative_lengths(coefficients: Array, parts: int, count: Array | None = None) -> Array:
    """Arc length from the start to every sub-interval break, (S·parts + 1,), from 0.

    `count`: how many pieces are the curve's (int scalar, may be traced), the others padding
    of zero length (`None`: all)."""
    nodes, weights = _gauss(parts, coefficients.dtype)
    derivative = jnp.einsum(
        "kqd,sdc->skqc", monomials(nodes, coefficients.shape[-2] - 1, 1), coefficients
    )
    lengths = jnp.linalg.norm(derivative, axis=-1) @ weights
    if count is not None:
        lengths = jnp.where(jnp.arange(lengths.shape[0])[:, None] < count, lengths, 0)
    return jnp.concatenate([jnp.zeros((1,), coefficients.dtype), jnp.cumsum(lengths.reshape(-1))])


def _partial(coefficients: Array, a: Array, u: Array) -> Array:
    """`∫_a^u |P'|` on one piece (coefficients (d+1, 3)), for `u` of any shape (same shape)."""
    x, w = np.polynomial.legendre.leggauss(GAUSS_NODES)
    nodes = a + (u - a)[..., None] * jnp.asarray((x + 1) / 2, u.dtype)
    # (`norm`: a sum over a minor axis of 3 is slow batched on XLA's CPU backend, and this
    # runs in every Newton step of every point posed on an exact spine, in double precision.)
    speed = norm(piece_derivative(coefficients, nodes, 1))
    return (u - a) * dot(jnp.asarray(w / 2, u.dtype), speed)


def in_parameter(piece: Array, a: Array, start: Array, u0: Array, u1: Array, x, w):
    """A Gauss–Legendre rule (nodes `x`, weights `w` on `[−1, 1]`, NumPy) for `∫ f(s) T(s) ds`
    over the arc from local parameter `u0` to `u1` of one sub-interval of a piece
    (coefficients (d+1, 3), the sub-interval's start `a`, arc length `start` there), written
    in the piece's parameter: `T ds = P'(u) du`. No arc-length inverse: the nodes' arc lengths
    are the forward `s(u)` (`GAUSS_NODES` points each), where a rule in `s` needs `u(s)` at each.

    **Returns:** `(s, d, weights)`: the nodes' arc lengths (G,), `P'` there (G, 3) and the
    weights (G,), so that the integral is `Σ_g weights_g f(s_g) d_g`."""
    half = (u1 - u0) / 2
    u = u0 + half * jnp.asarray(np.asarray(x) + 1, u0.dtype)
    return start + _partial(piece, a, u), piece_derivative(piece, u, 1), half * jnp.asarray(
        w, u0.dtype)


def locate(cumulative: Array, s: Array, end: Array | int | None = None) -> Array:
    """Index `j` of the sub-interval with `σ_j ≤ s ≤ σ_{j+1}` (clamped to the valid range,
    below the last break `end`: the sub-intervals after it are padding)."""
    j = jnp.searchsorted(cumulative, s, side="right", method="compare_all") - 1
    end = cumulative.shape[0] - 1 if end is None else end
    return jnp.clip(j, 0, end - 1)


def sub_interval_start(j: Array, parts: int, dtype) -> Array:
    """The local parameter where sub-interval `j` (int) of its piece starts, in `[−1, 1)`."""
    return -1 + 2 * (j % parts).astype(dtype) / parts


def inverse(coefficients: Array, cumulative: Array, parts: int, s: Array, end=None):
    """The piece `i` and local parameter `u ∈ [−1, 1]` with `s(u) = s`, for `s ∈ [0, σ_M]`.

    **Arguments:** `coefficients` (S, d+1, 3) and `cumulative` (S·parts + 1,) from
    `cumulative_lengths` (both live: gradients flow through the final step); `parts`: static
    sub-intervals per piece; `s`: scalar; `end`: optional index of the last break of the
    curve (int scalar; the pieces after it are padding).

    **Returns:** `(i, u, j)`: piece index, local parameter (differentiable), sub-interval index.
    """
    fixed_coefficients, fixed_cumulative, s_fixed = jax.lax.stop_gradient(
        (coefficients, cumulative, s)
    )
    j = locate(fixed_cumulative, s_fixed, end)
    i = j // parts
    a = sub_interval_start(j, parts, s.dtype)
    b = a + 2.0 / parts
    sa, sb = fixed_cumulative[j], fixed_cumulative[j + 1]
    piece = fixed_coefficients[i]
    u = a + safe_divide(s_fixed - sa, sb - sa) * (b - a)

    # Newton stops where its last step was below `√eps` of the sub-interval (or after
    # `NEWTON_STEPS`): quadratic convergence leaves `~δ·eps` of it (`δ`, the speed's relative
    # change over the sub-interval: 1e-4 to 1e-3 on spot's limbs), and the polishing step below
    # takes that to round-off. On spot's rest spines the first step is 1.2e-3 of the
    # sub-interval at most, the second 7.6e-9 (`√eps` 1.5e-8): two steps, where five always
    # ran (each evaluates the speed at 9 points: most of a float64 pose's time). In single
    # precision the five run on (a float32 frame reads tables built from them once, at
    # registration): stopped early, u moved by its round-off and spot's posed vertices by 1.7e-7.
    double = jnp.finfo(s.dtype).bits > 32
    small = (jnp.sqrt(jnp.finfo(s.dtype).eps) if double else 0.0) * (b - a)

    def newton(carry):
        k, u, _ = carry
        residual = sa + _partial(piece, a, u) - s_fixed
        speed = norm(piece_derivative(piece, u, 1))
        moved = jnp.clip(u - safe_divide(residual, speed), a, b)
        # (The step taken, clamped: a root past the sub-interval's end, where `s` lies past the
        # curve's, stops there at once. Batched, one such point kept every point stepping.)
        return k + 1, moved, jnp.abs(moved - u)

    def going(carry):
        k, _, step = carry
        return (k < NEWTON_STEPS) & (step > small)

    start = (jnp.zeros((), jnp.int32), u, jnp.full_like(u, jnp.inf))
    _, u, _ = jax.lax.while_loop(going, newton, start)

    # `a` depends on `j` only (no derivative), but goes in the parameters all the same: the
    # residual may close over nothing traced.
    params = (coefficients[i], cumulative[j], a, s)
    return i, polish_root(_residual, u, params), j


def _residual(u: Array, params) -> tuple[Array, Array]:
    """`s(u) − s` on one sub-interval `[a, …]` of a piece, and its derivative in `u` (the speed)."""
    piece, start, a, s = params
    return start + _partial(piece, a, u) - s, norm(piece_derivative(piece, u, 1))

"""Numerics with safe gradients, shared by every subsystem.

Everything here is written so that values *and* derivatives stay finite at the degenerate
points the library meets all the time (zero curvature, zero offsets): the "double `where`"
pattern feeds a harmless argument to the unsafe function and then selects the result. The
explicit dot products keep XLA's CPU kernels fused (see `dot`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array


def dot(a: Array, b: Array) -> Array:
    """`a·b` over the last axis (leading axes broadcast), as an explicit sum of products.

    Not `jnp.dot`: batched by `vmap`, that becomes a reduction over a minor axis of length 3,
    which XLA's CPU backend runs about 7× slower than these fused multiply-adds
    (`benchmarks/README.md`). The per-point code of the batched paths uses this throughout.
    """
    return sum(a[..., i] * b[..., i] for i in range(a.shape[-1]))


def weighted_sum(weights: Array, rows: Array) -> Array:
    """`Σ_k weights[k] · rows[k]` over the first axis of `rows` (`weights (K,)`, `rows (K,
    ...)`), as an explicit sum of products: batched by `vmap`, `jnp.sum` over a short axis
    becomes a reduction that XLA's CPU backend runs several times slower (see `dot`; measured
    on the medial skin, `benchmarks/README.md`)."""
    return sum(weights[k] * rows[k] for k in range(rows.shape[0]))


def norm(a: Array) -> Array:
    """`|a|` over the last axis (see `dot`)."""
    return jnp.sqrt(dot(a, a))


def safe_sqrt(x: Array) -> Array:
    """`sqrt(x)` for `x > 0`, and 0 (with zero derivative) for `x <= 0`."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1)), 0)


def safe_divide(numerator: Array, denominator: Array) -> Array:
    """`numerator / denominator`, and 0 where the denominator is 0 (finite derivatives)."""
    nonzero = denominator != 0
    return jnp.where(nonzero, numerator / jnp.where(nonzero, denominator, 1), 0)


def cast_floats(tree, dtype):
    """Casts every floating array leaf of `tree` to `dtype` (so float32 points stay float32)."""

    def cast(leaf):
        if isinstance(leaf, jax.Array | np.ndarray) and jnp.issubdtype(leaf.dtype, jnp.floating):
            return leaf.astype(dtype)
        return leaf

    return jax.tree.map(cast, tree)


def relative_tolerance(dtype) -> float:
    """A tolerance for "converged" checks: the square root of the dtype's epsilon."""
    return float(np.sqrt(np.finfo(dtype).eps))


def polish_root(function, s: Array, params) -> Array:
    """One last Newton step on `f(s, params) = 0` from an approximate root `s`, as a function of
    `params` with the implicit-function derivatives to every order.

    `function(s, params)` returns `(f, slope)`, with `slope = ∂f/∂s` (the step is skipped and
    the derivative is zero where the slope is 0: callers zero it where Newton must not run).
    The value is `s − f/slope`, computed on stopped gradients; its derivative is
    `ds = −(∂f/∂params · dparams)/slope`, evaluated at the polished root with the root itself
    differentiated by this same rule. Being written in differentiable operations, the rule
    composes: second and higher derivatives (forward or reverse, `jax.hessian`) are those of the
    exact root, where one Newton step with live gradients would be right to first order only.

    **Arguments:** `function`: `(s, params) → (f, slope)`, scalars; it may close over no
    traced value (pass every array it uses in `params`, even those without a derivative);
    `s`: scalar starting root (its gradient is ignored); `params`: pytree of arrays.

    **Returns:** the polished root, scalar.
    """

    @jax.custom_jvp
    def root(s, params):
        s, params = jax.lax.stop_gradient((s, params))
        f, slope = function(s, params)
        return s - safe_divide(f, slope)

    @root.defjvp
    def _root_jvp(primals, tangents):
        s, params = primals
        _, dparams = tangents
        value = root(s, params)
        (_, slope), (df, _) = jax.jvp(lambda p: function(value, p), (params,), (dparams,))
        return value, -safe_divide(df, slope)

    return root(s, params)

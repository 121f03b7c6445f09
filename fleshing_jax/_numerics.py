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
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array


def dot(a: Array, b: Array) -> Array:
    """`a·b` over the last axis (leading axes broadcast), as an explicit sum of products.

    Not `jnp.dot`: batched by `vmap`, that becomes a reduction over a minor axis of length 3,
    which XLA's CPU backend runs about 7× slower than these fused multiply-adds
    (`benchmarks/README.md`). The per-point code of the batched paths uses this throughout.
    """
    # Components sliced keeping their axis and the sum squeezed once: a third fewer traced
    # operations than indexing each (a slice and a squeeze apiece), and the same arithmetic,
    # in the same order (the product taken once instead runs slower batched: XLA keeps it).
    def component(x, i):
        return jax.lax.slice_in_dim(x, i, i + 1, axis=-1)

    total = component(a, 0) * component(b, 0)
    for i in range(1, a.shape[-1]):
        total = total + component(a, i) * component(b, i)
    return total[..., 0]


def per_component(function, *vectors: Array) -> Array:
    """`function` applied to the components of short vectors (the last axis, 2 or 3), stacked:
    `per_component(lambda a, b: a + t * b, x, y)` is `x + t y`.

    For the per-point code of the batched paths: batched by `vmap`, an operation on a (3,)
    vector becomes one on an (N, 3) array, whose fused kernels XLA's CPU backend runs on one
    element at a time; on the components, each an (N,) array, its kernels are vectorised
    (points placed in frames of an arc, 2^20 of them: 7.3 ms as vectors, 0.9 ms per component;
    benchmarks/README.md).
    """
    return jnp.stack([function(*(v[i] for v in vectors)) for i in range(vectors[0].shape[-1])])


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


# π/2 in three parts for the reduction of `sincos`: the first two to 8 significant bits, so
# that their products with a quadrant count below 2^16 are exact in single precision.
_HALF_PI_1 = 201 / 128
_HALF_PI_2 = 127 / 2**18
_HALF_PI_3 = float(np.float32(np.pi / 2 - _HALF_PI_1 - _HALF_PI_2))
_SIN_TERMS = [(-1) ** k / float(np.prod(np.arange(2, 2 * k + 2))) for k in range(1, 5)]
_COS_TERMS = [(-1) ** k / float(np.prod(np.arange(1, 2 * k + 1))) for k in range(1, 6)]


@jax.custom_jvp
def sincos(x: Array) -> tuple[Array, Array]:
    """`(sin x, cos x)`, elementwise, with the derivative `(cos x, −sin x) dx`.

    In double precision `jnp.sin` and `jnp.cos`. In single precision, as fast as a few
    multiply-adds: `x` is reduced to `r ∈ [−π/4, π/4]` by the nearest multiple `q π/2`
    (Cody–Waite: `π/2` in three parts, exact products for `|q| < 2^16`), then Taylor
    polynomials to `r⁹` and `r¹⁰` (truncation below 2e-9) and the quadrant `q mod 4` pick the
    pair. XLA's own single-precision `sin` and `cos` cost 9× as much (both on 2^20 points:
    3.9 ms, against 0.43 ms; benchmarks/README.md), more than a table lookup. Error: within
    1e-7 of the exact values for `|x| ≤ 100` (7e-8 measured); beyond, it grows with `|x|` (at
    most 5e-10 `|x|` up to 1e4), as the resolution of `x` itself does (6e-8 `|x|`).
    """
    if x.dtype != jnp.float32:
        return jnp.sin(x), jnp.cos(x)
    q = jnp.round(x * np.float32(2 / np.pi))
    r = ((x - q * _HALF_PI_1) - q * _HALF_PI_2) - q * np.float32(_HALF_PI_3)
    r2 = r * r
    sin = r + r * r2 * _horner(_SIN_TERMS, r2)
    cos = 1 + r2 * _horner(_COS_TERMS, r2)
    quadrant = q.astype(jnp.int32)
    swap = (quadrant & 1) == 1  # odd quadrants: sin x = ±cos r, cos x = ∓sin r
    sin, cos = jnp.where(swap, cos, sin), jnp.where(swap, sin, cos)
    return (
        jnp.where((quadrant & 2) == 2, -sin, sin),
        jnp.where(((quadrant + 1) & 2) == 2, -cos, cos),
    )


@sincos.defjvp
def _sincos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    sin, cos = sincos(x)
    return (sin, cos), (cos * dx, -sin * dx)


def held_trig(*angles: Array, bounded: bool = False) -> list[tuple[Array, Array]]:
    """`(cos, sin)` of each of `angles` (arrays), computed once and held in memory, each pair
    made by a product with the identity: XLA computes a product on its own, and its consumers
    read it. Batched over a table's nodes, XLA's CPU backend fused the sines and cosines into
    each kernel that turns a vector with them, and computed them again for every coordinate it
    made (15 a node for a bent spine's frame and `Q′`, 3 a quadrature point; a limb's twist, a
    scalar, for each of its frames' 76k values). (An optimisation barrier is dropped by XLA's
    CPU pipeline; a conditional becomes a select under `vmap`, fused as the rest.) The product
    gives the values exactly, each one times 1 plus a zero (NaN where the angle is).
    `bounded`: the angles are within a few turns (a pose's bend or twist, at most a full turn,
    times a ramp in [0, 1]): in single precision, their values by `sincos`, within 1e-7 of
    exact where XLA's cost 5× as much (a call to the C library a value: a bent limb's table's
    15k angles a limb, a ninth of a float32 frame of spot's 9 limbs)."""
    out = []
    for angle in angles:
        sin, cos = sincos(angle) if bounded else (jnp.sin(angle), jnp.cos(angle))
        values = jnp.stack([cos, sin])
        held = jnp.einsum("wv,v...->w...", jnp.eye(2, dtype=values.dtype), values)
        out.append((held[0], held[1]))
    return out


def _horner(terms: list[float], y: Array) -> Array:
    """`terms[0] + terms[1] y + terms[2] y² + …`, by Horner's rule."""
    value = jnp.asarray(terms[-1], y.dtype)
    for term in reversed(terms[:-1]):
        value = term + y * value
    return value


def on_device(x, dtype=None) -> Array:
    """`x` (concrete: numbers, NumPy or device arrays) as a device array of `dtype`, converted
    on the host: `jnp.asarray(x, dtype)` compiles a conversion program for each shape and
    dtype (a dozen of the programs of a skeleton's first registration, tens of ms each)."""
    return jax.device_put(np.asarray(x, dtype))


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

    def _root_jvp(primals, tangents):
        s, params = primals
        _, dparams = tangents
        value = root(s, params)
        # Pushed forward through the parameters that move only (symbolic zeros: the others,
        # a spine's coefficients under a fit's derivative in its angles, are held). With
        # their zero tangents materialised, the derivative of the whole residual was traced
        # and compiled: a shape fit's Jacobian held 2,000 operations more.
        leaves, tree = jax.tree.flatten(params)
        moving = [i for i, d in enumerate(tree.flatten_up_to(dparams))
                  if not isinstance(d, SymbolicZero)]

        def at(*values):
            full = list(leaves)
            for i, v in zip(moving, values):
                full[i] = v
            return function(value, tree.unflatten(full))

        dleaves = tree.flatten_up_to(dparams)
        (_, slope), (df, _) = jax.jvp(at, [leaves[i] for i in moving],
                                      [dleaves[i] for i in moving])
        return value, -safe_divide(df, slope)

    root.defjvp(_root_jvp, symbolic_zeros=True)
    return root(s, params)

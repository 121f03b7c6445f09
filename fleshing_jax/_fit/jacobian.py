"""Residuals whose derivative is their Jacobian, materialised once per point of a solve.

optimistix's Gauss–Newton solvers linearise the residuals at each step (`jax.linearize`) and
keep the linear function for the step's descent and trust-region tests. Traced through a
large residual (a fit's fleshing of every point), that linear function and the intermediates
it needs are carried in the solver's loop and its code inlined at each use: the solve's one
program took several times the residual's own compile. With the Jacobian computed up front by
forward mode (one `vmap` of `jvp` over the parameters' basis: the primal computed once beside
it) the linear function is a matrix product, and the loop carries the matrix. A minimiser
(BFGS: the fits without correspondences) needs only the gradient, one reverse pass, and keeps
the residuals as they are (`for_solver`).

Where parameters move disjoint parts of an intermediate (a skeleton's limbs, each moving its
own vertices and its descendants'), several share one forward pass through it (`compressed`:
the Jacobian's columns coloured, as sparse finite differences do), and the full columns are
rebuilt from which rows each parameter moves before the cheap rest of the residuals.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, PyTree


def materialised(residuals: Callable[[PyTree], PyTree]) -> Callable:
    """`residuals` (`y` → a pytree of arrays, `y` a pytree of floating arrays) as an optimistix
    function `(y, args) -> residuals(y)` whose `jvp` is `J ẏ`, each leaf's Jacobian (…, p)
    computed by forward mode with the value (`p` the parameters' count). First order only
    (what least squares needs; its transpose serves reverse mode); the value is exactly
    `residuals(y)`."""

    @jax.custom_jvp
    def function(y, args=None):
        return residuals(y)

    @function.defjvp
    def _jvp(primals, tangents):
        y, _ = primals
        dy, _ = tangents
        flat, unravel = ravel_pytree(y)

        def pushed(direction):
            return jax.jvp(residuals, (y,), (unravel(direction),))

        basis = jnp.eye(flat.size, dtype=flat.dtype)
        value, columns = jax.vmap(pushed, out_axes=(None, -1))(basis)
        step = ravel_pytree(dy)[0]
        return value, jax.tree.map(lambda column: column @ step, columns)

    return function


def compressed(inner: Callable[[PyTree], Array], outer: Callable[[Array], PyTree],
               seeds: Array, moves: Array, keep_inner: bool = False) -> Callable:
    """`outer(inner(y))` as `materialised` makes it (its `jvp` `J ẏ`, the Jacobian by forward
    mode), with one forward pass through `inner` per row of `seeds` rather than per parameter.
    With `keep_inner`, `(outer(inner(y)), inner(y))`: a solver's auxiliary output (`has_aux`),
    `inner`'s value read from the Jacobian's forward pass, with no copy of `inner` of its own.

    `inner`: `y` → an (m, …) array (a posed mesh's vertices), the costly part; `outer`: that
    array → the residuals (a pytree; cheap beside `inner`). `seeds` (c, p) of 0 and 1: the
    parameters (`y` flattened, p) that share each pass, each parameter in exactly one;
    `moves` (m, p) bool: which parameters each row of `inner`'s output depends on. Parameters
    that share a seed must never move the same row: a row's tangent from a seed is then its
    one parameter's column, taken where `moves` says (exact: the other parameters' tangents
    are zeros there). The p full columns are then pushed through `outer`."""

    @jax.custom_jvp
    def function(y, args=None):
        x = inner(y)
        return (outer(x), x) if keep_inner else outer(x)

    @function.defjvp
    def _jvp(primals, tangents):
        y, _ = primals
        dy, _ = tangents
        flat, unravel = ravel_pytree(y)
        x, pushed = jax.vmap(lambda seed: jax.jvp(inner, (y,), (unravel(seed),)),
                             out_axes=(None, 0))(seeds.astype(flat.dtype))
        shape = (moves.shape[1], moves.shape[0]) + (1,) * (pushed.ndim - 2)
        columns = jnp.where(moves.T.reshape(shape), pushed[jnp.argmax(seeds, axis=0)], 0)
        value, out = jax.vmap(lambda column: jax.jvp(outer, (x,), (column,)),
                              out_axes=(None, -1))(columns)
        step = ravel_pytree(dy)[0]
        tangent = jax.tree.map(lambda column: column @ step, out)
        if not keep_inner:
            return value, tangent
        return (value, x), (tangent, jnp.tensordot(step, columns, axes=1))

    return function


def for_solver(residuals: Callable[[PyTree], PyTree], solver) -> Callable:
    """What a fit passes to `optimistix.least_squares` with `solver`: `materialised(residuals)`
    for a least-squares solver, `residuals` itself for a minimiser."""
    if isinstance(solver, optx.AbstractLeastSquaresSolver):
        return materialised(residuals)
    return residuals

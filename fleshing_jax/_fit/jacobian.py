"""Residuals whose derivative is their Jacobian, materialised once per point of a solve.

optimistix's Gauss–Newton solvers linearise the residuals at each step (`jax.linearize`) and
keep the linear function for the step's descent and trust-region tests. Traced through a
large residual (`fit_skeleton_pose`: the fleshing of every chosen vertex), that linear function
and the intermediates it needs are carried in the solver's loop and its code inlined at each
use: the solve's one program took several times the residual's own compile. With the Jacobian
computed up front by forward mode (one `vmap` of `jvp` over the parameters' basis: the primal
computed once beside it) the linear function is a matrix product, and the loop carries the
(m, p) matrix.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array


def materialised(residuals: Callable[[Array], Array]) -> Callable:
    """`residuals` (`y` (p…) → (m,)) as an optimistix function `(y, args) -> (m,)`, whose
    `jvp` is `J ẏ` with `J` (m, p) computed by forward mode with the value. First order only
    (what least squares needs); the value is `residuals(y)` exactly."""

    @jax.custom_jvp
    def function(y, args=None):
        return residuals(y)

    @function.defjvp
    def _jvp(primals, tangents):
        y, _ = primals
        dy, _ = tangents
        basis = jnp.eye(y.size, dtype=y.dtype).reshape(-1, *y.shape)
        value, columns = jax.vmap(lambda d: jax.jvp(residuals, (y,), (d,)), out_axes=(None, -1))(
            basis)
        return value, columns @ dy.reshape(-1)

    return function

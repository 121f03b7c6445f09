"""Running an expensive per-point function on the few points that need it, under `jit`.

Under `vmap`, a per-point `lax.cond` computes both branches for every point. Here the points that
need the expensive branch are gathered (`jnp.nonzero` with a static size), processed in chunks
of `chunk` points by a `while_loop` whose trip count is the number of such chunks, and scattered
back: the cost follows the number of points that need the work, not the number of points.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, PyTree

from .chunks import per_point

CHUNK = 32


def update_where(
    needed: Bool[Array, " N"],
    function: Callable,
    values: PyTree,
    inputs: PyTree,
    chunk: int = CHUNK,
) -> PyTree:
    """`values` with entry `i` replaced by `function(inputs[i])` wherever `needed[i]`.

    **Arguments:** `needed`: (N,) bool; `function`: one point's inputs → one point's values;
    `values`, `inputs`: pytrees of arrays with leading axis N (scalar leaves of `inputs` are
    shared by all points). No gradients flow through the update (use it for searches and flags).
    Nothing runs when no point needs it.

    **Returns:** the updated `values`.
    """
    n = needed.shape[0]
    if n == 0:
        return values
    chunk = min(chunk, n)
    padded = -(-n // chunk) * chunk
    inputs, shared = per_point(jax.lax.stop_gradient(inputs))

    def run(values):
        # Indices of the needed points first; the padding points at n (dropped when scattering).
        (index,) = jnp.nonzero(needed, size=padded, fill_value=n)
        count = jnp.sum(needed)

        def body(state):
            start, values = state
            where = jax.lax.dynamic_slice(index, (start,), (chunk,))
            batch = jax.tree.map(lambda a: a.at[where].get(mode="clip"), inputs)
            result = jax.vmap(lambda b: function(eqx.combine(b, shared)))(batch)
            values = jax.tree.map(lambda v, r: v.at[where].set(r, mode="drop"), values, result)
            return start + chunk, values

        return jax.lax.while_loop(lambda state: state[0] < count, body, (0, values))[1]

    # Usually no point needs it: skip even the search for the indices.
    return jax.lax.cond(jnp.any(needed), run, lambda values: values, values)

"""A spine tabulated as cubic pieces: the fast evaluator of the batched paths in single precision.

Evaluating a spine exactly is expensive where it matters most, once per point of a large batch:
a free-form spine needs a span search, a Newton arc-length inverse and a double-reflection step,
and every spine needs the circular continuation past its ends. None of that depends on the
points, so the batched paths (`register`, `pose`, `flesh`) can evaluate the spine once on a grid
and then, per point, look up a cubic: one gathered row and a few fused multiply-adds.

The table covers the closest-point search range `[lo, hi]` (the spine and its continuations) in
three uniform grids, on `[lo, 0]`, `[0, length]` and `[length, hi]`, so that no piece straddles
an end (where the continuation joins with only two continuous derivatives). On each piece the
jet and normals `(C, T, k, I, J)` are interpolated at the 4 Chebyshev points of the piece. With
at least 32 pieces per radian of turning the interpolation error is below 1e-9 relative
(measured in `tests/test_table.py`): far below single precision's resolution (1.2e-7), so that in
float32 the tabulated paths agree with the exact ones to round-off. In float64 they would not
(`det J = 1` to 1e-15 is the point of the exact spines): there the batched paths evaluate the
spine exactly (`fast_evaluator`). Polylines are piecewise by nature and are never tabulated.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from . import _arclength as arclength
from ._spine import AbstractSpine

DEGREE = 3
END_PIECES = 32  # pieces on each continuation (at most a quarter turn, or one length, long)
MIN_PIECES = 128  # pieces on [0, length], at least (else the spine's search samples)


class SpineTable(eqx.Module):
    """A spine tabulated on its closest-point search range, evaluated like a prepared spine.

    Provides `length`, `jet`, `jet_and_normals`, `__call__`, `extension`, `default_samples` and
    `_prepare` with the meaning they have on a spine, for `s` in `[lo, hi]` (beyond, the end
    pieces extrapolate: callers keep to the range, or use the exact spine there).

    **Fields:** `length`, `lo`, `hi` (scalars); `coefficients`: (4, 15, P) monomial coefficients
    of `(C, T, k, I, J)` on each piece, in its local parameter `u ∈ [−1, 1]`; `inner`: static
    number of pieces on `[0, length]` (`P = inner + 2 END_PIECES`); `samples`: static, the
    spine's `default_samples()`.
    """

    length: Array
    lo: Array
    hi: Array
    coefficients: Array
    inner: int = eqx.field(static=True)
    samples: int = eqx.field(static=True)

    def __init__(self, spine: AbstractSpine, inner: int):
        e0, e1 = spine.extension()
        self.length, self.lo, self.hi, self.inner = spine.length, -e0, spine.length + e1, inner
        self.samples = spine.default_samples()
        x, fit = arclength.fit_matrix(DEGREE)
        x = jnp.asarray((x + 1) / 2, self.length.dtype)  # Chebyshev points of [0, 1]
        widths = self._widths()
        counts = (END_PIECES, inner, END_PIECES)
        breaks = (self.lo, jnp.zeros_like(self.length), self.length)
        starts = jnp.concatenate(
            [a + w * jnp.arange(n, dtype=w.dtype) for a, w, n in zip(breaks, widths, counts)]
        )
        width = jnp.concatenate([jnp.full((n,), w) for w, n in zip(widths, counts)])

        def values(s):
            (c, t, k), (i, j) = spine.jet_and_normals(s)
            return jnp.concatenate([c, t, k, i, j])

        samples = jax.vmap(jax.vmap(values))(starts[:, None] + width[:, None] * x)  # (P, 4, 15)
        self.coefficients = jnp.einsum("kq,pqf->kfp", jnp.asarray(fit, samples.dtype), samples)

    def _widths(self) -> tuple[Array, Array, Array]:
        return -self.lo / END_PIECES, self.length / self.inner, (self.hi - self.length) / END_PIECES

    def _values(self, s: Array) -> Array:
        """The 15 tabulated values at `s`: `(C, T, k, I, J)` concatenated, (15,)."""
        s = jnp.asarray(s, self.length.dtype)
        w0, w1, w2 = self._widths()
        # A fractional piece index: whole part = the piece, fraction = where in it.
        index = jnp.where(
            s < 0,
            (s - self.lo) / w0,
            jnp.where(
                s > self.length,
                END_PIECES + self.inner + (s - self.length) / w2,
                END_PIECES + s / w1,
            ),
        )
        piece = jnp.clip(jnp.floor(index), 0, self.coefficients.shape[-1] - 1)
        u = 2 * (index - piece) - 1
        # One gather per coefficient, from rows of P values: batched, these are fast loads from
        # a table that stays in cache, where gathering whole (4, 15) rows per point is ~7×
        # slower on XLA's CPU backend (benchmarks/README.md).
        a = [
            [row.at[piece.astype(jnp.int32)].get(mode="promise_in_bounds") for row in rows]
            for rows in self.coefficients
        ]
        values = jnp.stack([a0 + u * (a1 + u * (a2 + u * a3)) for a0, a1, a2, a3 in zip(*a)])
        # Materialised once per point: left to itself, XLA splits the gathers into separate
        # kernels when many consumers share them (~5× slower registration).
        return jax.lax.optimization_barrier(values)

    def jet_and_normals(self, s):
        """`((C, T, k), (I, J))` at `s`, each (3,)."""
        c, t, k, i, j = jnp.split(self._values(s), 5)
        return (c, t, k), (i, j)

    def jet(self, s):
        """`(C, T, k)` at `s`, each (3,)."""
        return self.jet_and_normals(s)[0]

    def __call__(self, s):
        """`C(s)`, (3,)."""
        return self.jet(s)[0]

    def extension(self) -> tuple[Array, Array]:
        """How far the table reaches past each end: the spine's search extension."""
        return -self.lo, self.hi - self.length

    def default_samples(self) -> int:
        """The closest-point search samples of the tabulated spine."""
        return self.samples

    def _prepare(self) -> SpineTable:
        return self


def fast_evaluator(spine: AbstractSpine) -> AbstractSpine | SpineTable:
    """What the batched paths evaluate: the prepared `spine` itself in double precision (and
    for polylines), its `SpineTable` in single precision (the spine's dtype, cast to the
    points')."""
    spine = spine._prepare()
    if jnp.finfo(spine.length.dtype).bits > 32 or not spine._tabulable():
        return spine
    return SpineTable(spine, max(MIN_PIECES, spine.default_samples()))

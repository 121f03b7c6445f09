"""Functions of arc length tabulated as cubic pieces: the fast evaluators of the batched paths
in single precision.

Evaluating a spine exactly is expensive where it matters most, once per point of a large batch:
a free-form spine needs a span search, a Newton arc-length inverse and a double-reflection step,
and every spine needs the circular continuation past its ends. None of that depends on the
points, so the batched paths (`register`, `pose`, `flesh`) can evaluate the spine once on a grid
and then, per point, look up a cubic: a few gathered coefficients and fused multiply-adds.

A `PiecewiseCubic` covers the closest-point search range `[lo, hi]` of a spine (the spine and its
continuations) in three uniform grids, on `[lo, 0]`, `[0, length]` and `[length, hi]`, so that no
piece straddles an end (where the continuation joins with only two continuous derivatives). On
each piece the tabulated function is interpolated at the 4 Chebyshev points of the piece. With
at least 32 pieces per radian of turning the interpolation error is below 1e-9 relative
(measured in `tests/test_table.py`): far below single precision's resolution (1.2e-7), so that in
float32 the tabulated paths agree with the exact ones to round-off. In float64 they would not
(`det J = 1` to 1e-15 is the point of the exact spines): there the batched paths evaluate the
spine exactly (`tabulates`). Polylines are piecewise by nature and are never tabulated. On an
arc every such function is a sinusoid of `s`, held exactly by three coefficients a value
(`tabulated`, `_spines.sinusoid`): an arc's registration of 1M float32 points 66 → 22 ms.

`SpineTable` tabulates the jet and normals of a spine and the products the closest-point
search needs (`_foot_terms`, `_local_terms`); `_fleshing.target.TargetFrames` tabulates what a pose
needs of its target.

Why products and single uses: batched, a looked-up value used once is fused by XLA into the
kernel that consumes it (a few loads and multiply-adds per point); a value used by several
kernels is materialised, one kernel and one round trip through memory per value, several times
slower on XLA's CPU backend (benchmarks/README.md). So the search's terms are tabulated as
products (`C·T`, `k·C`, …) and formed per point from values each used once.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._batching.grid import grid_vmap
from .._numerics import dot
from . import arclength
from .analytic import Arc
from .lookups import Lookups
from .sinusoid import Sinusoid
from .spine import AbstractSpine

DEGREE = 3
END_PIECES = 32  # pieces on each continuation (at most a quarter turn, or one length, long)
MIN_PIECES = 128  # pieces on [0, length], at least (else the spine's search samples)
JET_VALUES = 9  # C, T, k: the first values a table holds, all a jet-only table holds (`refit`)


_READ = jax.lax.GatherDimensionNumbers(
    offset_dims=(), collapsed_slice_dims=(0,), start_index_map=(0,)
)


def _read(flat: Array, index: Array) -> Array:
    """`flat[index]` for an index known to be in bounds: the gather that
    `flat.at[index].get(mode="promise_in_bounds")` becomes, built directly, because the
    lookups are many (4 F per evaluation) and NumPy-style indexing costs about 2 ms of tracing
    each (most of a command-line call's tracing time)."""
    return jax.lax.gather(
        flat,
        index[None],
        _READ,
        slice_sizes=(1,),
        mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS,
    )


class PiecewiseCubic(eqx.Module):
    """A function of arc length `s ↦ (F,)` tabulated on a spine's closest-point search range.

    **Fields:** `length`, `lo`, `hi` (scalars: the spine's length and search range);
    `coefficients`: (P, 4, F) monomial coefficients of the F values on each piece, in its local
    parameter `u ∈ [−1, 1]` (piece-major: a point's lookups read one contiguous block, which
    stays fast when the table outgrows the caches); `inner`: static number of pieces on
    `[0, length]` (`P = inner + 2 END_PIECES`).
    """

    length: Array
    lo: Array
    hi: Array
    coefficients: Array
    inner: int = eqx.field(static=True)

    def __init__(
        self,
        spine: AbstractSpine,
        function: Callable,
        inner: int | None = None,
        extension: tuple[Array, Array] | None = None,
    ):
        """`function`: `s` (scalar) → (F,); `spine` gives the range and the default `inner`
        (`max(MIN_PIECES, spine.default_samples())`); `extension`: `spine.extension()`, where
        the caller has it (each evaluates the spine at both ends: on a free-form spine, an
        arc-length inverse apiece, traced and compiled again)."""
        e0, e1 = spine.extension() if extension is None else extension
        self.length, self.lo, self.hi = spine.length, -e0, spine.length + e1
        self.inner = max(MIN_PIECES, spine.default_samples()) if inner is None else inner
        self.coefficients = _fit(grid_vmap(function, self.nodes()))

    def nodes(self) -> Array:
        """(P, 4): the arc lengths where each piece interpolates, increasing (the Chebyshev
        points of each piece)."""
        x, _ = arclength.fit_matrix(DEGREE)
        x = jnp.asarray((x + 1) / 2, self.length.dtype)  # Chebyshev points of [0, 1]
        widths = self._widths()
        counts = (END_PIECES, self.inner, END_PIECES)
        breaks = (self.lo, jnp.zeros_like(self.length), self.length)
        starts = jnp.concatenate(
            [a + w * jnp.arange(n, dtype=w.dtype) for a, w, n in zip(breaks, widths, counts)]
        )
        width = jnp.concatenate([jnp.full((n,), w) for w, n in zip(widths, counts)])
        return starts[:, None] + width[:, None] * x

    def refit(self, samples: Array) -> PiecewiseCubic:
        """The same pieces interpolating other values at `nodes()`: `samples` (P, 4, F)."""
        return eqx.tree_at(lambda table: table.coefficients, self, _fit(samples))

    def _widths(self) -> tuple[Array, Array, Array]:
        return -self.lo / END_PIECES, self.length / self.inner, (self.hi - self.length) / END_PIECES

    def fields(self, s: Array) -> Lookups:
        """The F tabulated values at `s`, as F scalars, each looked up where it is first read
        (`Lookups`).

        Each is its own lookup (one gather per coefficient): batched,
        XLA fuses a lookup into the kernel that consumes it, where a stacked (F,) vector would
        be materialised and then read back (several times slower on XLA's CPU backend,
        benchmarks/README.md). So callers look up only the values they need, each used once.
        """
        piece, u = self._locate(s)
        count = self.coefficients.shape[2]
        start = piece * (4 * count)
        flat = self.coefficients.reshape(-1)

        def value(f):
            b0, b1, b2, b3 = (_read(flat, start + (k * count + f)) for k in range(4))
            return b0 + u * (b1 + u * (b2 + u * b3))

        return Lookups(count, value)

    def vector(self, s: Array, count: int | None = None) -> Array:
        """The F tabulated values at `s` as one (F,) vector, read in one block: for the paths
        that use them together (building other tables), where `fields` would trace 4 F reads
        and F polynomials (about half a second of tracing for a spine table's 21 values).
        `count` (static): the first `count` values only, read alone (a bent spine's
        quadrature reads a tangent: the whole block of a point was most of its cost)."""
        piece, u = self._locate(s)
        if count is None:
            block = jax.lax.dynamic_index_in_dim(self.coefficients, piece, keepdims=False)
        else:
            zero = jnp.zeros_like(piece)
            block = jax.lax.dynamic_slice(self.coefficients, (piece, zero, zero), (1, 4, count))[0]
        b0, b1, b2, b3 = block
        return b0 + u * (b1 + u * (b2 + u * b3))

    def _locate(self, s: Array) -> tuple[Array, Array]:
        """`(piece (int32), u ∈ [−1, 1])`: the piece holding `s` and where in it."""
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
        index = jnp.where(jnp.isnan(index), 0, index)  # (keeps the reads below in bounds)
        piece = jnp.clip(jnp.floor(index), 0, self.coefficients.shape[0] - 1)
        return piece.astype(jnp.int32), 2 * (index - piece) - 1


def _fit(samples: Array) -> Array:
    """Monomial coefficients (P, 4, F) of the cubics through `samples` (P, 4, F) at each
    piece's Chebyshev points."""
    _, fit = arclength.fit_matrix(DEGREE)
    return jnp.einsum("kq,pqf->pkf", jnp.asarray(fit, samples.dtype), samples)


def tabulated(
    spine: AbstractSpine,
    function: Callable,
    inner: int | None = None,
    extension: tuple[Array, Array] | None = None,
) -> PiecewiseCubic | Sinusoid:
    """`function` of arc length (`s` → (F,)) on `spine`'s search range, to be looked up per
    point (`fields`): as a `PiecewiseCubic`, or on an arc exactly as a `Sinusoid` (whatever is
    built from its point, frame and curvature is one), whose `sincos` costs less than the
    cubics' four reads a value. `extension`: `spine.extension()`, where the caller has it."""
    if isinstance(spine, Arc):
        return Sinusoid(spine.radius, function)
    return PiecewiseCubic(spine, function, inner, extension)


class SpineTable(eqx.Module):
    """A spine tabulated on its closest-point search range, evaluated like a prepared spine.

    Provides `length`, `jet`, `jet_and_normals`, `__call__`, `extension`, `default_samples`,
    `_prepare` and the search's `_foot_terms` and `_local_terms` with the meaning they have on a
    spine, for `s` in `[lo, hi]` (beyond, the end pieces extrapolate: callers keep to the range,
    or use the exact spine there).

    **Fields:** `length`, `lo`, `hi`: the spine's length and search range; `cubics`: the
    values `C, T, k, I, J` and the products `C·T, k·C, C·I, C·J, k·I, k·J` (F = 21) as a
    `PiecewiseCubic`, or exactly as a `Sinusoid` on an arc (`tabulated`); `samples`: static,
    the spine's `default_samples()`. A table `refit` from a jet alone holds `C, T, k` (F = 9):
    it provides `jet` and `__call__`, not the normals nor the search's terms (`searchable`).
    """

    length: Array
    lo: Array
    hi: Array
    cubics: PiecewiseCubic | Sinusoid
    samples: int = eqx.field(static=True)

    def __init__(self, spine: AbstractSpine, inner: int | None = None):
        extension = spine.extension()
        self.length, self.lo, self.hi = spine.length, -extension[0], spine.length + extension[1]
        self.cubics = tabulated(
            spine, lambda s: table_values(*spine.jet_and_normals(s)), inner, extension
        )
        self.samples = spine.default_samples()

    def refit(
        self, jets: tuple[Array, Array, Array], normals: tuple[Array, Array] | None = None
    ) -> SpineTable:
        """The table of another spine over the same search range, from its jet and normals at
        this table's `cubics.nodes()` (each (P, 4, 3)): no evaluation of that spine elsewhere
        (`_spines.bent`: a bent limb, whose search range is its rest spine's). Without
        `normals`, a table of the jet alone (not `searchable`): 9 values a node fit, not 21
        (a posed limb's target, whose valid region reads only `C, T, k`: its normals and
        products were a tenth of a float32 frame of spot's 9 limbs)."""
        if normals is None:
            samples = jnp.concatenate(jets, axis=-1)
        else:
            samples = grid_vmap(table_values, jets, normals)
        return eqx.tree_at(lambda table: table.cubics, self, self.cubics.refit(samples))

    @property
    def searchable(self) -> bool:
        """Whether the table holds the normals and the search's products, not the jet `C, T, k`
        alone (`refit` without normals; static: from the coefficients' shape)."""
        cubics = self.cubics
        return not isinstance(cubics, PiecewiseCubic) or cubics.coefficients.shape[-1] > JET_VALUES

    def _searched(self, what: str) -> None:
        """`ValueError` where this table holds the jet alone (`searchable`), for `what`."""
        if not self.searchable:
            raise ValueError(
                f"{what} needs a spine table with its normals and products; this one holds "
                "the jet (C, T, k) alone (SpineTable.refit without normals): use the spine's "
                "full table (fast_evaluator)."
            )

    def jet_and_normals(self, s):
        """`((C, T, k), (I, J))` at `s`, each (3,)."""
        self._searched("jet_and_normals")
        # For the rare paths (global search, building other tables): the batched search uses
        # `_foot_terms` and `_local_terms`, whose lookups fuse.
        c, t, k, i, j = jnp.split(self.cubics.vector(s)[:15], 5)
        return (c, t, k), (i, j)

    def _anchors(self, s):
        """`jet_and_normals` at `s`, at 0 and at `length` (as `AbstractSpine._anchors`)."""
        return [self.jet_and_normals(s), *self._end_anchors()]

    def _end_anchors(self):
        """`jet_and_normals` at 0 and at `length` (as `AbstractSpine._end_anchors`)."""
        return [self.jet_and_normals(x) for x in (jnp.zeros_like(self.length), self.length)]

    def jet(self, s):
        """`(C, T, k)` at `s`, each (3,): their 9 values read alone."""
        c, t, k = jnp.split(self.cubics.vector(s, JET_VALUES), 3)
        return c, t, k

    def __call__(self, s):
        """`C(s)`, (3,)."""
        return self.jet(s)[0]

    # The search's own terms, from the tabulated products: no vector of the spine is formed and
    # each looked-up value is used once, so XLA fuses the lookups into their consumer (the
    # whole fast registration of a point is a few kernels). Callers use each result once too.

    def _foot_terms(self, x, s):
        """`(f, slope, distance)` at `s` for a point `x` (3,), as `AbstractSpine._foot_terms`:
        `f = C·T − x·T`, `slope = 1 + k·C − x·k`, `distance = |x − C|`."""
        self._searched("the closest-point search")
        v = self.cubics.fields(s)
        f = v[15] - _dot(x, v[3:6])
        slope = 1 + v[16] - _dot(x, v[6:9])
        distance = jnp.sqrt(sum(jnp.square(x[a] - v[a]) for a in range(3)))
        return f, slope, distance

    def _local_terms(self, x, s):
        """`(offset (2,), curvature (2,), slope)` at `s`, as `AbstractSpine._local_terms`:
        offset `(x·I − C·I, x·J − C·J)`, curvature `(k·I, k·J)`, slope `1 + k·C − x·k`."""
        self._searched("the registration's local terms")
        v = self.cubics.fields(s)
        offset = jnp.stack([_dot(x, v[9:12]) - v[17], _dot(x, v[12:15]) - v[18]])
        return offset, jnp.stack(v[19:21]), 1 + v[16] - _dot(x, v[6:9])

    def extension(self) -> tuple[Array, Array]:
        """How far the table reaches past each end: the spine's search extension."""
        return -self.lo, self.hi - self.length

    def default_samples(self) -> int:
        """The closest-point search samples of the tabulated spine."""
        return self.samples

    def _prepare(self) -> SpineTable:
        return self


def table_values(jet: tuple[Array, Array, Array], normals: tuple[Array, Array]) -> Array:
    """What a `SpineTable` holds at one arc length, (21,): `C, T, k, I, J` and the products
    `C·T, k·C, C·I, C·J, k·I, k·J`."""
    (c, t, k), (i, j) = jet, normals
    products = [dot(c, t), dot(k, c), dot(c, i), dot(c, j), dot(k, i), dot(k, j)]
    return jnp.concatenate([c, t, k, i, j, jnp.stack(products)])


def _dot(x: Array, values: list[Array]) -> Array:
    """`x·v` for `x` (3,) and `v` given as 3 looked-up scalars."""
    return x[0] * values[0] + x[1] * values[1] + x[2] * values[2]


def tabulates(spine: AbstractSpine, dtype=None) -> bool:
    """Whether the batched paths evaluate `spine` through tables: in single precision, and for
    smooth spines that are not cheaper exactly (static). `dtype`: the spine's floats', where
    the caller knows it (a free-form spine's `length` is computed from its tables)."""
    dtype = spine.length.dtype if dtype is None else dtype
    return jnp.finfo(dtype).bits <= 32 and tabulable(spine)


def tabulable(spine: AbstractSpine) -> bool:
    """Whether `spine` has a table worth reading, whatever its dtype: smooth and not cheaper
    exactly (static; `tabulates` in single precision)."""
    return spine._tabulable() and not spine._is_cheap()


def runs_whole(spine: AbstractSpine | SpineTable) -> bool:
    """Whether the batched paths run batches on `spine` (or on its `fast_evaluator`) whole:
    tabulated, or cheap exactly (lines); other exact spines run in chunks, so that memory
    does not grow with their intermediates per point (`map_chunks`; static)."""
    return isinstance(spine, SpineTable) or tabulates(spine) or spine._is_cheap()


def fast_evaluator(spine: AbstractSpine) -> AbstractSpine | SpineTable:
    """What the batched paths search: the prepared `spine` itself in double precision (and for
    polylines and lines), its `SpineTable` in single precision (the spine's dtype, cast to the
    points'; see `tabulates`)."""
    return fast_evaluator_at_nodes(spine)[0]


def fast_evaluator_at_nodes(
    spine: AbstractSpine, jet_only: bool = False
) -> tuple[AbstractSpine | SpineTable, tuple | None]:
    """`(fast_evaluator(spine), at_nodes)`: `at_nodes` the values `(jet, normals)` (each (P, 4,
    3)) that a table the spine made of itself was fit to at its nodes (a bent limb's:
    `AbstractSpine._table_at_nodes`), else `None`. A table of other values on its pieces is fit
    from them (`_fleshing.target.TargetFrames`), not from the table read back at its nodes.
    `jet_only` (static): such a table of the jet alone (`SpineTable.searchable`), for a caller
    that reads nothing else of it (a pose's valid region)."""
    spine = spine._prepare()
    if not tabulates(spine):
        return spine, None
    own, at_nodes = spine._table_at_nodes(jet_only)
    return (SpineTable(spine), None) if own is None else (own, at_nodes)

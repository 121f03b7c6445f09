"""A spine evaluated through its float32 table: what a posed limb's bent spine is built on.

A limb is posed every frame onto a `BentSpine` of its rest spine, and preparing that target
(its table of frames, its search table, its valid region) evaluates the bent spine at about
1,300 arc lengths, each of which reads the rest spine five times (its frame, and the four
quadrature points of its position). On a B-spline every read is a span search and an
arc-length inversion: two thirds of a frame's time on spot. The rest spine does not change
from frame to frame, so posing tabulates it once (`LookedUpSpine`, at registration) and the
bent spine reads the table: a few gathered cubic coefficients per read. The bent spine's own
table is made from the rest table's values at its nodes and at the quadrature points between
them, the same every frame: those are kept too (`NodeSamples`, made with the table; reading
them again each frame was 1.3 of the 3 ms of spot's head). The table's error
(below 1e-9 relative, `table`) is far below single precision's resolution, which is where it
is used (`fleshing_jax._skeleton.posing`: double precision keeps the exact spine).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._batching.grid import grid_vmap
from .spine import AbstractSpine, torsion_of
from .table import PiecewiseCubic, SpineTable

# The Gauss–Legendre rule a bent spine integrates its position with (`bent`: exact for degree
# 7 on its short intervals), kept here with the values a bent table reads at its points.
GAUSS = 4
GAUSS_POINTS, GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(GAUSS)
# The rule a bent table integrates its position with between consecutive nodes (`NodeSamples`):
# 2 points, exact for degree 3 on intervals a quarter of a piece long; its error there is the
# integrand's fourth derivative times the interval's fifth power / 4320. Against 4 points, in
# double precision, spot's head, hind leg and front leg bent 30-180° (direction 30°, twist 5°):
# the nodes' positions moved by 3e-10 at most (4e-10 of the limb's length; 2e-12 to 3e-11 on
# the legs), far below single precision's resolution (6e-8), where the table is read. With 4,
# these points took three quarters of a float32 frame's sines and cosines.
NODE_GAUSS = 2
NODE_POINTS, NODE_WEIGHTS = np.polynomial.legendre.leggauss(NODE_GAUSS)


class NodeSamples(eqx.Module):
    """A `SpineTable`'s values where a spine bent from it reads them every frame
    (`BentSpine._table`), computed once: at the table's nodes, and its tangent at the
    quadrature points between consecutive nodes (from the search range's start).

    **Fields:** `arc_length` (P, 4): the nodes; `jet` `(C, T, k)` and `normals` `(I, J)`, each
    (P·4, 3), there; `half` (P·4,): half of each interval; `points` (P·4, NODE_GAUSS) and
    `tangents` (P·4, NODE_GAUSS, 3): the quadrature points and `T` there.
    """

    arc_length: Array
    jet: tuple[Array, Array, Array]
    normals: tuple[Array, Array]
    half: Array
    points: Array
    tangents: Array

    def __init__(self, table: SpineTable):
        self.arc_length = table.cubics.nodes()
        flat = self.arc_length.reshape(-1)
        self.jet, self.normals = jax.vmap(table.jet_and_normals)(flat)
        starts = jnp.concatenate([table.lo[None], flat[:-1]])
        self.half = (flat - starts) / 2
        x = jnp.asarray(NODE_POINTS, flat.dtype)
        self.points = (starts + self.half)[:, None] + self.half[:, None] * x
        self.tangents = grid_vmap(lambda s: table.jet(s)[1], self.points)


class LookedUpSpine(AbstractSpine):
    """`spine` (prepared) evaluated on `[0, length]` through its `SpineTable`.

    **Arguments:** `spine`: any smooth `AbstractSpine`. **Fields:** `table`: its `SpineTable`;
    `samples`: its `NodeSamples` (`None` on an arc's exact table).

    The same spine to the table's error; as every spine, continued past its ends along its
    osculating circles there (computed from the table's end values).
    """

    table: SpineTable
    samples: NodeSamples | None  # for the spines bent from it (on a piecewise-cubic table)

    def __init__(self, spine: AbstractSpine):
        self.table = SpineTable(spine._prepare())
        cubic = isinstance(self.table.cubics, PiecewiseCubic)
        self.samples = NodeSamples(self.table) if cubic else None

    @property
    def length(self) -> Array:
        return self.table.length

    def _jet_and_normals(self, s: Array):
        return self.table.jet_and_normals(s)

    def _jet(self, s: Array):
        return self.table.jet(s)

    def _normals(self, s: Array):
        return self._jet_and_normals(s)[1]

    def _torsion(self, s: Array) -> Array:
        return torsion_of(self._jet, s)  # k′: the tabulated cubic's derivative

    def default_samples(self) -> int:
        return self.table.default_samples()

    # `_breaks`: none. The table's pieces join with jumps at its interpolation error (1e-9
    # relative), which a quadrature across them does not see in single precision.

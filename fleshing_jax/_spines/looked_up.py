"""A spine evaluated through its float32 table: what a posed limb's bent spine is built on.

A limb is posed every frame onto a `BentSpine` of its rest spine, and preparing that target
(its table of frames, its search table, its valid region) evaluates the bent spine at about
1,300 arc lengths, each of which reads the rest spine five times (its frame, and the four
quadrature points of its position). On a B-spline every read is a span search and an
arc-length inversion: two thirds of a frame's time on spot. The rest spine does not change
from frame to frame, so posing tabulates it once (`LookedUpSpine`, at registration) and the
bent spine reads the table: a few gathered cubic coefficients per read. The table's error
(below 1e-9 relative, `table`) is far below single precision's resolution, which is where it
is used (`fleshing_jax._skeleton.posing`: double precision keeps the exact spine).
"""

from __future__ import annotations

from jaxtyping import Array

from .spine import AbstractSpine, torsion_of
from .table import SpineTable


class LookedUpSpine(AbstractSpine):
    """`spine` (prepared) evaluated on `[0, length]` through its `SpineTable`.

    **Arguments:** `spine`: any smooth `AbstractSpine`. **Fields:** `table`: its `SpineTable`.

    The same spine to the table's error; as every spine, continued past its ends along its
    osculating circles there (computed from the table's end values).
    """

    table: SpineTable

    def __init__(self, spine: AbstractSpine):
        self.table = SpineTable(spine._prepare())

    @property
    def length(self) -> Array:
        return self.table.length

    def _jet_and_normals(self, s: Array):
        return self.table.jet_and_normals(s)

    def _jet(self, s: Array):
        return self._jet_and_normals(s)[0]

    def _normals(self, s: Array):
        return self._jet_and_normals(s)[1]

    def _torsion(self, s: Array) -> Array:
        return torsion_of(self._jet, s)  # k′: the tabulated cubic's derivative

    def default_samples(self) -> int:
        return self.table.default_samples()

    # `_breaks`: none. The table's pieces join with jumps at its interpolation error (1e-9
    # relative), which a quadrature across them does not see in single precision.

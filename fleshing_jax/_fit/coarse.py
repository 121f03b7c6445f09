"""A free-form spine's fit solved first on coarser frames, then finished on its own.

A `BSpline` places its frame nodes and arc-length sub-intervals by the turning of its most
turning knot span (`_spines.parametric.static_sizes`: 96 nodes a radian, for frames exact to
1e-9), and a fit keeps the static configuration of its `init`. A curved rest spine used as
`init` (the insect's body from `rest_spine`: 192 subdivisions in each of its 11 spans) makes
every pose of the solve, and each of the Jacobian's forward passes, walk thousands of nodes:
its steps cost 7-10 times those of a spine of 24 (the biped's arm), the solve's whole time.

Far from the answer the solve needs no such precision: its steps only bring the spine near.
`coarser` is the same fit's parameters on the same control points with `COARSE_SUBDIVISIONS`
(frames within about 1e-7 of the diagonal on the insect bent 90°); the fit solves that
first, then the fit as asked from there, which starts within that error of its answer and
stops after a few steps. Its result (spine, rms, convergence) is the fine fit's.
"""

from __future__ import annotations

from .._checks import is_concrete
from .._spines.bspline import BSpline
from .problem import Parameters

COARSE_SUBDIVISIONS = 24  # subdivisions per knot span of the first solve (the arm's own)


def coarser(parameters: Parameters) -> Parameters | None:
    """`parameters` whose base spine has `COARSE_SUBDIVISIONS` per knot span (the same
    control points, knots and degree: the same `y`), or `None` where that is not coarser (a
    spine other than a concrete `BSpline`, or one with that many or fewer)."""
    init = parameters.base
    if not (
        isinstance(init, BSpline)
        and init.subdivisions > COARSE_SUBDIVISIONS
        and is_concrete((init.control_points, init.knots))
    ):
        return None
    spine = BSpline(
        init.control_points, degree=init.degree, knots=init.knots, subdivisions=COARSE_SUBDIVISIONS
    )
    return Parameters(spine, parameters.free, parameters.where)

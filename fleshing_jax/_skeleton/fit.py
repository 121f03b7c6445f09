"""A smooth, exactly arc-length spine through a path of medial spheres.

Shared by `rest_spine` (one spine for the whole shape) and `skeleton` (one per limb): the
medial graph, a path's continuation beyond its end (to the surface, or by a given length),
and the least-squares quintic B-spline whose curvature stays below the inverse of the local
medial radius. Our own construction (neither paper gives one): the path resampled at a constant
arc-length step and approximated by a clamped B-spline in least squares (chord-length
parameters, the knots `fj.BSpline` uses by default). Few control points (about one per two
sphere radii along the path) keep it smooth where the medial axis zigzags between its
spheres, and a penalty on their second differences where that is not enough: the spine's
curvature must stay below the inverse of the local medial radius (a tighter turn than the
shape is thick folds the fleshing's cross-sections into each other: no valid bend), so the
penalty's weight grows until it does (issue 31: a wavy spine on an animal, radius of curvature
0.010 where the radii were 0.5). `fj.BSpline` then parameterises it exactly by arc length.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.interpolate import BSpline as ScipyBSpline
from scipy.sparse import csgraph

from .._spines.bspline import BSpline

RESAMPLED = 200  # points of the path given to the least-squares fit
MAX_CONTROL_POINTS = 16
END_WEIGHT = 100.0  # least-squares weight of the two end points
CURVATURE_SAMPLES = 1000  # where the curvature is checked against the local medial radius
# The bound is κ r < CURVATURE_MARGIN: r interpolated between the path's spheres is only an
# estimate of the radius of the sphere nearest to each point of the spine.
CURVATURE_MARGIN = 0.8
BLOCK = 2**18  # point-sphere pairs at a time in `sphere_gaps` (6 MB of float64 differences)


def medial_graph(centers: np.ndarray, edges: np.ndarray) -> sparse.csr_matrix:
    """The medial mesh's edges as a sparse graph weighted by their lengths (kept above zero:
    a zero weight would read as no edge)."""
    n = len(centers)
    lengths = np.linalg.norm(centers[edges[:, 0]] - centers[edges[:, 1]], axis=1)
    lengths = np.maximum(lengths, 1e-12 * (np.ptp(centers, axis=0).max() + 1e-300))
    return sparse.coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()


def farthest(graph, start: int, radii: np.ndarray) -> int:
    """The sphere farthest from `start` through the graph *and then to the surface* (its
    radius added): the end of a spike of the medial axis (a small sphere near the surface)
    loses to the end of the shape's main axis, whose sphere reaches farther."""
    distance = csgraph.dijkstra(graph, directed=False, indices=start)
    distance[~np.isfinite(distance)] = -np.inf
    return int(np.argmax(distance + radii))


def end_direction(inward: np.ndarray, r: float) -> np.ndarray:
    """The unit direction out of the path's end `inward[0]` (the path walked from that end
    inwards), taken a distance `r` back: the end spheres of a sampled medial axis sit close
    together in noisy directions. Zero when the path has no length."""
    along = np.cumsum(np.r_[0, np.linalg.norm(np.diff(inward, axis=0), axis=1)])
    back = inward[min(np.searchsorted(along, r), len(inward) - 1)]
    direction = inward[0] - back
    norm = np.linalg.norm(direction)
    return direction / norm if norm > 0 else direction


def extend_beyond(inward: np.ndarray, r: float, surface) -> np.ndarray:
    """The point beyond the path's end `inward[0]` (the path walked from that end inwards)
    where it meets `surface` ((V, 3) vertices: the farthest one within `r / 2` of the end
    direction), or a distance `r` beyond it when `surface` is `None` or none is near."""
    p = inward[0]
    direction = end_direction(inward, r)
    reach = r
    if surface is not None and np.any(direction):
        offsets = surface - p
        ahead = offsets @ direction
        aside = np.linalg.norm(offsets - ahead[:, None] * direction, axis=1)
        near = (ahead > 0) & (aside < 0.5 * max(r, 1e-12))
        if np.any(near):
            reach = float(np.max(ahead[near]))
    return p + reach * direction


def fit_bspline(points, radii, control_points=None, degree=5, *, bounded=None,
                subdivisions=None, straight_ends=False,
                strict=False) -> BSpline | None:  # fmt: skip
    """A B-spline through `points` ((k, 3), in order) in least squares, its ends nearly at the
    first and last point.

    **Arguments:** `points`; `radii`: (k,) the local medial radius at each point;
    `control_points`: of the B-spline (default: about one per two radii, between `degree + 1`
    and 16); `degree`; `bounded`: whether to bound the curvature (default: unless
    `control_points` is given); `subdivisions`: passed to `fj.BSpline` (given, with the same
    `control_points`, spines share their compiled programs); `straight_ends`: with no
    curvature at either end (a limb's: see `_skeleton.build`); `strict`: `None` where no
    smoothing meets the curvature bound (a route far shorter than its radii).

    **Returns:** an `fj.BSpline` (float64) whose curvature stays below
    `CURVATURE_MARGIN / r` (`r` the radii interpolated along it) when `bounded`: the smoothing
    penalty grows until it does; where none does, the straight segment between the first and
    last point (or `None`, when `strict`).
    """
    chord = np.r_[0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]
    keep = np.r_[True, np.diff(chord) > 1e-12 * chord[-1]]
    points, chord, radii = points[keep], chord[keep], radii[keep]
    u = np.linspace(0, chord[-1], RESAMPLED)
    resampled = np.stack([np.interp(u, chord, points[:, k]) for k in range(3)], axis=1)
    if bounded is None:
        bounded = control_points is None
    if control_points is None:
        typical = max(float(np.median(radii)), 1e-12)
        control_points = int(round(chord[-1] / (2 * typical))) + 1
    count = int(np.clip(control_points, degree + 1, MAX_CONTROL_POINTS))
    weights = np.ones(RESAMPLED)
    weights[[0, -1]] = END_WEIGHT  # the ends where the path meets the surface, nearly exactly
    inner = np.linspace(0.0, 1.0, count - degree + 1)
    knots = np.r_[np.zeros(degree), inner, np.ones(degree)]  # as `clamped_uniform_knots`
    at = np.linspace(0.0, 1.0, CURVATURE_SAMPLES)
    bound = CURVATURE_MARGIN / np.maximum(np.interp(at * chord[-1], chord, radii), 1e-300)
    # Least squares with a penalty on the control points' second differences (a P-spline),
    # its weight raised until the curvature bound holds: a straight line is the limit.
    basis = ScipyBSpline.design_matrix(u / chord[-1], knots, degree).toarray()
    normal = basis.T @ (weights[:, None] * basis)
    right = basis.T @ (weights[:, None] * resampled)
    second = np.diff(np.eye(count), 2, axis=0)
    penalty = second.T @ second
    scale = np.trace(normal) / np.trace(penalty)
    # Straight ends: the second derivative vanishes at both (equality constraints, solved
    # with their Lagrange multipliers).
    ends = ScipyBSpline(knots, np.eye(count), degree).derivative(2)(np.array([0.0, 1.0]))
    ends = ends if straight_ends else np.zeros((0, count))
    zeros = np.zeros((len(ends), len(ends)))
    for smoothing in (0.0, *(scale * 4.0 ** np.arange(-12, 12))):
        system = np.block([[normal + smoothing * penalty, ends.T], [ends, zeros]])
        solution = np.linalg.solve(system, np.concatenate([right, np.zeros((len(ends), 3))]))
        coefficients = solution[:count]
        curve = ScipyBSpline(knots, coefficients, degree)
        if not bounded or np.all(curvature(curve, at) < bound):
            break
    else:
        # No smoothing meets the bound (a path much shorter than its radii: a knuckle's). The
        # penalty's limit is then no line but a point (straight ends ask `C″ = 0` there, which
        # evenly spaced control points do not give on clamped knots): the straight segment
        # between the path's ends instead, its control points at the knots' averages
        # (Greville's abscissae), on which a B-spline is the segment at constant speed.
        if strict:
            return None
        greville = np.convolve(knots[1:-1], np.ones(degree) / degree, mode="valid")
        coefficients = points[0] + greville[:, None] * (points[-1] - points[0])
    return BSpline(coefficients, degree=degree, subdivisions=subdivisions)


def sphere_gaps(points: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(k,) the distance from each of `points` (k, 3) to the nearest surface of the spheres
    `(centers (m, 3), radii (m,))`, `min |p − c| − r` (negative inside one; `inf` for no
    sphere), in blocks of `BLOCK` point-sphere pairs: all pairs at once took 10 GB (spot at
    10,000 spheres, a 302k-vertex mesh)."""
    return _nearest_surfaces(points, centers, radii)[0]


def nearest_spheres(points: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(k,) int: for each of `points` (k, 3), the index of the sphere `(centers (m, 3),
    radii (m,))` whose surface is nearest (`sphere_gaps`'s; m ≥ 1)."""
    return _nearest_surfaces(points, centers, radii)[1]


def _nearest_surfaces(points, centers, radii):
    """`sphere_gaps` and `nearest_spheres`, in blocks of `BLOCK` point-sphere pairs."""
    gaps = np.full(len(points), np.inf)
    nearest = np.zeros(len(points), int)
    step = max(1, BLOCK // max(len(centers), 1))
    for i in range(0, len(points) if len(centers) else 0, step):
        distance = np.linalg.norm(points[i : i + step, None] - centers[None], axis=-1) - radii
        nearest[i : i + step] = np.argmin(distance, axis=1)
        gaps[i : i + step] = np.take_along_axis(distance, nearest[i : i + step, None], 1)[:, 0]
    return gaps, nearest


def spine_from_unit(spine: BSpline, frame) -> BSpline:
    """`spine`, fitted in a `UnitFrame`, in the mesh's frame: its control points mapped (its
    knots are the spline's parameters, not lengths, and stay)."""
    points = frame.from_unit(np.asarray(spine.control_points))
    return BSpline(points, degree=spine.degree, knots=np.asarray(spine.knots),
                   subdivisions=spine.subdivisions)  # fmt: skip


def curvature(curve, at: np.ndarray) -> np.ndarray:
    """`|C′ × C″| / |C′|³` of a scipy B-spline curve at parameters `at`."""
    first, second = curve.derivative(1)(at), curve.derivative(2)(at)
    speed = np.maximum(np.linalg.norm(first, axis=1), 1e-300)
    return np.linalg.norm(np.cross(first, second), axis=1) / speed**3

"""A rest spine for Fleshing found from the medial axis: no spine placed by hand.

Our own construction (neither paper gives one): the medial graph's longest geodesic path
(double sweep of Dijkstra, the usual estimate of a graph's diameter, each end scored by its
geodesic distance plus its radius: the path runs from surface to surface) or the path between two
given points, continued to the surface at both ends along its end directions, resampled at
a constant arc-length step and approximated by a clamped quintic B-spline in least squares
(chord-length parameters, the knots `fj.BSpline` uses by
default). Few control points (about one per two sphere radii along the path) keep it smooth
where the medial axis zigzags between its spheres, and a penalty on their second differences
where that is not enough: the spine's curvature must stay below the inverse of the local medial
radius (a tighter turn than the shape is thick folds the fleshing's cross-sections into each
other: no valid bend), so the penalty's weight grows until it does (issue 31: a wavy spine on
an animal, radius of curvature 0.010 where the radii were 0.5). `fj.BSpline` then
parameterises it exactly by arc length.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import ArrayLike
from scipy import sparse
from scipy.interpolate import BSpline as ScipyBSpline
from scipy.sparse import csgraph

from .._medial_axis.medial_mesh import MedialMesh
from .._spines.bspline import BSpline

RESAMPLED = 200  # points of the path given to the least-squares fit
MAX_CONTROL_POINTS = 16
END_WEIGHT = 100.0  # least-squares weight of the two end points
CURVATURE_SAMPLES = 1000  # where the curvature is checked against the local medial radius
# The bound is κ r < CURVATURE_MARGIN: r interpolated between the path's spheres is only an
# estimate of the radius of the sphere nearest to each point of the spine.
CURVATURE_MARGIN = 0.8


def rest_spine(
    mesh_or_medial,
    *,
    ends: ArrayLike | None = None,
    control_points: int | None = None,
    degree: int = 5,
    spheres: int = 100,
    seed: int = 0,
    surface=None,
) -> BSpline:
    """A smooth rest spine through the medial axis of a shape.

    **Arguments:**

    - `mesh_or_medial`: a closed mesh (`trimesh.Trimesh` or `(vertices, faces)`, whose medial
      mesh is computed with `medial_mesh(..., spheres=spheres, seed=seed, refine=0)`) or a
      `MedialMesh`.
    - `ends`: optional (2, 3) points: the spine runs between the spheres nearest to them
      (default: along the longest path of the medial graph).
    - `control_points`: of the B-spline (default: about one per two radii along the path,
      between `degree + 1` and 16; given, no curvature bound is imposed);
      `degree`: of the B-spline (default 5, quintic).
    - `surface`: with a `MedialMesh`, optionally the mesh it was computed from
      (`trimesh.Trimesh` or `(vertices, faces)`), to continue the spine to its surface.

    Given a mesh (or `surface`), the spine is continued from its end spheres to the mesh's
    surface (the farthest vertex near the end direction); given only a medial mesh, by the end
    spheres' radii. Starts at the end nearest to the first of `ends` (or the path's first
    end). Unless `control_points` is given, its curvature stays below the inverse of the
    local medial radius (the radius of the path's spheres, interpolated along it).

    **Returns:** an `fj.BSpline` (float64). **Raises:** `ValueError` when the medial graph has
    no path of two spheres, or `ends` is not (2, 3) and finite.
    """
    from .._medial_axis.surface import closed_mesh_arrays

    if isinstance(mesh_or_medial, MedialMesh):
        medial = mesh_or_medial
        if surface is not None:
            surface = closed_mesh_arrays(surface)[0]
    else:
        if surface is not None:
            raise ValueError("`surface` goes with a `MedialMesh` (a mesh is its own surface).")
        from .._medial_axis.construct import medial_mesh

        # No fit of the spheres (`refine=0`): a least-squares spline through the path
        # smooths them anyway, and `deform` without `--from` stays as fast as before.
        medial = medial_mesh(mesh_or_medial, spheres=spheres, seed=seed, refine=0,
                             progress=False)
        surface = closed_mesh_arrays(mesh_or_medial)[0]
    centers, radii, edges, _ = medial.numpy()
    path = _medial_path(centers, radii, edges, _check_ends(ends))
    if len(path) < 2:
        raise ValueError(
            "`mesh_or_medial`: its medial graph has no path of two spheres to put a spine on "
            f"({len(centers)} spheres, {len(edges)} edges)."
        )
    points = _extend_to_surface(centers[path], radii[path], surface)
    # The local radius at the points: the path's spheres', the end ones' for the extensions.
    local = radii[path][np.r_[0, np.arange(len(path)), len(path) - 1]]
    return _fit_bspline(points, local, control_points, degree)


def _check_ends(ends):
    if ends is None:
        return None
    ends = np.asarray(ends, dtype=np.float64)
    if ends.shape != (2, 3) or not np.all(np.isfinite(ends)):
        raise ValueError(f"`ends` must be two finite points, shape (2, 3), got {ends.shape}.")
    return ends


def _medial_path(centers: np.ndarray, radii: np.ndarray, edges: np.ndarray, ends) -> np.ndarray:
    """Sphere indices along the longest geodesic path of the medial graph (in its largest
    connected part), or along the shortest path between the spheres nearest to `ends`."""
    n = len(centers)
    if n < 2 or len(edges) == 0:
        return np.arange(min(n, 1))
    lengths = np.linalg.norm(centers[edges[:, 0]] - centers[edges[:, 1]], axis=1)
    lengths = np.maximum(lengths, 1e-12 * (np.ptp(centers, axis=0).max() + 1e-300))
    graph = sparse.coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    _, labels = csgraph.connected_components(graph, directed=False)
    if ends is None:
        largest = np.argmax(np.bincount(labels))
        start = int(np.flatnonzero(labels == largest)[0])
        a = _farthest(graph, start, radii)
        b = _farthest(graph, a, radii)
    else:
        a, b = (int(np.argmin(np.linalg.norm(centers - e, axis=1))) for e in ends)
        if labels[a] != labels[b]:
            raise ValueError(
                "`ends`: the spheres nearest to the two points are not connected in the "
                "medial graph."
            )
    distance, predecessors = csgraph.dijkstra(graph, directed=False, indices=b,
                                              return_predecessors=True)
    path = [a]
    while path[-1] != b:
        path.append(int(predecessors[path[-1]]))
    return np.asarray(path)


def _farthest(graph, start: int, radii: np.ndarray) -> int:
    """The sphere farthest from `start` through the graph *and then to the surface* (its
    radius added): the end of a spike of the medial axis (a small sphere near the surface)
    loses to the end of the shape's main axis, whose sphere reaches farther."""
    distance = csgraph.dijkstra(graph, directed=False, indices=start)
    distance[~np.isfinite(distance)] = -np.inf
    return int(np.argmax(distance + radii))


def _extend_to_surface(points: np.ndarray, radii: np.ndarray, surface) -> np.ndarray:
    """The path with a point added beyond each end, where it meets the surface."""

    def beyond(inward: np.ndarray, r: float) -> np.ndarray:
        """The surface point beyond `inward[0]`, the path walked from that end inwards."""
        p = inward[0]
        # The end direction from the path a radius back, not from the last edge: the end
        # spheres of a sampled medial axis sit close together in noisy directions.
        along = np.cumsum(np.r_[0, np.linalg.norm(np.diff(inward, axis=0), axis=1)])
        back = inward[min(np.searchsorted(along, r), len(inward) - 1)]
        direction = p - back
        norm = np.linalg.norm(direction)
        if norm == 0:
            return p
        direction /= norm
        reach = r
        if surface is not None:
            offsets = surface - p
            ahead = offsets @ direction
            aside = np.linalg.norm(offsets - ahead[:, None] * direction, axis=1)
            near = (ahead > 0) & (aside < 0.5 * max(r, 1e-12))
            if np.any(near):
                reach = float(np.max(ahead[near]))
        return p + reach * direction

    first, last = beyond(points, radii[0]), beyond(points[::-1], radii[-1])
    return np.concatenate([first[None], points, last[None]])


def _fit_bspline(points, radii, control_points, degree) -> BSpline:
    chord = np.r_[0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]
    keep = np.r_[True, np.diff(chord) > 1e-12 * chord[-1]]
    points, chord, radii = points[keep], chord[keep], radii[keep]
    u = np.linspace(0, chord[-1], RESAMPLED)
    resampled = np.stack([np.interp(u, chord, points[:, k]) for k in range(3)], axis=1)
    given = control_points is not None
    if not given:
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
    for smoothing in (0.0, *(scale * 4.0 ** np.arange(-12, 12))):
        coefficients = np.linalg.solve(normal + smoothing * penalty, right)
        curve = ScipyBSpline(knots, coefficients, degree)
        if given or np.all(_curvature(curve, at) < bound):
            break
    return BSpline(coefficients, degree=degree)


def _curvature(curve, at: np.ndarray) -> np.ndarray:
    """`|C′ × C″| / |C′|³` of a scipy B-spline curve at parameters `at`."""
    first, second = curve.derivative(1)(at), curve.derivative(2)(at)
    speed = np.maximum(np.linalg.norm(first, axis=1), 1e-300)
    return np.linalg.norm(np.cross(first, second), axis=1) / speed**3


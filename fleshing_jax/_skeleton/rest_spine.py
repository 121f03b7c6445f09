"""A rest spine for Fleshing found from the medial axis: no spine placed by hand.

Our own construction (neither paper gives one): the medial graph's longest geodesic path
(double sweep of Dijkstra, the usual estimate of a graph's diameter, each end scored by its
geodesic distance plus its radius: the path runs from surface to surface) or the path between two
given points, continued to the surface at both ends along its end directions and fitted by a
smooth, exactly arc-length quintic B-spline whose curvature stays below the inverse of the local
medial radius (`fit.fit_bspline`).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import ArrayLike
from scipy.sparse import csgraph

from .._medial_axis.medial_mesh import MedialMesh
from .._medial_axis.unit import UnitFrame
from .._spines.bspline import BSpline
from .fit import extend_beyond, farthest, fit_bspline, medial_graph, spine_from_unit


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
        medial = medial_mesh(mesh_or_medial, spheres=spheres, seed=seed, refine=0, progress=False)
        surface = closed_mesh_arrays(mesh_or_medial)[0]
    centers, radii, edges, _ = medial.numpy()
    path = _medial_path(centers, radii, edges, _check_ends(ends))
    if len(path) < 2:
        raise ValueError(
            "`mesh_or_medial`: its medial graph has no path of two spheres to put a spine on "
            f"({len(centers)} spheres, {len(edges)} edges)."
        )
    inward = centers[path]
    first = extend_beyond(inward, radii[path[0]], surface)
    last = extend_beyond(inward[::-1], radii[path[-1]], surface)
    points = np.concatenate([first[None], inward, last[None]])
    # The local radius at the points: the path's spheres', the end ones' for the extensions.
    local = radii[path][np.r_[0, np.arange(len(path)), len(path) - 1]]
    # Fitted near the origin at a size near 1 and mapped back: 1e4 from the origin the least
    # squares' right side carried the offset, and the fit lost the path's detail to it.
    frame = UnitFrame.of(points)
    spine = fit_bspline(frame.to_unit(points), local / frame.scale, control_points, degree)
    return spine_from_unit(spine, frame)


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
    graph = medial_graph(centers, edges)
    _, labels = csgraph.connected_components(graph, directed=False)
    if ends is None:
        largest = np.argmax(np.bincount(labels))
        start = int(np.flatnonzero(labels == largest)[0])
        a = farthest(graph, start, radii)
        b = farthest(graph, a, radii)
    else:
        a, b = (int(np.argmin(np.linalg.norm(centers - e, axis=1))) for e in ends)
        if labels[a] != labels[b]:
            raise ValueError(
                "`ends`: the spheres nearest to the two points are not connected in the "
                "medial graph."
            )
    distance, predecessors = csgraph.dijkstra(
        graph, directed=False, indices=b, return_predecessors=True
    )
    path = [a]
    while path[-1] != b:
        path.append(int(predecessors[path[-1]]))
    return np.asarray(path)

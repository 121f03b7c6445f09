"""`medial_mesh`: the simplified medial mesh of a closed triangle mesh."""

from __future__ import annotations

import warnings

import numpy as np
from tqdm.auto import tqdm

from .medial_mesh import MedialMesh
from .refine import refine_spheres
from .simplify import contact_quadrics, simplify
from .surface import SurfaceQuery, closed_mesh_arrays, sample_surface
from .unit import UnitFrame
from .voronoi import initial_medial_axis


def medial_mesh(mesh, spheres: int = 200, *, seed: int = 0, samples: int = 20_000,
                refine: int = 20, progress: bool = True) -> MedialMesh:
    """The medial mesh of a closed triangle mesh, simplified to `spheres` spheres.

    1. `samples` area-uniform random points on the surface (from `seed`; the mesh's own
       vertices are added when there are at most `samples / 4` of them, so that the corners
       of coarse, sharp meshes such as a box are sampled).
    2. The inner Voronoi complex of the samples (`voronoi.initial_medial_axis`): Delaunay
       circumcentres inside the mesh, radius = distance to the mesh, joined by Voronoi edges
       and faces (Q-MAT's initial medial axis).
    3. Q-MAT's edge collapses by sphere-quadric error with the stability ratio (saturated:
       our own change, see `simplify`), down to `spheres` (`simplify.simplify`); from 4 ×
       `spheres` (at most 200) down, the cost also counts the farthest contact sample that
       a collapse would leave uncovered (our own addition).
    4. Our own addition: `refine` damped Gauss-Newton steps on all centres and radii, the
       connectivity fixed, fitting the union's signed distance to the samples (0) and to
       a quarter as many centres of the initial axis (minus their radii), the samples
       weighted towards the worst covered (an approximate `Σ |d|⁴`: the targets are
       Hausdorff distances), with every sphere kept inside the surface; then up to 21
       steps twice as long, centres kept inside, in rounds of 3 kept while they bring the
       worst sample nearer (`refine.refine_spheres`). On sphere-like shapes, where nearly
       every primitive lies near every sample, a regular selection of the samples is fitted.
       Last, every centre is put inside the surface (told by rays: `surface.ray_inside`)
       and no sphere overhangs it by more than the farthest sample lies outside the union.

    Deterministic for a given `seed` (NumPy, SciPy and a loop compiled by numba, `pairs`;
    no threads). Computed on the mesh moved near the origin and scaled by a power of two to
    a diagonal near 1 (`unit.UnitFrame`, an exact map): a mesh scaled by a power of two or
    moved by a multiple of it gives the same spheres, bit for bit; one scaled by 10 gives
    spheres as close to the surface, but the collapses' order among near ties may differ.

    **Arguments:**

    - `mesh`: a closed `trimesh.Trimesh` or `(vertices (V, 3), faces (F, 3))`.
    - `spheres`: number of spheres to keep (>= 2).
    - `seed`: seed of the surface samples.
    - `samples`: number of random surface samples (more: finer initial axis, slower).
    - `refine`: number of fitting steps after the simplification, before the longer ones
      (0: no fit at all, the spheres as the collapses left them).
    - `progress`: show a progress bar of the simplification (`tqdm`).

    **Returns:** a `MedialMesh` with NumPy float64 centres and radii.

    **Raises:** `ValueError` for fewer than 2 spheres or too few samples, and for meshes that
    are open (close them with `fj.cap_holes`), non-manifold, one-sided, flat (no volume) or
    with non-finite vertices. Faces wound against their neighbours (the fewer of each shell)
    and shells inside out are flipped, with a warning.
    """
    if int(spheres) != spheres or spheres < 2:
        raise ValueError(f"spheres must be an integer >= 2, got {spheres!r}")
    if int(refine) != refine or refine < 0:
        raise ValueError(f"refine must be an integer >= 0, got {refine!r}")
    if int(samples) != samples or samples < 100:
        raise ValueError(f"samples must be an integer >= 100, got {samples!r}")
    vertices, faces = closed_mesh_arrays(mesh)
    # Computed on the mesh moved near the origin and scaled to a diagonal near 1 (exactly),
    # mapped back at the end: far from the origin its coordinates lose digits to the offset.
    frame = UnitFrame.of(vertices)
    vertices = frame.to_unit(vertices)
    query = SurfaceQuery(vertices, faces)
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    rng = np.random.default_rng(seed)
    points, normals, weights, sample_faces = axis_samples(query, int(samples), rng)
    axis = initial_medial_axis(query, points, normals, weights, sample_faces)
    if len(axis.centers) < spheres:
        raise ValueError(f"the initial medial axis has only {len(axis.centers)} spheres, fewer "
                         f"than the {spheres} asked for: ask for fewer or raise `samples`")
    present = len(np.unique(axis.volume))
    if present < axis.volumes:
        warnings.warn(f"{axis.volumes - present} of the shape's {axis.volumes} volumes hold no "
                      f"inner Voronoi vertex (too thin for {samples} samples) and get no "
                      f"sphere: raise `samples`", stacklevel=2)
    if spheres < 2 * present:
        raise ValueError(f"spheres must be at least 2 per volume of the shape, so that every "
                         f"sphere lies in an edge: the mesh bounds {present} volumes, so at "
                         f"least {2 * present}, got {spheres}")
    quadrics = contact_quadrics(axis)
    bar = tqdm(total=len(axis.centers) - spheres, desc="medial axis", unit="collapse",
               disable=not progress, leave=False)
    with bar:
        centers, radii, edges, tris = simplify(axis.centers, axis.radii, axis.edges,
                                               axis.faces, quadrics, int(spheres),
                                               scale=diagonal, progress=bar,
                                               contacts=(axis.points, axis.contacts))
    if refine:
        # The surface samples at distance 0, and centres of the initial axis at minus their
        # radius: without the latter, nothing would stop the fit from opening holes inside.
        inner = rng.choice(len(axis.centers), size=min(len(axis.centers), len(points) // 4),
                           replace=False)
        fit_points = np.concatenate([points, axis.centers[inner]])
        targets = np.concatenate([np.zeros(len(points)), -axis.radii[inner]])
        centers, radii = refine_spheres(fit_points, targets, centers, radii, edges, tris,
                                        scale=diagonal, surface=query,
                                        iterations=int(refine))
    return MedialMesh(frame.from_unit(centers), frame.scale * radii, edges, tris)


def axis_samples(query: SurfaceQuery, samples: int, rng: np.random.Generator):
    """The surface samples of the initial axis (step 1 of `medial_mesh`): `samples`
    area-uniform random points of the closed mesh of `query`, and its vertices when there
    are at most `samples / 4` of them (weight 0), jittered by 1e-7 of the diagonal.

    **Returns:** `(points (s, 3), normals (s, 3), weights (s,), sample_faces (s, 1))`: the
    outward unit normals, the area shares and a face that each point lies on.
    """
    vertices, faces = query.vertices, query.faces
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    points, normals, on_face = sample_surface(vertices, faces, samples, rng)
    sample_faces = on_face[:, None]
    weights = np.full(len(points), 1.0 / len(points))
    if len(vertices) <= samples // 4:
        # Vertices shape the Delaunay tetrahedra but add no planes: a corner has no single
        # tangent plane, and its faces' planes already come from the random samples.
        normal = query.vertex_normal / np.maximum(
            np.linalg.norm(query.vertex_normal, axis=1, keepdims=True), 1e-300)
        points = np.concatenate([points, vertices])
        normals = np.concatenate([normals, normal])
        weights = np.concatenate([weights, np.zeros(len(vertices))])
        # A vertex lies on the faces around it; one of them suffices (`around` adds the rest).
        one_face = np.zeros(len(vertices), dtype=np.int64)
        one_face[faces.reshape(-1)] = np.repeat(np.arange(len(faces)), 3)
        sample_faces = np.concatenate([sample_faces, one_face[:, None]])
        points, first = np.unique(points, axis=0, return_index=True)
        normals, weights, sample_faces = normals[first], weights[first], sample_faces[first]
    # Samples on planar faces are coplanar, which makes Qhull's Delaunay 30x slower (it
    # merges coplanar facets); a jitter of 1e-7 of the diagonal avoids that.
    points = points + 1e-7 * diagonal * rng.standard_normal(points.shape)
    return points, normals, weights, sample_faces

"""`medial_distance`: how far a medial mesh's envelope is from a surface (Q-MAT's measure)."""

from __future__ import annotations

import numpy as np

from .envelope import envelope_arrays
from .medial_mesh import MedialMesh
from .primitives import union_distance
from .surface import SurfaceQuery, check_coordinates, sample_surface


def _mesh_arrays(mesh):
    vertices, faces = (mesh.vertices, mesh.faces) if hasattr(mesh, "vertices") else mesh
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"mesh must have vertices (V, 3) and faces (F, 3), got "
                         f"{vertices.shape} and {faces.shape}")
    check_coordinates(vertices)
    return vertices, faces


def medial_distance(medial: MedialMesh, mesh, *, samples: int = 20_000, resolution: int = 96,
                    seed: int = 0) -> tuple[float, float]:
    """The two one-sided Hausdorff distances between a surface and a medial mesh's envelope
    (the boundary of the union of its spheres, cones and slabs), as fractions of the mesh's
    bounding-box diagonal, as Q-MAT (Li et al. 2015) reports them: the largest of
    `point_distances`'s.

    **Arguments:** `medial`; `mesh`: a `trimesh.Trimesh` or `(vertices, faces)`; `samples`,
    `resolution` and `seed`: see `point_distances`.

    **Returns:** `(surface_to_envelope, envelope_to_surface)`, floats.
    """
    to_envelope, to_surface = point_distances(medial, mesh, samples=samples,
                                              resolution=resolution, seed=seed)
    return float(to_envelope.max()), float(to_surface.max())


def point_distances(medial: MedialMesh, mesh, *, samples: int = 20_000, resolution: int = 96,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Each point's distance between a surface and a medial mesh's envelope, as fractions of
    the mesh's bounding-box diagonal (`medial_distance` reports their largest):

    - surface → envelope: of the mesh's vertices and `samples` random surface points
      (`seed`). A point outside the union gets its exact distance (the minimum over the
      primitives' closed-form distances); a point inside gets its distance to the envelope
      mesh (`MedialMesh.envelope(resolution)`, whose vertices lie on the exact envelope).
    - envelope → surface: the exact distance to the mesh of every vertex of the envelope
      mesh (points of the exact envelope, about `resolution` per side).

    **Returns:** `(surface_to_envelope (V + samples,), envelope_to_surface (m,))`, `m` the
    envelope mesh's vertices.
    """
    if not isinstance(medial, MedialMesh):
        raise TypeError(f"`medial` must be a MedialMesh, got {type(medial).__name__}")
    vertices, faces = _mesh_arrays(mesh)
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    centers, radii, edges, tris = medial.numpy()
    # Every vertex on the union (not kept off it where a face would turn over): the
    # distances are unsigned.
    env_vertices, env_faces = envelope_arrays(centers, radii, edges, tris, resolution=resolution,
                                              unfold=False)
    rng = np.random.default_rng(seed)
    points = np.concatenate([vertices, sample_surface(vertices, faces, samples, rng)[0]])
    signed = union_distance(points, centers, radii, edges, tris, cutoff=0.05 * diagonal)
    far = signed >= 0.05 * diagonal  # nothing within the first cutoff: look further
    if far.any():
        signed[far] = union_distance(points[far], centers, radii, edges, tris, cutoff=diagonal)
    to_envelope = np.maximum(signed, 0.0)
    inner = signed < 0
    if inner.any():
        to_envelope[inner] = SurfaceQuery(env_vertices, env_faces).query(points[inner])[0]
    to_surface = SurfaceQuery(vertices, faces).query(env_vertices)[0]
    return to_envelope / diagonal, to_surface / diagonal

"""Bending meshes and point clouds (trimesh), in chunks for large inputs.

Vertices are fleshed; faces are never touched, so the deformed mesh has exactly the input's
faces, vertex count and vertex order.
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
import numpy as np
import trimesh

from .._checks import as_margin, as_points, as_twist
from .._fleshing.ends import check_beyond
from .._fleshing.methods import check_method
from .._fleshing.pipeline import pose_prepared, register
from .._fleshing.verify import registered_stretch
from .._numerics import cast_floats
from .._spines.spine import AbstractSpine
from .overlap import register_and_prepare

CHUNK_SIZE = 200_000
PROGRESS_POINTS = 4_000_000


def flesh_chunked(
    points: np.ndarray,
    source: AbstractSpine,
    target: AbstractSpine,
    *,
    method: str = "radial",
    twist: float = 0.0,
    chunk_size: int = CHUNK_SIZE,
    progress: Callable[[int, int], None] | None = None,
    margin: float = 0.0,
    beyond: str = "continue",
    stretch: bool = False,
) -> tuple[np.ndarray, ...]:
    """`flesh` in chunks of at most `chunk_size` points (bounded memory, progress reports).

    Every chunk has the same shape (the last one is padded), so the work compiles once.

    **Arguments:** `points`: (N, 3) array; spines, `method`, `twist`, `margin` and `beyond` as
    for `flesh`;
    `progress(done, total)`: called after each chunk (default: a `tqdm` progress bar on
    stderr from `PROGRESS_POINTS` points on, work of a few seconds or more);
    `stretch`: also measure the map's principal stretch at each point (see `deform_mesh`).

    **Returns:** `(deformed (N, 3), valid (N,) bool)` as NumPy arrays, dtype of `points`; with
    `stretch`, `(deformed, valid, stretch (N,))`.
    """
    check_method(method)
    twist = float(as_twist(twist))
    margin = float(as_margin(margin))
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int | np.integer):
        raise TypeError(f"`chunk_size` must be a positive int, got {chunk_size!r}.")
    if chunk_size < 1:
        raise ValueError(f"`chunk_size` must be a positive int, got {chunk_size}.")
    if not isinstance(stretch, bool | np.bool_):
        raise TypeError(f"`stretch` must be a bool, got {type(stretch).__name__}.")
    if isinstance(points, np.ndarray) and points.dtype in (np.float32, np.float64):
        if points.ndim != 2 or points.shape[-1] != 3:  # (as below, without a copy)
            raise ValueError(f"`points` must have shape (N, 3), got shape {points.shape}.")
    else:  # not real numbers, half precision, a wrong shape: `TypeError`/`ValueError`
        points = np.asarray(as_points(points, "points"))
    n = len(points)
    size = max(1, min(int(chunk_size), n))
    deformed, valid = np.empty_like(points), np.zeros(n, dtype=bool)
    stretches = np.full(n, np.nan, points.dtype) if stretch else None
    if progress is None and n >= PROGRESS_POINTS:
        progress = _progress_bar(n)
    poser = None  # the target, prepared once for all chunks
    for start in range(0, n, size):
        chunk = points[start : start + size]
        m = len(chunk)
        if m < size:
            chunk = np.concatenate([chunk, np.repeat(chunk[:1], size - m, axis=0)])
        chunk = jnp.asarray(chunk)
        if poser is None:
            options = dict(method=method, twist=twist, margin=margin, beyond=check_beyond(beyond))
            registration, poser = register_and_prepare(chunk, source, target, **options)
        else:
            registration = register(chunk, source, margin=margin)
        out, ok = pose_prepared(registration, poser)
        deformed[start : start + m] = np.asarray(out)[:m]
        valid[start : start + m] = np.asarray(ok)[:m]
        if stretch:
            # The same map as the images' (registration and prepared target); NaN where the
            # registration is not valid, and where the images are not (projection check).
            measured = np.asarray(registered_stretch(cast_floats(source, chunk.dtype),
                                                     registration, poser))[:m]
            stretches[start : start + m] = np.where(valid[start : start + m], measured, np.nan)
        if progress is not None:
            progress(start + m, n)
    return (deformed, valid) if not stretch else (deformed, valid, stretches)


def deform_mesh(
    mesh,
    source: AbstractSpine,
    target: AbstractSpine,
    *,
    method: str = "radial",
    twist: float = 0.0,
    chunk_size: int = CHUNK_SIZE,
    progress: Callable[[int, int], None] | None = None,
    margin: float | None = None,
    beyond: str = "continue",
    stretch: bool = False,
):
    """Bends a mesh or point cloud from around `source` to around `target`.

    **Arguments:**

    - `mesh`: a `trimesh.Trimesh` (triangles; quad meshes as trimesh loads them, i.e. each quad
      split in two triangles, vertex order kept), a `(vertices (N, 3), faces (F, k))` pair of
      arrays for polygon meshes of any face size (quads: `k = 4`, as in the paper's §5.2), a
      `trimesh.PointCloud`, or an (N, 3) array of points.
    - `source`, `target`: spines; `method` (one of `METHODS`) and `twist` (radians) as for
      `flesh`.
    - `chunk_size`, `progress`: see `flesh_chunked` (for large inputs).
    - `margin`: the valid region's margin (`register`). By default half the mesh's longest
      edge, so that an edge whose two ends are valid never crosses the spines' cut locus or
      focal set, where the map is discontinuous: valid edges are never torn. 0 for a point
      cloud or array (no edges).
    - `beyond`: `"continue"` or `"rigid"`: the points beyond the source's ends move rigidly
      with its end frames (a body behind a bent tail stays still); see `flesh`.
    - `stretch`: also measure, at each vertex, the largest factor by which the map stretches
      or squeezes a direction (`fj.principal_stretch`, by `jax.jacfwd`: about as much work
      again as the bend). A valid bend keeps volume but near the edge of its range can draw
      a part out into a spike (the command line refuses such a bend beyond `--max-stretch`);
      `fj.edge_stretch(mesh, result.vertices, valid=...)` gives the edges' changes of length.

    **Returns:** for a `Trimesh`, a new `Trimesh` with the input's faces, vertex order and
    visuals, its vertices fleshed, and the per-vertex validity (N,) bool in
    `result.vertex_attributes["valid"]` (invalid vertices are left where they were). For a
    `(vertices, faces)` pair, `(deformed vertices (N, 3), faces (the same array), valid (N,))`
    (measure quad volumes with `fj.volume(deformed, faces)`). For a point cloud or array, a
    `trimesh.PointCloud`, with the validity in `result.metadata["valid"]`. With `stretch`,
    the principal stretch (N,) (NaN at invalid vertices) is in `vertex_attributes["stretch"]`,
    `metadata["stretch"]`, or last in the tuple `(deformed, faces, valid, stretch)`.
    """
    faces = None
    if isinstance(mesh, trimesh.Trimesh):
        points, faces = mesh.vertices, np.asarray(mesh.faces)
    elif isinstance(mesh, trimesh.PointCloud):
        points = mesh.vertices
    elif isinstance(mesh, tuple) and len(mesh) == 2:
        points, faces = mesh[0], checked_faces(mesh[1], mesh[0])
    elif hasattr(mesh, "shape"):
        points = mesh
    else:
        raise TypeError(
            "`mesh` must be a trimesh.Trimesh, a (vertices, faces) pair, a trimesh.PointCloud "
            f"or an (N, 3) array, got {type(mesh)}."
        )
    if margin is None:
        margin = 0.5 * longest_edge(points, faces) if faces is not None else 0.0
    deformed, valid, *measured = flesh_chunked(
        points,
        source,
        target,
        method=method,
        twist=twist,
        chunk_size=chunk_size,
        progress=progress,
        margin=margin,
        beyond=beyond,
        stretch=stretch,
    )
    attributes = {"valid": valid, **({"stretch": measured[0]} if stretch else {})}
    if isinstance(mesh, trimesh.Trimesh):
        result = mesh.copy()
        result.vertices = deformed
        result.vertex_attributes.update(attributes)
        return result
    if isinstance(mesh, tuple):
        return deformed, faces, *attributes.values()
    cloud = trimesh.PointCloud(deformed)
    if isinstance(mesh, trimesh.PointCloud) and mesh.colors is not None and len(mesh.colors):
        cloud.colors = mesh.colors
    cloud.metadata.update(attributes)
    return cloud


def checked_faces(faces, vertices) -> np.ndarray:
    """The faces of a `(vertices, faces)` pair as an (F, k) integer array indexing the
    vertices, else a `ValueError` naming `mesh` (the vertices are checked by their users)."""
    faces = np.asarray(faces)
    if faces.ndim != 2 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"`mesh` faces must be an (F, k) integer array, got {faces.shape}.")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"`mesh` faces must index its {len(vertices)} vertices.")
    return faces


def polygon_mesh(mesh) -> tuple[np.ndarray, np.ndarray]:
    """`(vertices (n, 3), faces (F, k))` of a `trimesh.Trimesh` or a `(vertices, faces)` pair,
    vertex order kept; a `TypeError`/`ValueError` naming `mesh` otherwise."""
    if isinstance(mesh, trimesh.Trimesh):
        return np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if not (isinstance(mesh, tuple) and len(mesh) == 2):
        raise TypeError(
            f"`mesh` must be a trimesh.Trimesh or a (vertices, faces) pair, got {type(mesh)}."
        )
    vertices = np.asarray(mesh[0])
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"`mesh` vertices must be an (n, 3) array, got {vertices.shape}.")
    return vertices, checked_faces(mesh[1], vertices)


def longest_edge(points, faces) -> float:
    """The longest edge of the polygons `faces` (F, k) over `points` (N, 3) (0 if none)."""
    faces = np.asarray(faces)
    if faces.size == 0:
        return 0.0
    p = np.asarray(points, dtype=np.float64)
    edges = p[np.roll(faces, -1, axis=1)] - p[faces]
    return float(np.sqrt(np.max(np.einsum("...i,...i->...", edges, edges))))


def _progress_bar(total: int) -> Callable[[int, int], None]:
    """A `progress(done, total)` callback drawing a `tqdm` bar, closed when done."""
    from tqdm.auto import tqdm

    bar = tqdm(total=total, desc="vertices", unit="pt", unit_scale=True, leave=False)

    def report(done: int, _: int) -> None:
        bar.update(done - bar.n)
        if done >= total:
            bar.close()

    return report

"""Meshes and point clouds (trimesh): bending, reading, atomic writing, closing holes.

Vertices are fleshed; faces are never touched, so the deformed mesh has exactly the input's
faces, vertex count and vertex order.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import trimesh

from ._fleshing import pose, register
from ._maps import check_method
from ._spine import AbstractSpine

CHUNK_SIZE = 200_000


def flesh_chunked(
    points: np.ndarray,
    source: AbstractSpine,
    target: AbstractSpine,
    *,
    method: str = "radial",
    twist: float = 0.0,
    chunk_size: int = CHUNK_SIZE,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`flesh` in chunks of at most `chunk_size` points (bounded memory, progress reports).

    Every chunk has the same shape (the last one is padded), so the work compiles once.

    **Arguments:** `points`: (N, 3) array; spines, `method` and `twist` as for `flesh`;
    `progress(done, total)`: called after each chunk.

    **Returns:** `(deformed (N, 3), valid (N,) bool)` as NumPy arrays, dtype of `points`.
    """
    check_method(method)
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[-1] != 3:
        raise ValueError(f"`points` must have shape (N, 3), got shape {points.shape}.")
    if not np.issubdtype(points.dtype, np.floating):
        points = points.astype(np.float64)
    n = len(points)
    size = max(1, min(int(chunk_size), n))
    deformed, valid = np.empty_like(points), np.zeros(n, dtype=bool)
    for start in range(0, n, size):
        chunk = points[start : start + size]
        m = len(chunk)
        if m < size:
            chunk = np.concatenate([chunk, np.repeat(chunk[:1], size - m, axis=0)])
        registration = register(jnp.asarray(chunk), source)
        out, ok = pose(registration, target, method=method, twist=twist)
        deformed[start : start + m] = np.asarray(out)[:m]
        valid[start : start + m] = np.asarray(ok)[:m]
        if progress is not None:
            progress(start + m, n)
    return deformed, valid


def deform_mesh(
    mesh,
    source: AbstractSpine,
    target: AbstractSpine,
    *,
    method: str = "radial",
    twist: float = 0.0,
    chunk_size: int = CHUNK_SIZE,
    progress: Callable[[int, int], None] | None = None,
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

    **Returns:** for a `Trimesh`, a new `Trimesh` with the input's faces, vertex order and
    visuals, its vertices fleshed, and the per-vertex validity (N,) bool in
    `result.vertex_attributes["valid"]` (invalid vertices are left where they were). For a
    `(vertices, faces)` pair, `(deformed vertices (N, 3), faces (the same array), valid (N,))`
    (measure quad volumes with `fj.volume(deformed, faces)`). For a point cloud or array, a
    `trimesh.PointCloud`, with the validity in `result.metadata["valid"]`.
    """
    if isinstance(mesh, trimesh.Trimesh | trimesh.PointCloud):
        points = mesh.vertices
    elif isinstance(mesh, tuple) and len(mesh) == 2:
        points, faces = mesh
        faces = np.asarray(faces)
        if faces.ndim != 2 or not np.issubdtype(faces.dtype, np.integer):
            raise ValueError(f"`mesh` faces must be an (F, k) integer array, got {faces.shape}.")
        if faces.size and (faces.min() < 0 or faces.max() >= len(points)):
            raise ValueError(f"`mesh` faces must index its {len(points)} vertices.")
    elif hasattr(mesh, "shape"):
        points = mesh
    else:
        raise TypeError(
            "`mesh` must be a trimesh.Trimesh, a (vertices, faces) pair, a trimesh.PointCloud "
            f"or an (N, 3) array, got {type(mesh)}."
        )
    deformed, valid = flesh_chunked(
        np.asarray(points),
        source,
        target,
        method=method,
        twist=twist,
        chunk_size=chunk_size,
        progress=progress,
    )
    if isinstance(mesh, trimesh.Trimesh):
        result = mesh.copy()
        result.vertices = deformed
        result.vertex_attributes["valid"] = valid
        return result
    if isinstance(mesh, tuple):
        return deformed, faces, valid
    cloud = trimesh.PointCloud(deformed)
    if isinstance(mesh, trimesh.PointCloud) and mesh.colors is not None and len(mesh.colors):
        cloud.colors = mesh.colors
    cloud.metadata["valid"] = valid
    return cloud


def load_mesh(path: str | os.PathLike):
    """Reads a mesh or point cloud with trimesh, keeping vertex count and order.

    OBJ files keep their `v` lines as vertices, in order, whenever trimesh allows (quads are
    split in two triangles). Scenes with several meshes are concatenated.

    **Returns:** a `trimesh.Trimesh` or `trimesh.PointCloud`. **Raises:** `FileNotFoundError`
    when `path` does not exist, `ValueError` when it holds no mesh or points.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        loaded = trimesh.load(str(path), process=False)
        if path.suffix.lower() == ".obj" and isinstance(loaded, trimesh.Trimesh):
            loaded = _obj_in_file_order(path, loaded)
    except Exception as error:  # trimesh raises many kinds for unreadable files
        raise ValueError(f"{path}: not a mesh trimesh can read ({error})") from error
    if isinstance(loaded, trimesh.Scene):
        geometries = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        if not geometries:
            raise ValueError(f"{path}: contains no mesh")
        loaded = trimesh.util.concatenate(geometries)
    if not isinstance(loaded, trimesh.Trimesh | trimesh.PointCloud) or len(loaded.vertices) == 0:
        raise ValueError(f"{path}: contains no mesh or points")
    return loaded


def _obj_in_file_order(path: Path, loaded: trimesh.Trimesh) -> trimesh.Trimesh:
    """The OBJ mesh with one vertex per `v` line, in file order, when trimesh can give it.

    trimesh splits vertices along texture seams by default, and along normal seams with
    `maintain_order=True`; one of the two keeps the file's vertices as they are.
    """
    with open(path, "rb") as file:
        count = sum(1 for line in file if line.startswith(b"v "))
    if len(loaded.vertices) == count:
        return loaded
    ordered = trimesh.load(str(path), process=False, maintain_order=True)
    if isinstance(ordered, trimesh.Trimesh) and len(ordered.vertices) == count:
        return ordered
    return loaded


def write_mesh_atomic(mesh, path: str | os.PathLike) -> None:
    """Writes `mesh` to `path` in the format of its extension, atomically.

    The mesh is exported to a temporary file in the same folder, then renamed over `path`: a
    failed export never leaves `path` half-written (a previous file there stays intact).
    Boolean vertex attributes (e.g. `"valid"`) are written as 0/1 bytes where the format
    stores attributes (PLY).
    """
    path = Path(path)
    file_type = path.suffix.lower().lstrip(".")
    if not file_type:
        raise ValueError(f"{path}: no extension to choose the output format from")
    if isinstance(mesh, trimesh.Trimesh):
        mesh = mesh.copy()
        for name, values in list(mesh.vertex_attributes.items()):
            if np.asarray(values).dtype == bool:
                mesh.vertex_attributes[name] = np.asarray(values, dtype=np.uint8)
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as file:
            data = mesh.export(file_type=file_type)
            file.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def cap_holes(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Closes every boundary loop of `mesh` with a fan of triangles around the loop's centroid.

    The input's vertices come first, in order (one new vertex per loop is appended), and its
    faces come first too, so a deformation of the input carries over to the capped mesh.
    Suited to roughly planar holes such as the bottom of the Stanford bunny.

    **Returns:** a new `Trimesh` (unchanged copy if the mesh had no boundary).
    """
    faces = np.asarray(mesh.faces)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = edges[counts[inverse.reshape(-1)] == 1]
    # Boundary half-edges a→b of the faces; the caps run them backwards (b→a).
    following: dict[int, list[int]] = {}
    for a, b in boundary:
        following.setdefault(int(b), []).append(int(a))
    vertices = [np.asarray(mesh.vertices)]
    new_faces = [faces]
    next_index = len(mesh.vertices)
    while following:
        start = next(iter(following))
        loop, current = [start], start
        while True:
            successors = following.get(current)
            if not successors:
                break
            nxt = successors.pop()
            if not successors:
                del following[current]
            if nxt == start:
                break
            loop.append(nxt)
            current = nxt
        if len(loop) < 3:
            continue
        loop = np.asarray(loop)
        vertices.append(np.asarray(mesh.vertices)[loop].mean(axis=0, keepdims=True))
        new_faces.append(np.stack([loop, np.roll(loop, -1), np.full_like(loop, next_index)], 1))
        next_index += 1
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(new_faces), process=False)

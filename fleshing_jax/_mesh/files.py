"""Reading meshes with their vertex order kept, and writing them atomically (trimesh)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import trimesh


def load_mesh(path: str | os.PathLike):
    """Reads a mesh or point cloud with trimesh, keeping vertex count and order.

    OBJ files keep their `v` lines as vertices, in order, whenever trimesh allows (quads are
    split in two triangles). Scenes with several meshes are concatenated.

    **Returns:** a `trimesh.Trimesh` or `trimesh.PointCloud`. **Raises:** `FileNotFoundError`
    when `path` does not exist, `ValueError` when it holds no mesh or points.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a mesh file")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    obj = path.suffix.lower() == ".obj"
    try:
        loaded = trimesh.load(str(path), process=False, **({"maintain_order": True} if obj else {}))
        if obj and isinstance(loaded, trimesh.Trimesh):
            loaded = _obj_in_file_order(path, loaded)
    except Exception as error:  # trimesh raises many kinds for unreadable files
        # An optional module trimesh reaches for on unreadable bytes (e.g. its text-encoding
        # guess) says nothing about the file: name the file's content instead.
        why = "unrecognised content" if isinstance(error, ImportError) else error
        raise ValueError(f"{path}: not a mesh trimesh can read ({why})") from error
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

    `loaded` was read with `maintain_order=True`, which kept the file's vertices with
    texture seams, normal seams and unused vertices alike (`tests/test_mesh.py`, and the
    meshes of `../shared/data`), where trimesh's default read splits seams and drops unused
    vertices; that read is the fallback. (Reading with `maintain_order` first read the bunny
    once instead of twice: a warm `deform` 75 ms shorter.)
    """
    with open(path, "rb") as file:
        count = sum(1 for line in file if line.startswith(b"v "))
    if len(loaded.vertices) == count:
        return loaded
    default = trimesh.load(str(path), process=False)
    if isinstance(default, trimesh.Trimesh) and len(default.vertices) == count:
        return default
    return loaded


WRITABLE = ("obj", "ply", "stl", "off", "glb", "xyz")  # single-file formats trimesh exports
POINTS_ONLY = ("xyz",)  # formats of points, no faces: a mesh is not written there
MESH_WRITABLE = tuple(w for w in WRITABLE if w not in POINTS_ONLY)


def check_output_path(path: str | os.PathLike, extensions: tuple[str, ...] = WRITABLE) -> Path:
    """Checks, before any work, that a mesh can be written at `path`: an extension of
    `extensions` (default `WRITABLE`; `MESH_WRITABLE` for an output that is a mesh, `("json",)`
    for a spine) and an existing, writable folder. Raises `ValueError` naming the problem."""
    path = Path(path)
    file_type = path.suffix.lower().lstrip(".")
    if file_type not in extensions:
        found = f"'.{file_type}'" if file_type else "no extension"
        if file_type in POINTS_ONLY and file_type in WRITABLE:
            found += ": a format of points, and the output is a mesh"
        raise ValueError(
            f"{path}: the output format is chosen by the extension, one of "
            f"{', '.join('.' + w for w in extensions)} (got {found})"
        )
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise ValueError(f"{path}: the output folder {directory} does not exist")
    if not os.access(directory, os.W_OK | os.X_OK):
        raise ValueError(f"{path}: the output folder {directory} is not writable")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a file name")
    return path


def write_mesh_atomic(mesh, path: str | os.PathLike) -> None:
    """Writes `mesh` to `path` in the format of its extension (one of `WRITABLE`), atomically.

    The mesh is exported to a temporary file in the same folder, then renamed over `path`: a
    failed export never leaves `path` half-written (a previous file there stays intact). The
    file's permissions follow the umask, as for any new file. Boolean vertex attributes (e.g.
    `"valid"`) are written as 0/1 bytes where the format stores attributes (PLY). OBJ files
    are written without materials (no `mtllib` line pointing at a file that is not written).
    """
    path = check_output_path(path)
    file_type = path.suffix.lower().lstrip(".")
    if isinstance(mesh, trimesh.Trimesh):
        mesh = mesh.copy()
        for name, values in list(mesh.vertex_attributes.items()):
            if np.asarray(values).dtype == bool:
                mesh.vertex_attributes[name] = np.asarray(values, dtype=np.uint8)
    options = {"include_texture": False} if file_type == "obj" else {}
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as file:
            data = mesh.export(file_type=file_type, **options)
            file.write(data.encode() if isinstance(data, str) else data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)  # the only way to read it: set and restore
    os.umask(mask)
    return mask

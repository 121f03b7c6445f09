"""Example data shipped with the package, so that a fresh install runs the notebooks and tests.

`spot()` is Keenan Crane's cow (CC0, see `spot.LICENSE.md` beside it): 2,930 vertices once
its texture seams are welded, 5,856 triangles, y up, its head towards −z.
"""

from __future__ import annotations

from pathlib import Path

import trimesh

__all__ = ["spot", "spot_path"]


def spot_path() -> Path:
    """The path of the shipped `spot.obj` (for `fleshing-jax` commands, or `fj.load_mesh`)."""
    return Path(__file__).with_name("spot.obj")


def spot(weld: bool = True) -> trimesh.Trimesh:
    """Spot the cow (Keenan Crane, CC0) as a new `trimesh.Trimesh`.

    **Arguments:**

    - `weld`: `True` (default) merges the vertices that the file duplicates along its texture
      seams, so that the mesh is closed (watertight: 2,930 vertices, 5,856 triangles) and fit
      for volumes, medial meshes and deformations. `False` returns the mesh as loaded with
      `process=False`: 3,225 vertices (one per texture coordinate), seams open.

    **Returns:**

    A `trimesh.Trimesh`, y up, head towards −z, extents about (0.94, 1.69, 1.72).
    """
    if not isinstance(weld, bool):
        raise TypeError(f"weld must be True or False, got {type(weld).__name__}")
    mesh = trimesh.load(spot_path(), process=False, force="mesh")
    if weld:
        mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return mesh

"""`deform_medial`: a mesh deformed through its medial mesh, from handles to skin, in one call."""

from __future__ import annotations

import numpy as np
import trimesh
from jaxtyping import ArrayLike

from .._batching.quick import QUICK_BATCH
from .._medial_axis.medial_mesh import MedialMesh
from .arap import ITERATIONS, SMOOTHNESS, _prepare, posed
from .rig import MedialRig, check_method, skinned


def deform_medial(
    mesh,
    medial: MedialMesh,
    handles: ArrayLike,
    targets: ArrayLike,
    method: str = "medial",
    *,
    rotations: ArrayLike | None = None,
    implicit: bool = True,
    iterations: int = ITERATIONS,
    solver: str = "global",
):
    """Deforms `mesh` by moving handle spheres of its medial mesh (Lan et al. 2017).

    The chain: bind the surface to `medial` (`MedialRig`), deform the medial mesh as rigidly
    as possible with the handles at `targets` (`arap_medial`), and skin the surface from it
    (`rig.pose`). For many poses of one shape, build the rig once and call `arap_medial` and
    `rig.pose` per frame instead.

    **Arguments:**

    - `mesh`: a `trimesh.Trimesh`, a `(vertices (N, 3), faces (F, 3 or 4))` pair of arrays, or
      an `(N, 3)` array of points (no faces: no smoothing of the skin's rotation weights and no
      tangential relaxation).
    - `medial`: the rest `MedialMesh` of the shape (e.g. `fj.medial_mesh(mesh)`).
    - `handles`: `(h,)` sphere indices; `targets`: `(h, 3)` their new centres;
      `rotations`: optional `(h, 3, 3)` prescribed handle rotations.
    - `method`: `"medial"` (the paper's footprint skin), `"lbs"` or `"dqs"` (baselines with
      the same weights); `implicit`: the implicit-skinning correction.
    - `iterations`, `solver`: of `arap_medial`.

    **Returns:** like `deform_mesh`: for a `Trimesh`, a new `Trimesh` with the input's faces,
    vertex count and order, and the per-vertex validity (N,) bool in
    `result.vertex_attributes["valid"]`; for a `(vertices, faces)` pair,
    `(deformed vertices (N, 3), faces, valid (N,))`; for an array, `(deformed, valid)`.
    Invalid vertices (and any whose image is not finite) are left where they were. Copies of
    a vertex (seams of a mesh read with `process=False`) are posed as one (see `MedialRig`).

    Raises `TypeError`/`ValueError` naming the argument, before any work, for a bad `mesh`,
    `medial`, `handles`, `targets`, `rotations`, `method`, `iterations` or `solver`.
    """
    if not isinstance(medial, MedialMesh):
        raise TypeError(f"`medial` must be a MedialMesh, got {type(medial).__name__}.")
    faces = None
    if isinstance(mesh, trimesh.Trimesh):
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    elif isinstance(mesh, tuple) and len(mesh) == 2:
        vertices, faces = mesh
    elif hasattr(mesh, "shape") or isinstance(mesh, list):
        vertices = mesh
    else:
        raise TypeError(
            "`mesh` must be a trimesh.Trimesh, a (vertices, faces) pair or an (N, 3) array, "
            f"got {type(mesh).__name__}."
        )
    check_method(method)
    # Every argument is checked before the binding, the costly step (seconds on 100k
    # vertices).
    prepared = _prepare(medial, handles, targets, rotations, iterations, solver, SMOOTHNESS)
    rig = MedialRig(vertices, medial, faces=faces)
    # One call: on a small mesh its two programs (the solve, the skin) are compiled quickly
    # (`_batching.quick`; spot's first call 7.3 -> 2.2 s of CPU), not as the per-frame
    # `arap_medial` and `rig.pose`, whose programs are optimised for their many calls.
    quick = rig.rest_vertices.shape[0] <= QUICK_BATCH
    pose = posed(medial, *prepared, solver, quick=quick)[0]
    deformed, valid = skinned(rig, pose, method, implicit, quick=quick)
    if isinstance(mesh, trimesh.Trimesh):
        result = mesh.copy()
        result.vertices = np.asarray(deformed, dtype=np.float64)
        result.vertex_attributes["valid"] = np.asarray(valid)
        return result
    if isinstance(mesh, tuple):
        return deformed, faces, valid
    return deformed, valid

"""How much a deformation distorts a mesh's edges, per vertex.

A fleshing keeps volume exactly (`det J = 1`) and a valid vertex is never torn from its
neighbours, yet near the edge of the valid range a volume-preserving map can still squeeze a
cross-section and draw it out (spot's snout into a spike 7.5× its edge length, with no vertex
flagged). `edge_stretch` measures what a user sees there: the factor by which each edge's
length changed, the worse of stretched and squeezed.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .deform import polygon_mesh


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """The distinct undirected edges of the polygons `faces` (F, k), (E, 2) int, each with its
    smaller vertex first."""
    faces = np.asarray(faces)
    if faces.size == 0:
        return np.zeros((0, 2), np.int64)
    pairs = np.stack([faces.ravel(), np.roll(faces, -1, axis=1).ravel()], axis=1)
    return np.unique(np.sort(pairs, axis=1), axis=0)


def edge_stretch(mesh, deformed: ArrayLike, valid: ArrayLike | None = None
                 ) -> Float[Array, " n"]:
    """Per vertex, the largest factor by which one of its edges changed length.

    **Arguments:**

    - `mesh`: the mesh at rest, a `trimesh.Trimesh` or `(vertices (n, 3), faces (F, k))`.
    - `deformed`: (n, 3) its vertices after a deformation (`fj.pose_skeleton`'s, `fj.flesh`'s,
      `fj.deform_medial`'s…), in the same order.
    - `valid`: optional (n,) bool, the deformation's flags: only the edges between two valid
      vertices count (those to a flagged vertex are the flags' to report).

    **Returns:** (n,) `max(l′/l, l/l′)` over the vertex's edges (`l`, `l′` its length before
    and after): 1 where the edges kept their lengths (a rigid motion), 2 where one doubled or
    halved; 1 at a vertex in no edge. An edge of zero length at rest has no factor and is
    skipped; one that shrinks to zero length gives `inf`. In the dtype of `deformed` (floating),
    differentiable in it (a fit may penalise distortion).

    **Raises:** `TypeError`/`ValueError` naming the argument: a `mesh` that is not one, a
    `deformed` that is not (n, 3) finite numbers for its n vertices.
    """
    vertices, faces = polygon_mesh(mesh)
    deformed = jnp.asarray(deformed)
    if deformed.shape != vertices.shape:
        raise ValueError(
            f"`deformed` must be ({len(vertices)}, 3), the mesh's vertices moved, got "
            f"{deformed.shape}."
        )
    if not jnp.issubdtype(deformed.dtype, jnp.floating):
        raise TypeError(f"`deformed` must be floating point, got {deformed.dtype}.")
    if not isinstance(deformed, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(deformed))):
        raise ValueError("`deformed` has NaN or infinite coordinates.")
    edges = mesh_edges(faces)
    if valid is not None:
        valid = np.asarray(valid)
        if valid.shape != (len(vertices),) or valid.dtype != bool:
            raise ValueError(f"`valid` must be ({len(vertices)},) bool, got {valid.dtype} "
                             f"{valid.shape}.")
        edges = edges[valid[edges].all(axis=1)]
    rest = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    edges, rest = edges[rest > 0], rest[rest > 0]
    return _stretch(deformed, jnp.asarray(edges), jnp.asarray(rest, deformed.dtype))


@jax.jit
def _stretch(deformed, edges, rest):
    offset = deformed[edges[:, 0]] - deformed[edges[:, 1]]
    squared = jnp.sum(offset * offset, axis=1)
    # Double `where`: the square root's derivative is infinite at a zero-length edge.
    positive = squared > 0
    length = jnp.sqrt(jnp.where(positive, squared, 1.0))
    factor = jnp.where(positive, jnp.maximum(length / rest, rest / length), jnp.inf)
    n = deformed.shape[0]
    worst = jnp.maximum(jax.ops.segment_max(factor, edges[:, 0], num_segments=n),
                        jax.ops.segment_max(factor, edges[:, 1], num_segments=n))
    return jnp.maximum(worst, jnp.ones((), deformed.dtype))  # in no edge: -inf → 1

"""`MedialPose`: a deformed medial mesh, the input of skinning.

The pose is what the skin needs from a deformation of the medial mesh: the new centre of every
sphere and a rotation per sphere (radii are kept, as in Lan et al. 2017). Each sphere then
carries the rigid motion `x ↦ centers[i] + rotations[i] · (x − rest centre)`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._checks import as_float_array, is_concrete
from .._medial_axis.medial_mesh import MedialMesh

ROTATION_TOLERANCE = 1e-4  # of |RᵀR − I| (max entry), so that float32 rotations pass


def not_rotations(rotations) -> np.ndarray:
    """Positions of the concrete `(h, 3, 3)` matrices that are not rotations: not finite, not
    orthonormal to `ROTATION_TOLERANCE`, or of determinant ≤ 0 (reflections)."""
    r = np.asarray(rotations, np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        error = np.abs(np.einsum("hba,hbc->hac", r, r) - np.eye(3)).max(axis=(1, 2))
        det = np.linalg.det(np.where(np.isfinite(r), r, 0.0))
    good = np.isfinite(r).all(axis=(1, 2)) & (error <= ROTATION_TOLERANCE) & (det > 0)
    return np.flatnonzero(~good)


class MedialPose(eqx.Module):
    """A pose of a medial mesh: new sphere centres and per-sphere rotations.

    **Fields:**

    - `medial`: the rest `MedialMesh` (its radii are the pose's radii).
    - `centers`: `(n, 3)` posed sphere centres.
    - `rotations`: `(n, 3, 3)` rotation of each sphere from rest to pose.
    """

    medial: MedialMesh
    centers: Float[Array, "n 3"]
    rotations: Float[Array, "n 3 3"]

    def __init__(self, medial: MedialMesh, centers: ArrayLike, rotations: ArrayLike):
        if not isinstance(medial, MedialMesh):
            raise TypeError(f"MedialPose `medial` must be a MedialMesh, got "
                            f"{type(medial).__name__}")
        self.medial = medial
        self.centers = as_float_array(centers, "centers")
        self.rotations = as_float_array(rotations, "rotations")

    def __check_init__(self):
        n = self.medial.centers.shape[0]
        if self.centers.shape != (n, 3):
            raise ValueError(f"MedialPose centers must have shape ({n}, 3), got "
                             f"{self.centers.shape}")
        if self.rotations.shape != (n, 3, 3):
            raise ValueError(f"MedialPose rotations must have shape ({n}, 3, 3), got "
                             f"{self.rotations.shape}")
        # Values are checked where known (outside `jit`): a pose with a NaN centre or a
        # matrix that is not a rotation skins to silently wrong vertices.
        if is_concrete(self.centers) and not np.isfinite(np.asarray(self.centers)).all():
            bad = np.flatnonzero(~np.isfinite(np.asarray(self.centers)).all(axis=1))
            raise ValueError(f"MedialPose centers must be finite; spheres {bad.tolist()[:10]} "
                             "are not")
        if is_concrete(self.rotations):
            bad = not_rotations(self.rotations)
            if bad.size:
                raise ValueError(f"MedialPose rotations must be rotation matrices (finite, "
                                 f"orthonormal to {ROTATION_TOLERANCE}, det +1); spheres "
                                 f"{bad.tolist()[:10]} are not")

    @classmethod
    def rest(cls, medial: MedialMesh) -> MedialPose:
        """The rest pose: rest centres and identity rotations."""
        centers = jnp.asarray(medial.centers)
        eye = jnp.broadcast_to(jnp.eye(3, dtype=centers.dtype), (centers.shape[0], 3, 3))
        return cls(medial, centers, eye)

    def deformed(self) -> MedialMesh:
        """The posed medial mesh: posed centres, rest radii, edges and faces."""
        m = self.medial
        return MedialMesh(self.centers, m.radii, m.edges, m.faces)

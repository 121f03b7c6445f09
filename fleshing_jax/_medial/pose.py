"""`MedialPose`: a deformed medial mesh, the input of skinning.

The pose is what the skin needs from a deformation of the medial mesh: the new centre of every
sphere and a rotation per sphere (radii are kept, as in Lan et al. 2017). Each sphere then
carries the rigid motion `x ↦ centers[i] + rotations[i] · (x − rest centre)`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .medial_mesh import MedialMesh


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

    def __check_init__(self):
        n = self.medial.centers.shape[0]
        if self.centers.shape != (n, 3):
            raise ValueError(f"MedialPose centers must have shape ({n}, 3), got "
                             f"{self.centers.shape}")
        if self.rotations.shape != (n, 3, 3):
            raise ValueError(f"MedialPose rotations must have shape ({n}, 3, 3), got "
                             f"{self.rotations.shape}")

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

"""How far a pose squeezes each limb: the posing map's principal stretch at every vertex.

A posed limb keeps its volume exactly (`det J = 1`), yet near the edge of its valid range the
map squeezes one direction and draws out another: spot's snout is pressed into a blade with no
vertex flagged and its edges changed by at most 2.44× (`fj.edge_stretch`), while the map
there squeezes a direction 4× (`fj.principal_stretch`). `pose_stretch` gives that factor for
every vertex of a posed skeleton, so that a command line, a fit or a user can refuse it.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._fleshing.methods import check_method
from .._fleshing.verify import registered_stretch
from .posing import (
    as_registration,
    check_poses,
    limb_check,
    limb_poser,
    limb_target,
    placed_poses,
    posed,
)
from .skeleton import Skeleton


def pose_stretch(mesh_or_registration, skeleton: Skeleton, poses: dict, *,
                 method: str = "radial") -> Float[Array, " n"]:
    """Per vertex, the largest factor by which the pose stretches or squeezes a direction.

    **Arguments:** as `fj.pose_skeleton` (the mesh or its `register_skeleton`, the skeleton,
    the poses, the method).

    **Returns:** (n,) `max(σ₁, 1/σ₃)` of the posing map's Jacobian at each vertex (see
    `fj.principal_stretch`): 1 on the body, on the limbs neither posed nor below a posed limb
    and on those a parent carries (rigid motions), more inside posed regions; NaN at the
    vertices `pose_skeleton` flags invalid (they are left in place: see `valid`). In the
    registration's dtype. Computed by `jax.jacfwd` at every posed vertex: for checking a pose,
    not for the per-frame path.
    """
    registration = as_registration(mesh_or_registration, skeleton)
    placed, poses, _ = placed_poses(registration, skeleton, check_poses(poses, skeleton))
    method = check_method(method)
    valid = posed(registration, skeleton, poses, method).valid
    stretch = jnp.ones(valid.shape, registration.vertices.dtype)
    for k, pose in poses.items():
        # The same map as `pose_skeleton`'s, at the registered vertices (their validity is
        # taken from there: it includes the images' projection check).
        # (Prepared as the pose prepares it, checked on the same spine: the stretch reads only
        # its frames, and `pose_skeleton`'s compiled preparation serves it.)
        ids, limb = placed.indices[k], placed.registrations[k]
        poser = limb_poser(limb, limb_target(placed, k, pose), method,
                           checked_on=limb_check(placed, k, pose))
        limb = registered_stretch(placed.rests[k], limb, poser)
        stretch = stretch.at[ids].set(limb[: ids.shape[0]])
    return jnp.where(valid, stretch, jnp.nan)

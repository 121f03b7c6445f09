"""A bend past a joint's exact range carried on by the next joint of its chain.

The radial map bends a limb of radius `r` exactly only while `κ·r < 1/√3`: a bend of `θ`
needs a zone of at least `√3 θ r` (120° at the biped's knee, radius 0.036: 0.13, where its
limb has 0.059 of room before its foot). A joint's zone cannot grow past its child's border
(the child carries on rigidly from there), so a bend past the joint's exact range
(`JointZone.reach`) is carried on at the next joint of the chain, when the animator left that
joint free: a knee bent 120° with a free ankle bends the knee to its exact range and the ankle
the rest, in the same plane (the tip points where the knee alone would have sent it, and no
vertex leaves the map's exact range while both joints have room).

The share, continuous in the angle: the limb alone up to `SHARE` of its exact range `R₁`
in the pose's direction (its pose then unchanged, bit for bit); then the child takes the rest
up to `SHARE` of its own `R₂`; past both, the excess is split as `R₁ : R₂` (both inexact, as
one limb bent past its range is). Each child carries the bend on to its own only child, when
free. A limb with several children (a head with ears) or a posed child keeps its whole bend.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._checks import is_concrete
from .._spines.bent import rotate
from .limb_pose import LimbPose

SHARE = 0.95  # of a joint's exact range it takes before its child does: short of its edge,
# where the map's blend towards the sections (`posing.BLEND_WIDTH`) would start in round-off


def spilled(registration, skeleton, poses: dict) -> dict:
    """`poses` (limb index → `LimbPose` or spine, checked) with each `LimbPose` bent past its
    joint's exact range carried on by its only child, when that child is not posed (see the
    module's docstring): the limbs in topological order, so that a carried bend carries on
    down the chain. Eagerly, a child the bend does not reach is left unposed (carried rigidly,
    as before); traced, it is posed with its share, zero or not."""
    poses = dict(poses)
    for k in range(len(skeleton.limbs)):
        pose, children = poses.get(k), skeleton.children(k)
        if not isinstance(pose, LimbPose) or len(children) != 1 or children[0] in poses:
            continue
        poses[k], child = _split(registration, k, children[0], pose)
        if not (is_concrete(child) and float(child.bend) == 0):
            poses[children[0]] = child
    return dict(sorted(poses.items()))


def _split(registration, k: int, c: int, pose: LimbPose) -> tuple[LimbPose, LimbPose]:
    """`(limb k's pose, its child c's)`: `pose`'s bend shared between them (module's
    docstring), the child's towards the parent's bend direction at rest, turned back by the
    parent's twist (which the child's region is carried through)."""
    rest, joint = registration.rests[k], registration.joints[k]
    bend, direction, twist = pose.radians(rest, joint)
    # A negative bend is a positive one the other way.
    direction = jnp.where(bend < 0, direction + jnp.pi, direction)
    angle = jnp.abs(bend)
    own, next_, child_direction = _reaches(registration, k, c, direction, twist)
    first_share, both = SHARE * own, SHARE * (own + next_)
    # Past both ranges the excess is split as their ranges (reached only where both are
    # finite: an infinite range takes any angle).
    finite = jnp.isfinite(own) & jnp.isfinite(next_)
    ratio = jnp.where(finite, own, 1.0) / jnp.where(finite, own + next_, 1.0)
    kept = jnp.where(angle <= first_share, angle, jnp.where(
        angle <= both, first_share, first_share + ratio * (angle - jnp.where(finite, both, 0.0))))
    dtype = pose.bend.dtype
    parent_bend = jnp.where(angle <= first_share, pose.bend,
                            (jnp.sign(bend) * jnp.rad2deg(kept)).astype(dtype))
    parent = eqx.tree_at(lambda p: p.bend, pose, parent_bend)
    child = LimbPose(jnp.rad2deg(angle - kept).astype(dtype),
                     jnp.rad2deg(child_direction).astype(dtype))
    return parent, child


def _reaches(registration, k: int, c: int, direction, twist) -> tuple:
    """`(limb k's reach, its child c's, the child's direction)` (radians) for a bend of limb
    k towards `direction` with `twist` (radians): the child's the parent's direction at rest,
    turned back by the parent's twist (which the child's region is carried through), read
    about the child's own tangent (`JointZone.reach`)."""
    zone, below = registration.zones[k], registration.zones[c]
    t, first, second = zone.axes
    towards = rotate(t, -twist, jnp.cos(direction) * first + jnp.sin(direction) * second)
    tangent, across_i, across_j = below.axes
    # (Its part across the child's tangent: where none, any direction; refused nowhere.)
    x, y = jnp.dot(towards, across_i), jnp.dot(towards, across_j)
    aside = jnp.hypot(x, y) > 0
    child_direction = jnp.where(aside, jnp.arctan2(y, jnp.where(aside, x, 1.0)), 0.0)
    own = zone.reach(direction, registration.joints[k], registration.stops[k])
    next_ = below.reach(child_direction, registration.joints[c], registration.stops[c])
    return own, next_, child_direction


def carried_range(registration, k: int, own: float, direction, twist) -> float:
    """Limb k's exact range (radians) towards `direction` with `twist` (radians) when its only
    child is free and carries the bend on (`spilled`): `own`, its range alone (`joint_range`'s
    scan), until the share gives the child its part, then the least bend at which either
    leaves its exact range (the child's own range counting its free only child in turn)."""
    from .joint_zone import joint_range

    (c,) = registration.children[k]
    reach, below, child_direction = (float(x) for x in _reaches(
        registration, k, c, direction, twist))
    first_share = SHARE * reach
    if not np.isfinite(reach) or own < first_share:  # (the limb alone up to its range)
        return own
    child = np.radians(float(joint_range(registration, c, np.degrees(child_direction))))
    if not np.isfinite(below):  # (the child takes all past the limb's share)
        return min(first_share + child, 2 * np.pi)
    # The limb holds `first_share` until both shares are taken, then the excess is split as
    # `reach : below`: the limb leaves `own` and the child its range where the split says.
    both, ratio = SHARE * (reach + below), reach / (reach + below)
    limb_leaves = both + (own - first_share) / ratio
    child_leaves = (first_share + child if child < SHARE * below
                    else both + (child - SHARE * below) / (1 - ratio))
    return min(limb_leaves, child_leaves, 2 * np.pi)

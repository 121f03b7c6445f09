"""`aim`: the pose that points a limb at a point, as an animator aims a bone."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._checks import as_float_array
from .joint_zone import joint_range
from .limb_pose import LimbPose
from .posing import SkeletonRegistration, check_limb_index, limb_target

_STEPS = 32  # bisection steps on the bend (degrees): 180° / 2³²
# Degrees: how far past the middle the angle is compared, above the bend's resolution.
_STEP = {np.dtype(np.float64): 1e-7, np.dtype(np.float32): 1e-3}


def aim(registration: SkeletonRegistration, skeleton, limb: int, point) -> LimbPose:
    """The `LimbPose` that bends limb `limb` at its joint so that its end points at `point`.

    **Arguments:** `registration`: the mesh's `register_skeleton`; `skeleton`: its
    `fj.Skeleton`; `limb`: a limb index; `point` (3,): in the mesh's coordinates at rest (a
    limb below a posed one turns with it).

    The bend is towards `point` (`LimbPose(towards=…)`), by the angle that puts `point` on the
    line from the joint through the limb's end (its spine's end, or where its first child
    starts): found by bisection on the bent spine, whose bending zone depends on the angle.
    Bends up to 180°. **Returns:** the `LimbPose`. **Raises** `ValueError` for a limb index
    of no limb, a `point` that is not a finite (3,) array, or one on the limb's own axis at its
    joint (no direction to bend towards).
    """
    k = check_limb_index(limb, skeleton, "limb")
    joint_range(registration, k)  # (the registration's limb index checked too)
    target = np.asarray(as_float_array(point, "point", (3,)), float)
    if not np.all(np.isfinite(target)):
        raise ValueError(f"`point` must be finite, got {target.tolist()}.")
    rest = registration.rests[k]
    joint, stop = registration.joints[k], registration.stops[k]
    origin = np.asarray(rest(joint), float)
    towards = target - origin
    if np.linalg.norm(towards) == 0:
        raise ValueError("`point` is the limb's joint: there is no direction to aim it at.")
    dtype = registration.vertices.dtype

    @eqx.filter_jit
    def turned(bend):  # the angle from the joint-to-end chord to the point's direction
        pose = LimbPose(bend, towards=jnp.asarray(towards, dtype))
        spine = limb_target(registration, k, pose)
        chord = spine(stop) - jnp.asarray(origin, dtype)
        axis = jnp.asarray(towards, dtype)
        return jnp.arctan2(jnp.linalg.norm(jnp.cross(chord, axis)), jnp.dot(chord, axis))

    # The chord turns towards the point as the bend grows, then past it: its angle to the
    # point falls and then rises, so the bend where it is least is found by comparing it at
    # `middle` and a little past it.
    lo, hi = 0.0, 180.0
    for _ in range(_STEPS):
        middle = 0.5 * (lo + hi)
        here = float(turned(jnp.asarray(middle, dtype)))
        past = float(turned(jnp.asarray(middle + _STEP[np.dtype(dtype)], dtype)))
        lo, hi = (middle, hi) if past < here else (lo, middle)
    return LimbPose(0.5 * (lo + hi), towards=towards)


def nod(registration: SkeletonRegistration, skeleton, limb: int, degrees, *, up) -> LimbPose:
    """A limb (a head) bent `degrees` at its joint towards the world's `up` (3,) (negative:
    down): a nod, about the limb's side. **Returns** the `LimbPose`; `ValueError` for a limb
    along `up` (no side to nod about)."""
    return LimbPose(abs(float(degrees)), towards=_sign(degrees) * _across(
        registration, skeleton, limb, up, lambda tangent, up: up))


def turn(registration: SkeletonRegistration, skeleton, limb: int, degrees, *, up) -> LimbPose:
    """A limb (a head) turned `degrees` about the world's `up` (3,) at its joint, by the
    right-hand rule (positive: counter-clockwise seen from above): bent towards `up × t`, `t`
    its tangent there. **Returns** the `LimbPose`; `ValueError` for a limb along `up`."""
    return LimbPose(abs(float(degrees)), towards=_sign(degrees) * _across(
        registration, skeleton, limb, up, lambda tangent, up: np.cross(up, tangent)))


def _sign(degrees) -> float:
    return -1.0 if float(degrees) < 0 else 1.0


def _across(registration, skeleton, limb, up, direction) -> np.ndarray:
    """`direction(t, up)` (3,) for limb `limb`'s tangent `t` at its joint and the unit `up`,
    checked to lie across the limb (else `ValueError`: the limb runs along `up`)."""
    k = check_limb_index(limb, skeleton, "limb")
    up = np.asarray(as_float_array(up, "up", (3,)), float)
    if not (np.all(np.isfinite(up)) and np.any(up)):
        raise ValueError(f"`up` must be a finite non-zero direction (3,), got {up.tolist()}.")
    up = up / np.linalg.norm(up)
    tangent = np.asarray(registration.rests[k]._prepare()._jet(registration.joints[k])[1], float)
    towards = direction(tangent, up)
    if np.linalg.norm(towards - np.dot(towards, tangent) * tangent) < 1e-6:
        raise ValueError(f"limb {k} runs along `up` at its joint: it has no side to turn or nod "
                         "about; use fj.LimbPose(bend, towards=...).")
    return towards

"""`aim`: the pose that points a limb at a point, as an animator aims a bone."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._checks import as_float_array
from .joint_zone import joint_range
from .limb_pose import LimbPose
from .posing import SkeletonRegistration, carrying, check_limb_index, limb_target

_STEPS = 32  # bisection steps on the bend (degrees): 180° / 2³²
# Degrees: how far past the middle the angle is compared, above the bend's resolution.
_STEP = {np.dtype(np.float64): 1e-7, np.dtype(np.float32): 1e-3}
_REACHED = 0.05  # degrees: the chord that far from the point at best still points at it
_DIRECTION_STEPS = 8  # corrections of the bend's direction (each a bisection of its angle)


@eqx.filter_jit  # (one program for every call on a registration's limb: `limb` is static)
def _chord(registration, limb: int, origin, stop, bend, across):
    """The unit chord (3,) from limb `limb`'s joint at `origin` to its end (arc length `stop`),
    the limb bent by `bend` degrees towards `across`."""
    spine = limb_target(registration, limb, LimbPose(bend, towards=across))
    c = spine(stop) - origin
    return c / jnp.linalg.norm(c)


def aim(registration: SkeletonRegistration, skeleton, limb: int, point) -> LimbPose:
    """The `LimbPose` that bends limb `limb` at its joint so that its end points at `point`.

    **Arguments:** `registration`: the mesh's `register_skeleton`; `skeleton`: its
    `fj.Skeleton`; `limb`: a limb index; `point` (3,): in the mesh's coordinates at rest (a
    limb below a posed one turns with it).

    The bend is by the angle and towards the direction that put `point` on the line from the
    joint through the limb's end (its spine's end, or where its first child starts): the
    angle by bisection on the bent spine (its bending zone depends on the angle), the
    direction corrected until the chord reaches the point (a curved limb's chord turns out of
    the bend's plane). Solved on the limb alone: past its exact range a free only child
    carries the bend on (`fj.pose_skeleton`), so pose that child too (`fj.LimbPose()`) to
    keep the limb aimed there. Bends up to 180°. **Returns:** the `LimbPose`. **Raises**
    `ValueError` for a limb index of no limb, a `point` that is not a finite (3,) array,
    one on the limb's own axis at its joint (no direction to bend towards), or one no bend
    reaches (saying how near it comes).
    """
    k = check_limb_index(limb, skeleton, "limb")
    # (Its children, unposed, ride on its bend: `posing.WholeLimb`.)
    registration = carrying(registration, {k})[0]
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
    wanted = towards / np.linalg.norm(towards)
    tangent = _tangent(registration, k)

    def chord(bend, across):  # the unit chord from the joint to the limb's end, bent
        return _chord(registration, k, jnp.asarray(origin, dtype), stop, bend, across)

    def off(bend, across):  # the chord's angle to the point's direction
        c = np.asarray(chord(jnp.asarray(bend, dtype), jnp.asarray(across, dtype)), float)
        return float(np.arctan2(np.linalg.norm(np.cross(c, wanted)), c @ wanted))

    # The bend's direction about the tangent: first the point's, turned as the rest chord is
    # from the tangent; then corrected by the angle about the tangent between the chord
    # reached and the point (a curved limb's chord does not turn in the bend's plane).
    across = _rotated(_turning(_unit(np.asarray(rest(stop), float) - origin), wanted), tangent)
    across = across - (across @ tangent) * tangent
    if np.linalg.norm(across) < 1e-12:
        across = wanted - (wanted @ tangent) * tangent
    for _ in range(_DIRECTION_STEPS):
        best = _least(lambda bend: off(bend, across), np.dtype(dtype))
        if np.degrees(off(best, across)) <= _REACHED:
            break
        reached = np.asarray(chord(jnp.asarray(best, dtype), jnp.asarray(across, dtype)), float)
        across = _rotated(_turning(_flat(reached, tangent), _flat(wanted, tangent)), across)
    # Past its range a limb's zone grows towards all its room and its chord turns by less
    # than the bend (half of it over a whole-room arc): some points are out of its reach.
    miss = np.degrees(off(best, across))
    if miss > _REACHED:
        raise ValueError(
            f"`point`: limb {k} cannot point at {target.tolist()}: its chord comes within "
            f"{miss:.1f} degrees of it at best (a bend of {best:.1f} degrees, past its exact "
            f"range {joint_range(registration, k):.1f}); bend the limb below or above it "
            "too, or aim at a point nearer its rest direction.")
    return LimbPose(best, towards=across)


def _least(angle, dtype) -> float:
    """The bend in [0°, 180°] where `angle(bend)` is least: it falls as the chord turns
    towards the point and rises past it, so it is found by comparing it at the middle and a
    little past it, by bisection."""
    lo, hi = 0.0, 180.0
    for _ in range(_STEPS):
        middle = 0.5 * (lo + hi)
        lo, hi = (middle, hi) if angle(middle + _STEP[dtype]) < angle(middle) else (lo, middle)
    return 0.5 * (lo + hi)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _flat(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """`v`'s part across the unit `axis`, unit (or 0)."""
    across = v - (v @ axis) * axis
    size = np.linalg.norm(across)
    return across / size if size > 1e-12 else across


def _turning(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking the unit `a` to the unit `b` (the identity for
    opposite or null ones)."""
    axis, c = np.cross(a, b), float(a @ b)
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + cross + cross @ cross / (1 + c)


def _rotated(rotation: np.ndarray, v: np.ndarray) -> np.ndarray:
    return rotation @ v


def nod(registration: SkeletonRegistration, skeleton, limb: int, degrees, *, up,
        side=None) -> LimbPose:
    """A limb (a head) nodded `degrees` at its joint: turned about `side` (3,) by the
    right-hand rule, by default its own side `t × up` (`t` its tangent there), about which a
    positive angle raises it towards the world's `up` (3,) and a negative one lowers it. A limb
    along `up` (a biped's head) has no side of its own: give `side` (the character's left to
    right, say). Split into a bend and a twist as `turn` is. **Returns** the `LimbPose`;
    `ValueError` for a limb along `up` without `side`, or a `side` along the limb."""
    k = check_limb_index(limb, skeleton, "limb")
    # (Its children, unposed, ride on its bend: `posing.WholeLimb`.)
    registration = carrying(registration, {k})[0]
    up, tangent = _unit_up(up), _tangent(registration, k)
    if side is None:
        side = np.cross(tangent, up)
        if np.linalg.norm(side) < 1e-6:
            raise ValueError(f"limb {k} runs along `up` at its joint: it has no side of its own "
                             "to nod about; give `side=` (the character's left to right).")
    else:
        side = _unit_up(side, "side")
    return _rotation_pose(tangent, side / np.linalg.norm(side), float(degrees))


def turn(registration: SkeletonRegistration, skeleton, limb: int, degrees, *, up) -> LimbPose:
    """A limb (a head) turned `degrees` about the world's `up` (3,) at its joint, by the
    right-hand rule (positive: counter-clockwise seen from above). A head across `up` (a
    quadruped's) swings sideways; a head along it (a biped's) turns about its own axis, as a
    person looks aside. **Returns** the `LimbPose`."""
    k = check_limb_index(limb, skeleton, "limb")
    # (Its children, unposed, ride on its bend: `posing.WholeLimb`.)
    registration = carrying(registration, {k})[0]
    return _rotation_pose(_tangent(registration, k), _unit_up(up), float(degrees))


def _rotation_pose(tangent: np.ndarray, axis: np.ndarray, degrees: float) -> LimbPose:
    """The `LimbPose` whose part past the zone turns by `degrees` about the unit `axis`: the
    rotation `R` split into a swing and a twist about the limb's unit `tangent` `t` at its
    joint: bent by the angle from `t` to `R t`, towards `R t`, and twisted by
    `2 atan2((axis·t) sin(φ/2), cos(φ/2))`."""
    half = np.radians(degrees) / 2
    # R t by Rodrigues' formula (angle 2·half about axis).
    turned = (tangent * np.cos(2 * half) + np.cross(axis, tangent) * np.sin(2 * half)
              + axis * np.dot(axis, tangent) * (1 - np.cos(2 * half)))
    swing = np.degrees(np.arctan2(np.linalg.norm(np.cross(tangent, turned)),
                                  np.dot(tangent, turned)))
    twist = np.degrees(2 * np.arctan2(np.dot(axis, tangent) * np.sin(half), np.cos(half)))
    across = turned - np.dot(turned, tangent) * tangent
    if np.linalg.norm(across) < 1e-9:  # about the limb's own axis: a twist only
        return LimbPose(0.0, twist=twist)
    return LimbPose(swing, towards=across, twist=twist)


def _unit_up(up, name: str = "up") -> np.ndarray:
    """`up` (3,) as a unit vector, or `ValueError` naming it (`name`)."""
    up = np.asarray(as_float_array(up, name, (3,)), float)
    if not (np.all(np.isfinite(up)) and np.any(up)):
        raise ValueError(f"`{name}` must be a finite non-zero direction (3,), got "
                         f"{up.tolist()}.")
    return up / np.linalg.norm(up)


def _tangent(registration, k: int) -> np.ndarray:
    """Limb `k`'s unit tangent (3,) at its joint, at rest."""
    return np.asarray(registration.rests[k]._prepare()._jet(registration.joints[k])[1], float)

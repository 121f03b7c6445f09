"""`LimbPose`: how one limb of a skeleton is posed, in degrees, and the bent spine it makes."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._checks import as_float_array, is_concrete
from .._spines.bent import BentSpine
from .._spines.spine import AbstractSpine

FULL_TURN = 360.0  # degrees: the largest bend or twist a pose takes


class LimbPose(eqx.Module):
    """A limb's pose: its bend from the joint, the direction of the bend, its twist (degrees).

    **Arguments/fields** (scalars, degrees; differentiable):

    - `bend`: the angle the limb turns through at its joint: in a short zone past the joint
      (no kink there; as short as the map's validity allows for the angle, `fj.joint_range`),
      the limb past it moving rigidly. Past the limb's exact range in its direction, a
      limb's only child, if not posed, carries the rest of the bend on at its own joint
      (`fj.pose_skeleton`).
    - `direction`: the direction the limb bends towards, about its tangent at the joint,
      measured from the first normal of its rest spine's frame there.
    - `twist`: the turn of the limb about its tangent at the joint, in the same zone.
    - `towards` (3,), instead of `direction`: the direction the limb bends towards, in the
      mesh's coordinates at rest (a limb below a posed one turns with it): its part across
      the limb's tangent at the joint. `LimbPose(90, towards=(0, 0, 1))` raises a limb.

    `LimbPose()` is the rest pose. See `fj.BentSpine` for the spine it makes.
    """

    bend: Array
    direction: Array
    twist: Array
    towards: Array | None

    def __init__(self, bend: ArrayLike = 0.0, direction: ArrayLike = 0.0, twist: ArrayLike = 0.0,
                 *, towards: ArrayLike | None = None):
        if towards is None and _plain(bend, direction, twist):
            # A frame's poses, built anew each frame from Python numbers: kept on the host as
            # the general path keeps them (the same dtype, the same compiled frame), in about a
            # quarter of its time (its checks and conversions: 65 → 18 µs a pose, loaded).
            dtype = jax.dtypes.canonicalize_dtype(np.float64)
            self.bend, self.direction, self.twist = (
                np.asarray(float(v), dtype) for v in (bend, direction, twist))
            self.towards = None
            return
        # (A number is kept on the host: a jitted frame transfers it with its other arguments,
        # where putting each angle on the device was most of a pose's construction, 0.17 ms.)
        self.bend, self.direction, self.twist = (
            _strong(as_float_array(v, name, (), host=True))
            for v, name in ((bend, "bend"), (direction, "direction"), (twist, "twist")))
        for name, value in (("bend", bend), ("direction", direction), ("twist", twist)):
            boolean = np.dtype(getattr(value, "dtype", float)) == np.bool_
            if isinstance(value, bool | np.bool_) or boolean:
                raise TypeError(f"`{name}` must be an angle in degrees, got {value!r}.")
            value = getattr(self, name)
            if is_concrete(value) and not np.isfinite(float(value)):
                raise ValueError(f"`{name}` must be a finite angle in degrees, got {float(value)}.")
            if name != "direction" and is_concrete(value) and abs(float(value)) > FULL_TURN:
                raise ValueError(f"`{name}` must be at most a full turn ({FULL_TURN:g} degrees) "
                                 f"either way, got {float(value):g}.")
        self.towards = (None if towards is None
                        else as_float_array(towards, "towards", (3,), host=True))
        if self.towards is not None and is_concrete(self.towards):
            if not np.all(np.isfinite(self.towards)) or not np.any(self.towards):
                raise ValueError(f"`towards` must be a finite non-zero direction (3,), got "
                                 f"{np.asarray(self.towards).tolist()}.")
            if is_concrete(self.direction) and float(self.direction) != 0:
                raise ValueError("give the bend's `direction` or `towards`, not both.")

    def radians(self, rest: AbstractSpine, joint: Array) -> tuple[Array, Array, Array]:
        """`(bend, direction, twist)` in radians, in `rest`'s dtype, the direction measured
        from the first normal of `rest`'s frame at arc length `joint` (`towards` read there):
        the arguments of the `fj.BentSpine` the pose makes."""
        dtype = rest.length.dtype
        bend, direction, twist = (jnp.deg2rad(v).astype(dtype)
                                  for v in (self.bend, self.direction, self.twist))
        if self.towards is not None:
            direction = _direction_of(rest, joint, self.towards.astype(dtype))
        return bend, direction, twist

    def spine(self, rest: AbstractSpine, joint: Array, stop: Array) -> BentSpine:
        """The limb's `rest` spine bent by this pose from arc length `joint` to `stop`."""
        bend, direction, twist = self.radians(rest, joint)
        return BentSpine(rest, joint=joint, stop=stop, bend=bend, direction=direction,
                         twist=twist)


def _plain(bend, direction, twist) -> bool:
    """Whether the angles are Python numbers (not bools) within a full turn either way, which
    `LimbPose` takes as they are (others take the general path, which says what is wrong)."""
    return all(type(v) in (float, int) and abs(v) <= FULL_TURN for v in (bend, direction, twist))


def _strong(angle: Array) -> Array:
    """`angle` not weakly typed: a jitted frame's program is keyed on its arguments' types,
    and `jnp.asarray(60.0)` (weak) then `60.0` (strong) would compile it twice."""
    if getattr(angle, "weak_type", False):
        return jax.lax.convert_element_type(angle, angle.dtype)
    return angle


def _direction_of(rest: AbstractSpine, joint: Array, towards: Array) -> Array:
    """The bend direction (radians, from the first normal of `rest`'s frame at `joint`) of the
    world direction `towards` (3,); `ValueError` where it runs along the limb (concrete)."""
    (_, tangent, _), (first, second) = rest._prepare()._jet_and_normals(joint)
    x, y = jnp.dot(towards, first), jnp.dot(towards, second)
    across = jnp.hypot(x, y)
    if is_concrete(across) and float(across) <= 1e-6 * float(jnp.linalg.norm(towards)):
        raise ValueError(
            f"`towards` {np.asarray(towards).tolist()} runs along the limb's tangent at its "
            f"joint, {np.round(np.asarray(tangent), 6).tolist()}: it names no bend direction."
        )
    # (Safe at x = y = 0 under tracing: that direction is refused eagerly.)
    safe = across > 0
    return jnp.where(safe, jnp.arctan2(y, jnp.where(safe, x, 1.0)), 0.0)


def sane_angles(pose: LimbPose) -> Array:
    """Whether `pose`'s angles are finite and its bend and twist at most a full turn (scalar
    bool): what a traced pose cannot refuse, and flags instead."""
    angles = jnp.stack([pose.bend, pose.direction, pose.twist])
    turns = jnp.abs(jnp.stack([pose.bend, pose.twist]))
    finite = jnp.all(jnp.isfinite(angles))
    if pose.towards is not None:
        finite = finite & jnp.all(jnp.isfinite(pose.towards))
    return finite & jnp.all(turns <= FULL_TURN)

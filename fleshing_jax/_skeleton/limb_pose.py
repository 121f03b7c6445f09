"""`LimbPose`: how one limb of a skeleton is posed, in degrees, and the bent spine it makes."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._checks import as_float_array, is_concrete
from .._spines.bent import BentSpine
from .._spines.spine import AbstractSpine


class LimbPose(eqx.Module):
    """A limb's pose: its bend from the joint, the direction of the bend, its twist (degrees).

    **Arguments/fields** (scalars, degrees; differentiable):

    - `bend`: the angle the limb turns through, spread smoothly along it from its joint (no
      kink there) to its end (or where its first child limb starts).
    - `direction`: the direction the limb bends towards, about its tangent at the joint,
      measured from the first normal of its rest spine's frame there.
    - `twist`: the turn of the limb about its tangent at the joint, spread as the bend.

    `LimbPose()` is the rest pose. See `fj.BentSpine` for the spine it makes.
    """

    bend: Array
    direction: Array
    twist: Array

    def __init__(self, bend: ArrayLike = 0.0, direction: ArrayLike = 0.0, twist: ArrayLike = 0.0):
        self.bend = as_float_array(bend, "bend", ())
        self.direction = as_float_array(direction, "direction", ())
        self.twist = as_float_array(twist, "twist", ())
        for name in ("bend", "direction", "twist"):
            value = getattr(self, name)
            if is_concrete(value) and not np.isfinite(float(value)):
                raise ValueError(f"`{name}` must be a finite angle in degrees, got {float(value)}.")

    def spine(self, rest: AbstractSpine, joint: Array, stop: Array) -> BentSpine:
        """The limb's `rest` spine bent by this pose from arc length `joint` to `stop`."""
        dtype = rest.length.dtype
        angle = [jnp.deg2rad(v).astype(dtype) for v in (self.bend, self.direction, self.twist)]
        return BentSpine(rest, joint=joint, stop=stop, bend=angle[0], direction=angle[1],
                         twist=angle[2])

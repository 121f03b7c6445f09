"""Why points are invalid, and how far an arc may bend before any point is.

For people bending real meshes: a count of invalid vertices says little; these say which of
the three conditions failed (the source's reach, the method's bending limit, the target's
reach) and which arc would have kept every vertex valid.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._batching.buckets import bucket, pad_batch, unpad_batch
from .._batching.chunks import batch_axes
from .._checks import is_concrete
from .._numerics import cast_floats
from .._spines.analytic import Arc, Line
from .._spines.frames import rotation_minimizing_frame
from .._spines.spine import AbstractSpine
from .ends import aligned_twist
from .pipeline import bend_checks, pose
from .projection import Registration
from .target import TargetFrames


class Causes(NamedTuple):
    """Counts of invalid points by their first failed condition (in this order)."""

    points: int  # all points
    outside_source: int  # not finite, or not strictly inside the source's local reach
    beyond_limit: int  # the method's unbend/bend equations have no solution (too bent)
    # the image outside the target's reach or search range, or not projecting back on it at
    # the mapped arc length only (with the margin):
    outside_target: int
    # inside the source's local reach, but within the margin of its cut locus or focal set:
    # beyond the spine's reach, where the map is discontinuous (`region`)
    beyond_reach: int = 0

    @property
    def invalid(self) -> int:
        return self.outside_source + self.beyond_limit + self.outside_target + self.beyond_reach


def diagnose(
    registration: Registration,
    target: AbstractSpine,
    *,
    method: str = "radial",
    twist: ArrayLike = 0.0,
    check_projection: bool = True,
    margin: ArrayLike = 0.0,
    beyond: str = "continue",
) -> Causes:
    """Counts the invalid points of `pose(registration, target, ...)` by cause.

    A point is counted once, under the first condition it fails: the source's local reach,
    the source's cut locus (`beyond_reach`, from `registration.discontinuous`), the method's
    bending limit, the target's reach (which includes the projection check, with `margin`).
    """
    options = dict(method=method, twist=twist, check_projection=check_projection, margin=margin,
                   beyond=beyond)
    _, valid = pose(registration, target, **options)
    dtype = registration.points.dtype
    n = registration.points.shape[0]  # (padded as in `pose`: one program per bucket of sizes)
    padded = pad_batch(registration, bucket(n)) if is_concrete(registration) else registration
    registered, within = unpad_batch(
        _checks(padded, cast_floats(target, dtype)._bucketed(), method, jnp.asarray(twist, dtype)),
        n,
    )
    registered, within, valid = (np.asarray(a) for a in (registered, within, valid))
    discontinuous = np.asarray(registration.discontinuous)
    outside_source = int(np.sum(~registered & ~discontinuous))
    beyond_limit = int(np.sum(registered & ~within))
    outside_target = int(np.sum(registered & within & ~valid))
    return Causes(
        len(valid), outside_source, beyond_limit, outside_target, int(np.sum(discontinuous))
    )


@eqx.filter_jit
def _checks(registration, target, method, twist):
    target = target._prepare()
    frames = TargetFrames(target, aligned_twist(registration.ends, target, twist))

    def one(reg):
        _, (registered, within_limit, _), _, _ = bend_checks(reg, frames, method)
        return registered, within_limit

    return jax.vmap(one, in_axes=(batch_axes(registration),))(registration)


def planar_bend(spine: AbstractSpine, angle: float) -> AbstractSpine:
    """The arc of `spine`'s length that starts as `spine` does and turns by `angle` (radians)
    towards its initial normal `I(0)` (a negative angle turns the other way; 0 is a line)."""
    return _arc_from(_start_frame(spine), float(spine.length), angle)


def _arc_from(start: tuple, length: float, angle: float) -> AbstractSpine:
    """`planar_bend` from the spine's `_start_frame` and length (computed once per bisection:
    the frame at 0 of a free-form spine is an eager evaluation of many small operations)."""
    origin, tangent, normal = start
    if angle == 0:
        return Line(length, origin=origin, tangent=tangent)
    if angle < 0:
        normal, angle = -normal, -angle
    return Arc(length / angle, length, origin=origin, tangent=tangent, normal=normal)


def _start_frame(spine: AbstractSpine):
    frame = np.asarray(rotation_minimizing_frame(spine, 0.0), dtype=np.float64)
    return np.asarray(spine(0.0), dtype=np.float64), frame[0], frame[1]


def largest_valid_bend(
    registration: Registration,
    source: AbstractSpine,
    *,
    method: str = "radial",
    twist: ArrayLike = 0.0,
    check_projection: bool = True,
    margin: ArrayLike = 0.0,
    beyond: str = "continue",
    sign: float = 1.0,
    steps: int = 16,
) -> float:
    """The largest angle (radians, ≤ 2π·(1 − 1e-6)) of `planar_bend(source, sign·angle)` for
    which every point whose registration is valid stays valid, by bisection (`steps` poses;
    16 bring the bracket below 0.006°, finer than the 0.01° that the command line prints).

    Validity is assumed monotone in the angle (true for the method limits and the reach of an
    arc, which tighten as it bends); 0 when no bend at all keeps them valid.
    """
    keep = np.asarray(registration.valid)
    start, length = _start_frame(source), float(source.length)

    def all_valid(angle: float) -> bool:
        target = _arc_from(start, length, sign * angle)
        options = dict(check_projection=check_projection, margin=margin, beyond=beyond)
        _, valid = pose(registration, target, method=method, twist=twist, **options)
        return bool(np.all(np.asarray(valid)[keep]))

    hi = 2 * np.pi * (1 - 1e-6)
    if all_valid(hi):
        return hi
    lo = 0.0
    if not all_valid(lo):
        return 0.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if all_valid(mid) else (lo, mid)
    return lo

"""Where a posed limb bends: a short zone past its joint, as long as its angle needs.

An animator's joint turns the bone past it rigidly; only the flesh around the joint deforms.
Fleshing bends a limb through a zone `[joint, joint + L]` of its rest spine (`fj.BentSpine`:
a ramped bend, rigid past the zone, carrying the children); the shorter the zone, the more
the limb past it is one rigid piece, and the higher the curvature the zone needs. The radial
map exists while `κ·ρ < 1/√3` for a point at distance `ρ` on the concave side, so the zone is
the shortest one in which every vertex keeps `k₁·d* ≤ k₀·d* + κ |d*| ≤ JOINT_CURVATURE`, with
`d*` its unbent offset, `k₀` the rest spine's curvature and `κ` the bend's, in any direction:
with the ramp's plateau `4/3`, a bend of `θ` radians over a zone of length `L` has
`κ ≤ 4θ/(3L)`.

At registration, each limb gets a table: for zone lengths from the limb's radius at the joint
to all of its room to bend (`stop − joint`), the largest bend the zone allows (`JointZone`). A pose
reads the zone for its angle by interpolation: continuous and non-decreasing in the angle, so
a sweep of the angle moves every vertex continuously; past the largest angle the zone is the
whole room, as before joints were concentrated, and the vertices beyond the map's reach are
flagged.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._fleshing.maps import WHOLE_FROM

# κ·ρ kept in a zone: below the radial map's limit 1/√3 ≈ 0.577, where its concave side would
# be crushed flat; at 0.45 a vertex's principal stretch stays below about 2.5. Below where a
# pose's whole map leaves the exact one (`maps.WHOLE_FROM`), with room for the interpolated
# zone's few per cent.
JOINT_CURVATURE = 0.45
ZONE_LENGTHS = 32  # the zone lengths tabulated, evenly spaced up to the room to bend
_PLATEAU = 4.0 / 3.0  # the largest slope of `fj.BentSpine`'s ramp (`_spines.bent.ramp`)


class JointZone(eqx.Module):
    """A limb's bending zones: `capacities` (Z,) radians, increasing (its last ones may repeat),
    `lengths` (Z,), non-decreasing and ending at the limb's room to bend, and `slopes` (Z,):
    a zone of `lengths[i]` keeps the curvature bound for bends up to `capacities[i]` (see the
    module's docstring), and the zone's length between them is the monotone cubic through
    these points with these slopes (Fritsch–Carlson): continuous in the angle with its first
    derivative, so that a fit of the angle sees no kink."""

    lengths: Array
    capacities: Array
    slopes: Array
    # The largest bend over the whole room that keeps every vertex's `k₁·d*` below the map's
    # own `maps.WHOLE_FROM` (scalar radians, at least the range): past the range the zone is
    # the whole room, and the map is exact up to about this bend.
    exact: Array

    def length(self, bend: Array) -> Array:
        """The zone's length for a bend of `bend` radians (scalar, either sign): the shortest
        that keeps the map's curvature bound, interpolated; the whole room past the range."""
        x, y, m = self.capacities, self.lengths, self.slopes
        angle = jnp.clip(jnp.abs(bend), x[0], x[-1])
        i = jnp.clip(jnp.searchsorted(x, angle, side="right") - 1, 0, x.shape[0] - 2)
        width = x[i + 1] - x[i]
        safe = jnp.where(width > 0, width, 1)
        t = jnp.where(width > 0, (angle - x[i]) / safe, 0)
        # Cubic Hermite on [x_i, x_{i+1}].
        h00, h10 = (1 + 2 * t) * (1 - t) ** 2, t * (1 - t) ** 2
        h01, h11 = t**2 * (3 - 2 * t), t**2 * (t - 1)
        return h00 * y[i] + h10 * safe * m[i] + h01 * y[i + 1] + h11 * safe * m[i + 1]

    @property
    def range(self) -> Array:
        """The largest bend (radians) the limb takes with its curvature bound kept."""
        return self.capacities[-1]


def _monotone_slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Fritsch–Carlson slopes (n,) of a monotone C¹ cubic through increasing `x`, non-decreasing
    `y` (n,): flat at both ends, where the length is constant beyond them."""
    secant = np.diff(y) / np.diff(x)
    slopes = np.zeros_like(y)
    inner = (secant[:-1] > 0) & (secant[1:] > 0)
    # The weighted harmonic mean keeps each piece monotone.
    w1, w2 = 2 * np.diff(x)[1:] + np.diff(x)[:-1], np.diff(x)[1:] + 2 * np.diff(x)[:-1]
    slopes[1:-1][inner] = ((w1 + w2) / (w1 / secant[:-1] + w2 / secant[1:]))[inner]
    return slopes


def joint_zone(arc_length: np.ndarray, offset: np.ndarray, curvature: np.ndarray,
               valid: np.ndarray, joint: float, stop: float, dtype) -> JointZone:
    """A limb's `JointZone`, from its region's registration on its rest spine: per vertex (n,)
    `arc_length`, `offset` (n, 2) and rest `curvature` (n, 2) in the frame there, and `valid`
    (n,); `joint`, `stop`: where the limb's bend may start and must be complete."""
    room = stop - joint
    s = np.asarray(arc_length, float)
    keep = np.asarray(valid, bool) & (s >= joint) & (s <= stop)
    s = s[keep]
    d, k = np.asarray(offset, float)[keep], np.asarray(curvature, float)[keep]
    # The shortest zone is the limb's thickness at the joint: the flesh of a joint deforms
    # over about its radius (and a shorter zone's valid region, sampled on the bent spine,
    # flagged the joint's own vertices on the posing tests' tube).
    near = s <= joint + room / 8
    shortest = min(float(np.max(np.linalg.norm(d[near], axis=1), initial=0.0)), room)
    lengths = np.linspace(max(shortest, room / ZONE_LENGTHS), room, ZONE_LENGTHS)
    rest = np.sum(k * d, axis=1)
    # The offset unbent (the radial map's `d* = d √(1 − (2/3) k₀·d)`): the bent curvature acts
    # on it, `k₁·d* = k₀·d* + κ n·d*` with `n` the bend's direction, at most `κ |d*|`.
    unbent = np.sqrt(np.maximum(1 - (2 / 3) * rest, 0))
    allowed = (np.maximum(JOINT_CURVATURE - rest * unbent, 0.0)
               / np.maximum(np.linalg.norm(d, axis=1) * unbent, 1e-300))
    # A zone reaching arc length s is bounded by every vertex before s.
    curvature_bound = np.full(ZONE_LENGTHS, np.inf)  # (an empty zone bounds nothing)
    if len(s):
        order = np.argsort(s)
        bound = np.minimum.accumulate(allowed[order])
        reached = np.searchsorted(s[order], joint + lengths, side="right")
        curvature_bound = np.where(reached > 0, bound[np.maximum(reached - 1, 0)], np.inf)
    capacities = np.minimum(lengths * curvature_bound / _PLATEAU, 2 * np.pi)
    whole_bound = np.min(np.maximum(WHOLE_FROM - rest * unbent, 0.0)
                         / np.maximum(np.linalg.norm(d, axis=1) * unbent, 1e-300), initial=np.inf)
    # A zone's capacity falls where a thick part enters it; a bend must not then be given
    # the shorter zone before the thick part and the longer one past it by turns. So each zone
    # is credited with the least capacity of the longer ones (non-decreasing; every zone still
    # keeps its bound), and a run of equal capacities reads its longest zone: the length then
    # grows continuously with the angle, up to each run's end.
    capacities = np.minimum.accumulate(capacities[::-1])[::-1]
    # A run's points share its longest zone: one knot a run, the last repeated to keep Z.
    capacities, last = np.unique(capacities[::-1], return_index=True)
    lengths = lengths[::-1][last]
    slopes = (_monotone_slopes(capacities, lengths) if len(capacities) > 1
              else np.zeros_like(capacities))
    pad = ZONE_LENGTHS - len(capacities)
    capacities, lengths, slopes = (np.pad(a, (0, pad), mode="edge")
                                   for a in (capacities, lengths, slopes))
    exact = max(float(capacities[-1]), min(room * whole_bound / _PLATEAU, 2 * np.pi))
    return JointZone(*(jnp.asarray(a, dtype) for a in (lengths, capacities, slopes, exact)))


def joint_range(registration, limb: int) -> Array:
    """The largest bend (degrees, scalar) limb `limb` takes at its joint within the map's
    curvature bound, in every direction: its region is bent, in the shortest zone past the
    joint the angle needs, with every vertex's `k₁·d* ≤ JOINT_CURVATURE` (below the radial
    map's `1/√3`). Past it the zone is the limb's whole room and vertices may be flagged.

    **Arguments:** `registration`: a `register_skeleton` (`SkeletonRegistration`); `limb`:
    a limb index of its skeleton. **Raises** `ValueError` for another limb index.
    """
    zones = registration.zones
    if isinstance(limb, bool) or not isinstance(limb, int | np.integer) or not (
            0 <= limb < len(zones)):
        raise ValueError(
            f"`limb`: {limb!r} is not a limb index of this registration (0 to {len(zones) - 1})."
        )
    return jnp.rad2deg(zones[limb].range)

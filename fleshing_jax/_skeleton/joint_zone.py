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

The table holds in every direction. A pose bends in one: the zone also keeps, per vertex, what
gives its `k₁·d*` on the bent spine in any direction and twist (`JointZone.margins`), so that
a pose knows whether the map over its zone is exact where it is asked to bend, not at each
vertex's worst direction.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import is_concrete
from .._fleshing.maps import WHOLE_FROM
from .._numerics import dot, on_device
from .._spines.bent import ramp, rotate
from .skeleton import limb_index

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
    derivative, so that a fit of the angle sees no kink.

    For the map's exactness in a given direction (`margins`), per registered vertex (N,) (rows
    of vertices not validly registered, or outside `[joint, stop]`, are zero: they bound
    nothing): `arc` its arc length, `rests` its `k₀·d*`, `moments` (N, 3) `T₀ × D` and
    `twisting` `(t × T₀)·D`, with `D` its unbent offset `d*` in space and `T₀` the rest
    spine's tangent there; `axes` (3, 3): the rest spine's tangent `t` and normals `(I, J)` at
    the joint (rows)."""

    lengths: Array
    capacities: Array
    slopes: Array
    axes: Array
    arc: Array
    rests: Array
    moments: Array
    twisting: Array

    def length(self, bend: Array) -> Array:
        """The zone's length for a bend of `bend` radians (scalar, either sign): the shortest
        that keeps the map's curvature bound, interpolated; the whole room past the range.
        Concrete, computed on the host (`_host`)."""
        xp = _host(self, bend)
        x, y, m = (xp.asarray(a) for a in (self.capacities, self.lengths, self.slopes))
        angle = xp.clip(xp.abs(bend), x[0], x[-1])
        # (Traced, by comparing with every capacity, one kernel: XLA's CPU backend ran the
        # binary search's loop step by step, a few kernels a step, for every posed limb.)
        found = (np.searchsorted(x, angle, side="right") if xp is np
                 else jnp.searchsorted(x, angle, side="right", method="compare_all"))
        i = xp.clip(found - 1, 0, x.shape[0] - 2)
        width = x[i + 1] - x[i]
        safe = xp.where(width > 0, width, 1)
        t = xp.where(width > 0, (angle - x[i]) / safe, 0)
        # Cubic Hermite on [x_i, x_{i+1}]. (Squares as products: numpy's scalar power is not
        # always the product's bits, which XLA's `x**2` is.)
        u, v = (1 - t) * (1 - t), t * t
        h00, h10 = (1 + 2 * t) * u, t * u
        h01, h11 = v * (3 - 2 * t), v * (t - 1)
        return h00 * y[i] + h10 * safe * m[i] + h01 * y[i + 1] + h11 * safe * m[i + 1]

    def end(self, bend: Array, joint: Array, stop: Array) -> Array:
        """Where a bend of `bend` radians (scalar) is complete, past `joint`, at most `stop`
        (scalar arc lengths: the limb's joint and its room's end). Concrete, computed on the
        host (`_host`), as a 0-d array of the joint's dtype."""
        # (`minimum`: the whole room in single precision is at most the stop, not an ulp past.)
        xp = _host(self, bend, joint, stop)
        return xp.minimum(xp.asarray(joint) + self.length(bend), xp.asarray(stop))

    @property
    def range(self) -> Array:
        """The largest bend (radians) the limb takes with its curvature bound kept."""
        return self.capacities[-1]

    def margins(self, bend: Array, direction: Array, twist: Array, joint: Array,
                stop: Array) -> Array:
        """How far each vertex (N,) is past where the radial map over the zone stops being
        exact, `(k₁·d* − WHOLE_FROM) / max(WHOLE_FROM − k₀·d*, WHOLE_FROM / 2)`: `≤ 0` where it
        is exact; for the vertex's own `k₁·d*` linear in the bend, the bend's relative excess
        over where that vertex leaves it, `(θ − θᵢ)/θᵢ` (clamped denominators: a vertex already
        near the bound at rest is not given an abrupt ramp). Continuous in every argument.

        **Arguments** (scalars, radians; arc lengths): the `fj.BentSpine`'s `bend`,
        `direction` (from `I` at the joint), `twist`, `joint` and `stop`.

        The bent spine's curvature in its frame, which turns with the bend, is `k₀ + Qᵀ Q′ T₀`
        (`fj.BentSpine`: `Q = R_a(θ r) R_t(ψ r)`, `a = t × (cos φ I + sin φ J)`), and `Qᵀ Q′ T₀
        = r′ (θ R_t(−ψ r) a × T₀ + ψ t × T₀)`: the twist turns the bend's direction in the frame
        by `−ψ r` along the zone, and on a curved rest spine adds a curvature of its own.
        """
        width = stop - joint
        r, slope = ramp(jnp.clip((self.arc - joint) / width, 0, 1))
        t, first, second = self.axes
        axis = jnp.cross(t, jnp.cos(direction) * first + jnp.sin(direction) * second)
        turned = jax.vmap(rotate, in_axes=(None, 0, None))(t, -twist * r, axis)
        # (An explicit dot, `_numerics.dot`: a sum over the short axis ran as a reduction, a
        # frame of spot's head at 104,644 vertices CPU 3.4 → 3.0 ms.)
        bent = (slope / width) * (bend * dot(turned, self.moments) + twist * self.twisting)
        room = jnp.maximum(WHOLE_FROM - self.rests, WHOLE_FROM / 2)
        return (self.rests + bent - WHOLE_FROM) / room

    def reach(self, direction: Array, joint: Array, stop: Array) -> Array:
        """The largest bend (radians, scalar, `inf` where none leaves it) towards `direction`
        (radians from `I`), without a twist, that keeps the radial map exact over the whole
        room `[joint, stop]` (every `margins ≤ 0`): there each vertex's `k₁·d*` is linear in
        the bend, `k₀·d* + θ cᵢ`, so the bound is `minᵢ (WHOLE_FROM − k₀·d*) / cᵢ` over
        `cᵢ > 0`. Past the table's `range` a pose's zone is the whole room: this is then the
        limb's exact range in that direction (`joint_range`'s, in closed form: traceable)."""
        width = stop - joint
        _, slope = ramp(jnp.clip((self.arc - joint) / width, 0, 1))
        t, first, second = self.axes
        axis = jnp.cross(t, jnp.cos(direction) * first + jnp.sin(direction) * second)
        rate = (slope / width) * jnp.sum(axis * self.moments, axis=-1)
        # (Rows that bound nothing, padded or unregistered, have zero moments: no rate.)
        rising = rate > 0
        bounds = (WHOLE_FROM - self.rests) / jnp.where(rising, rate, 1)
        return jnp.min(jnp.where(rising, bounds, jnp.inf))


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
               valid: np.ndarray, joint: float, stop: float, dtype, *, frames: tuple,
               axes: np.ndarray) -> JointZone:
    """A limb's `JointZone`, from its region's registration on its rest spine: per vertex (n,)
    `arc_length`, `offset` (n, 2) and rest `curvature` (n, 2) in the frame there, and `valid`
    (n,); `joint`, `stop`: where the limb's bend may start and must be complete; `frames`:
    the rest spine's `(tangent, I, J)` (each (n, 3)) at each vertex's arc length, and `axes`
    (3, 3) its `(tangent, I, J)` at `joint` (rows)."""
    room = stop - joint
    s = np.asarray(arc_length, float)
    keep = np.asarray(valid, bool) & (s >= joint) & (s <= stop)
    margins = _margin_rows(keep, offset, curvature, s, frames, axes)
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
    return JointZone(*(on_device(a, dtype) for a in (lengths, capacities, slopes, axes,
                                                     *margins)))


def _margin_rows(keep, offset, curvature, s, frames, axes) -> tuple:
    """`JointZone`'s per-vertex fields `(arc, rests, moments, twisting)` (see there), zero
    where not `keep` and where a vertex's `k₀·d*` is already past `WHOLE_FROM` at rest (the
    map flags it in every pose; a blend it started would move the rest pose)."""
    d, k = np.asarray(offset, float), np.asarray(curvature, float)
    rest = np.sum(k * d, axis=1)
    unbent = np.sqrt(np.maximum(1 - (2 / 3) * rest, 0))
    tangent, first, second = (np.asarray(f, float) for f in frames)
    offsets = unbent[:, None] * (d[:, :1] * first + d[:, 1:] * second)
    rests = rest * unbent
    keep = keep & (rests < WHOLE_FROM)
    moments = np.cross(tangent, offsets)
    twisting = np.sum(np.cross(np.asarray(axes, float)[0], tangent) * offsets, axis=1)
    return (np.where(keep, s, 0.0), np.where(keep, rests, 0.0),
            np.where(keep[:, None], moments, 0.0), np.where(keep, twisting, 0.0))


def joint_range(registration, limb: int, direction=None, *, twist=0.0,
                towards=None, children_posed: bool = False) -> Array:
    """The largest bend (degrees, scalar) limb `limb` takes at its joint exactly.

    Without a direction: in every direction, within the map's curvature bound: its region is
    bent, in the shortest zone past the joint the angle needs, with every vertex's `k₁·d* ≤
    JOINT_CURVATURE` (below the radial map's `1/√3`); past it the zone is the limb's whole
    room. With a `direction` (degrees, as `fj.LimbPose`'s) or `towards` (3,), and a `twist`:
    the largest bend in that direction up to which every bend keeps the radial map exact over
    its zone (every vertex's `k₁·d* ≤ maps.WHOLE_FROM`: `JointZone.margins`), where a pose is
    neither blended nor flagged for its curvature (at least the range without a twist;
    360 where no bend leaves it; 0 where the twist alone does).

    A limb with several children (a head with its ears) bends them with it where they are not
    posed (`posing.WholeLimb`), and its zone may run on past them; a limb with one child
    left free has it carry a bend past its own range on (`fj.pose_skeleton`'s `spill`), and
    its range in a direction counts the child's (and its free only child's in turn): the
    largest bend with no vertex past the map's exact range. `children_posed=True`: the range
    when a child is posed too, the limb's zone then ending before their borders, alone.

    **Arguments:** `registration`: a `register_skeleton` (`SkeletonRegistration`); `limb`:
    a limb index of its skeleton or the limb's name; `direction`, `twist`, `towards`: as
    `fj.LimbPose`'s; `children_posed`: bool.
    **Raises** `ValueError` for another limb index or name, or a direction as `fj.LimbPose`
    does.
    """
    limb = limb_index(limb, registration.names or ("",) * len(registration.zones), "limb",
                      "registration")
    whole = None if children_posed else registration.wholes[limb]
    zone, joint, stop = ((registration.zones[limb], registration.joints[limb],
                          registration.stops[limb]) if whole is None
                         else (whole.zone, whole.joint, whole.stop))
    if direction is None and towards is None and twist == 0:
        return jnp.rad2deg(zone.range)
    from .limb_pose import LimbPose
    from .spill import carried_range

    pose = LimbPose(0.0, 0.0 if direction is None else direction, twist, towards=towards)
    _, phi, psi = pose.radians(registration.rests[limb], joint)
    own = _directed_range(zone, phi, psi, joint, stop)
    children = registration.children[limb]
    if whole is None and len(children) == 1 and not children_posed:
        own = carried_range(registration, limb, own, phi, psi)
    return jnp.rad2deg(jnp.asarray(own, joint.dtype))


def _directed_range(zone: JointZone, direction: Array, twist: Array, joint: Array,
                    stop: Array) -> float:
    """The largest bend (radians; 2π where none leaves it) towards `direction` with `twist`
    (radians) up to which every bend keeps the radial map exact over its zone."""
    bends = jnp.linspace(0, 2 * np.pi, _SCANNED, dtype=joint.dtype)
    excess = np.asarray(_excess(zone, bends, direction, twist, joint, stop))
    past = np.flatnonzero(excess > 0)
    if not len(past):
        return 2 * np.pi
    if past[0] == 0:
        return 0.0
    # Between the last exact bend scanned and the first inexact one, by bisection.
    lo, hi = float(bends[past[0] - 1]), float(bends[past[0]])
    for _ in range(_BISECTIONS):
        middle = 0.5 * (lo + hi)
        inexact = float(_excess(zone, jnp.asarray([middle], joint.dtype), direction, twist,
                                joint, stop)[0]) > 0
        lo, hi = (lo, middle) if inexact else (middle, hi)
    return lo


def _host(*values):
    """`numpy` where every one of `values` is concrete, else `jax.numpy`: an eager pose reads
    each limb's zone four times (`posing.bend_stop`), and its dozen scalar operations, run one
    by one as device operations, cost 4 ms of CPU a call (a shape fit's warm call made 24).
    The same IEEE operations on the same dtypes: the same bits (no contraction into fused
    multiply-adds, which a compiled program of them may make)."""
    return np if is_concrete(values) else jnp


_SCANNED = 721  # bends scanned from 0 to a full turn (every half degree) by `joint_range`
_BISECTIONS = 30  # then halving the half degree: to 5e-10 degrees


@eqx.filter_jit
def _excess(zone: JointZone, bends: Array, direction: Array, twist: Array, joint: Array,
            stop: Array) -> Array:
    """The largest `JointZone.margins` (B,) at each of `bends` (B,) radians."""
    def largest(bend):
        return jnp.max(zone.margins(bend, direction, twist, joint, zone.end(bend, joint, stop)))

    return jax.vmap(largest)(bends)

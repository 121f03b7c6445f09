"""Analytic spines: line, circular arc and circular helix, with closed-form frames.

Their rotation-minimising frames are exact: constant for a line, the Frenet frame rotated by a
constant angle for a planar arc, and the Frenet frame rotated by `−τ s` for a helix.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._batching.buckets import bucket
from .._checks import as_float_array, check_positive, is_concrete, unit
from .._numerics import dot, norm
from .sinusoid import turn
from .spine import AbstractSpine, initial_normal


class Line(AbstractSpine):
    """The straight spine `C(s) = origin + s · tangent`, `s ∈ [0, length]`.

    **Arguments:**

    - `length`: positive scalar.
    - `origin`: (3,) start point.
    - `tangent`: (3,) direction (normalised here).
    """

    length: Array
    origin: Array
    direction: Array

    def __init__(self, length: ArrayLike, *, origin=(0.0, 0.0, 0.0), tangent=(1.0, 0.0, 0.0)):
        self.length = as_float_array(length, "length", ())
        self.origin = as_float_array(origin, "origin", (3,))
        self.direction = unit(as_float_array(tangent, "tangent", (3,)), "tangent")
        check_positive(self.length, "length")

    def _jet(self, s):
        return self.origin + s * self.direction, self.direction, jnp.zeros_like(self.direction)

    def _normals(self, s):
        normal = initial_normal(self.direction)
        return normal, jnp.cross(self.direction, normal)

    def _torsion(self, s):
        return jnp.zeros_like(s)

    def _closest_start(self, x, lo, hi):
        # The continuation of a line is the line: the foot is unique everywhere.
        s = dot(x - self.origin, self.direction)
        return s, (s > lo) & (s < hi)

    def _foot_is_unique(self, s, lo, hi):
        # A point's foot on a line is the plane through it normal to the line.
        return jnp.ones_like(s, dtype=bool)

    def _is_cheap(self):
        return True

    def _continues_as_itself(self):
        return True

    # The search's and the registration's terms in closed form (constant normals, no
    # curvature): a few multiply-adds a point, where the generic terms, even from the
    # closed-form jet, keep the curvature's products (the tube's float32 registration on one
    # core: 8.7 ms, against 20.6 ms with the generic terms).
    def _foot_terms(self, x, s):
        d = x - self.origin - s * self.direction
        return -dot(d, self.direction), jnp.ones_like(s), norm(d)

    def _local_terms(self, x, s):
        i, j = self._normals(s)
        d = x - self.origin - s * self.direction
        offset = jnp.stack([dot(d, i), dot(d, j)])
        return offset, jnp.zeros_like(offset), jnp.ones_like(s)


class Arc(AbstractSpine):
    """The circular arc `C(s) = o + R sin(s/R) t + R (1 − cos(s/R)) n`, `s ∈ [0, length]`.

    **Arguments:**

    - `radius`: positive scalar `R`.
    - `length`: positive scalar (arc length; may exceed a full turn).
    - `origin`: (3,) start point `o`.
    - `tangent`: (3,) start tangent `t` (normalised here).
    - `normal`: (3,) direction of the centre from the start (made orthogonal to `t`).
    """

    radius: Array
    length: Array
    origin: Array
    start_tangent: Array
    start_normal: Array

    def __init__(
        self,
        radius: ArrayLike,
        length: ArrayLike,
        *,
        origin=(0.0, 0.0, 0.0),
        tangent=(1.0, 0.0, 0.0),
        normal=(0.0, 1.0, 0.0),
    ):
        self.radius = as_float_array(radius, "radius", ())
        self.length = as_float_array(length, "length", ())
        self.origin = as_float_array(origin, "origin", (3,))
        t = unit(as_float_array(tangent, "tangent", (3,)), "tangent")
        n = as_float_array(normal, "normal", (3,))
        n = unit(n - dot(n, t) * t, "normal (its part orthogonal to tangent)")
        self.start_tangent, self.start_normal = t, n
        check_positive(self.radius, "radius")
        check_positive(self.length, "length")

    def _continues_as_itself(self):
        return True  # along its osculating circle: itself

    def _jet(self, s):
        t, n, r = self.start_tangent, self.start_normal, self.radius
        sin, cos, versine = turn(s, self.radius)  # (one `sincos`)
        position = self.origin + r * sin * t + r * versine * n
        return position, cos * t + sin * n, (cos * n - sin * t) / r

    def _normals(self, s):
        t, n = self.start_tangent, self.start_normal
        b = jnp.cross(t, n)
        i0 = initial_normal(t)
        sin, cos, _ = turn(s, self.radius)
        principal = cos * n - sin * t  # the Frenet normal N(s)
        normal = dot(i0, n) * principal + dot(i0, b) * b
        return normal, jnp.cross(cos * t + sin * n, normal)

    def _torsion(self, s):
        return jnp.zeros_like(s)

    def _closest_start(self, x, lo, hi):
        # The continuation of an arc is its circle: the foot is where the point's direction
        # from the centre meets it, at the angle φ from the start, s = R (φ + 2πm).
        t, n, r = self.start_tangent, self.start_normal, self.radius
        v = x - (self.origin + r * n)
        a, b = -dot(v, n), dot(v, t)
        phi = jnp.arctan2(b, a)
        turn = 2 * jnp.pi * r
        s = r * phi + turn * jnp.ceil((lo - r * phi) / turn)  # the first candidate past lo
        # Unique: off the axis, and the next candidate (the same point of the circle, a turn
        # later) outside the range.
        certified = (a**2 + b**2 > 0) & (s > lo) & (s < hi) & (s + turn >= hi)
        return s, certified

    def _foot_is_unique(self, s, lo, hi):
        # A point of the normal plane at `s` on the centre's side of the axis (inside the
        # reach) is nearest to the circle's point at `s`, which the arc continued over
        # `[lo, hi]` passes again a turn before or after, if the range holds a turn more.
        turn = 2 * jnp.pi * self.radius
        return (s - turn <= lo) & (s + turn >= hi)

    def default_samples(self) -> int:
        return _samples_for_turns(self.length / self.radius)


class Helix(AbstractSpine):
    """The circular helix `C(s) = (r cos u, r sin u, h u)`, `h = pitch/2π`, `u = s/√(r² + h²)`.

    Its axis is `z`; it starts at `(r, 0, 0)`. A negative pitch gives a left-handed helix.

    **Arguments:**

    - `radius`: positive scalar `r`.
    - `pitch`: scalar, rise per turn (0 gives a circle).
    - `length`: positive scalar arc length.
    """

    radius: Array
    pitch: Array
    length: Array

    def __init__(self, radius: ArrayLike, pitch: ArrayLike, length: ArrayLike):
        self.radius = as_float_array(radius, "radius", ())
        self.pitch = as_float_array(pitch, "pitch", ())
        self.length = as_float_array(length, "length", ())
        check_positive(self.radius, "radius")
        check_positive(self.length, "length")
        if is_concrete(self.pitch) and not np.isfinite(np.asarray(self.pitch)):
            raise ValueError(f"`pitch` must be finite, got {self.pitch}.")

    def _constants(self):
        h = self.pitch / (2 * jnp.pi)
        c = jnp.sqrt(self.radius**2 + h**2)
        return h, c

    def _frenet(self, s, constants=None):
        r = self.radius
        h, c = self._constants() if constants is None else constants
        u = s / c
        sin, cos = jnp.sin(u), jnp.cos(u)
        position = jnp.stack([r * cos, r * sin, h * u])
        tangent = jnp.stack([-r * sin, r * cos, h]) / c
        normal = jnp.stack([-cos, -sin, jnp.zeros_like(u)])
        binormal = jnp.stack([h * sin, -h * cos, r]) / c
        return position, tangent, normal, binormal

    def _jet(self, s):
        constants = self._constants()
        return self._jet_of(self._frenet(s, constants), constants)

    def _jet_of(self, frenet, constants):
        position, tangent, normal, _ = frenet
        return position, tangent, (self.radius / constants[1] ** 2) * normal

    def _normals(self, s):
        constants = self._constants()
        start = self._frenet(jnp.zeros_like(s), constants)
        return self._normals_of(s, self._frenet(s, constants), start, constants)

    def _normals_of(self, s, frenet, start, constants):
        """The RMF normals at `s` from the Frenet frames at `s` and at 0."""
        _, tangent0, normal0, binormal0 = start
        _, tangent, normal, binormal = frenet
        i0 = initial_normal(tangent0)
        a, b = dot(i0, normal0), dot(i0, binormal0)
        angle = self._torsion(s) * s  # the RMF turns by −∫τ ds relative to Frenet
        cos, sin = jnp.cos(angle), jnp.sin(angle)
        normal_out = (a * cos + b * sin) * normal + (b * cos - a * sin) * binormal
        return normal_out, jnp.cross(tangent, normal_out)

    # At `s` and at both ends at once (`AbstractSpine._evaluate` continues from the ends): the
    # constants and the Frenet frames at 0 and at the end computed once, rather than once for
    # each of the three evaluations and again for each one's normals (9 Frenet frames, now 3):
    # smaller programs wherever a helix is evaluated (the det J of the three maps, helix onto
    # helix: 7 % less HLO, tracing and compiling 18.2 → 16.5 s of CPU).
    def _anchors(self, s):
        constants = self._constants()
        where = (s, jnp.zeros_like(self.length), self.length)
        frenets = [self._frenet(x, constants) for x in where]
        return [
            (self._jet_of(f, constants), self._normals_of(x, f, frenets[1], constants))
            for x, f in zip(where, frenets, strict=True)
        ]

    def _anchor_jets(self, s):
        constants = self._constants()
        where = (s, jnp.zeros_like(self.length), self.length)
        return [self._jet_of(self._frenet(x, constants), constants) for x in where]

    def _torsion(self, s):
        h, c = self._constants()
        return jnp.broadcast_to(h / c**2, jnp.shape(s))

    def default_samples(self) -> int:
        h, c = self._constants()
        return _samples_for_turns(self.length * self.radius / c**2)


def _samples_for_turns(turning_angle) -> int:
    """32 samples per radian of turning (at least 128), rounded up to a bucket size
    (`128·2^k` or `192·2^k`: spines of similar turning share their compiled programs); 256
    when the angle is traced."""
    try:
        angle = float(jax.device_get(turning_angle))
    except (jax.errors.ConcretizationTypeError, TypeError):
        return 256
    if not np.isfinite(angle):
        return 256
    return bucket(int(max(128, min(32 * angle, 8192))), 128)

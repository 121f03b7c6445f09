"""A 3D curve to slide a shape along (Fig. 7), and pieces of a spine as spines of their own.

The paper slides a dolphin along a 3D curve by moving the origin of the arc length of C1. Here
the curve is a conical spiral — widening turns that also rise, so that both curvature and
torsion change along it — as a quintic B-spline (exact arc length, double-reflection frames),
and frame i of the animation is its piece `[σ_i, σ_i + L]` (`Piece`).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import fleshing_jax as fj
from fleshing_jax._checks import as_float_array


def conical_spiral(turns: float = 2.0, samples: int = 25) -> fj.BSpline:
    """A B-spline whose control points follow a conical spiral: radius 2 → 2 + 3·turns/2, rising
    1.2 per turn (curvature ≈ 0.45 → 0.2, torsion ≈ 0.04 → 0.02); about 50 long for 2 turns."""
    angle = np.linspace(0.0, 2 * np.pi * turns, samples)
    radius = 2.0 + 1.5 * angle / (2 * np.pi)
    rise = 1.2 * angle / (2 * np.pi)
    return fj.BSpline(np.stack([radius * np.cos(angle), radius * np.sin(angle), rise], -1))


class Piece(fj.AbstractSpine):
    """The piece `[start, start + length]` of `base`, as a spine parameterised from 0.

    Position, tangent and curvature are the base's, shifted; the rotation-minimising frame is
    the base's rotated by the constant angle that makes it start from `initial_normal` of the
    piece's own start tangent (a rotation-minimising frame is unique up to such a rotation).

    **Arguments:** `base`: any spine (prepared once here); `start`, `length`: scalars.
    """

    base: fj.AbstractSpine
    start: jnp.ndarray
    length: jnp.ndarray

    def __init__(self, base, start, length):
        self.base = base._prepare()
        self.start = as_float_array(start, "start", ())
        self.length = as_float_array(length, "length", ())

    def _jet(self, s):
        return self.base.jet(self.start + s)

    def _normals(self, s):
        (_, t0, _), (i0, j0) = self.base.jet_and_normals(self.start)
        first = fj.initial_normal(t0)
        a, b = jnp.dot(first, i0), jnp.dot(first, j0)
        (_, tangent, _), (i, j) = self.base.jet_and_normals(self.start + s)
        normal = a * i + b * j
        return normal, jnp.cross(tangent, normal)

    def _torsion(self, s):
        return self.base.torsion(self.start + s)

    def base_twist(self):
        """The twist that turns this piece's frame into the base's: posing with it, shapes
        slid along the base keep a continuous orientation (the rule that starts each piece's
        own frame jumps where the start tangent crosses between coordinate axes)."""
        zero = jnp.zeros_like(self.start)
        i, j = self.jet_and_normals(zero)[1]
        base = self.base.jet_and_normals(self.start)[1][0]
        return jnp.arctan2(jnp.dot(base, j), jnp.dot(base, i))

    def default_samples(self) -> int:
        return self.base.default_samples()

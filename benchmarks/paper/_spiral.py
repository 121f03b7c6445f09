"""A planar logarithmic spiral spine: curvature that changes along the curve, in closed form.

`r = a e^{bθ}` has arc length (from its pole) `σ = c r`, `c = √(1 + b²)/b`, so it is exactly
arc-length parameterised: `r(s) = (start + s)/c`, `θ = ln(r/a)/b`, curvature `1/(r √(1 + b²))`.
It lies in the (x, y) plane (zero torsion), so its rotation-minimising frame is its Frenet
frame turned by a constant angle. Used to slide a shape along a curve (Fig. 7): each frame is
the piece `[start, start + length]` of one spiral.
"""

from __future__ import annotations

import jax.numpy as jnp

import fleshing_jax as fj
from fleshing_jax._misc import as_float_array


class LogSpiral(fj.AbstractSpine):
    """The piece of arc length `length` of `r = a e^{bθ}` from arc length `start` (from the pole).

    **Arguments:** `start`, `length`: positive scalars; `a` (scale) and `b` (growth rate).
    """

    start: jnp.ndarray
    length: jnp.ndarray
    a: jnp.ndarray
    b: jnp.ndarray

    def __init__(self, start, length, a=1.0, b=0.25):
        self.start = as_float_array(start, "start", ())
        self.length = as_float_array(length, "length", ())
        self.a = as_float_array(a, "a", ())
        self.b = as_float_array(b, "b", ())

    def _polar(self, s):
        root = jnp.sqrt(1 + self.b**2)
        r = (self.start + s) * self.b / root
        theta = jnp.log(r / self.a) / self.b
        psi = theta + jnp.arctan2(1.0, self.b)  # tangent direction: constant angle to radius
        return r, theta, psi, root

    def _jet(self, s):
        r, theta, psi, root = self._polar(s)
        zero = jnp.zeros_like(r)
        position = jnp.stack([r * jnp.cos(theta), r * jnp.sin(theta), zero])
        tangent = jnp.stack([jnp.cos(psi), jnp.sin(psi), zero])
        normal = jnp.stack([-jnp.sin(psi), jnp.cos(psi), zero])
        return position, tangent, normal / (r * root)

    def _normals(self, s):
        _, _, psi0, _ = self._polar(jnp.zeros_like(s))
        _, _, psi, _ = self._polar(s)
        zero = jnp.zeros_like(psi)
        tangent0 = jnp.stack([jnp.cos(psi0), jnp.sin(psi0), zero])
        i0 = fj.initial_normal(tangent0)
        normal0 = jnp.stack([-jnp.sin(psi0), jnp.cos(psi0), zero])
        binormal = jnp.array([0.0, 0.0, 1.0], dtype=psi.dtype)
        normal = jnp.stack([-jnp.sin(psi), jnp.cos(psi), zero])
        i = jnp.dot(i0, normal0) * normal + jnp.dot(i0, binormal) * binormal
        tangent = jnp.stack([jnp.cos(psi), jnp.sin(psi), zero])
        return i, jnp.cross(tangent, i)

    def _torsion(self, s):
        return jnp.zeros_like(s)

"""Functions of arc length along a circle: `s ↦ a + b sin(s/R) + c (1 − cos(s/R))`.

An arc's point, tangent, curvature vector and rotation-minimising normals, twisted by a constant
angle or not, are all of this form (`Arc`: constant vectors turned by `φ = s/R` in the arc's
plane), for every `s`, the arc continuing as its circle. So are the products of them that a
pose needs. Three coefficient vectors then give them exactly, where a `PiecewiseCubic` reads
four coefficients a value from a table: a pose onto an arc evaluates one `sincos` a point and
two multiply-adds a value, against 44 lookups (11 values) that cost more than all its other
work together (benchmarks/README.md).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._numerics import sincos
from .lookups import Lookups


class Sinusoid(eqx.Module):
    """A function of arc length `s ↦ (F,)` of the form `a + b sin(s/R) + c (1 − cos(s/R))`.

    **Arguments:** `radius`: scalar `R`; `function`: `s` (scalar) → (F,), of that form (what
    it returns at `s = 0`, `πR/2` and `πR` gives `a`, `b` and `c`; other functions are not
    represented).

    **Fields:** `radius`; `coefficients`: (3, F), the rows `a`, `b`, `c`.
    """

    radius: Array
    coefficients: Array

    def __init__(self, radius: Array, function: Callable):
        self.radius = radius
        quarter = jnp.pi / 2 * radius
        # At φ = 0, π/2, π: f = a, a + b + c, a + 2c.
        start, side, opposite = (function(k * quarter) for k in range(3))
        c = (opposite - start) / 2
        self.coefficients = jnp.stack([start, side - start - c, c])

    def fields(self, s: Array) -> Lookups:
        """The F values at `s`, as F scalars, each computed where it is first read (as
        `PiecewiseCubic.fields`: callers use each once, so that XLA fuses its evaluation into
        the kernel that consumes it)."""
        sin, _, versine = turn(jnp.asarray(s, self.radius.dtype), self.radius)
        a, b, c = self.coefficients
        return Lookups(a.shape[0], lambda f: a[f] + sin * b[f] + versine * c[f])


    def vector(self, s: Array, count: int | None = None) -> Array:
        """The F values at `s` as one (F,) vector, or its first `count` (as
        `PiecewiseCubic.vector`)."""
        sin, _, versine = turn(jnp.asarray(s, self.radius.dtype), self.radius)
        a, b, c = (v[:count] for v in self.coefficients)
        return a + sin * b + versine * c


def turn(s: Array, radius: Array) -> tuple[Array, Array, Array]:
    """`(sin φ, cos φ, 1 − cos φ)` at the angle `φ = s/R` turned along a circle of `radius`,
    from one `sincos` of `φ/2`: `1 − cos φ = 2 sin²(φ/2)` has no cancellation near `φ = 0`."""
    half_sin, half_cos = sincos(s / (2 * radius))
    versine = 2 * half_sin**2
    return 2 * half_sin * half_cos, 1 - versine, versine

"""The closed-form unbending and bending maps of the paper (§4), in curvature-vector form.

All functions act in one cross-section, in the 2D coordinates of a twist-compensated frame
`(I, J)`: `d` is the offset of a point from the spine and `k` the curvature vector there, both
(2,) arrays. With `p = k·d` (`= κx`, the paper's `κ r cos θ`), the volume element around the
spine is `(1 − p) ds dA`. Each `unbend` has area Jacobian `1 − p` (it straightens the spine
locally) and each `bend` is its inverse, so unbend → transfer → bend has `det J = 1`.

Every function returns `(image, ok)`: `ok` is the method's own existence condition (paper eqs.
7–9, 11–13, 15–17). Values stay finite outside it, with finite derivatives, so that invalid
points never poison a batch or a gradient. The reach conditions `1 − k·d > 0` before and after
are checked by the caller.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._numerics import dot, safe_divide, safe_sqrt

_A = 2.0 / (3.0 * 3.0**0.5)  # the branch point of μ³ − μ = α


def _normal_part(d: Array, k: Array) -> tuple[Array, Array]:
    """`p = k·d` and the component `x N` of `d` along the Frenet normal `N = k/κ`.

    `x N = p k/κ²`; it vanishes as `κ → 0` (straight spines, inflections), where `N` is
    undefined: the safe division gives 0 there, with finite derivatives.
    """
    p = dot(k, d)
    return p, safe_divide(p, dot(k, k)) * k


HALLEY_STEPS = 3  # from the starting guesses of `_halley_root`: relative error ≤ 1e-15


@jax.custom_jvp
def cubic_root(alpha: Array) -> Array:
    """The root `μ` of `μ³ − μ − α = 0` that equals 1 at `α = 0` (closed form).

    With `a = 2/(3√3)`: `μ = (2/√3) cos(arccos(α/a)/3)` for `|α| ≤ a` and
    `μ = (2/√3) cosh(arccosh(α/a)/3)` for `α > a`. For `α < −a` there is no such root (the point
    is outside the valid space) and `1/√3` is returned. One Newton step polishes the root to
    round-off. The derivative is `1/(3μ² − 1)`, finite at the branch point `α = a`.

    In single precision the same root comes from `_halley_root` instead: the closed form's four
    transcendental functions cost 16× its arithmetic, and were the largest kernel of the
    batched `pose` (benchmarks/README.md); both agree to float32 round-off (tested).
    """
    alpha = jnp.asarray(alpha)
    if alpha.dtype == jnp.float32:
        return _halley_root(alpha)
    z = alpha / _A
    inside = jnp.clip(z, -1.0, 1.0)
    outside = jnp.where(z > 1, z, 1.0)
    scale = 2.0 / 3.0**0.5
    mu = jnp.where(
        z > 1,
        scale * jnp.cosh(jnp.arccosh(outside) / 3),
        scale * jnp.cos(jnp.arccos(inside) / 3),
    )
    slope = 3 * mu**2 - 1
    # Newton polish, skipped near the double root μ = 1/√3 where it would be ill-conditioned.
    step = safe_divide(mu**3 - mu - alpha, jnp.where(slope > 1e-2, slope, 0))
    return mu - step


def _halley_root(alpha: Array) -> Array:
    """`cubic_root` by `HALLEY_STEPS` Halley steps (cubic convergence) from a guess within 12%:
    the expansion at the double root, `1/√3 + √((α + a)/√3)`, for `α ≤ 1`, and `c + 1/(3c)`
    with `c ≈ ∛α` read off the floating-point exponent for `α > 1`.

    Measured against a bisection in extended precision: relative error ≤ 7e-16 in float64 and
    ≤ 5e-7 in float32 (as the closed form's), except within 1e-3 of the double root `α = −a`,
    where the root itself is ill-conditioned (`dμ/dα → ∞`).
    """
    large = alpha > 1
    c = _cube_root_guess(jnp.where(large, alpha, 1))
    double_root = 3**-0.5 + jnp.sqrt(jnp.maximum(alpha + _A, 0) * 3**-0.5)
    mu = jnp.where(large, c + 1 / (3 * c), double_root)
    for _ in range(HALLEY_STEPS):
        f, slope = mu**3 - mu - alpha, 3 * mu**2 - 1
        newton = safe_divide(f, slope)  # 0 at the double root, where the slope vanishes
        mu = mu - safe_divide(newton, 1 - 3 * mu * safe_divide(newton, slope))
    return jnp.where(alpha < -_A, 3**-0.5, mu)


def _cube_root_guess(x: Array) -> Array:
    """`∛x` to ±5% for `x > 0`: the float's bits, read as an integer (≈ a scaled `log₂ x`),
    divided by 3 and re-biased (Kahan's initial step of `cbrt`; `jnp.cbrt` costs 7× as much
    as the whole Halley iteration)."""
    bits, magic = (
        (jnp.int32, 709921077) if x.dtype == jnp.float32 else (jnp.int64, 0x2A9F7893782DA1CE)
    )
    i = jax.lax.bitcast_convert_type(x, bits)
    return jax.lax.bitcast_convert_type(i // 3 + jnp.asarray(magic, bits), x.dtype)


@cubic_root.defjvp
def _cubic_root_jvp(primals, tangents):
    (alpha,), (alpha_dot,) = primals, tangents
    mu = cubic_root(alpha)
    return mu, safe_divide(alpha_dot, 3 * mu**2 - 1)


def radial_unbend(d: Array, k: Array) -> tuple[Array, Array]:
    """Radial unbending (eq. 7): `d* = d √(1 − (2/3) k·d)`."""
    arg = 1 - (2.0 / 3.0) * dot(k, d)
    return d * safe_sqrt(arg), arg > 0


def radial_bend(d: Array, k: Array) -> tuple[Array, Array]:
    """Radial bending (eqs. 8–9): `d₁ = d/μ`, `μ³ − μ = α = −(2/3) k·d`; needs `α > −a`."""
    alpha = -(2.0 / 3.0) * dot(k, d)
    mu = cubic_root(alpha)
    return d / mu, alpha > -_A


# Where `radial_bend_whole` leaves the exact map: above the `k·d* ≤ 0.45` that a posed limb's
# joint zone keeps (`_skeleton.joint_zone`), below the map's limit `1/√3 ≈ 0.577`, near which
# the concave side is crushed onto the centre of curvature (at 0.55 the compression starts
# with a slope 3.6 and creases the mesh).
WHOLE_FROM = 0.5


def _whole_constants() -> tuple[float, float]:
    """The exact radial map at `p = WHOLE_FROM`: `(p₁, dp₁/dp)`, with `p₁ = k·d₁ = p/μ`."""
    p = WHOLE_FROM
    mu = 2 / 3**0.5 * np.cos((np.arccos(-(2 / 3) * p / _A) + 2 * np.pi) / 3 - 2 * np.pi / 3)
    # μ³ − μ = −(2/3)p, so dμ/dp = −(2/3)/(3μ² − 1).
    slope = 1 / mu + (2 * p / 3) / (mu**2 * (3 * mu**2 - 1))
    return float(p / mu), float(slope)


_P1, _SLOPE = _whole_constants()


def radial_bend_whole(d: Array, k: Array) -> tuple[Array, Array]:
    """`radial_bend` up to `p = k·d = WHOLE_FROM`, continued past it by an image that tends to
    the centre of curvature without reaching it: `p₁ = 1 − (1 − p₁⁰) exp(−s (p − p⁰)/(1 −
    p₁⁰))`, matching the exact map's value `p₁⁰` and slope `s` there, `d₁ = d p₁/p`.

    Continuous with its derivative, and monotone in `p`, so the concave side of a bend too
    tight for the exact map is compressed towards the centre, never folded across it (the
    exact map's continuation, its root held at the branch point, sends those points past the
    centre: a flap). Valid (`ok`) only up to `WHOLE_FROM`: past it, volume is lost.
    """
    p = dot(k, d)
    exact, ok = radial_bend(d, k)
    past = p > WHOLE_FROM
    excess = jnp.where(past, p - WHOLE_FROM, 0)
    p1 = 1 - (1 - _P1) * jnp.exp(-_SLOPE * excess / (1 - _P1))
    held = d * (p1 / jnp.where(past, p, 1))[..., None]
    return jnp.where(past[..., None], held, exact), ok & ~past


def normal_unbend(d: Array, k: Array) -> tuple[Array, Array]:
    """Normal unbending (eq. 11): `x* = x − (κ/2) x²`, i.e. `d* = d − (p/2) x N`."""
    p, xn = _normal_part(d, k)
    return d - 0.5 * p * xn, jnp.ones_like(p, dtype=bool)


def normal_bend(d: Array, k: Array) -> tuple[Array, Array]:
    """Normal bending (eqs. 12–13): `x₁ = 2x/(1 + √(1 − 2κx))`; needs `κx ≤ 1/2`.

    Written as `d₁ = d + x N · 2p/(1 + q)²`, `q = √(1 − 2p)`: no cancellation at small `p`.
    """
    p, xn = _normal_part(d, k)
    arg = 1 - 2 * p
    q = safe_sqrt(arg)
    return d + xn * (2 * p / (1 + q) ** 2), arg >= 0


def binormal_unbend(d: Array, k: Array) -> tuple[Array, Array]:
    """Binormal unbending (eq. 15): `y* = (1 − κx) y`, i.e. `d* = d − p (d − x N)`."""
    p, xn = _normal_part(d, k)
    return d - p * (d - xn), jnp.ones_like(p, dtype=bool)


def binormal_bend(d: Array, k: Array) -> tuple[Array, Array]:
    """Binormal bending (eqs. 16–17): `y₁ = y/(1 − κx)`; needs `κx < 1`."""
    p, xn = _normal_part(d, k)
    return d + safe_divide(p, 1 - p) * (d - xn), p < 1


def skinning(d: Array, k: Array) -> tuple[Array, Array]:
    """The uncorrected baseline: offsets carried rigidly in the frames (not volume preserving)."""
    return d, jnp.ones(jnp.shape(d)[:-1], dtype=bool)


UNBEND = {"radial": radial_unbend, "normal": normal_unbend, "binormal": binormal_unbend}
BEND = {"radial": radial_bend, "normal": normal_bend, "binormal": binormal_bend}
UNBEND["skinning"] = BEND["skinning"] = skinning
# The bends a pose that keeps every point (`Poser`'s `fallback`) uses: whole past the limit.
WHOLE = {**BEND, "radial": radial_bend_whole}

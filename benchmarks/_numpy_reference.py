"""A straightforward vectorised NumPy fleshing from a `Line` onto an `Arc` (benchmark reference).

Written for `throughput.py`, independently of the library, to measure what the same maps cost
in plain NumPy. Everything is closed form, which is what a hand-written line → arc fleshing
would do:

- registration on a line: `s = (X − o)·t`, offset in the constant frame `(I₀, J₀)`, zero
  curvature; valid inside the library's search range `(−e₀, L₀ + e₁)`, here `(−L₀, 2 L₀)`;
- the radial, normal, binormal and skinning maps of the paper in curvature-vector form (general
  `k₀`, although it is zero on a line);
- the arc and its rotation-minimising frame at `s₁ = λ s` (the arc's continuation beyond its
  ends is the same circle, so one formula serves every `s₁`);
- the projection check in closed form: the polar angle of the image around the arc's centre.

The library instead runs its generic closest-point search (samples, then Newton) for any
spine, so the registration ratio measures the price of generality, not only of JAX.
"""

from __future__ import annotations

import numpy as np

_A = 2.0 / (3.0 * 3.0**0.5)


def initial_normal(tangent: np.ndarray) -> np.ndarray:
    """The library's first-normal rule: least aligned axis (small tie margins), orthogonalised."""
    axis = np.eye(3, dtype=tangent.dtype)[np.argmin(np.abs(tangent) + [0.0, 1e-4, 2e-4])]
    normal = axis - np.dot(axis, tangent) * tangent
    return normal / np.linalg.norm(normal)


def register_line(points: np.ndarray, length: float, origin, tangent):
    """Closed-form registration on the line `origin + s tangent`, `s ∈ [0, length]`.

    **Returns:** `(s (N,), offset (N, 2), curvature (N, 2), valid (N,))`.
    """
    dtype = points.dtype
    t = np.asarray(tangent, dtype)
    t = t / np.linalg.norm(t)
    i0 = initial_normal(t)
    j0 = np.cross(t, i0)
    d = points - np.asarray(origin, dtype)
    s = d @ t
    offset = np.stack([d @ i0, d @ j0], axis=-1)
    finite = np.all(np.isfinite(points), axis=-1)
    valid = finite & (s > -length) & (s < 2 * length)
    return s, offset, np.zeros_like(offset), valid


def _normal_part(d, k):
    p = np.sum(k * d, axis=-1)
    kk = np.sum(k * k, axis=-1)
    factor = np.divide(p, kk, out=np.zeros_like(p), where=kk != 0)
    return p, factor[:, None] * k


def cubic_root(alpha):
    """The root of `μ³ − μ = α` equal to 1 at `α = 0` (trigonometric / hyperbolic form)."""
    z = alpha / _A
    scale = 2.0 / 3.0**0.5
    mu = np.where(
        z > 1,
        scale * np.cosh(np.arccosh(np.maximum(z, 1.0)) / 3),
        scale * np.cos(np.arccos(np.clip(z, -1.0, 1.0)) / 3),
    )
    slope = 3 * mu**2 - 1
    step = np.divide(mu**3 - mu - alpha, slope, out=np.zeros_like(mu), where=slope > 1e-2)
    return mu - step


def unbend(method: str, d, k):
    """`(d*, ok)`: the method's unbending of offsets `d` (N, 2) at curvature vectors `k`."""
    if method == "radial":
        arg = 1 - (2.0 / 3.0) * np.sum(k * d, axis=-1)
        return d * np.sqrt(np.maximum(arg, 0))[:, None], arg > 0
    if method == "normal":
        p, xn = _normal_part(d, k)
        return d - 0.5 * p[:, None] * xn, np.ones(len(d), bool)
    if method == "binormal":
        p, xn = _normal_part(d, k)
        return d - p[:, None] * (d - xn), np.ones(len(d), bool)
    return d, np.ones(len(d), bool)


def bend(method: str, d, k):
    """`(d₁, ok)`: the method's bending of straightened offsets `d` at curvature vectors `k`."""
    if method == "radial":
        alpha = -(2.0 / 3.0) * np.sum(k * d, axis=-1)
        return d / cubic_root(alpha)[:, None], alpha > -_A
    if method == "normal":
        p, xn = _normal_part(d, k)
        q = np.sqrt(np.maximum(1 - 2 * p, 0))
        return d + xn * (2 * p / (1 + q) ** 2)[:, None], 1 - 2 * p >= 0
    if method == "binormal":
        p, xn = _normal_part(d, k)
        one = 1 - p
        ratio = np.divide(p, one, out=np.zeros_like(p), where=one != 0)
        return d + ratio[:, None] * (d - xn), p < 1
    return d, np.ones(len(d), bool)


def arc_frame(s, radius: float, origin, tangent, normal):
    """Position, curvature vector and RMF normals `(I, J)` of the arc at `s` (N,), each (N, 3)."""
    dtype = s.dtype
    t = np.asarray(tangent, dtype)
    t = t / np.linalg.norm(t)
    n = np.asarray(normal, dtype)
    n = n - np.dot(n, t) * t
    n = n / np.linalg.norm(n)
    b = np.cross(t, n)
    i0 = initial_normal(t)
    phi = (s / radius)[:, None]
    sin, cos = np.sin(phi), np.cos(phi)
    position = np.asarray(origin, dtype) + radius * sin * t + 2 * radius * np.sin(phi / 2) ** 2 * n
    tangent_s = cos * t + sin * n
    principal = cos * n - sin * t
    i = np.dot(i0, n) * principal + np.dot(i0, b) * b
    j = np.cross(tangent_s, i)
    return position, principal / radius, i, j


def arc_projection(x, radius: float, length: float, origin, tangent, normal):
    """Arc length of the closest point of the (continued) arc to `x` (N, 3), closed form."""
    dtype = x.dtype
    t = np.asarray(tangent, dtype)
    t = t / np.linalg.norm(t)
    n = np.asarray(normal, dtype)
    n = n - np.dot(n, t) * t
    n = n / np.linalg.norm(n)
    v = x - (np.asarray(origin, dtype) + radius * n)
    # C(φ) − centre = R (sin φ t − cos φ n): the closest point is at the polar angle of v.
    phi = np.arctan2(v @ t, -(v @ n))
    extension = min(length, 0.5 * np.pi * radius)
    s = radius * phi
    s = np.where(s < -extension, s + 2 * np.pi * radius, s)  # the search range is one interval
    return s, (s > -extension) & (s < length + extension)


def flesh_line_arc(
    points: np.ndarray,
    line_length: float,
    radius: float,
    arc_length: float,
    *,
    method: str = "radial",
    twist: float = 0.0,
    check_projection: bool = True,
):
    """`fj.flesh(points, Line(line_length), Arc(radius, arc_length), ...)` in NumPy.

    Both spines start at the origin along `+x`; the arc bends towards `+y` (the library's
    defaults). **Returns:** `(deformed (N, 3), valid (N,))` in the dtype of `points`.
    """
    origin, tangent = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)
    s, offset, curvature, valid = register_line(points, line_length, origin, tangent)
    return pose_arc(
        points, s, offset, curvature, valid, line_length, radius, arc_length,
        method=method, twist=twist, check_projection=check_projection,
    )  # fmt: skip


def pose_arc(
    points, s, offset, curvature, valid, source_length, radius, arc_length, *,
    method="radial", twist=0.0, check_projection=True,
):  # fmt: skip
    """The per-frame half of `flesh_line_arc`: registered points onto the arc."""
    dtype = points.dtype
    origin, tangent, normal = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    stretch = arc_length / source_length
    s1 = stretch * s
    straight, unbent = unbend(method, offset, curvature)
    if method != "skinning":
        straight = straight / np.sqrt(stretch)
    c1, k1, i1, j1 = arc_frame(s1, radius, origin, tangent, normal)
    cos, sin = np.cos(twist), np.sin(twist)
    i1, j1 = cos * i1 + sin * j1, cos * j1 - sin * i1
    k1_2d = np.stack([np.sum(k1 * i1, -1), np.sum(k1 * j1, -1)], axis=-1)
    d1, bent = bend(method, straight, k1_2d)
    image = c1 + d1[:, :1] * i1 + d1[:, 1:] * j1
    ok = valid & unbent & bent & (1 - np.sum(k1_2d * d1, axis=-1) > 0)
    if check_projection:
        back, inside = arc_projection(image, radius, arc_length, origin, tangent, normal)
        tol = np.sqrt(np.finfo(dtype).eps) * (arc_length + np.linalg.norm(d1, axis=-1))
        ok &= inside & (np.abs(back - s1) <= tol)
    return np.where(ok[:, None], image, points).astype(dtype), ok

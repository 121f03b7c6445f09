"""The spines' ends: the target's first normal carried from the source's, and the points
beyond the ends moved rigidly (`beyond="rigid"`).

**The frame rule.** A spine's twist-compensated frame starts from `initial_normal(T(0))`, a rule
that jumps where the least aligned coordinate axis changes: two nearly equal start tangents
can get normals 90° apart, and a pose would roll the whole shape at zero twist. So the
target's frame is instead started from the source's first normal `I₀(0)` carried by the
smallest rotation taking `T₀(0)` to `T₁(0)` (continuous in both spines): the target's own
normals turned by `aligned_twist`, added to the user's twist.

**Beyond the ends.** By default (`"continue"`) a point that projects before `s = 0` (or past
the end) is fleshed against the spines continued along their osculating circles there
(`_spines.spine`): a bend that starts at `s = 0` with another curvature then moves everything
behind the start. With `"rigid"`, such points move rigidly with the start frame (or the end
frame): the body behind a bent tail stays where it is — exactly, bit for bit, when the two
start frames agree (to round-off) — and a hoof follows its leg. Where the two spines'
curvature vectors (or their lengths) differ at that end, the fleshed part's cross-section
there is not the rigid one: its offsets are unbent and bent (`end_section`). The fleshed
points near that end then give up that difference, fully at the end plane and less over a
band as deep as each point's offset (`end_band`), so that the two parts join continuously
and the rigid part stays rigid (the body still, a hoof's children carried); the band is not
volume-exact. (Left as they were, the two parts were torn apart at the end plane.)

The source's end frames are carried by the `Registration` (`EndFrames`), so that `pose` needs
only the target.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._numerics import dot, norm, safe_divide
from .._spines.frames import twist_normals
from .maps import BEND, UNBEND

BEYOND = ("continue", "rigid")


def check_beyond(beyond: str) -> str:
    """`beyond` if it is one of `BEYOND`, else a `ValueError` naming it."""
    if not isinstance(beyond, str) or beyond not in BEYOND:
        raise ValueError(f"`beyond` must be one of {BEYOND}, got {beyond!r}.")
    return beyond


class EndFrames(eqx.Module):
    """A spine's frames `(C, T, I, J)` and curvature vectors `K` at `s = 0` and at its length,
    as 30 scalars: scalars, so that the batching helpers share them across points as they
    share a registration's `length` (`_batching.chunks.per_point`)."""

    values: tuple[Array, ...]

    def __init__(self, spine=None, values=None):
        if values is None:
            frames = _frames(jax.lax.stop_gradient(spine))
            values = tuple(v for frame in frames for vector in frame for v in vector)
        self.values = tuple(values)

    def frame(self, end: int) -> tuple[Array, Array, Array, Array]:
        """`(C, T, I, J)`, each (3,), at the start (`end = 0`) or the end (`end = 1`)."""
        return self._vectors(end)[:4]

    def curvature(self, end: int) -> Array:
        """The curvature vector `K` (3,) at the start (`end = 0`) or the end (`end = 1`)."""
        return self._vectors(end)[4]

    def _vectors(self, end):
        v = self.values[15 * end : 15 * end + 15]
        return tuple(jnp.stack(v[3 * i : 3 * i + 3]) for i in range(5))


@eqx.filter_jit
def end_frames(spine) -> EndFrames:
    """`EndFrames(spine)` compiled (eagerly, a free-form spine's frames are many small
    operations)."""
    return EndFrames(spine)


def _frames(spine) -> list[tuple[Array, Array, Array, Array, Array]]:
    """`(C, T, I, J, K)` of `spine` at 0 and at its length, evaluated together (`_anchors`:
    spines share their work between the two ends; no continuation past them is traced)."""
    start, end = spine._prepare()._end_anchors()
    return [(c, t, i, j, k) for (c, t, k), (i, j) in (start, end)]


def aligned_twist(start: EndFrames, target, twist: Array) -> Array:
    """`twist` plus the angle about `T₁(0)` from the target's own first normal to the source's
    `I₀(0)` carried by the smallest rotation taking `T₀(0)` to `T₁(0)` (scalar; exactly
    `twist` when the two start tangents and normals are equal, so that a spine posed on
    itself keeps its frame to the last bit). `target`: a prepared spine."""
    _, t0, i0, _ = start.frame(0)
    (_, t1, _), (i1, j1) = target._jet_and_normals(jnp.zeros_like(target.length))
    t0, i0 = jax.lax.stop_gradient((t0, i0))
    # The smallest rotation taking t0 to t1, applied to i0: with a = t0 × t1 and c = t0·t1,
    # R v = c v + a × v + a (a·v) / (1 + c). Undefined for opposite tangents (c = −1): there
    # any normal is as good, and 0 is used.
    a, c = jnp.cross(t0, t1), dot(t0, t1)
    opposite = c <= -1 + 1e-6
    carried = c * i0 + jnp.cross(a, i0) + a * dot(a, i0) / jnp.where(opposite, 1, 1 + c)
    angle = jnp.arctan2(dot(carried, j1), dot(carried, i1))
    return twist + jnp.where(_same((t0, i0), (t1, i1)) | opposite, 0, angle)


def _same(a: tuple[Array, ...], b: tuple[Array, ...], scale: Array = 1.0) -> Array:
    """Whether the vectors `a` and `b` agree to round-off (8 ε, times `scale`), each."""
    eps = 8 * jnp.finfo(a[0].dtype).eps
    return jnp.all(jnp.stack([jnp.max(jnp.abs(u - v)) for u, v in zip(a, b)]) <= eps * scale)


def target_ends(target, twist: Array) -> EndFrames:
    """The target's `EndFrames` with its normals turned by `twist` (a prepared spine)."""
    frames = [(c, t, *twist_normals((i, j), twist), k) for c, t, i, j, k in _frames(target)]
    return EndFrames(values=[v for frame in frames for vector in frame for v in vector])


def rigid_beyond(
    source: EndFrames, target: EndFrames, x: Array, s: Array, length: Array
) -> tuple[Array, Array]:
    """`(image (3,), beyond)` of one point `x` registered at `s` on a source of `length`:
    where `beyond` (`s ≤ 0` or `s ≥ length`), `x` moved rigidly from the source's frame at that
    end to the target's; `x` itself where the two frames agree to round-off."""
    end = (s >= length).astype(jnp.int32)
    c0, t0, i0, j0 = _pick(source.frame(0), source.frame(1), end)
    c1, t1, i1, j1 = _pick(target.frame(0), target.frame(1), end)
    d = x - c0
    image = c1 + dot(d, t0) * t1 + dot(d, i0) * i1 + dot(d, j0) * j1
    # (Whether each end's frames agree, picked by the point's end: batched, the same test on
    # each point's picked frames ran as reductions over their 3 coordinates, a point at a time.)
    same = _pick(*(_same_frames(source.frame(e), target.frame(e)) for e in (0, 1)), end)
    return jnp.where(same, x, image), (s <= 0) | (s >= length)


def _same_frames(rest: tuple[Array, ...], moved: tuple[Array, ...]) -> Array:
    """Whether the frames `(C, T, I, J)` `rest` and `moved` agree to round-off (`_same`; the
    position relative to its size)."""
    c0, *axes0 = rest
    c1, *axes1 = moved
    return _same((c0,), (c1,), 1 + jnp.max(jnp.abs(c0))) & _same(tuple(axes0), tuple(axes1))


def end_band(source: EndFrames, target: EndFrames, d: Array, s: Array, length: Array,
             target_length: Array, method: str) -> Array:
    """The correction (2,) of a fleshed point's bent offset, at offset `d` (2,) and arc
    length `s` on a source of `length`, so that it joins the rigid part beyond the nearer end
    continuously (`beyond="rigid"`): minus the departure of that end's fleshed cross-section
    from the rigid one (`end_section`), weighted `(1 − a/|d|)²` at a distance `a < |d|` from
    the end plane, 1 on it; none where the departure is round-off (a bend that ramps up from
    the end, as a limb's pose: its points stay exact). Inside the band the map is continuous
    but not volume-exact: on a tube bent from a line onto an arc that starts and ends with
    curvature 1/1.2, the whole volume changed by 2e-5 (the end planes' jump, 1.5× the edges
    across them, is gone)."""
    end = (2 * s >= length).astype(jnp.int32)
    i0, j0 = _pick(source.frame(0), source.frame(1), end)[2:]
    i1, j1 = _pick(target.frame(0), target.frame(1), end)[2:]
    k0 = _pick(source.curvature(0), source.curvature(1), end)
    k1 = _pick(target.curvature(0), target.curvature(1), end)
    section, ok = end_section(d, jnp.stack([dot(k0, i0), dot(k0, j0)]),
                              jnp.stack([dot(k1, i1), dot(k1, j1)]), target_length / length,
                              method)
    # Where the section's map has no solution, the point is flagged by its own map already.
    departure = jnp.where(ok, section - d, 0)
    depth = safe_divide(jnp.where(end == 1, length - s, s), norm(d))
    fade = jnp.where(depth < 1, (1 - jnp.clip(depth, 0, 1)) ** 2, 0)
    scale = 1 + norm(d)
    # (The larger of its two components, not `jnp.max`: batched, a reduction over them ran
    # as a kernel of its own on the (n, 2) departures.)
    largest = jnp.maximum(jnp.abs(departure[..., 0]), jnp.abs(departure[..., 1]))
    negligible = largest <= 64 * jnp.finfo(d.dtype).eps * scale
    return -jnp.where(negligible, 0, fade) * departure


def end_section(e: Array, k0: Array, k1: Array, ratio: Array, method: str
                ) -> tuple[Array, Array]:
    """`(image (2,), ok)`: the fleshed part's image of an offset `e` (2,) on an end's normal
    plane, and whether the map has its solution there: unbent
    with the source's curvature there `k0`, scaled for the lengths' `ratio` (target over
    source), bent with the target's `k1` (all in the end frames' normals), as
    `pipeline.bent_offset` does at that end."""
    straight, unbent = UNBEND[method](e, k0)
    if method != "skinning":
        straight = straight / jnp.sqrt(ratio)
    image, bent = BEND[method](straight, k1)
    return image, unbent & bent


def _pick(start, last, end: Array):
    """`last` where `end == 1`, else `start` (arrays or tuples of arrays)."""
    return jax.tree.map(lambda a, b: jnp.where(end == 1, b, a), start, last)

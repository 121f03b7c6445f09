"""A spine bent smoothly from a point on it: what posing a limb turns its rest spine into.

`BentSpine(base, joint=j, bend=θ, direction=φ, twist=ψ, stop=e)` is the spine `base` left as it
is up to arc length `j`, turned beyond it by a rotation that grows smoothly from the identity at
`j` to its full angle at `e` (default: the base's end), and moved rigidly past `e`:

    T₁(s) = Q(s) T₀(s),   Q(s) = R_a(θ r(u)) R_t(ψ r(u)),   u = (s − j) / (e − j) ∈ [0, 1],

where `t = T₀(j)` is the tangent at the joint, `a = t × (cos φ I + sin φ J)` with `(I, J)` the
base's normals there (the bend turns the limb towards the normal at angle `φ` from `I`), and
`r` rises from 0 to 1 with a slope that rises smoothly from 0 to a plateau and falls back to 0
(`ramp`: its first two derivatives vanish at both ends). So the curvature starts changing from
nothing at the joint (a ramp, not a kink: what lies at the joint does not
move, nor does anything before it), and past `e` the spine is the base moved rigidly (a hoof
follows its leg). Both rotations have fixed axes, so that past `e` the whole frame is the rest
frame turned by one rotation. The normals turn with the tangent, `(I₁, J₁) = Q (I₀, J₀)`: the
limb's cross-sections rotate with it and the twist turns them about the joint's tangent.

Exactly arc length (`|T₁| = 1`) and as long as the base, so that the fleshing from the base to it
preserves volume exactly: `det J = 1` needs only `C₁′ = T₁` and `k₁ = T₁′` (a frame turning
about the tangent does not change the determinant). `k₁ = Q k₀ + Q′ T₀` is written out; the
position between `j` and `e` is the integral of `T₁`, by Gauss–Legendre on intervals split at the
base's own breaks (B-spline pieces), at `j` and at `e`, where the integrand is analytic: the
quadrature's error, and its derivative's, are at round-off. On a free-form base (B-spline,
polynomial) the rule is taken in the base's own parameter `u`, where `T₀ ds = P′(u) du` and the
nodes' arc lengths are the forward `s(u)`: no arc-length inverse at the nodes (each was a
Newton iteration, most of a float64 pose), one only at the point itself, which its jet needs.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._batching.grid import grid_vmap
from .._checks import as_float_array, is_concrete
from .._numerics import dot, held_trig
from . import arclength, parametric
from .looked_up import GAUSS_POINTS, GAUSS_WEIGHTS, NODE_WEIGHTS, LookedUpSpine
from .spine import AbstractSpine, AbstractTabulatedSpine, torsion_of
from .table import SpineTable

INTERVALS = 64  # uniform intervals on [0, length], besides the base's own breaks


EDGE = 0.25  # the fraction of the ramp over which its slope rises (and then falls)


def _rise(v: Array) -> tuple[Array, Array]:
    """`(∫₀ᵛ S, S(v))` of the smoothstep `S(v) = 3v² − 2v³` on `[0, 1]`."""
    return v**3 - v**4 / 2, 3 * v**2 - 2 * v**3


def ramp(u: Array) -> tuple[Array, Array]:
    """`(r(u), r′(u))` on `[0, 1]`: `r` goes from 0 to 1, its slope rises from 0 to a plateau
    over the first `EDGE` of the way (a smoothstep: no jump in the slope's derivative either)
    and falls back to 0 over the last. The plateau is `1/(1 − EDGE)` (4/3), where a single
    smooth bump would peak at 15/8: the largest curvature a bend needs is that much lower."""
    e, scale = EDGE, 1 / (1 - EDGE)
    first, first_slope = _rise(jnp.where(u < e, u, e) / e)
    last, last_slope = _rise(jnp.where(u > 1 - e, 1 - u, e) / e)
    value = jnp.where(u < e, scale * e * first,
                      jnp.where(u > 1 - e, 1 - scale * e * last, scale * (u - e / 2)))
    slope = jnp.where(u < e, first_slope, jnp.where(u > 1 - e, last_slope, 1))
    return value, scale * slope


def rotate(axis: Array, angle: Array, v: Array, trig: tuple[Array, Array] | None = None) -> Array:
    """`v` (..., 3) turned by `angle` radians about the unit `axis` (3,) (Rodrigues): exactly
    `v` at angle 0. Several vectors turned at once (stacked) are turned exactly as one by one.
    `trig`: `(cos, sin)` of `angle`, where the caller has them (`held_trig`)."""
    cos, sin = (jnp.cos(angle), jnp.sin(angle)) if trig is None else trig
    return cos * v + sin * jnp.cross(axis, v) + (1 - cos) * dot(axis, v)[..., None] * axis


def _rotate_coordinates(axis: Array, trig: tuple[Array, Array], v: list[Array]) -> list[Array]:
    """`rotate` with `v` given as its three coordinates (arrays of the angle's shape), and
    returned so, by the angle's `trig` `(cos, sin)` (`held_trig`: each point's computed once
    for all three, see `_table_at_nodes`)."""
    cos, sin = trig
    cross = (axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2],
             axis[0] * v[1] - axis[1] * v[0])
    along = (1 - cos) * (axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2])
    return [cos * x + sin * y + along * a for x, y, a in zip(v, cross, axis)]


class BentSpine(AbstractTabulatedSpine):
    """`base` bent by `bend` radians from arc length `joint`, ramped up smoothly until `stop`.

    **Arguments:**

    - `base`: a smooth spine (any `AbstractSpine`; a limb's rest spine).
    - `joint`: scalar arc length where the bend starts, in `[0, length)`.
    - `bend`: scalar radians: the angle between the tangents at `joint` and at `stop`.
    - `direction`: scalar radians: the bend turns the spine towards the normal
      `cos(direction) I + sin(direction) J` of the base's frame at `joint`.
    - `twist`: scalar radians: the frame, and what lies beyond `joint`, turned about the tangent
      at `joint`, ramped up with the bend.
    - `stop`: scalar arc length where the bend is complete, in `(joint, length]` (default: the
      base's length); past it the spine is the base moved rigidly.

    The same length as `base`, exactly arc length, identical to it up to `joint`. Differentiable
    in every argument (angles, arc lengths and the base's parameters).
    """

    base: AbstractSpine
    joint: Array
    stop: Array
    bend: Array
    direction: Array
    twist: Array

    def __init__(
        self,
        base: AbstractSpine,
        *,
        joint: ArrayLike,
        bend: ArrayLike = 0.0,
        direction: ArrayLike = 0.0,
        twist: ArrayLike = 0.0,
        stop: ArrayLike | None = None,
    ):
        if not isinstance(base, AbstractSpine):
            raise TypeError(f"`base` must be a spine (AbstractSpine), got {type(base)}.")
        self.base = base
        self.joint = as_float_array(joint, "joint", ())
        self.stop = base.length if stop is None else as_float_array(stop, "stop", ())
        self.bend = as_float_array(bend, "bend", ())
        self.direction = as_float_array(direction, "direction", ())
        self.twist = as_float_array(twist, "twist", ())
        _check(self)

    @property
    def length(self) -> Array:
        """The base's length (scalar)."""
        return self.base.length

    def _prepare(self) -> PreparedBent:
        return _prepared(self)

    def _bucketed(self) -> BentSpine:
        return eqx.tree_at(lambda b: b.base, self, self.base._bucketed())

    def default_samples(self) -> int:
        return self.base.default_samples()

    def _tabulable(self) -> bool:
        return self.base._tabulable()


def _check(spine: BentSpine) -> None:
    """`ValueError`s for concrete arguments out of range (traced ones are not checked)."""
    values = (spine.joint, spine.stop, spine.bend, spine.direction, spine.twist, spine.length)
    if not all(is_concrete(v) for v in values):
        return
    joint, stop, bend, direction, twist, length = (float(v) for v in values)
    for name, value in zip(("bend", "direction", "twist"), (bend, direction, twist)):
        if not np.isfinite(value):
            raise ValueError(f"`{name}` must be a finite angle in radians, got {value}.")
    if not 0 <= joint < length:
        raise ValueError(f"`joint` must be an arc length in [0, {length:g}), got {joint}.")
    if not joint < stop <= length * (1 + 1e-12):
        raise ValueError(f"`stop` must be an arc length in ({joint:g}, {length:g}], got {stop}.")


class PreparedBent(AbstractSpine):
    """A `BentSpine` with what does not depend on `s` computed once: the prepared base, the
    rotation axes, and `C₁` at the quadrature's breaks.

    **Fields:** `base` (prepared); `joint`, `stop`, `bend`, `twist` (scalars); `bend_axis` and
    `twist_axis` (3,): the bend's axis and the joint's tangent (the twist's axis); `breaks`
    (M,): the quadrature's breaks on `[joint, stop]`; `positions` (M, 3): `C₁` there;
    `rest_stop` (3,): `C₀(stop)`; `located`: on a free-form base (`parametric.Tables`), where
    each break lies on it, `(piece, parameter, sub-interval)` (M,) each (`parametric.locate`),
    else `None`.
    """

    base: AbstractSpine
    joint: Array
    stop: Array
    bend: Array
    twist: Array
    bend_axis: Array
    twist_axis: Array
    breaks: Array
    positions: Array
    rest_stop: Array
    located: tuple[Array, Array, Array] | None = None

    @property
    def length(self) -> Array:
        return self.base.length

    def _angles(self, s: Array) -> tuple[Array, Array, Array]:
        """`(r(u), r′(u) du/ds)` at `s`: the ramp and its slope in `s`."""
        width = self.stop - self.joint
        u = (s - self.joint) / width
        u = jnp.where(u < 0, 0, jnp.where(u > 1, 1, u))
        value, slope = ramp(u)
        return value, slope / width

    def _trig(self, r: Array, bounded: bool = False) -> tuple[tuple[Array, Array], ...]:
        """The twist's and the bend's `(cos, sin)` for the ramp value `r` (any shape), held in
        memory (`held_trig`): evaluated a point at a time (double precision), each was
        computed again for every coordinate of the frame and the quadrature it turns.
        `bounded`: `held_trig`'s (a table's nodes: in float32 by polynomials)."""
        twist, bend = held_trig(self.twist * r, self.bend * r, bounded=bounded)
        return twist, bend  # (a tuple: vmapped as one argument)

    def _turn(self, r: Array, v: Array, trig: tuple) -> Array:
        """`Q v` for the ramp value `r` (`trig`: `_trig(r)`)."""
        twist, bend = trig
        return rotate(self.bend_axis, self.bend * r,
                      rotate(self.twist_axis, self.twist * r, v, twist), bend)

    def _turn_frame(self, r: Array, slope: Array, t0: Array, k0: Array, i0: Array, j0: Array,
                    trig: tuple):
        """`(Q T₀, Q k₀ + Q′ T₀, Q I₀, Q J₀)` (each (3,)) for the ramp value `r` and its slope
        in `s`. The four vectors and `Q′`'s (`twist_axis × twisted T₀`) are turned as one stack:
        the same values as one by one, in a fifth of the traced operations. `trig`: the
        twist's and the bend's `(cos, sin)` at `r` (`_trig`)."""
        twist, bend = trig
        twisted = rotate(self.twist_axis, self.twist * r, jnp.stack([t0, k0, i0, j0]), twist)
        stack = jnp.concatenate([twisted, jnp.cross(self.twist_axis, twisted[:1])])
        tangent, k, i, j, about_tangent = rotate(self.bend_axis, self.bend * r, stack, bend)
        turn_slope = slope * (self.bend * jnp.cross(self.bend_axis, tangent)
                              + self.twist * about_tangent)
        return tangent, k + turn_slope, i, j

    def _turn_along(self, s: Array, v: Array) -> Array:
        """`Q(s) v` (n, 3) at arc lengths `s` (n,) for vectors `v` (n, 3), each point's sines
        and cosines held (`_trig`)."""
        r = self._angles(s)[0]
        return jax.vmap(lambda r, v, *trig: self._turn(r, v, trig))(r, v, *self._trig(r))

    def _tangents(self, s: Array) -> Array:
        """`T₁(s) = Q(s) T₀(s)` (..., 3) at arc lengths `s` (any shape) in `[joint, stop]`
        (the quadrature's integrand)."""
        flat = s.reshape(-1)
        turned = self._turn_along(flat, jax.vmap(lambda p: self.base._jet(p)[1])(flat))
        return turned.reshape(s.shape + (3,))

    def _free_form(self) -> parametric.Tables | None:
        """The base's tables where it is a free-form spine (`parametric`), else `None`."""
        tables = getattr(self.base, "tables", None)
        return tables if isinstance(tables, parametric.Tables) else None

    def _integral_in_parameter(self, m: Array, u: Array, j: Array) -> Array:
        """`∫ T₁ ds` (3,) from break `m` to the base's point at parameter `u` of sub-interval
        `j` (`parametric.locate`), on a free-form base: Gauss–Legendre in its parameter
        (`arclength.in_parameter`). The break and the point share their sub-interval (the
        breaks hold the base's); where they do not (a point outside `(joint, stop)`, whose
        integral is not used), to the end of the break's."""
        tab = self._free_form()
        piece, start, sub = (v[m] for v in self.located)
        a = arclength.sub_interval_start(sub, tab.parts, u.dtype)
        end = jnp.where(j == sub, u, a + 2.0 / tab.parts)
        s, d, w = arclength.in_parameter(tab.coefficients[piece], a, tab.cumulative[sub], start,
                                         end, GAUSS_POINTS, GAUSS_WEIGHTS)
        return w @ self._turn_along(s, d)

    def _position(self, s: Array, c0: Array, integrate: bool = True, at=None) -> Array:
        """`C₁(s)`, given `c0 = C₀(s)`; `integrate=False` for an `s` known to lie outside
        `(joint, stop)` (the ends: no quadrature traced); `at`: where `s` lies on a free-form
        base (`parametric.locate`), for its quadrature in the base's parameter."""
        one = jnp.ones_like(s)
        rigid = self.positions[-1] + self._turn(one, c0 - self.rest_stop, self._trig(one))
        if not integrate:
            return jnp.where(s <= self.joint, c0, rigid)
        inside = jnp.where(s < self.joint, self.joint, jnp.where(s > self.stop, self.stop, s))
        m = jnp.clip(jnp.searchsorted(self.breaks, inside, side="right") - 1, 0,
                     self.breaks.shape[0] - 2)
        if at is not None:
            integral = self.positions[m] + self._integral_in_parameter(m, at[1], at[2])
            return jnp.where(s <= self.joint, c0, jnp.where(s >= self.stop, rigid, integral))
        start = self.breaks[m]
        half = (inside - start) / 2
        points = start + half * (1 + jnp.asarray(GAUSS_POINTS, s.dtype))
        values = self._tangents(points)
        integral = self.positions[m] + half * jnp.asarray(GAUSS_WEIGHTS, s.dtype) @ values
        return jnp.where(s <= self.joint, c0, jnp.where(s >= self.stop, rigid, integral))

    def carried(self, x: Array, s: Array, table: SpineTable | None = None) -> Array:
        """`x` (3,) moved rigidly with the cross-section at arc length `s`: `C₁(s) + Q(s) (x −
        C₀(s))` (itself before the joint, the rigid part's motion past the stop). Where the
        fleshing cannot place a point (it was not registered on the base), this places it as
        a cross-section of the bent limb there moves. `table`: this spine's (`_table`), where
        the caller made it: `C₁(s)` read from it, not integrated (float32 posing)."""
        at = self._located(s)
        c0 = self.base._jet(s)[0] if at is None else self._base_located(at)[0][0][0]
        c1 = self._position(s, c0, at=at) if table is None else table.jet(s)[0]
        r = self._angles(s)[0]
        return c1 + self._turn(r, x - c0, self._trig(r))

    def _turned(self, s: Array, base, integrate: bool = True, at=None):
        """`_jet_and_normals` at `s` from the base's there (`integrate`, `at`: as
        `_position`)."""
        (c0, t0, k0), (i0, j0) = base
        r, slope = self._angles(s)
        tangent, k, i, j = self._turn_frame(r, slope, t0, k0, i0, j0, self._trig(r))
        return (self._position(s, c0, integrate, at), tangent, k), (i, j)

    def _located(self, s: Array):
        """Where `s` lies on a free-form base (`parametric.locate`), else `None`: located once
        for the base's jet and the position's quadrature."""
        tab = self._free_form()
        return None if tab is None or self.located is None else parametric.locate(tab, s)

    def _base_located(self, at) -> list:
        """The base's `_anchors` at the point `at` (`_located`)."""
        return parametric.evaluate_located(self._free_form(), *at)

    def _jet_and_normals(self, s: Array):
        at = self._located(s)
        if at is None:
            return self._turned(s, self.base._jet_and_normals(s))
        return self._turned(s, self._base_located(at)[0], at=at)

    def _anchors(self, s: Array) -> list:
        # The base's three evaluations shared (`AbstractSpine._anchors`); the ends lie before
        # the joint and past the stop, where no quadrature is needed.
        at = self._located(s)
        here, start, end = self.base._anchors(s) if at is None else self._base_located(at)
        ends = (jnp.zeros_like(self.length), self.length)
        return [self._turned(s, here, at=at)] + [
            self._turned(x, base, integrate=False) for x, base in zip(ends, (start, end))
        ]

    def _anchor_jets(self, s: Array) -> list:
        return [jet for jet, _ in self._anchors(s)]

    def _jet(self, s: Array):
        return self._jet_and_normals(s)[0]

    def _normals(self, s: Array):
        return self._jet_and_normals(s)[1]

    def _torsion(self, s: Array) -> Array:
        return torsion_of(self._jet, s)

    def _table_at_nodes(self, jet_only: bool = False) -> tuple[SpineTable | None, tuple | None]:
        """On a tabulated base (`LookedUpSpine`, float32 posing), the bent spine's table on the
        base table's own pieces (the same search range: before the joint the spine is the
        base, past its end the base moved rigidly), from the base's values at their nodes,
        turned: `T₁ = Q T₀`, `k₁ = Q k₀ + Q′ T₀`, `(I₁, J₁) = Q (I₀, J₀)`, and
        `C₁ = C₀ + ∫ (Q − 1) T₀` by Gauss–Legendre between consecutive nodes (`NODE_GAUSS`
        points; exactly `C₀` up to the joint). A few rotations a node, where evaluating the
        bent spine there would integrate its position from the nearest break and continue it
        past its ends; with those values at its nodes, `(jet, normals)`. `jet_only`: the table
        of the jet alone (`SpineTable.refit` without normals)."""
        base = self.base
        if not (isinstance(base, LookedUpSpine) and base.samples is not None):
            return None, None
        table, at = base.table, base.samples  # the base's values there, read once
        nodes = at.arc_length
        flat = nodes.reshape(-1)
        (c0, t0, k0), (i0, j0) = at.jet, at.normals
        r, slope = jax.vmap(self._angles)(flat)
        # (Each node's sines and cosines computed once for its 15 coordinates: `held_trig`; in
        # float32 by polynomials, 5x faster than XLA's: within 1e-7, the vertices within 1.2e-7.)
        trig = self._trig(r, bounded=True)
        tangent, k, i, j = jax.vmap(self._turn_frame)(r, slope, t0, k0, i0, j0, trig)

        # (Q − 1) T₀ at the quadrature points, one coordinate at a time, each point's sines and
        # cosines computed once for the three (`held_trig`).
        r = grid_vmap(lambda s: self._angles(s)[0], at.points)  # (P·4, NODE_GAUSS)
        tangents = [at.tangents[..., c] for c in range(3)]
        twist, bend = self._trig(r, bounded=True)
        turned = _rotate_coordinates(self.bend_axis, bend, _rotate_coordinates(
            self.twist_axis, twist, tangents))
        weights = jnp.asarray(NODE_WEIGHTS, flat.dtype)
        steps = jnp.stack([at.half * sum(w * (q[:, g] - t[:, g]) for g, w in enumerate(weights))
                           for q, t in zip(turned, tangents)], axis=-1)
        c = c0 + jnp.cumsum(steps, axis=0)

        def shaped(v):
            return v.reshape(nodes.shape + (3,))

        jet, normals = (shaped(c), shaped(tangent), shaped(k)), (shaped(i), shaped(j))
        return table.refit(jet, None if jet_only else normals), (jet, normals)

    def default_samples(self) -> int:
        return self.base.default_samples()

    def _tabulable(self) -> bool:
        return self.base._tabulable()


def _prepared(spine: BentSpine) -> PreparedBent:
    """The `PreparedBent` of `spine` (differentiable in its parameters)."""
    base = spine.base._prepare()
    (c, t, _), (i, j) = base._jet_and_normals(spine.joint)
    # (The direction's cosine and sine held: XLA fused them into each kernel that turns a
    # vector about the axis, computed again for every node's every coordinate.)
    ((cos, sin),) = held_trig(spine.direction)
    axis = jnp.cross(t, cos * i + sin * j)
    length = base.length
    uniform = jnp.linspace(0, 1, INTERVALS + 1, dtype=length.dtype) * length
    # (The ramp is analytic between the joint, the ends of its edges and the stop.)
    width = spine.stop - spine.joint
    ends = [spine.joint, spine.joint + EDGE * width, spine.stop - EDGE * width, spine.stop]
    cuts = jnp.concatenate([base._breaks(), uniform, jnp.stack(ends)])
    breaks = sorted_by_rank(jnp.where(cuts < spine.joint, spine.joint,
                                      jnp.where(cuts > spine.stop, spine.stop, cuts)))
    tab = getattr(base, "tables", None)
    located = (jax.vmap(lambda b: parametric.locate(tab, b))(breaks)
               if isinstance(tab, parametric.Tables) else None)
    partial = PreparedBent(base, spine.joint, spine.stop, spine.bend, spine.twist, axis, t,
                           breaks, jnp.zeros((breaks.shape[0], 3), c.dtype), c, located)
    # Each interval's integral of T₁ (Gauss–Legendre), summed from C₀(joint).
    if located is None:
        half = (breaks[1:] - breaks[:-1]) / 2
        points = (breaks[:-1] + half)[:, None] + half[:, None] * jnp.asarray(GAUSS_POINTS,
                                                                            c.dtype)
        values = partial._tangents(points)  # (M − 1, GAUSS, 3)
        steps = half[:, None] * jnp.einsum("g,mgc->mc", jnp.asarray(GAUSS_WEIGHTS, c.dtype),
                                           values)
    else:  # (to each next break, in the base's parameter)
        _, u, j = located
        steps = jax.vmap(partial._integral_in_parameter)(jnp.arange(breaks.shape[0] - 1), u[1:],
                                                         j[1:])
    positions = c + jnp.concatenate([jnp.zeros((1, 3), c.dtype), jnp.cumsum(steps, axis=0)])
    rest_stop = base._jet(spine.stop)[0]
    return PreparedBent(base, spine.joint, spine.stop, spine.bend, spine.twist, axis, t, breaks,
                        positions, rest_stop, located)


def sorted_by_rank(values: Array) -> Array:
    """`jnp.sort(values)` (M,) for a few values (a bent spine's breaks): each placed at its
    rank, counted by comparing every pair (ties in order of position), the same values in the
    same order. XLA's CPU sort ran a comparator a pair at a time, 39 µs for spot's 9 limbs'
    69 breaks each, batched; the M² comparisons are one kernel. NaNs everywhere where any
    value is NaN (a traced pose's NaN angle: flagged anyway)."""
    m = values.shape[0]
    earlier = jnp.arange(m)[:, None] < jnp.arange(m)[None, :]  # [j, i]: j before i
    below = (values[:, None] < values[None, :]) | ((values[:, None] == values[None, :]) & earlier)
    rank = jnp.sum(below, axis=0, dtype=jnp.int32)
    placed = jnp.zeros_like(values).at[rank].set(values, unique_indices=True)
    return jnp.where(jnp.any(jnp.isnan(values)), jnp.nan, placed)

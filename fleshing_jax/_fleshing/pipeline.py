"""The fleshing pipeline (paper §3.3): register → unbend → transfer → bend.

Written for one point and batched with `vmap`. Registration depends only on the source spine,
so `register` runs once per shape and `pose` is the per-frame path: O(1) work per point plus,
by default, the check that each image projects back where it should (certified for most points
by lower bounds of the target's reach, `reach`; the valid region's sampled test runs on the others
only, `region`).
The batched paths (`Registrar`, `Poser`) run in chunks of points (`_batching.chunks`) on exact
spines, on whole batches on tabulated ones (single precision, `_spines.table`).

Unequal lengths: with `λ = L₁/L₀`, the cross-section at `s` goes to `s₁ = λ s` and its
straightened offset is scaled by `1/√λ`, so that `ds₁ dA₁ = ds dA` (`det J = 1` still).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .._batching import chunks as _chunks
from .._batching.buckets import bucket, pad_batch, unpad_batch
from .._batching.chunks import batch_axes, map_chunks
from .._batching.quick import Program, compiling
from .._checks import as_margin, as_points, as_twist, is_concrete
from .._numerics import cast_floats, dot, norm, per_component
from .._spines.spine import AbstractSpine
from .._spines.table import SpineTable, fast_evaluator_at_nodes, runs_whole, tabulates
from .eager import pose_eagerly, register_eagerly
from .ends import EndFrames, aligned_twist, check_beyond, end_band, rigid_beyond, target_ends
from .maps import BEND, UNBEND, WHOLE
from .methods import check_method
from .projection import Registrar, Registration, invalid_past, register_point
from .reach import search_range
from .region import ValidRegion, clear_all, clear_where
from .target import TargetFrames


def bend_point(
    registration: Registration, frames: TargetFrames, method: str, whole: bool = False,
    ends: EndFrames | None = None,
) -> tuple[Array, Array, Array, Array]:
    """Unbends, transfers and bends one registered point onto the target whose (twisted)
    `frames` are given, without the projection check: `(image (3,), valid, s₁, |d₁|)`
    (the image lies at offset `d₁` from `C₁(s₁)`, in its normal plane). Valid requires `s₁`
    inside the target's search range (its ends continued a quarter turn at most), as the
    registration requires on the source. `whole`: the bend continued past its conditions
    without a fold (`maps.WHOLE`), for the points a pose keeps anyway (`Poser`'s `fallback`).
    `ends`: the target's `EndFrames` where the points beyond its ends move rigidly
    (`beyond="rigid"`): the points near an end join them (`ends.end_band`)."""
    image, (registered, within_limit, inside_target), s1, distance = bend_checks(
        registration, frames, method, whole, ends
    )
    return image, registered & within_limit & inside_target, s1, distance


def bend_checks(
    registration: Registration, frames: TargetFrames, method: str, whole: bool = False,
    ends: EndFrames | None = None,
) -> tuple[Array, tuple[Array, Array, Array], Array, Array]:
    """`bend_point` with its validity split by cause: `(image, (registered, within_limit,
    inside_target), s₁, |d₁|)` — the point's registration on the source is valid; the method's
    unbend and bend equations have their solution; the image is inside the target's reach and
    search range. (What `diagnose` counts.)"""
    s1 = target_arc_length(registration, frames)
    frame = frames(s1)  # evaluated once (exact spines' frames cost a search each)
    d1, causes = bent_offset(registration, frames, s1, frame[3], method, whole, ends)
    return in_frame(frame, d1), causes, s1, norm(d1)


def target_arc_length(registration: Registration, frames: TargetFrames) -> Array:
    """`s₁ = λ s`, where a point's cross-section goes on the target (`λ = L₁/L₀`)."""
    return frames.length / registration.length * registration.arc_length


def bent_offset(
    registration: Registration, frames: TargetFrames, s1: Array, k1: Array, method: str,
    whole: bool = False, ends: EndFrames | None = None,
) -> tuple[Array, tuple[Array, Array, Array]]:
    """The offset `d₁` (2,) of a registered point from the target at `s₁`, in its twisted
    normals, where the target's curvature vector is `k1` (2,) in them; and the causes of
    validity of `bend_checks`."""
    reg = registration
    straight, unbent = UNBEND[method](reg.offset, reg.curvature)
    if method != "skinning":  # skinning is the uncorrected baseline: offsets carried rigidly
        straight = straight / jnp.sqrt(frames.length / reg.length)
    d1, bent = (WHOLE if whole else BEND)[method](straight, k1)
    if ends is not None:  # joined to the rigid parts beyond the ends
        d1 = d1 + end_band(reg.ends, ends, reg.offset, reg.arc_length, reg.length,
                           frames.length, method)
    inside = (s1 > frames.lo) & (s1 < frames.hi) & (1 - dot(k1, d1) > 0)
    return d1, (reg.valid, unbent & bent, inside)


def in_frame(frame: tuple[Array, ...], d1: Array) -> Array:
    """The point at offset `d₁` (2,) from the target in its `frame` at `s₁` (`TargetFrames`):
    `C₁ + d₁ₓ I₁ + d₁ᵧ J₁`, (3,)."""
    c1, i1, j1, _ = frame
    return per_component(lambda c, i, j: c + d1[0] * i + d1[1] * j, c1, i1, j1)


def projects_back(
    target: AbstractSpine | SpineTable, image: Array, s1: Array, margin: Array = 0.0
) -> Array:
    """Whether `image` (3,) projects on `target` at `s₁` only, with the ball of radius
    `margin` around it clear of the target's cut locus and focal set (`region`; one point),
    where `image` was bent into the normal plane at `s₁`, inside the reach there and inside
    the search range (`bend_checks`; the caller holds these conditions). The target's
    valid region is built here: the batched paths build it once (`Poser`).

    Lines and arcs answer in closed form, from `s₁` alone (`_foot_is_unique`): their feet
    are unique but for a wrapped arc's candidates a turn apart. (Reading the image's foot
    instead, an arc's `arctan2` was 60 % of a pose.)
    """
    if isinstance(target, AbstractSpine) and target._has_closed_form_foot():
        return target._foot_is_unique(s1, *search_range(target))
    return ValidRegion(target, margin).clear(jax.lax.stop_gradient(image), s1)


def pose_point(
    registration: Registration,
    target: AbstractSpine,
    method: str,
    twist: Array,
    check_projection: bool = True,
    margin: Array = 0.0,
    beyond: str = "continue",
) -> tuple[Array, Array]:
    """Maps one registered point onto `target`. Returns `(image (3,), valid)`.

    Invalid points are returned unchanged (their image is computed from safe values and
    discarded, so that neither values nor gradients of other points are affected).
    """
    target = target._prepare()
    twist = aligned_twist(registration.ends, target, twist)
    ends = target_ends(target, twist) if beyond == "rigid" else None
    image, valid, s1, _ = bend_point(registration, TargetFrames(target, twist), method,
                                     ends=ends)
    if check_projection:
        valid = valid & projects_back(target, image, s1, margin)
    image = jnp.where(valid, image, registration.points)
    if beyond == "rigid":
        reg = registration
        moved, outside = rigid_beyond(
            reg.ends, ends, reg.points, reg.arc_length, reg.length
        )
        finite = jnp.all(jnp.isfinite(reg.points))
        image, valid = jnp.where(outside, moved, image), jnp.where(outside, finite, valid)
    return image, valid


class Poser(eqx.Module):
    """A target spine prepared for batched posing, once for all points: its frames with the
    twist (tabulated in single precision, `target`), its fast evaluator for the projection
    check (`_spines.table`) and its valid region with the margin (`region`).

    The projection check is certified on the way for the images closer to the target than the
    lower bound of its reach with the margin (`reach`); the others are bent again and run the
    region's pruned test, and the few it leaves its sampled test (`region.clear_where`; O(runs),
    then O(samples) a point, no global search), so that
    the images are consumed once (by the output) and XLA computes them in the same kernel as
    the frames they are made of. Lines and arcs are checked in closed form instead
    (`projects_back`, from `s₁` alone): no region and no spine table to build (most of the
    preparation's compilation).
    """

    frames: TargetFrames  # what the points are bent with
    # What the images are checked on: the spine's `fast_evaluator`, or the line or arc itself.
    target: AbstractSpine | SpineTable
    method: str = eqx.field(static=True)
    check_projection: bool = eqx.field(static=True)
    region: ValidRegion | None  # for the projection check, without a closed-form foot
    ends: EndFrames | None  # the target's end frames, for `beyond="rigid"`
    fallback: bool = eqx.field(static=True)

    def __init__(
        self, target, method, twist, check_projection=True, margin=0.0, start=None,
        beyond="continue", fallback=False, checked_on=None, certificate=None,
    ):
        """`start`: the source's `EndFrames`, from which the target's first normal is carried
        (`ends.aligned_twist`; `None`: the target's own, for callers that align the twist
        themselves); `beyond`: `"continue"` or `"rigid"` (`ends`); `fallback`: the points
        registered on the source but not validly bent keep their image (still flagged): the
        map's formulas continued past their conditions, continuous in the point and the target
        (the radial map compresses its concave side towards the centre past `k·d* =
        WHOLE_FROM`, flagged from there, never across it: `maps.radial_bend_whole`), where
        otherwise they are left where they were. `checked_on`: a spine with a table of its
        own (`_table`) that equals `target` far within the projection check's resolution (its
        samples' spacing), on which the check's valid region is built instead (a bent limb
        read from its rest spine's table, in double precision: `_skeleton.posing`); the
        points are still bent on `target` exactly. `certificate`: the samples of the valid
        region's reach certificate (`ValidRegion`; default its own samples')."""
        self.fallback = fallback
        target = target._prepare()  # once: each preparation is traced again
        if start is not None:
            twist = aligned_twist(start, target, twist)
        self.ends = target_ends(target, twist) if beyond == "rigid" else None
        closed = target._has_closed_form_foot()
        # Tabulated from the spine table (its nodes are the table's, so no exact evaluation),
        # but for lines and arcs: cheap to evaluate exactly, and checked without the table,
        # so that none is built (half the preparation's compilation of an arc).
        # (A table the target makes of itself holds its jet alone: the region reads no more.)
        self.target, at_nodes = ((target, None) if closed
                                 else fast_evaluator_at_nodes(target, jet_only=True))
        self.frames = TargetFrames(self.target, twist, tabulate=tabulates(target),
                                   at_nodes=at_nodes)
        self.method, self.check_projection = method, check_projection
        use = check_projection and not closed
        checked = self.target if checked_on is None or not use else _own_table(checked_on)
        self.region = ValidRegion(checked, margin, certificate=certificate) if use else None

    @property
    def fused(self) -> bool:
        """Whether the target is tabulated (so are the frames), or cheap exactly (lines):
        batches then run whole (`map_chunks`)."""
        return runs_whole(self.target)

    def pose(self, registration: Registration) -> tuple[Array, Array]:
        """`pose_point` for a batch of registered points (`length` shared or repeated per
        point): `(images (n, 3), valid (n,))`.

        On looked-up frames (`fused`), from `PLACED_APART_FROM` points on, the points are
        bent (`bend`), the pending ones tested at their images placed from there, and all
        placed (`place`), as the eager pose does (`eager`): bent into images that the
        region's test reads too, XLA computed the bend in one kernel per looked-up
        coefficient, even where no point was pending (spot's head at 104,644 vertices: 10.0
        → 6.5 ms, none pending)."""
        if self.fused and registration.points.shape[0] >= PLACED_APART_FROM:
            bent = self.bend(registration)
            valid = bent.certified
            if self.region is not None:  # the sampled test, for the images left pending
                valid = clear_where(bent.pending, self.region, valid,
                                    (bent.arc_length, bent.x, bent.y), place=self._placed)
            kept = self._kept(valid, registration)
            return self.rigid(registration, self.place(bent._replace(kept=kept),
                                                       registration.points), valid)
        image, s1, valid, pending = self._bent_images(registration)
        if self.region is not None:  # the sampled test, for the images left pending
            # (On this pass's images: bent again in the test's loops, the bend was traced and
            # compiled twice more, half of a bent B-spline limb's posing program.)
            valid = clear_where(pending, self.region, valid, (image, s1))
        image = jnp.where(self._kept(valid, registration)[:, None], image, registration.points)
        return self.rigid(registration, image, valid)

    def _placed(self, bent: tuple[Array, Array, Array]) -> tuple[Array, Array]:
        """`(image (3,), s₁)` of one point bent to `(s₁, x, y)` (`bend`; the region's test's
        inputs): its frame looked up, not bent again."""
        s1, x, y = bent
        return in_frame(self.frames(s1), jnp.stack([x, y])), s1

    def _kept(self, valid: Array, registration: Registration) -> Array:
        """(n,) the points whose image is kept: the valid ones, and with `fallback` every
        point registered on the source."""
        return valid | registration.valid if self.fallback else valid

    def rigid(self, registration: Registration, images: Array, valid: Array):
        """`(images, valid)` with the points beyond the source's ends moved rigidly with the
        end frames (`beyond="rigid"`, valid where finite); as they are otherwise."""
        if self.ends is None:
            return images, valid
        reg = registration

        def one(ends, x, s, length):
            return rigid_beyond(ends, self.ends, x, s, length)

        axes = batch_axes((reg.ends, reg.points, reg.arc_length, reg.length))
        moved, outside = jax.vmap(one, in_axes=axes)(reg.ends, reg.points, reg.arc_length,
                                                     reg.length)
        finite = jnp.all(jnp.isfinite(reg.points), axis=-1)
        return jnp.where(outside[:, None], moved, images), jnp.where(outside, finite, valid)

    def pose_certified(self, registration: Registration) -> tuple[Array, Array, Array]:
        """`pose` without the region's sampled check: `(images, valid, pending)`, where the
        pending points (valid but not certified by the reach bound; none on lines and arcs)
        have their image but are not valid yet, for `eager` to check them."""
        image, _, certified, pending = self._bent_images(registration)  # (`_`: s₁)
        kept = self._kept(certified | pending, registration)
        return jnp.where(kept[:, None], image, registration.points), certified, pending

    def bend(self, registration: Registration) -> Bent:
        """`pose_certified` up to the images: where each point goes, as a `Bent` (the
        target's frames looked up for its curvature only)."""

        def offset(reg):
            s1 = target_arc_length(reg, self.frames)
            d1, (registered, within_limit, inside_target) = bent_offset(
                reg, self.frames, s1, self.frames(s1)[3], self.method, self.fallback,
                self.ends,
            )
            return s1, d1[0], d1[1], registered & within_limit & inside_target, norm(d1)

        s1, x, y, valid, distance = jax.vmap(offset, in_axes=(batch_axes(registration),))(
            registration
        )
        certified, pending = self._certify(valid, s1, distance)
        return Bent(s1, x, y, certified, pending, self._kept(certified | pending, registration))

    def place(self, bent: Bent, points: Array) -> Array:
        """The images of `bend`, `(n, 3)`, or the `points` themselves where neither certified
        nor pending.

        On looked-up frames, placed a coordinate at a time into a (3, n) array, made (n, 3)
        by a product with the identity: placed as (n, 3) points, XLA's CPU backend fused the
        three coordinates into one kernel that ran a point's coordinates one by one, not
        vectorised (spot's head at 104,644 vertices: CPU 3.8 → 3.3 ms a frame). Its rows are
        the coordinates' values exactly; the product sees only placed points (finite: a
        point left as it is, a non-finite coordinate among finite ones, keeps them all)."""
        if self.frames.table is None:
            def image(s1, x, y, kept, point):
                return jnp.where(kept, self._placed((s1, x, y))[0], point)

            return jax.vmap(image)(bent.arc_length, bent.x, bent.y, bent.kept, points)
        c, i, j = self.frames.coordinates(bent.arc_length)
        rows = jnp.stack([jnp.where(bent.kept, c[a] + bent.x * i[a] + bent.y * j[a], 0)
                          for a in range(3)])
        placed = jnp.einsum("an,ab->nb", rows, jnp.eye(3, dtype=rows.dtype))
        return jnp.where(bent.kept[:, None], placed, points)

    def projects(self, registration: Registration, images: Array) -> Array:
        """The region's sampled check (n,) of registered points' `images` (n, 3), as this
        poser placed them. (Bent again in the check's loop, the bend was compiled twice: the
        eager pose's program for its pending points: 17.0 → 4.7 s on the tube's limb bent
        175°, test XLA flags.)"""
        return clear_all(self.region, (images, target_arc_length(registration, self.frames)))

    def _bent_images(self, registration: Registration) -> tuple[Array, Array, Array, Array]:
        """`(images, s₁, certified, pending)`: `s₁` the images' arc lengths on the target;
        certified by the reach bound or checked in closed form (or valid, without the check);
        pending: the valid points that the bound does not certify, for the sampled test."""
        image, valid, s1, distance = jax.vmap(
            lambda reg: bend_point(reg, self.frames, self.method, self.fallback, self.ends),
            in_axes=(batch_axes(registration),),
        )(registration)
        return image, s1, *self._certify(valid, s1, distance)

    def _certify(self, valid: Array, s1: Array, distance: Array) -> tuple[Array, Array]:
        """`(certified, pending)` of valid images at `s₁` and `distance` from the target."""
        if not self.check_projection:
            return valid, jnp.zeros_like(valid)
        if self.region is not None:
            certified = valid & jax.vmap(self.region.certified)(s1, distance)
            return certified, valid & ~certified
        # A line or an arc: checked in closed form from `s₁` alone (`projects_back`).
        lo, hi = search_range(self.target)
        checked = jax.vmap(lambda s: self.target._foot_is_unique(s, lo, hi))(s1)
        return valid & checked, jnp.zeros_like(valid)

    def pose_all(self, registration: Registration) -> tuple[Array, Array]:
        """`pose` for any number of registered points: in chunks (`map_chunks`) with exact
        frames, whole with tabulated ones."""
        return map_chunks(self.pose, registration, whole=self.fused)


# Below this many points a checked `Poser.pose` bends them into images (one program's kernels
# fewer): spot's 2,930 vertices, 1 / 3 / 9 limbs posed a frame, were 5-10 % slower placed apart.
PLACED_APART_FROM = 8192


def _own_table(spine: AbstractSpine) -> SpineTable:
    """The table `spine` makes of itself (`Poser`'s `checked_on`), or `ValueError`."""
    table = spine._prepare()._table(jet_only=True)  # (the region reads its jet alone)
    if table is None:
        raise ValueError(f"a spine checked on must have a table of its own, got {type(spine)}.")
    return table


class Bent(NamedTuple):
    """Registered points bent onto a target, not yet placed there (`Poser.bend`): the arc
    length `s₁` on the target, the offset `(x, y)` in its twisted normals (`d₁`), and the
    flags of `Poser.pose_certified`, and those placed (certified, pending, or kept by the
    poser's `fallback`); each (n,)."""

    arc_length: Array
    x: Array
    y: Array
    certified: Array
    pending: Array
    kept: Array


def pose_points(
    registration: Registration,
    target: AbstractSpine,
    method: str,
    twist: Array,
    check_projection: bool = True,
    margin: Array = 0.0,
    beyond: str = "continue",
) -> tuple[Array, Array]:
    """`pose_point` for registered points: `(images (N, 3), valid (N,))`.

    Tabulated frames (single precision) bend all points at once: a few values per point, fused
    into a few kernels. Exact spines bend in chunks (`_batching.chunks`), their evaluation
    having many intermediates per point.
    """
    poser = Poser(target, method, twist, check_projection, margin, registration.ends, beyond)
    return poser.pose_all(registration)


def flesh_points(
    points: Array,
    source: AbstractSpine,
    target: AbstractSpine,
    method: str,
    twist: Array,
    check_projection: bool = True,
    samples: int | None = None,
    margin: Array = 0.0,
    beyond: str = "continue",
) -> tuple[Array, Array]:
    """`register_points` then `pose_points`, chunk by chunk: the registration of all points is
    never held in memory at once."""
    registrar = Registrar(source, samples, margin)
    start = EndFrames(registrar.exact)
    poser = Poser(target, method, twist, check_projection, margin, start, beyond)
    return map_chunks(lambda chunk: poser.pose(registrar.register(chunk)), points)


class Fleshing(eqx.Module):
    """A locally volume-preserving map from around `source` to around `target`.

    `M = Fleshing(C0, C1, method="radial", twist=0.0)`; `M(x)` maps one point (3,) → (3,) and
    works under `jit`, `vmap`, `jax.jacfwd` and `grad` (also with respect to the spines'
    parameters and `twist`). Points outside the valid space are returned unchanged; test them
    with `M.is_valid(x)` or get both at once with `M.apply(x)`.

    **Arguments:**

    - `source`, `target`: `AbstractSpine`s (`C0`, `C1`); their lengths may differ.
    - `method`: `"radial"`, `"normal"`, `"binormal"` or `"skinning"` (the uncorrected baseline).
    - `twist`: scalar global twist in radians about `T₁(0)`, from the source's first normal
      carried to the target's start (`ends.aligned_twist`).
    - `check_projection`: also require that `M(x)` projects back on `target` at the mapped arc
      length only (the target's valid region: catches spines that come back near themselves).
    - `margin`: a point is valid only if the ball of this radius around it is clear of the
      source's cut locus and focal set, where the map is discontinuous (and its image's ball
      of the target's, with `check_projection`); see `register`.
    - `beyond`: `"continue"` (default: points that project before `s = 0` or past the end are
      fleshed against the spines' continuations) or `"rigid"` (they move rigidly with the
      end frames: a body behind a bent tail stays still); see `_fleshing.ends`.

    The target's first normal is the source's carried by the smallest rotation taking
    `T₀(0)` to `T₁(0)`, and `twist` turns it from there.
    """

    source: AbstractSpine
    target: AbstractSpine
    twist: Array
    margin: Array
    method: str = eqx.field(static=True)
    check_projection: bool = eqx.field(static=True)
    beyond: str = eqx.field(static=True)

    def __init__(
        self,
        source,
        target,
        *,
        method="radial",
        twist=0.0,
        check_projection=True,
        margin=0.0,
        beyond="continue",
    ):
        _check_spine(source, "source")
        _check_spine(target, "target")
        self.source, self.target = source, target
        self.method = check_method(method)
        self.twist = as_twist(twist)
        self.margin = as_margin(margin)
        self.check_projection = bool(check_projection)
        self.beyond = check_beyond(beyond)

    def apply(self, x: ArrayLike) -> tuple[Array, Array]:
        """`(M(x), valid)` for one point `x` (3,)."""
        x = _check_points(x, "x", single=True)
        if not is_concrete(self, x) and compiling():
            # Inside a user's compiled program (`jit`, and `jacfwd` or `vmap` under it) a
            # nested compiled program is traced, then rewritten by each transformation;
            # inline, it is traced once (notebook 02's `jacfwd` of four methods under `vmap`
            # and `jit`: tracing and lowering 12 → 8.5 s). Under transformations applied
            # eagerly (`jax.vmap(M)(points)`), the compiled program is transformed whole:
            # inline, each of its operations would be compiled and run on its own (300 points
            # through `vmap`: 2.5 → 0.4 s of CPU the first time; `jacfwd`: 2.7 → 0.7 s).
            return apply_point(self, x)
        return self._apply(x)

    @eqx.filter_jit
    def _apply(self, x):
        return apply_point(self, x)

    def __call__(self, x: ArrayLike) -> Array:
        """The image of one point `x` (3,), (3,) (unchanged if `x` is not valid)."""
        return self.apply(x)[0]

    def is_valid(self, x: ArrayLike) -> Array:
        """Whether `x` (3,) lies in the valid space of this fleshing (scalar bool)."""
        return self.apply(x)[1]

    @property
    def inverse(self) -> Fleshing:
        """The fleshing back from `target` to `source` (same method, opposite twist)."""
        return Fleshing(
            self.target,
            self.source,
            method=self.method,
            twist=-self.twist,
            check_projection=self.check_projection,
            margin=self.margin,
            beyond=self.beyond,
        )


def apply_point(fleshing: Fleshing, x: Array) -> tuple[Array, Array]:
    """`Fleshing.apply` not compiled on its own: for the library's functions that transform
    it inside their own compiled program (`jacobian_determinant`). Their transformations then
    trace this code once, rather than a nested program and then each of their rewrites of it
    (`jacobian_determinant`'s program on polylines and on helices: 27 and 33 % less time
    tracing, 3.4 → 2.5 s and 1.6 → 1.1 s, the same program)."""
    source, target, twist, margin = cast_floats(
        (fleshing.source, fleshing.target, fleshing.twist, fleshing.margin), x.dtype
    )
    registration = register_point(source, x, margin=margin)
    check = fleshing.check_projection
    return pose_point(
        registration, target, fleshing.method, twist, check, margin, fleshing.beyond
    )


def _check_points(points: ArrayLike, name: str, single: bool = False) -> Array:
    return as_points(points, name, single)


def _check_spine(spine, name: str) -> None:
    if not isinstance(spine, AbstractSpine):
        raise TypeError(f"`{name}` must be a spine (AbstractSpine), got {type(spine)}.")


def register(
    points: ArrayLike, source: AbstractSpine, *, samples: int | None = None, margin: ArrayLike = 0.0
):
    """Registers `points` on the spine `source` (closest projection and local coordinates).

    **Arguments:** `points`: (N, 3) array; `source`: an `AbstractSpine`; `samples`: number of
    coarse samples of the closest-point search (default: the spine's `default_samples()`);
    `margin`: a point is valid only if the ball of this radius around it is clear of the
    spine's cut locus (points with two closest feet) and focal set, where the closest
    projection — and the map — is discontinuous (`_fleshing.region`). For a mesh, half its
    longest edge (what `deform_mesh` uses): then no edge with two valid ends is torn. The
    default 0 suits point sets: a point is valid when its own projection is unique (to within
    half the region's sample spacing, `length / 383`).

    **Returns:** a `Registration` (per-point arc length, offset, curvature and validity, and
    which invalid points are `discontinuous`), to be posed on any number of target spines
    with `pose`.
    """
    points = _check_points(points, "points")
    _check_spine(source, "source")
    samples = source.default_samples() if samples is None else int(samples)
    margin = as_margin(margin, points.dtype)
    # (Spines padded to a bucket of sizes, as the batch: `AbstractSpine._bucketed`.)
    registrar = _registrar(cast_floats(source, points.dtype)._bucketed(), samples, margin)
    # The points are put in outside the compiled call: returned from it, they would be copied.
    if is_concrete(points):  # called eagerly: the global search compiled only if needed
        n = points.shape[0]  # and the batch padded to a bucket size (`_batching.buckets`)
        fields = register_eagerly(registrar, pad_batch(points, bucket(n)))
        return Registration(points, *unpad_batch(fields, n))
    return Registration(points, *_register(registrar, points))


# The prepared spine (tables, search samples, reach bounds) is built by a compiled call of its
# own: compiled with the points, XLA fuses parts of it into every point's kernel (2× slower).
# It runs once per registration, on the spine alone: compiled quickly (`_batching.quick`).
@Program
def _registrar(source, samples, margin=0.0):
    return Registrar(source, samples, margin)


@eqx.filter_jit
def _register(registrar, points):
    r = registrar.register_all(points)
    return r.arc_length, r.offset, r.curvature, r.valid, r.discontinuous, r.length, r.ends


def pose(
    registration: Registration,
    target: AbstractSpine,
    *,
    method: str = "radial",
    twist: ArrayLike = 0.0,
    check_projection: bool = True,
    margin: ArrayLike = 0.0,
    beyond: str = "continue",
) -> tuple[Float[Array, "N 3"], Bool[Array, " N"]]:
    """Poses registered points on a new spine: the per-frame path of an animation.

    Same result as `flesh(points, source, target, ...)` without repeating the projection.

    **Arguments:** `registration` from `register`; `target` spine; `method`, `twist`,
    `check_projection`, `margin` (on the target) and `beyond` as for `Fleshing`.

    **Returns:** `(deformed (N, 3), valid (N,) bool)`, in the dtype of the registered points.
    """
    if not isinstance(registration, Registration):
        raise TypeError(f"`registration` must come from `register`, got {type(registration)}.")
    options = dict(method=method, twist=twist, check_projection=check_projection, margin=margin,
                   start=registration.ends, beyond=beyond)
    return pose_prepared(registration, prepare_target(target, registration.points.dtype, **options))


def prepare_target(
    target: AbstractSpine,
    dtype,
    *,
    method: str = "radial",
    twist: ArrayLike = 0.0,
    check_projection: bool = True,
    margin: ArrayLike = 0.0,
    start: EndFrames | None = None,
    beyond: str = "continue",
    fallback: bool = False,
    checked_on: AbstractSpine | None = None,
    certificate: int | None = None,
) -> Poser:
    """`target` prepared once for posing points of `dtype` (`pose` = `pose_prepared` of this):
    a compiled call of its own, which `_mesh.overlap` may run beside the registration.
    `start`: the source's `EndFrames` (`Registration.ends`, or `EndFrames(source)`), from
    which the target's first normal is carried; `beyond` as for `Fleshing`; `fallback`,
    `checked_on` and `certificate` as for `Poser`."""
    _check_spine(target, "target")
    target, twist, start, checked_on = cast_floats(
        (target, as_twist(twist, dtype), start, checked_on), dtype)
    margin = as_margin(margin, dtype)
    options = (check_method(method), twist, bool(check_projection), margin, start,
               check_beyond(beyond), bool(fallback), checked_on, certificate)
    return _poser(target._bucketed(), *options)


def pose_prepared(registration: Registration, poser: Poser) -> tuple[Array, Array]:
    """`pose` onto a target from `prepare_target` (with the registered points' dtype)."""
    # Called eagerly (the points and the target known): the sampled check compiled only if
    # needed, and the batch padded to a bucket size. A traced target (`grad` in a pose's
    # parameters) or registration: one program.
    if is_concrete(registration, poser):
        n = registration.points.shape[0]
        padded = invalid_past(pad_batch(registration, bucket(n)), n)
        return unpad_batch(pose_eagerly(poser, padded), n)
    return _pose(poser, registration)


@eqx.filter_jit
def _poser(target, method, twist, check_projection, margin=0.0, start=None, beyond="continue",
           fallback=False, checked_on=None, certificate=None):
    # (compiled apart, as `_registrar`)
    return Poser(target, method, twist, check_projection, margin, start, beyond, fallback,
                 checked_on, certificate)


@eqx.filter_jit
def _pose(poser, registration):
    return poser.pose_all(registration)


def flesh(
    points: ArrayLike,
    source: AbstractSpine,
    target: AbstractSpine,
    *,
    method: str = "radial",
    twist: ArrayLike = 0.0,
    check_projection: bool = True,
    margin: ArrayLike = 0.0,
    beyond: str = "continue",
    progress: bool | None = None,
    stretch: bool = False,
) -> tuple[Array, ...]:
    """Bends `points` from around `source` to around `target`, preserving local volume.

    **Arguments:**

    - `points`: (N, 3) array (float32 in, float32 out).
    - `source`, `target`: `AbstractSpine`s.
    - `method`: `"radial"`, `"normal"`, `"binormal"` or `"skinning"`.
    - `twist`: scalar twist in radians.
    - `check_projection`, `margin`, `beyond`: see `Fleshing` and `register`.
    - `progress`: show a progress bar (`tqdm`, on stderr) over the blocks of a large batch
      (default: when there are at least `PROGRESS_BLOCKS` of them).
    - `stretch`: also return, at each point, the largest factor by which the map stretches or
      squeezes a direction (`fj.principal_stretch` of this fleshing: by `jax.jacfwd`, several
      times the work of the bend, in one batch). A valid bend keeps volume, yet near the edge
      of its range it can draw a part out into a spike; the command line refuses it beyond
      `--max-stretch`. (`fj.deform_mesh(..., stretch=True)` measures it chunk by chunk.)

    Memory stays bounded on large batches: called eagerly on tabulated spines, more than
    `BLOCK_POINTS` points are fleshed a block at a time into the output (whose buffer is
    updated in place), so that the peak is the input and output arrays plus one block's work.

    **Returns:** `(deformed (N, 3), valid (N,) bool)`; with `stretch`, `(deformed, valid,
    stretch (N,))`, NaN where not valid. Invalid points (outside the valid space, or not
    finite) are returned unchanged and flagged `False`; they never raise.
    """
    points = _check_points(points, "points")
    _check_spine(source, "source")
    _check_spine(target, "target")
    method, check_projection = check_method(method), bool(check_projection)
    twist = as_twist(twist, points.dtype)  # checked before any work
    margin = as_margin(margin, points.dtype)
    beyond = check_beyond(beyond)
    if not isinstance(stretch, bool | np.bool_):
        raise TypeError(f"`stretch` must be a bool, got {type(stretch).__name__}.")
    if stretch:
        from .verify import principal_stretch  # (it builds on this module)

        fleshing = Fleshing(source, target, method=method, twist=twist, margin=margin,
                            check_projection=check_projection, beyond=beyond)
        options = dict(method=method, twist=twist, check_projection=check_projection,
                       margin=margin, beyond=beyond, progress=progress)
        return *flesh(points, source, target, **options), principal_stretch(fleshing, points)
    cast_source, cast_target = cast_floats((source, target), points.dtype)
    if points.shape[0] <= _chunks.CHUNK_POINTS or (
        runs_whole(cast_source) and runs_whole(cast_target)
    ):
        # One chunk, or tabulated or cheap spines (whose batches run whole): nothing to gain
        # from one program, and compiled apart, the registration is compiled once for all the
        # methods and targets a shape is fleshed onto. (In one program XLA fuses the
        # registration's lookups into the pose's kernels, ~1.5× slower than the two calls.)
        options = dict(method=method, twist=twist, check_projection=check_projection,
                       margin=margin, beyond=beyond)
        if is_concrete(points) and points.shape[0] > BLOCK_POINTS:
            return _flesh_in_blocks(points, source, target, options, progress)
        return pose(register(points, source, margin=margin), target, **options)
    samples = source.default_samples()
    n = points.shape[0]
    padded = pad_batch(points, bucket(n)) if is_concrete(points) else points
    images, valid = _flesh(padded, cast_source._bucketed(), cast_target._bucketed(), method,
                           twist, check_projection, samples, margin, beyond)
    return unpad_batch((images, valid), n)


@eqx.filter_jit
def _flesh(points, source, target, method, twist, check_projection, samples, margin, beyond):
    options = (twist, check_projection, samples, margin, beyond)
    return flesh_points(points, source, target, method, *options)


BLOCK_POINTS = 1 << 21  # points fleshed at a time in large eager batches (~100 MB of work)
PROGRESS_BLOCKS = 4  # the default progress bar is shown from this many blocks on


def _flesh_in_blocks(points, source, target, options, progress):
    """`flesh` a block of `BLOCK_POINTS` at a time (the last one padded with copies of the
    last point, so that every block runs the same compiled programs), each written into the
    output in place."""
    n, size = points.shape[0], BLOCK_POINTS
    count = -(-n // size)
    show = count >= PROGRESS_BLOCKS if progress is None else bool(progress)
    images = jnp.zeros_like(points)
    valid = jnp.zeros(n, bool)
    blocks = range(count)
    if show:
        from tqdm.auto import tqdm

        blocks = tqdm(blocks, desc="flesh", unit="block", leave=False)
    for b in blocks:
        start = min(b * size, n - size)  # the last block overlaps the one before: same size
        block = jax.lax.dynamic_slice_in_dim(points, start, size)
        image, ok = pose(register(block, source, margin=options["margin"]), target, **options)
        images, valid = _write_block(images, valid, image, ok, jnp.asarray(start, jnp.int32))
    return images, valid


@eqx.filter_jit(donate="all")
def _write_block(images, valid, image, ok, start):
    update = jax.lax.dynamic_update_slice_in_dim
    return update(images, image, start, 0), update(valid, ok, start, 0)

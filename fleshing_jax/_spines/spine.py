"""The spine interface, and the continuation of every spine beyond its ends.

A spine is a smooth curve `C(s)` parameterised by arc length on `[0, length]`. Concrete spines
implement four private methods valid on `[0, length]`; this module turns them into the public
methods, which are defined for every `s`: beyond its ends a spine continues along its
osculating circle there (a straight ray where the end curvature is zero). Position, tangent and
curvature vector are then continuous through the ends, so the fleshing of points that project
beyond the ends is continuous and still exactly volume preserving.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from .._numerics import dot, norm, safe_divide, safe_sqrt


def initial_normal(tangent: Array) -> Array:
    """The fixed rule that picks the first normal of a twist-compensated frame.

    The coordinate axis least aligned with `tangent` (the first one on ties, within 1e-4), made
    orthogonal to it and normalised. Two spines that start with the same tangent thus start with
    the same frame.

    **Arguments:** `tangent`: (3,) unit vector. **Returns:** (3,) unit vector orthogonal to it.
    """
    # Ties are broken with a small margin, so that round-off in an axis-aligned tangent (common:
    # computed tangents such as (1, 6e-17, 2e-17)) cannot flip the choice and rotate the whole
    # frame by 90°. Any such rule jumps somewhere on the sphere; the margin moves the jump away
    # from the axes, where fits and straight rest spines live.
    margin = jnp.asarray([0.0, 1e-4, 2e-4], tangent.dtype)
    axis = jnp.eye(3, dtype=tangent.dtype)[jnp.argmin(jnp.abs(tangent) + margin)]
    normal = axis - dot(axis, tangent) * tangent
    return normal / norm(normal)


def _circle_functions(kk: Array, t: Array) -> tuple[Array, Array, Array]:
    """`cos(κt)`, `sin(κt)/κ` and `(1 − cos(κt))/κ²` as smooth functions of `kk = κ²`.

    All three are entire in `κ²`, so they are exact (and differentiable) at `κ = 0`, where they
    become `1`, `t` and `t²/2`: the straight-ray continuation.
    """
    kappa = safe_sqrt(kk)
    x = kappa * t / jnp.pi  # jnp.sinc(x) = sin(πx)/(πx), smooth at 0
    cos = jnp.cos(kappa * t)
    sin_over_k = t * jnp.sinc(x)
    one_minus_cos_over_kk = 0.5 * t**2 * jnp.sinc(x / 2) ** 2
    return cos, sin_over_k, one_minus_cos_over_kk


def _continue(jet: tuple[Array, Array, Array], normals: tuple[Array, Array], t: Array):
    """Jet and frame at signed distance `t` past an end, along the end's osculating circle.

    `jet = (C, T, k)` and `normals = (I, J)` at the end. The circle has zero torsion, so its
    rotation-minimising frame is the end frame rotated with the tangent about the binormal.
    """
    c, tangent, k = jet
    kk = dot(k, k)
    cos, sin_k, vers_kk = _circle_functions(kk, t)
    position = c + sin_k * tangent + vers_kk * k
    new_tangent = cos * tangent + sin_k * k
    new_k = cos * k - kk * sin_k * tangent

    def rotate(v):  # the rotation taking T to the new tangent, applied to v ⟂ T
        return v - dot(v, k) * (vers_kk * k + sin_k * tangent)

    return (position, new_tangent, new_k), tuple(rotate(v) for v in normals)


class AbstractSpine(eqx.Module):
    """A smooth 3D curve parameterised by arc length on `[0, length]`.

    Subclasses provide `length` and the private methods `_jet`, `_normals` and `_torsion` on
    `[0, length]`. The public methods accept any `s` (scalar; `vmap` for many): beyond the ends
    the spine continues along its osculating circle there.
    """

    if TYPE_CHECKING:  # (a field or a property of each subclass)
        # Not an `eqx.AbstractVar` at run time: under `from __future__ import annotations`
        # equinox takes it for a field, and checks it after `__init__` by reading it, so that
        # a tabulated spine computed its tables (and compiled them for its size) when built.
        length: Array

    @abc.abstractmethod
    def _jet(self, s: Array) -> tuple[Array, Array, Array]:
        """Position, unit tangent and curvature vector at `s ∈ [0, length]`, each (3,)."""

    @abc.abstractmethod
    def _normals(self, s: Array) -> tuple[Array, Array]:
        """The rotation-minimising normals `(I, J)` at `s ∈ [0, length]`, each (3,).

        `I(0) = initial_normal(T(0))`, transported without twist; `J = T × I`.
        """

    @abc.abstractmethod
    def _torsion(self, s: Array) -> Array:
        """Torsion at `s ∈ [0, length]` (0 where the spine is straight)."""

    def _jet_and_normals(self, s: Array):
        """`(self._jet(s), self._normals(s))` at `s ∈ [0, length]`."""
        return self._jet(s), self._normals(s)

    def _anchors(self, s: Array) -> list:
        """`_jet_and_normals` at `s`, at 0 and at `length` (spines override it to share work)."""
        zero = jnp.zeros_like(self.length)
        return [self._jet_and_normals(x) for x in (s, zero, self.length)]

    def _end_anchors(self) -> list:
        """`_anchors` at 0 and at `length` only (spines with tables read them without
        evaluating the spine anywhere else: the end frames, `_fleshing.ends`)."""
        return self._anchors(jnp.zeros_like(self.length))[1:]

    def _prepare(self) -> AbstractSpine:
        """An equivalent spine for many evaluations in one trace (tables computed once)."""
        return self

    def _bucketed(self) -> AbstractSpine:
        """An equivalent spine whose compiled programs serve every spine of its bucket: its
        arrays padded to a few sizes, so that the eager entry points do not compile once per
        control-point count (`_batching.buckets`). Spines of a fixed size return themselves."""
        return self

    def _anchor_jets(self, s: Array) -> list:
        """`_jet` at `s`, at 0 and at `length` (spines override it to share work)."""
        zero = jnp.zeros_like(self.length)
        return [self._jet(x) for x in (s, zero, self.length)]

    def default_samples(self) -> int:
        """How many samples the coarse closest-point search uses on this spine (static)."""
        return 128

    def _breaks(self) -> Array:
        """Arc lengths where the spine's pieces join (K,), where it may be less smooth than
        elsewhere (quadratures split there: `bent`); none (the default) for analytic spines."""
        return jnp.zeros((0,), self.length.dtype)

    def _table(self, jet_only: bool = False):
        """This (prepared) spine's `table.SpineTable` if it has a cheaper way to build it than
        evaluating itself at the table's nodes (`bent`); `None` (the default) otherwise.
        `jet_only` (static): a table of the jet alone (`SpineTable.searchable`)."""
        return self._table_at_nodes(jet_only)[0]

    def _table_at_nodes(self, jet_only: bool = False):
        """`(_table(jet_only), (jet, normals))`: the table and the values it was fit to at its
        nodes, each (P, 4, 3), from which other tables on its pieces are fit (`TargetFrames`);
        `(None, None)` (the default) for a spine without a table of its own."""
        return None, None

    def _tabulable(self) -> bool:
        """Whether the batched single-precision paths may evaluate this spine through a table of
        cubic pieces (`table`): smooth spines yes, piecewise ones (polylines) no (static)."""
        return True

    def _continues_as_itself(self) -> bool:
        """Whether the spine's continuation past its ends (along the osculating circle there)
        is the spine itself, so that `_jet` and `_normals` hold for every `s` (lines, arcs;
        static): `jet` then evaluates them once, not also at both ends to continue from
        there (programs with arcs compile about twice as fast)."""
        return False

    def _is_cheap(self) -> bool:
        """Whether the spine is evaluated exactly in a few operations a point, fewer than a
        table lookup takes (lines): the batched paths then use it as it is, on whole batches
        (static)."""
        return False

    def _closest_start(self, x: Array, lo: Array, hi: Array) -> tuple[Array, Array] | None:
        """A closed-form closest projection of `x` (3,) on the spine continued over the search
        range `[lo, hi]`, for the batched registration: `(s, certified)`, certified when `s` is
        the unique closest point strictly inside the range. `None` (the default) where there is
        no closed form: the batched registration then searches (`_fleshing.projection`)."""
        return None

    def _foot_is_unique(self, s: Array, lo: Array, hi: Array) -> Array:
        """Where `_closest_start` has a closed form: whether every point in the normal plane
        at `s` (inside `(lo, hi)`) and inside the local reach there (`1 − k·d > 0`) has `s`
        as its unique foot on the spine continued over `[lo, hi]`. What the projection check
        of a pose needs: its images are built in that plane, so that it reads no foot."""
        raise NotImplementedError(f"{type(self).__name__} has no closed-form foot")

    def _has_closed_form_foot(self) -> bool:
        """Whether `_closest_start` has a closed form (static: the spine's type decides)."""
        return type(self)._closest_start is not AbstractSpine._closest_start

    def _foot_terms(self, x: Array, s: Array) -> tuple[Array, Array, Array]:
        """What the closest-point search needs at `s` for a point `x` (3,): `(f, slope,
        distance)`, where `f = (C − x)·T` vanishes at a foot, `slope = f'(s) = 1 − k·(x − C)`
        and `distance = |x − C|` (`SpineTable` computes the same from tabulated products)."""
        c, tangent, k = self.jet(s)
        d = x - c
        return -dot(d, tangent), 1 - dot(k, d), norm(d)

    def _local_terms(self, x: Array, s: Array) -> tuple[Array, Array, Array]:
        """`x` (3,) in the local frame at `s`: `(offset (2,), curvature (2,), slope)`, the
        offset `x − C` and the curvature vector in `(I, J)` coordinates and `1 − k·(x − C)`."""
        (c, _, k), (i, j) = self.jet_and_normals(s)
        d = x - c
        offset = jnp.stack([dot(d, i), dot(d, j)])
        curvature = jnp.stack([dot(k, i), dot(k, j)])
        return offset, curvature, 1 - dot(curvature, offset)

    def _split(self, s: ArrayLike) -> tuple[Array, Array, Array]:
        """`s` clamped to `[0, length]`, and the signed overshoots before 0 and past `length`.

        Selections use `where` rather than `clip`, whose derivative is 1/2 at the bounds.
        """
        s = jnp.asarray(s, dtype=self.length.dtype)
        before, after = s < 0, s > self.length
        inner = jnp.where(before, 0, jnp.where(after, self.length, s))
        return inner, jnp.where(before, s, 0), jnp.where(after, s - self.length, 0)

    def jet_and_normals(self, s: ArrayLike):
        """`((C, T, k), (I, J))` at any `s`: position, tangent, curvature vector, RMF normals."""
        return self._evaluate(s, with_normals=True)

    def jet(self, s: ArrayLike) -> tuple[Array, Array, Array]:
        """Position, unit tangent and curvature vector at `s`, each (3,)."""
        return self._evaluate(s, with_normals=False)[0]

    def _evaluate(self, s: ArrayLike, with_normals: bool):
        if self._continues_as_itself():
            s = jnp.asarray(s, dtype=self.length.dtype)
            return self._jet(s), (self._normals(s) if with_normals else ())
        inner, t0, t1 = self._split(s)
        if with_normals:
            anchors = self._anchors(inner)
        else:
            anchors = [(jet, ()) for jet in self._anchor_jets(inner)]
        # Continue from the end the point lies beyond (t = 0 inside: the identity).
        select = jnp.where(t0 < 0, 1, jnp.where(t1 > 0, 2, 0))
        jet, normals = _pick(select, anchors)
        return _continue(jet, normals, t0 + t1)

    def __call__(self, s: ArrayLike) -> Array:
        """The point `C(s)`, (3,)."""
        return self.jet(s)[0]

    def tangent(self, s: ArrayLike) -> Array:
        """The unit tangent `T(s) = C'(s)`, (3,)."""
        return self.jet(s)[1]

    def curvature_vector(self, s: ArrayLike) -> Array:
        """The curvature vector `k(s) = C''(s) = κN`, (3,); zero where the spine is straight."""
        return self.jet(s)[2]

    def torsion(self, s: ArrayLike) -> Array:
        """The torsion `τ(s)`, scalar; 0 on the circular continuations beyond the ends."""
        inner, t0, t1 = self._split(s)
        return jnp.where((t0 == 0) & (t1 == 0), self._torsion(inner), 0)

    def extension(self) -> tuple[Array, Array]:
        """How far past each end the closest-point search looks, `(before 0, after length)`.

        A quarter turn of the osculating circle at that end, at most `length`: far enough for
        points just beyond the ends, short of the continuation coming back on the spine.
        """

        def reach(s):
            k = self._jet(s)[2]
            kappa = safe_sqrt(dot(k, k))
            return jnp.minimum(self.length, 0.5 * jnp.pi / jnp.maximum(kappa, 1e-30))

        # Both ends in one batched evaluation: the same values (each end's own lanes), but the
        # spine's evaluation traced and compiled once, not twice (an exact spine's arc-length
        # inverse: a third of the operations of a skeleton's rest table program).
        before, after = jax.vmap(reach)(jnp.stack([jnp.zeros_like(self.length), self.length]))
        return before, after


def torsion_of(jet: Callable, s: Array) -> Array:
    """`τ = (T × k)·k′ / |k|²` at `s` from `jet`: `s ↦ (C, T, k)`, with `k′` by forward mode
    (0 where the spine is straight)."""

    def tangent_and_curvature(t):
        return jet(t)[1:]

    (tangent, k), (_, dk) = jax.jvp(tangent_and_curvature, (s,), (jnp.ones_like(s),))
    return safe_divide(dot(jnp.cross(tangent, k), dk), dot(k, k))


class Evaluators(NamedTuple):
    """Functions `(tables, s) → …` of a tabulated spine (see `PreparedSpine`)."""

    length: Callable  # tables → scalar
    jet: Callable  # → (C, T, k)
    jets: Callable  # → [jet at s, at 0, at length]
    evaluate: Callable  # → [(jet, (I, J)) at s, at 0, at length]
    torsion: Callable  # → scalar
    ends: Callable  # tables → [(jet, (I, J)) at 0, at length]

    def __repr__(self):
        # By the functions' names, not their addresses: the same in every process, as the key
        # of a program kept on disk (`_exported`) needs.
        names = (f"{name}={f.__module__}.{f.__qualname__}" for name, f in self._asdict().items())
        return f"Evaluators({', '.join(names)})"


class PreparedSpine(AbstractSpine):
    """A free-form spine with its tables (everything that does not depend on `s`) computed once.

    Internal: the projection and the fleshing prepare spines at the start of a traced call,
    so that coefficients, lengths and frame nodes are computed once per call rather than once
    per evaluation. Built from the live spine, it stays differentiable in its parameters.
    """

    tables: object
    functions: Evaluators = eqx.field(static=True)
    samples: int = eqx.field(static=True)
    tabulable: bool = eqx.field(static=True)

    def __init__(self, tables, functions: Evaluators, samples: int, tabulable: bool = True):
        self.tables, self.functions, self.samples = tables, functions, samples
        self.tabulable = tabulable

    @property
    def length(self):
        return _call(self.functions.length, self.tables)

    def _jet(self, s):
        return _call(self.functions.jet, self.tables, s)

    def _normals(self, s):
        return self._jet_and_normals(s)[1]

    def _jet_and_normals(self, s):
        return _call(self.functions.evaluate, self.tables, s)[0]

    def _anchors(self, s):
        return _call(self.functions.evaluate, self.tables, s)

    def _end_anchors(self):
        return _call(self.functions.ends, self.tables)

    def _anchor_jets(self, s):
        return _call(self.functions.jets, self.tables, s)

    def _torsion(self, s):
        return _call(self.functions.torsion, self.tables, s)

    def default_samples(self) -> int:
        return self.samples

    def _breaks(self) -> Array:
        # The piece breaks of a parametric spine's tables (`Tables.cumulative`), if any.
        cumulative = getattr(self.tables, "cumulative", None)
        return super()._breaks() if cumulative is None else cumulative

    def _tabulable(self) -> bool:
        return self.tabulable

    def _prepare(self):
        return self


@eqx.filter_jit
def _call(function, *args):
    return function(*args)


class AbstractTabulatedSpine(AbstractSpine):
    """A spine evaluated through tables computed from its parameters (free-form spines).

    Subclasses implement `_prepare()`, returning a `PreparedSpine`; every method delegates to it
    (under `jit`, XLA drops the tables a method does not use).
    """

    @abc.abstractmethod
    def _prepare(self) -> PreparedSpine:
        """The spine with its tables computed."""

    @property
    def length(self) -> Array:
        """The arc length of the spine (scalar, differentiable in its parameters)."""
        return self._prepare().length

    def _jet(self, s):
        return self._prepare()._jet(s)

    def _normals(self, s):
        return self._prepare()._normals(s)

    def _jet_and_normals(self, s):
        return self._prepare()._jet_and_normals(s)

    def _anchors(self, s):
        return self._prepare()._anchors(s)

    def _end_anchors(self):
        return self._prepare()._end_anchors()

    def _anchor_jets(self, s):
        return self._prepare()._anchor_jets(s)

    def _torsion(self, s):
        return self._prepare()._torsion(s)

    def _breaks(self):
        return self._prepare()._breaks()


def _pick(index: Array, candidates: list):
    """Selects `candidates[index]` leaf by leaf (all candidates are finite: safe under grad)."""

    def select(*leaves):
        return jnp.select([index == i for i in range(len(leaves))], leaves)

    return jax.tree.map(select, *candidates)

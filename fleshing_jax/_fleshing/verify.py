"""Verification of a fleshing with automatic differentiation: its Jacobian's determinant (the
local volume change) and its principal stretches (how far it squeezes the shape)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._batching.buckets import bucket, pad_batch, unpad_batch
from .._checks import is_concrete
from .._numerics import polish_root
from .._spines.spine import AbstractSpine
from .ends import rigid_beyond
from .pipeline import Fleshing, Poser, _check_points, apply_point, bend_point
from .projection import Registration, _foot_residual, _local_coordinates


def jacobian_determinant(fleshing: Fleshing, points: ArrayLike) -> Float[Array, " N"]:
    """`det ∂M/∂X` at each point, by forward-mode autodiff (`jax.jacfwd`).

    Equal to 1 (to round-off) for the three fleshings wherever the points are valid; skinning
    is the baseline that is not volume preserving.

    **Arguments:** `fleshing`: a `Fleshing`; `points`: (N, 3) array.

    **Returns:** (N,) array of determinants; NaN marks the points that are not valid
    (`fleshing.is_valid` is False there), where the map has no meaningful Jacobian.
    """
    return _per_point(jnp.linalg.det, fleshing, points)


def principal_stretch(fleshing: Fleshing, points: ArrayLike) -> Float[Array, " N"]:
    """At each point, the largest factor by which the map stretches or squeezes a direction.

    `max(σ₁, 1/σ₃)` for the singular values `σ₁ ≥ σ₂ ≥ σ₃` of `J = ∂M/∂X` (`jax.jacfwd`):
    1 for a rigid motion, 2 where a direction doubles or halves in length. A fleshing keeps
    `σ₁σ₂σ₃ = 1`, yet near the edge of its valid space it squeezes one direction and draws out
    another: a surface there is pressed into a blade or folded into wrinkles with no point
    flagged. This measures it exactly at the points, whatever the mesh's resolution (an edge's
    change of length, `fj.edge_stretch`, averages it over the edge).

    **Arguments:** `fleshing`: a `Fleshing`; `points`: (N, 3) array.

    **Returns:** (N,) array; NaN marks the points that are not valid (as
    `jacobian_determinant`).
    """
    return _per_point(stretch_of, fleshing, points)


def stretch_of(jacobian: Array) -> Array:
    """`max(σ₁, 1/σ₃)` of a (…, 3, 3) Jacobian; `inf` where it is singular. Its gradient is
    finite where singular values coincide (a rigid motion): only the values' own derivatives,
    never the singular vectors', enter it."""
    sigma = jnp.linalg.svd(jacobian, compute_uv=False)
    return jnp.maximum(sigma[..., 0], 1 / sigma[..., -1])


def _per_point(measure, fleshing: Fleshing, points: ArrayLike) -> Array:
    """`measure` (of a 3 × 3 Jacobian) at each of `points`, NaN where not valid."""
    if not isinstance(fleshing, Fleshing):
        raise TypeError(f"`fleshing` must be a `Fleshing`, got {type(fleshing)}.")
    points = _check_points(points, "points")
    fleshing = Fleshing(  # spines padded to a bucket of sizes (`AbstractSpine._bucketed`)
        fleshing.source._bucketed(),
        fleshing.target._bucketed(),
        method=fleshing.method,
        twist=fleshing.twist,
        margin=fleshing.margin,
        check_projection=fleshing.check_projection,
        beyond=fleshing.beyond,
    )
    if not is_concrete(points):
        return _measured(measure, fleshing, points)
    # Called eagerly: the Jacobians in one program per bucket of sizes (`_batching.buckets`),
    # shared by every measure, and the measure in a small one of its own. (With the measure
    # inside, `jacobian_determinant` and `principal_stretch` of one fleshing compiled the
    # map's Jacobian twice: a line onto a bent line, the stretch after the determinant took
    # 6.9 s of CPU, now 0.16 s.)
    n = points.shape[0]
    jacobians, valid = _jacobians_program(fleshing, pad_batch(points, bucket(n)))
    return unpad_batch(_masked(measure, jacobians, valid), n)


def _jacobians(fleshing: Fleshing, points: Array) -> tuple[Array, Array]:
    """`∂M/∂X` (N, 3, 3) and the validity (N,) at each of `points` (N, 3)."""
    return jax.vmap(jax.jacfwd(lambda x: apply_point(fleshing, x), has_aux=True))(points)


_jacobians_program = eqx.filter_jit(_jacobians)


@eqx.filter_jit
def _masked(measure, jacobians: Array, valid: Array) -> Array:
    """`measure` of each Jacobian (N, 3, 3), NaN where not `valid` (N,)."""
    return jnp.where(valid, measure(jacobians), jnp.nan)


def _measured(measure, fleshing, points):
    """`_per_point` traced in a caller's program."""
    return _masked(measure, *_jacobians(fleshing, points))


@eqx.filter_jit
def registered_stretch(source: AbstractSpine, registration: Registration,
                       poser: Poser) -> Float[Array, " N"]:
    """`principal_stretch` of the map from `source` onto a target prepared for posing (`poser`,
    from `prepare_target`, as the per-frame path prepares it) at points already registered on
    `source` (`registration`, (N,) points). Each point's foot is polished from its registered
    arc length (the exact implicit derivatives, `_numerics.polish_root`), so that neither the
    global search, the valid regions nor the target's preparation are differentiated (with
    them, the map at one point of a limb's bent B-spline compiles in 25 s). NaN where the
    registration is not valid; the images' projection check is the caller's."""
    source = source._prepare()
    reg = registration

    def image(x, s):
        s = polish_root(_foot_residual, s, (source, x))
        local = eqx.tree_at(lambda r: r.ends, _local_coordinates(source, x, s, True), reg.ends)
        bent = bend_point(local, poser.frames, poser.method, poser.fallback, poser.ends)[0]
        if poser.ends is None:
            return bent
        moved, outside = rigid_beyond(reg.ends, poser.ends, x, s, reg.length)
        return jnp.where(outside, moved, bent)

    def one(x, s, valid):
        jacobian = jax.jacfwd(image)(x, jax.lax.stop_gradient(s))
        return jnp.where(valid, stretch_of(jacobian), jnp.nan)

    return jax.vmap(one)(reg.points, reg.arc_length, reg.valid)

"""The batched paths called eagerly: two phases, the fallbacks compiled only if needed (the
registration's global search; a pose's sampled test of the valid region, `region`).

Under `jit`, `Registrar.register` and `Poser.pose` carry their global fallback (the
multi-candidate search for the points that the reach bounds do not certify) inside the
program, behind `update_where`: it is compiled even when no point needs it, and it is most of
the program (a line → arc pose: 4383 operations with it, 598 without; its compilation 8× the
rest's). Called with concrete points, `register` and `pose` instead run a lean program (two,
on looked-up spines: `register_eagerly`, `pose_eagerly`) that says which points are pending,
and compile and run the fallback for those points only, gathered into a batch of a
power-of-two size (so that a few programs serve every count). A
command-line call on a tame target therefore never compiles a global search. Results are
those of the one-program path: the same flags, and floats equal to their last bits (the two
programs are fused differently; tested).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._batching.chunks import map_chunks
from .._batching.quick import QUICK_BATCH, Program
from .projection import Registrar, Registration

MINIMUM_BATCH = 64  # the smallest batch of pending points (then 128, 256, …)
# Batches of up to this many points run their pending points as a batch of their own size:
# one fallback program a batch size whatever the count (a skeleton's limbs, all padded to one
# size, share it; each count's program compiled ~0.5 s to run for a millisecond).
WHOLE_BATCH = 1024


def pending_index(pending: Array) -> np.ndarray:
    """Indices of the pending points, padded with copies of the last one (recomputed
    identically, so that writing them back twice is harmless) to the batch's size for a
    batch of at most `WHOLE_BATCH` points, else to a power of two ≥ `MINIMUM_BATCH`."""
    index = np.flatnonzero(np.asarray(pending)).astype(np.int32)
    size = max(MINIMUM_BATCH, 1 << max(len(index) - 1, 0).bit_length())
    if pending.shape[0] <= WHOLE_BATCH:
        size = pending.shape[0]
    return np.pad(index, (0, size - len(index)), mode="edge")


def register_eagerly(registrar: Registrar, points: Array) -> tuple:
    """The fields of `registrar.register_all(points)` after `Registration.points`.

    On looked-up spines (`registrar.fused`) the fast path runs as two programs, as a pose
    does (`pose_eagerly`): the search's start, then Newton's polish and the local
    coordinates. In one, XLA fused the two into kernels that recompute the start's values
    (a B-spline's registration of a million points 147 → 97 ms; benchmarks/README.md)."""
    quick = points.shape[0] <= QUICK_BATCH  # (compiled quickly: compiling is most of it)
    if registrar.fused:
        start = _register_start(registrar, points, quick=quick)
        certified = _register_finish(registrar, points, *start, quick=quick)
    else:
        certified = _register_certified(registrar, points, quick=quick)
    return registered_pending(registrar, points, certified)


def certified_registration(registrar: Registrar, points: Array) -> tuple:
    """`(registration, pending, unclear, any_pending)`: the fast path's registration of
    `points` (n, 3), traced (in chunks on exact spines, `map_chunks`), for
    `registered_pending`; also traced by a caller that makes the registrar in the same
    program (`_skeleton.posing`)."""
    fields = map_chunks(registrar.register_certified, points, whole=registrar.fused)
    return _shared_and_pending(registrar, *fields)


def registered_pending(registrar: Registrar, points: Array, certified: tuple) -> tuple:
    """`register_eagerly`'s fields from the fast path's `certified` (`_register_certified`'s
    outputs): the sampled test and the global search run, each compiled only if a point needs
    it."""
    registration, pending, unclear, any_pending = certified
    quick = points.shape[0] <= QUICK_BATCH
    search, sampled = (bool(a) for a in np.asarray(any_pending))
    if sampled:  # before the search: its points are cleared with it
        registration = _register_clear(registrar, registration, pending_index(unclear),
                                       quick=quick)
    if search:
        registration = _register_pending(registrar, points, registration,
                                         pending_index(pending), quick=quick)
    r = registration
    return r.arc_length, r.offset, r.curvature, r.valid, r.discontinuous, r.length, r.ends


def pose_eagerly(poser, registration: Registration) -> tuple[Array, Array]:
    """`poser.pose_all(registration)` (`poser`: a `pipeline.Poser`).

    On looked-up frames (`poser.fused`), the points are bent and then placed by two programs:
    in one, XLA fuses the whole pose into its loop over the `(n, 3)` images, whose code LLVM
    leaves scalar as soon as it holds the bend; apart, the loops are vectorised (an arc's
    pose of a million points 17.6 → 8.4 ms, the bend's 14 bytes a point written and read back
    included; benchmarks/README.md). Exact frames (float64) are posed in one program: they
    would be evaluated in both."""
    if poser.fused:
        bent, any_pending = _bend(poser, registration)
        images = _place(poser, bent, registration.points)
        valid, pending = bent.certified, bent.pending
    else:
        images, valid, pending, any_pending = _pose_certified(poser, registration)
    if bool(any_pending):
        index = pending_index(pending)
        images, valid = _pose_pending(poser, registration, images, valid, index)
    if poser.ends is not None:  # beyond="rigid"
        images, valid = _rigid(poser, registration, images, valid)
    return images, valid


@eqx.filter_jit
def _rigid(poser, registration, images, valid):
    return poser.rigid(registration, images, valid)


_register_certified = Program(certified_registration)


@Program
def _register_start(registrar, points):
    return registrar.begin(points)


@Program
def _register_finish(registrar, points, s, certified):
    return _shared_and_pending(registrar, *registrar.finish(points, s, certified))


def _shared_and_pending(registrar, registration, pending, unclear):
    """The registration with its shared scalars, the two pending masks and whether any point
    is pending on each (one (2,) array: one transfer)."""
    any_pending = jnp.stack([jnp.any(pending), jnp.any(unclear)])
    return registrar.shared(registration), pending, unclear, any_pending


def _clear(registrar, registration, index):
    return registrar.clear_pending(registration, index)


# Kept (its trace on disk): a skeleton's registration prepares it ahead (`clear_ahead`).
_register_clear = Program(_clear, kept=True)


def clear_ahead(registrar, certified) -> None:
    """Starts compiling, in a thread, the sampled test that `registered_pending` runs on
    `certified` (`_register_certified`'s outputs, as `jax.ShapeDtypeStruct`s; `registrar`
    alike) should a point be unclear: its shapes are known ahead for a batch of at most
    `WHOLE_BATCH` points, whose pending points run as a batch of its size (`pending_index`).
    Compiled once the call found a point unclear (6 of spot's 9 limbs), it was traced,
    lowered and compiled at the end of a first `register_skeleton`, after every other
    program (0.4-0.7 s); ahead, it compiles while the registration's programs do. Where no
    point is unclear (the tests' tube), it is compiled for nothing, in its thread."""
    registration, _, unclear, _ = certified
    size = unclear.shape[0]
    if size <= WHOLE_BATCH:
        _register_clear.prepare(registrar, registration,
                                jax.ShapeDtypeStruct((size,), np.int32),
                                quick=size <= QUICK_BATCH)


@Program
def _register_pending(registrar, points, registration, index):
    part = registrar.register(points[index], closest=registrar.closest_global)
    fields = ("arc_length", "offset", "curvature", "valid", "discontinuous")

    def update(r):
        return tuple(getattr(r, name) for name in fields)

    values = tuple(a.at[index].set(b) for a, b in zip(update(registration), update(part)))
    return eqx.tree_at(update, registration, values)


@eqx.filter_jit
def _pose_certified(poser, registration):
    images, valid, pending = map_chunks(poser.pose_certified, registration, whole=poser.fused)
    return images, valid, pending, jnp.any(pending)


@eqx.filter_jit
def _bend(poser, registration):
    bent = poser.bend(registration)
    return bent, jnp.any(bent.pending)


@eqx.filter_jit
def _place(poser, bent, points):
    return poser.place(bent, points)


@eqx.filter_jit
def _pose_pending(poser, registration, images, valid, index):
    part = jax.tree.map(lambda a: a[index] if jnp.ndim(a) > 0 else a, registration)
    ok = poser.projects(part, images[index])  # (placed by the first phase: pending)
    kept = poser._kept(ok, part)
    images = images.at[index].set(jnp.where(kept[:, None], images[index], part.points))
    return images, valid.at[index].set(ok)

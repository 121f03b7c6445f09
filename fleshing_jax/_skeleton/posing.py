"""Posing a mesh limb by limb: each limb's region fleshed along its own spine, children carried.

`register_skeleton` registers each limb's region on the limb's rest spine, once per mesh and
skeleton; `pose_skeleton` then poses it (the per-frame path, compiled once per set of posed
limbs). A posed limb's target is its rest spine bent from the joint (`fj.BentSpine`, from a
`LimbPose`), or a spine the caller gives. Fleshing maps the region with `det J = 1`; a vertex
past the spine's end moves rigidly with the end frame (`beyond="rigid"`).

No crack at a region's borders, by construction of where the bend starts and stops:

- **Joint.** The bend starts at the largest arc length of the region's vertices on its border
  with the parent (or the limb's own `joint`, if larger). Before it the bent spine is the rest
  spine (frames and all), so those vertices map to themselves (to round-off): the seam with the
  still parent is closed.
- **Joint zone.** The bend is concentrated just past the joint, in the shortest zone that
  keeps the map's curvature bound for the angle (`joint_zone`): the limb past it moves as one
  rigid piece, as a bone does.
- **Children.** A limb's bend is complete by the smallest arc length of its vertices on its
  borders with its child limbs; past it the bent spine is the rest spine moved rigidly, and so
  is the fleshing. A child's region is first fleshed by its own pose (if any: it is still up to
  its own joint), then moved by that same rigid motion (its parent's end frame), composed with
  those of the parent's ancestors.
- **Children riding on the map.** A limb with several children (a head with its ears), posed
  while none of them is, is registered with their regions as one (`WholeLimb`): its bend may
  then run on past their borders, the fleshing moving them with it (`carrying`).

The body, and every limb that is not posed and has no posed ancestor, are never touched: they
stay bit for bit.
"""

from __future__ import annotations

import dataclasses
import hashlib
from functools import partial
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._batching.buckets import bucket, pad_batch, unpad_batch
from .._batching.quick import QUICK_BATCH, Program
from .._checks import as_margin, is_concrete
from .._exported import persistent
from .._fleshing.eager import certified_registration, clear_ahead, registered_pending
from .._fleshing.ends import EndFrames, aligned_twist, target_ends
from .._fleshing.methods import check_method
from .._fleshing.pipeline import Poser, pose_prepared, prepare_target
from .._fleshing.projection import Registrar, Registration, invalid_past
from .._mesh.deform import longest_edge, polygon_mesh
from .._numerics import cast_floats, on_device
from .._spines.looked_up import LookedUpSpine
from .._spines.spine import AbstractSpine
from .._spines.table import tabulable, tabulates
from .joint_zone import JointZone, joint_zone
from .limb_pose import LimbPose, sane_angles
from .restore import corner_table, rest_volume, restored_volume
from .skeleton import Skeleton, descendants, limb_index
from .spill import spilled


class WholeLimb(eqx.Module):
    """A limb with several children (a head with its ears, horns or antennae) registered with
    its descendants' regions (`below`, static) on its rest spine: what a pose of the limb
    that leaves them all unposed bends, as one region (`carrying`). Its children then ride on
    its map, exact wherever it is, and its zone may run on past their borders to the end of
    its spine: spot's head, whose ears and horns begin a fifth of the way along it, takes
    27.5° in any direction instead of 9.0°. Only where they lie within the limb's own reach
    about its spine (no vertex of theirs farther from it than its own farthest): cheburashka's
    ears, reaching twice as far as its head, would be stretched into spikes by a bend past
    the range (blended towards their cross-sections' motion, `restore`), which carried
    rigidly they are not. `registration`, `indices` (m,), `joint`, `stop`, `zone`: as
    `SkeletonRegistration`'s fields, for that region."""

    registration: Registration
    indices: Array
    joint: Array
    stop: Array
    zone: JointZone
    below: tuple[int, ...] = eqx.field(static=True)


class SkeletonRegistration(eqx.Module):
    """What posing a mesh on a skeleton needs, computed once (`register_skeleton`).

    **Fields** (per limb, in the skeleton's order): `registrations`: the limb's region
    registered on its rest spine (a `Registration`, padded to the largest limb's bucket size
    so that eager poses of any limb share compiled programs, `_batching.buckets`; a traced pose
    takes each limb's first rows, to its own bucket size: `posed_limbs`); `rests`: the rest
    spines, in the vertices' dtype and padded alike (in float32 read from a table, with its
    values where bent spines read them: `LookedUpSpine`; in float64 prepared: exact); `checks`:
    in float64, the rest spines read from their tables (`LookedUpSpine`, `None` for a spine
    without one), on which a bent limb's projection check is built (`limb_check`; `None`s
    in float32, where `rests` are those tables); `indices` (n_k,) int32:
    the region's vertices; `joints`, `stops`: scalars, where each limb's bend may start and
    must be complete (see the module's docstring); `vertices` (n, 3): the rest vertices;
    `margin`: scalar; `zones`: each limb's `JointZone`, where a bend of a given angle is
    concentrated past the joint (`joint_zone`); `wholes`: for each limb with several
    children within its reach, its region and its descendants' on its rest spine (`WholeLimb`),
    for the poses that leave those unposed (`carrying`), else `None`; `triangles` (T, 3)
    int32: the mesh's faces fanned into triangles (the surface a shape fit measures distances
    to); `corners` (n, m) int32: each vertex's corners of them (`restore.corner_table`);
    `volume`: the rest vertices' (about their centre, in float64, then cast); `skeleton_id`:
    the skeleton's `fingerprint` (its limbs and regions, its mesh, its spines and joints), so that
    a pose with another skeleton is refused, saying which part differs; `children`: each limb's
    children (the skeleton's, static: a joint's range counts a free only child's, `spill`);
    `names`: the limbs' names (static, `Limb.name`: `fj.joint_range` takes them).
    """

    registrations: tuple[Registration, ...]
    rests: tuple[AbstractSpine, ...]
    checks: tuple[AbstractSpine | None, ...]
    indices: tuple[Array, ...]
    joints: tuple[Array, ...]
    stops: tuple[Array, ...]
    vertices: Array
    margin: Array
    zones: tuple[JointZone, ...]
    wholes: tuple[WholeLimb | None, ...]
    triangles: Array  # (T, 3) int32: the mesh's faces as triangles (a shape fit's surface)
    corners: Array  # (n, m) int32: each vertex's corners of `triangles` (`restore`)
    volume: Array  # scalar: the rest vertices' volume (`restore`)
    skeleton_id: tuple[int, ...] = eqx.field(static=True)  # `fingerprint` of its skeleton
    children: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True, default=())  # the limbs' (`Limb.name`)


class PosedSkeleton(NamedTuple):
    """A posed mesh: `vertices` (n, 3) and `valid` (n,) bool: `False` where the pose is not
    exact. A vertex of a posed region outside its limb's valid space (a bend past the joint's
    range, `fj.joint_range`) is placed by the map continued past its conditions: continuous in
    the vertex and the angle, so the mesh stays whole, but its volume is not kept there; one
    not validly registered on its limb's rest spine moves with the bent limb's cross-section
    where it projects past a `LimbPose`'s joint, and is left where it was elsewhere, as is one
    with a non-finite image; past where the map over a joint's zone stops being exact in the
    pose's direction (`fj.joint_range` with a direction) every vertex past the joint blends
    towards its cross-section's motion (all flagged: inexact)."""

    vertices: Float[Array, "n 3"]
    valid: Bool[Array, " n"]


def _check_skeleton(skeleton, vertices: np.ndarray) -> None:
    if not isinstance(skeleton, Skeleton):
        raise TypeError(f"`skeleton` must be an fj.Skeleton, got {type(skeleton)}.")
    if skeleton.region.shape[0] != vertices.shape[0]:
        raise ValueError(
            f"`skeleton` has regions for {skeleton.region.shape[0]} vertices, the mesh has "
            f"{vertices.shape[0]}: it was built on another mesh."
        )
    rest = np.asarray(skeleton.vertices, float)
    if rest.shape == vertices.shape:
        # (Read back from a mesh file, the vertices may differ in their last digits.)
        size = max(float(np.linalg.norm(np.ptp(rest, axis=0))), np.finfo(float).tiny)
        apart = float(np.max(np.abs(rest - vertices), initial=0.0))
        if not apart <= 1e-6 * size:
            raise ValueError(
                f"`skeleton` was built on another mesh: its rest vertices differ from the mesh's "
                f"by up to {apart:.3g} ({100 * apart / size:.3g} % of its size; moved, scaled or "
                "reordered). Build the skeleton of this mesh (fj.skeleton) or load its own."
            )


def fingerprint(skeleton: Skeleton) -> tuple[int, int, int]:
    """Hashes of `skeleton`'s limbs' regions and parents, of its rest vertices (the mesh it was
    built on) and of its limbs' spines and joints: a registration's, checked by every pose,
    so that a pose never uses another skeleton's regions (limbs swapped, merged, split), nor
    a registration of another mesh or of spines since edited (the registration's, not the
    skeleton's, would be posed: silently)."""
    parents = np.asarray([limb.parent for limb in skeleton.limbs], np.int64).tobytes()
    spines = [np.asarray(x).tobytes()
              for x in jax.tree.leaves([(limb.spine, limb.joint) for limb in skeleton.limbs])]
    return (_digest(np.asarray(skeleton.region).tobytes(), parents),
            _digest(np.asarray(skeleton.vertices, np.float64).tobytes()), _digest(*spines))


def _digest(*parts: bytes) -> int:
    """A digest of `parts` as an integer, the same in every process (Python's `hash` of bytes
    is salted per process: a registration's static `skeleton_id` is part of the key of the
    programs kept on disk, `_exported`)."""
    digest = hashlib.blake2b(digest_size=8)
    for part in parts:
        digest.update(len(part).to_bytes(8, "little"))
        digest.update(part)
    return int.from_bytes(digest.digest(), "little", signed=True)


def register_skeleton(mesh, skeleton: Skeleton, *, margin: float | None = None,
                      dtype=None) -> SkeletonRegistration:
    """Registers each limb's region of `mesh` on the limb's rest spine, for `pose_skeleton`.

    **Arguments:** `mesh`: a `trimesh.Trimesh` or `(vertices (n, 3), faces (F, k))`, the mesh
    `skeleton` was built on; `skeleton`: an `fj.Skeleton`; `margin`: the valid region's margin
    (`fj.register`; default half the mesh's longest edge: an edge with two valid ends is never
    torn); `dtype`: of the posed vertices (default: the mesh's; float32 is the fast one).

    **Returns:** a `SkeletonRegistration`. **Raises:** `TypeError`/`ValueError` for a mesh or
    skeleton that does not fit, `ValueError` where a limb's children start before its joint.
    """
    vertices, faces = polygon_mesh(mesh)
    _check_skeleton(skeleton, vertices)
    points = on_device(vertices, dtype)
    if margin is None:
        margin = 0.5 * longest_edge(vertices, faces)
    margin = as_margin(margin, points.dtype)
    region = np.asarray(skeleton.region)
    lineage = descendants(skeleton.limbs)
    edges = _edges(faces)
    registrations, rests, checks, indices, joints, stops, zones = [], [], [], [], [], [], []
    # Every limb's region padded to the largest's bucket: one compiled program for all.
    size = bucket(max([int(np.sum(region == k)) for k in range(len(skeleton.limbs))], default=0))
    # (Each limb's rows gathered on the host: on the device, one program per region size.)
    rows = np.asarray(points)
    # (Each limb's floats cast on the host: on the device, one program per array shape.)
    spines = [jax.device_put(cast_floats(jax.tree.map(np.asarray, limb.spine),
                                         points.dtype))._bucketed() for limb in skeleton.limbs]
    _compile_ahead(spines, jax.ShapeDtypeStruct((size, 3), points.dtype), margin)
    wholes = []
    for k, (limb, spine) in enumerate(zip(skeleton.limbs, spines)):
        tabled = tabulates(spine, points.dtype)  # (its length not computed again)
        prepared, table, length = _rests(spine, tabulable(spine))
        rest = table if tabled else prepared
        register = partial(_registered_rows, rows, size=size, margin=margin,
                           prepared=prepared, table=table.table if tabled else None)
        placed = partial(_placed_part, k, edges, region, rest, float(limb.joint), float(length),
                         below=[k, *lineage[k]])
        own = np.flatnonzero(region == k).astype(np.int32)
        piece = (own, register(own))
        reg, ids, joint, stop, zone = placed([piece])
        registrations.append(reg)
        rests.append(rest)
        checks.append(None if tabled else table)
        indices.append(ids)
        joints.append(joint)
        stops.append(stop)
        zones.append(zone)
        # A limb with several children (a head with its ears or horns) is also registered with
        # their regions, for the poses that leave them unposed (`carrying`), where they lie
        # within its own reach about its spine (`WholeLimb`). (Their rows registered apart, at
        # the limb's own rows' size: the same compiled programs, none for the joined size.)
        whole = None
        if len(skeleton.children(k)) > 1:
            others = np.flatnonzero(np.isin(region, lineage[k])).astype(np.int32)
            below = (others, register(others))
            if _reach(below[1], len(others)) <= _reach(reg, len(own)):
                whole = WholeLimb(*placed([piece, below]), tuple(lineage[k]))
        wholes.append(whole)
    triangles = _triangles(faces)
    return SkeletonRegistration(tuple(registrations), tuple(rests), tuple(checks),
                                tuple(indices), tuple(joints),
                                tuple(stops), points, margin, tuple(zones), tuple(wholes),
                                on_device(triangles, np.int32),
                                on_device(corner_table(triangles, len(points)), np.int32),
                                on_device(rest_volume(points, triangles), points.dtype),
                                fingerprint(skeleton),
                                tuple(map(skeleton.children, range(len(skeleton.limbs)))),
                                skeleton.names)


def _registered_rows(rows: np.ndarray, ids: np.ndarray, *, size: int, margin: Array,
                     prepared, table) -> Registration:
    """`rows[ids]` registered on a rest spine (`prepared`, its `table` values or `None`),
    padded to `size` rows or to their bucket if more, the padding invalid."""
    size = max(size, bucket(len(ids)))
    batch = jax.device_put(pad_batch(rows[ids], size))
    registrar, certified = _registration(prepared, batch, margin, table,
                                         quick=size <= QUICK_BATCH)
    return invalid_past(Registration(batch, *registered_pending(registrar, batch, certified)),
                        len(ids))


def _placed_part(k: int, edges: np.ndarray, region: np.ndarray, rest, joint: float,
                 length: float, pieces: list, below: list) -> tuple:
    """Vertices registered on limb `k`'s rest spine as `pieces`, `[(indices (m,), their
    padded Registration)]` (`rest`: what its poses read, of `length`), as one region:
    `(Registration, indices, joint, stop, JointZone)`, the pieces' rows one after another,
    padded to their bucket (one piece: its own). The bend starts past their border with every
    region not in `below` (limb `k` and its descendants; or at the limb's own `joint`, if
    larger) and is complete before their borders with the rest of `below` (see the module's
    docstring)."""
    ids = np.concatenate([i for i, _ in pieces])
    inside = np.zeros(len(region), bool)
    inside[ids] = True
    arc = np.full(len(region), np.nan)
    for i, r in pieces:
        arc[i] = np.asarray(r.arc_length)[: len(i)]
    border = _border(edges, inside, ~np.isin(region, below))
    joint = max(joint, float(np.max(arc[border], initial=-np.inf)))
    inner = np.isin(region, below) & ~inside
    stop = min(length, float(np.min(arc[_border(edges, inside, inner)], initial=np.inf)))
    if not joint < stop:
        raise ValueError(
            f"`skeleton`: limb {k}'s region meets its child limbs (arc length {stop:.4g}) "
            f"before it leaves its parent ({joint:.4g}): there is no room to bend it."
        )
    dtype = pieces[0][1].points.dtype
    framed = []
    for _, r in pieces:  # (all rows, padded ones invalid: each piece's own program)
        at = np.where(np.asarray(r.valid), np.asarray(r.arc_length), joint)
        (_, *frames), axes = _frames_at(rest, on_device(at, dtype), on_device(joint, dtype))
        framed.append([np.asarray(f) for f in frames])
    counts = [len(i) for i, _ in pieces]
    size = bucket(sum(counts)) if len(pieces) > 1 else None
    reg = pieces[0][1] if size is None else invalid_past(eqx.tree_at(
        lambda r: tuple(getattr(r, f) for f in PER_POINT), pieces[0][1],
        tuple(jax.device_put(_stacked([getattr(r, f) for _, r in pieces], counts, size))
              for f in PER_POINT)), sum(counts))
    frames = framed[0] if size is None else [
        _stacked([f[c] for f in framed], counts, size) for c in range(len(framed[0]))]
    zone = joint_zone(*(np.asarray(f) for f in (
        reg.arc_length, reg.offset, reg.curvature, reg.valid)), joint, stop, dtype,
        frames=frames, axes=axes)
    # (Rounded to the dtype, the stop may fall an ulp past the rest spine's own length,
    # which a bent spine refuses: its table's length, in float32, rounds its own way.)
    stop = np.minimum(np.asarray(stop, dtype), rest.length)
    return (reg, jax.device_put(ids), on_device(joint, dtype), on_device(stop, dtype), zone)


# A `Registration`'s per-point fields (its others, the spine's length and end frames, shared).
PER_POINT = ("points", "arc_length", "offset", "curvature", "valid", "discontinuous")


def _stacked(arrays: list, counts: list, size: int) -> np.ndarray:
    """The first `counts[i]` rows of each of `arrays`, one after another, padded to `size`
    rows with copies of the last (as `pad_batch` pads)."""
    rows = np.concatenate([np.asarray(a)[:n] for a, n in zip(arrays, counts)])
    return np.pad(rows, [(0, size - len(rows))] + [(0, 0)] * (rows.ndim - 1), mode="edge")


def _reach(registration: Registration, n: int) -> float:
    """The largest distance from its spine of a registration's first `n` valid points."""
    offset = np.linalg.norm(np.asarray(registration.offset)[:n], axis=1)
    return float(np.max(offset[np.asarray(registration.valid)[:n]], initial=0.0))


def _compile_ahead(spines: list, batch: jax.ShapeDtypeStruct, margin: Array) -> None:
    """Starts compiling `register_skeleton`'s programs for the limbs' rest `spines` and
    padded `batch`, each in a thread as soon as it is traced (`_exported.persistent`'s
    `prepare`), so that each compiles while the next is traced (without a cache folder: each
    compiled by its first call)."""
    for spine in spines:  # (one program each for all limbs of a bucket: started once)
        rests = _rests.prepare(spine, tabulable(spine))
        if rests is None:
            return
        prepared, table, _ = rests
        tabled = tabulates(spine, batch.dtype)
        registered = _registration.prepare(prepared, batch, margin,
                                           table.table if tabled else None,
                                           quick=batch.shape[0] <= QUICK_BATCH)
        _frames_at.prepare(table if tabled else prepared,
                           jax.ShapeDtypeStruct(batch.shape[:1], batch.dtype),
                           jax.ShapeDtypeStruct((), batch.dtype))
        if registered is not None:
            clear_ahead(*registered)


def _triangles(faces: np.ndarray) -> np.ndarray:
    """The polygons `faces` (F, k) as triangles (F (k − 2), 3), each fanned from its first
    corner."""
    faces = np.asarray(faces, np.int64).reshape(len(faces), -1)
    fans = [faces[:, [0, i, i + 1]] for i in range(1, faces.shape[1] - 1)]
    return np.concatenate(fans, axis=0) if fans else np.zeros((0, 3), np.int64)


def _frames(spine: AbstractSpine, s: Array, joint: Array):
    """`((C, T, I, J) (n, 3) each, (T, I, J) (3, 3))`: `spine`'s frames at arc lengths `s`
    (n,) and at `joint` (scalar); one program for every limb (their shapes are bucketed),
    compiled quickly (run once a limb: the optimised compile of a float64 B-spline's frames
    was about 2 s of CPU)."""
    prepared = spine._prepare()
    (c, t, _), (i, j) = jax.vmap(prepared._jet_and_normals)(s)
    (_, t0, _), (i0, j0) = prepared._jet_and_normals(joint)
    return (c, t, i, j), jnp.stack([t0, i0, j0])


_frames_at = Program(_frames, kept=True)


def _edges(faces: np.ndarray) -> np.ndarray:
    """The polygon edges of `faces` (F, k), (E, 2)."""
    faces = np.asarray(faces)
    if faces.size == 0:
        return np.zeros((0, 2), np.int64)
    return np.stack([faces.ravel(), np.roll(faces, -1, axis=1).ravel()], axis=1)


def _border(edges: np.ndarray, inside: np.ndarray, other: np.ndarray) -> np.ndarray:
    """(n,) bool: the vertices of `inside` that share an edge with a vertex of `other`."""
    a, b = edges[:, 0], edges[:, 1]
    border = np.zeros(inside.shape, bool)
    border[a[inside[a] & other[b]]] = True
    border[b[inside[b] & other[a]]] = True
    return border


def check_poses(poses, skeleton: Skeleton, name: str = "poses") -> dict:
    """`poses` (the argument `name`) checked: a dict of limb index or name → `LimbPose` or
    spine, returned with `int` keys in order."""
    if not isinstance(poses, dict):
        raise TypeError(
            f"`{name}` must be a dict of limb index → LimbPose or spine, got {type(poses)}."
        )
    checked = {}
    for k, pose in poses.items():
        index = check_limb_index(k, skeleton, name)
        if not isinstance(pose, LimbPose | AbstractSpine):
            raise TypeError(f"`{name}[{k!r}]` must be a LimbPose or a spine, got {type(pose)}.")
        if index in checked:
            raise ValueError(f"`{name}`: limb {index} is posed twice (by its index and its "
                             "name).")  # fmt: skip
        checked[index] = pose
    return dict(sorted(checked.items()))


def check_limb_index(k, skeleton: Skeleton, name: str) -> int:
    """Limb `k` (an index or a limb's name) as an `int`, else `ValueError` naming the argument
    `name`."""
    return limb_index(k, skeleton.names, name)


def pose_skeleton(
    mesh_or_registration, skeleton: Skeleton, poses: dict, *, method: str = "radial",
    check_projection: bool = True,
) -> PosedSkeleton:
    """Poses a mesh limb by limb: each limb bent along its own spine, the rest still.

    **Arguments:**

    - `mesh_or_registration`: the mesh `skeleton` was built on (`trimesh.Trimesh` or
      `(vertices, faces)`), or its `register_skeleton` (the per-frame path: register once).
    - `skeleton`: an `fj.Skeleton`.
    - `poses`: dict of limb index (or name, `Limb.name`) → `fj.LimbPose` (degrees) or a
      target spine for the limb (as long as its rest spine, equal to it up to the joint for a
      closed seam).
    - `method`: the fleshing (`"radial"`, `"normal"`, `"binormal"`; `fj.METHODS`).
    - `check_projection`: whether each image is checked to project back onto its limb's bent
      spine at its mapped arc length (the global test, as `fj.pose`'s). `False` flags only the
      local conditions (the map's curvature bound, the rest side's valid region): about a
      third of a jitted frame's time on spot (0.6 against 2.3 ms a leg), for a live preview;
      an image then crossing the bent spine's cut locus (a bend past the limb's range folding
      onto itself) is not flagged.

    Each posed limb's region is fleshed from its rest spine to the bent one (`det J = 1`); its
    child limbs follow rigidly its end frame, then bend by their own poses (a limb with
    several children, none of them posed, bends them with it as one region: a head's ears
    and horns; its zone may then run on past them). A `LimbPose` past
    its limb's exact range in its direction is carried on, in the same plane, by the limb's
    only child where that child has no pose (a knee by its ankle: each up to 95 % of its exact
    range, then both past theirs). The body and the limbs neither posed nor below a posed limb
    are not touched. Differentiable in the poses'
    angles (`jax.grad`), under `jit` too.

    **Returns:** a `PosedSkeleton` `(vertices (n, 3), valid (n,))`.
    """
    registration = as_registration(mesh_or_registration, skeleton)
    poses = check_poses(poses, skeleton)
    if not isinstance(check_projection, bool | np.bool_):
        raise TypeError(f"`check_projection` must be a bool, got {type(check_projection)}.")
    return posed(registration, skeleton, poses, check_method(method), bool(check_projection))


def as_registration(mesh_or_registration, skeleton: Skeleton) -> SkeletonRegistration:
    """`mesh_or_registration` if it is a `SkeletonRegistration` on `skeleton`, else the mesh
    registered on it (`register_skeleton`)."""
    if not isinstance(mesh_or_registration, SkeletonRegistration):
        return register_skeleton(mesh_or_registration, skeleton)
    if not isinstance(skeleton, Skeleton):
        raise TypeError(f"`skeleton` must be an fj.Skeleton, got {type(skeleton)}.")
    limbs, mesh, spines = (fingerprint(skeleton) if is_concrete(skeleton)
                           else mesh_or_registration.skeleton_id)
    registered = mesh_or_registration.skeleton_id
    if len(mesh_or_registration.registrations) != len(skeleton.limbs) or limbs != registered[0]:
        raise ValueError(
            "`skeleton` is not the one `mesh_or_registration` was registered on (its limbs or "
            "their regions differ): register the mesh on this skeleton (fj.register_skeleton)."
        )
    if mesh != registered[1]:
        raise ValueError(
            "`skeleton` was built on another mesh than the one `mesh_or_registration` "
            "registered (its rest vertices differ: moved, scaled or reordered): register that "
            "mesh on its own skeleton (fj.register_skeleton)."
        )
    if spines != registered[2]:
        raise ValueError(
            "`skeleton`'s rest spines or joints differ from those `mesh_or_registration` was "
            "registered on (an edited skeleton): register the mesh on it again "
            "(fj.register_skeleton)."
        )
    return mesh_or_registration


def carrying(registration: SkeletonRegistration, limbs: set | dict):
    """`(registration, absorbed)`: `registration` with each of `limbs` (the posed ones) that has a
    `WholeLimb` and no descendant in `limbs` registered as one region with its descendants
    (its fields swapped for the `WholeLimb`'s), and `absorbed`, the frozenset of those
    descendants, whose vertices its pose places: a pose leaves them alone."""
    swap = {k: whole for k in limbs
            if (whole := registration.wholes[k]) is not None and not set(whole.below) & set(limbs)}
    if not swap:
        return registration, frozenset()

    def swapped(values, field):
        return tuple(getattr(swap[k], field) if k in swap else v for k, v in enumerate(values))

    # (A field replaced, not `eqx.tree_at`: no walk over the registration's leaves.)
    registration = dataclasses.replace(
        registration, registrations=swapped(registration.registrations, "registration"),
        indices=swapped(registration.indices, "indices"),
        joints=swapped(registration.joints, "joint"), stops=swapped(registration.stops, "stop"),
        zones=swapped(registration.zones, "zone"))
    return registration, frozenset(b for whole in swap.values() for b in whole.below)


def placed_poses(registration: SkeletonRegistration, skeleton: Skeleton, poses: dict):
    """`(registration, poses, absorbed)`: `poses` with the bends past a joint's range carried
    on by free only children (`spilled`), the registration and the limbs its posed limbs carry
    as one region (`carrying`). (A child a bend is carried on to is judged with its
    descendants' regions where they are not posed: its range then.)"""
    reach = set(poses)
    for k in range(len(skeleton.limbs)):  # (topological order: down a chain)
        children = skeleton.children(k)
        if k in reach and len(children) == 1:
            reach.add(children[0])
    poses = spilled(carrying(registration, reach)[0], skeleton, poses)
    registration, absorbed = carrying(registration, poses)
    return registration, poses, absorbed


class Rigid(NamedTuple):
    """The rigid motion `x ↦ R x + t`: `rotation` (3, 3), `translation` (3,)."""

    rotation: Array
    translation: Array

    def __call__(self, x: Array) -> Array:
        # (Multiply-adds on the coordinates, not `x @ R.T`: a product of an (n, 3) array ran as
        # a matrix kernel of its own, 0.1-0.2 ms for a carried child's 4-6k vertices.)
        r = self.rotation
        return (x[..., 0:1] * r[:, 0] + x[..., 1:2] * r[:, 1] + x[..., 2:3] * r[:, 2]
                + self.translation)

    def then(self, outer: Rigid | None) -> Rigid:
        """`outer ∘ self` (`self` if `outer` is None)."""
        if outer is None:
            return self
        return Rigid(outer.rotation @ self.rotation, outer(self.translation))


def end_motion(rest: AbstractSpine, posed: AbstractSpine) -> Rigid:
    """The rigid motion taking the frame `(C, T, I, J)` of `rest` at its end to that of
    `posed` (its normals carried from the rest's start, as the fleshing's: `aligned_twist`):
    where a posed limb carries its children. Differentiable in `posed`."""
    target = posed._prepare()
    ends = EndFrames(rest)
    twist = aligned_twist(ends, target, jnp.zeros((), target.length.dtype))
    return motion_between(ends, target_ends(target, twist))


def motion_between(rest: EndFrames, posed: EndFrames) -> Rigid:
    """The rigid motion taking the frame `rest` at its end (`EndFrames`) to `posed`'s."""
    c0, *f0 = rest.frame(1)
    c1, *f1 = posed.frame(1)
    rotation = jnp.stack(f1, axis=1) @ jnp.stack(f0, axis=0)
    return Rigid(rotation, c1 - rotation @ c0)


def posed(registration: SkeletonRegistration, skeleton: Skeleton, poses: dict,
          method: str, check: bool = True, stacked: bool = False,
          blend_tangent: bool = True, motions: bool = False):
    """`pose_skeleton` on a registration (traceable: `poses` are its only free values).
    `check=False` skips the global projection check of traced poses (a fit's objective:
    smooth, and a much smaller program; `valid` then flags only the local tests).
    `stacked=True` poses the limbs as one batch (`posed_limbs`), and carries their sections
    as one (`_stacked_sections`), for traced poses. `blend_tangent=False` differentiates the
    sections' blend past a joint's range as the map's own images (`_held_blend`; a fit's
    objective: its values unchanged, its program smaller). `motions=True` returns
    `(PosedSkeleton, carried)`, `carried` the rigid motion (`Rigid`) that carries each
    touched limb's children, keyed by limb (a fit's rows that move rigidly: `fit_pose.rigid`)."""
    reg = registration
    vertices = reg.vertices
    valid = jnp.ones(vertices.shape[0], bool)
    # A bend past a joint's exact range is carried on by its free child (`spill`). Traced, the
    # child is posed in every frame: batched with its parent, so that the program holds one
    # limb's code (a gradient of a knee's angles compiled twice as long with its foot's own).
    given = len(poses)
    reg, poses, absorbed = placed_poses(reg, skeleton, poses)
    stacked = stacked or (len(poses) > given and not is_concrete(poses))
    moved = posed_limbs(reg, poses, method, check, stacked)
    # Stacked, the limbs' sections are carried as one batch too (`_stacked_sections`).
    sections = _stacked_sections(reg, poses, moved, blend_tangent) if stacked else {}
    carried: dict[int, Rigid | None] = {}  # what moves each touched limb's children
    trusted: dict[int, Array] = {}  # whether the angles of the limb and its ancestors are sane
    blend = jnp.zeros(vertices.shape[0], vertices.dtype)  # towards the sections (`restore`)
    # Eagerly, each limb's rows are its registration's padded ones (`_padded_indices`): every
    # operation below then runs at the bucket's size, compiled once for every limb of it; at
    # each region's own size each ran, and compiled, once per limb (a biped's 15 limbs posed:
    # about 250 programs). Traced, each limb's own rows (the frame's program's shapes).
    eager = is_concrete(poses, reg)
    for k, limb in enumerate(skeleton.limbs):
        carry = carried.get(limb.parent)
        pose = poses.get(k)
        if (pose is None and (limb.parent not in carried)) or k in absorbed:
            continue  # neither posed nor below a posed limb, or placed by one: not touched
        ids = _padded_indices(reg, k) if eager else reg.indices[k]
        rest = reg.vertices.at[ids].get(mode="clip")  # (the padding's rows: any vertex)
        images, ok, motion = rest, jnp.ones(ids.shape[0], bool), None
        trust = trusted.get(limb.parent, jnp.asarray(True))
        if pose is not None:
            images, ok, motion, table = moved[k]
            images, ok = images[: ids.shape[0]], ok[: ids.shape[0]]
            if isinstance(pose, LimbPose):
                trust = trust & sane_angles(pose)
                images, ok, towards = sections[k] if k in sections else _sections_carried(
                    reg, k, pose, images, ok, table, blend_tangent)
                blend = blend.at[ids].set(towards, mode="drop")
        if carry is not None:
            images = carry(images)
        carried[k], trusted[k] = (carry if motion is None else motion.then(carry)), trust
        # A traced pose flags what it cannot place: a NaN or infinite angle, one past a full
        # turn (refused eagerly by `LimbPose`), and any non-finite image (left at rest).
        finite = jnp.all(jnp.isfinite(images), axis=1)
        vertices = vertices.at[ids].set(jnp.where(finite[:, None], images, rest), mode="drop")
        valid = valid.at[ids].set(ok & trust & finite, mode="drop")
    out = PosedSkeleton(_given_back(reg, vertices, blend), valid)
    return (out, carried) if motions else out


def _padded_indices(reg: SkeletonRegistration, k: int) -> Array:
    """Limb `k`'s vertex indices padded to its registration's rows (int32, on the device):
    the padding is the vertex count, outside the mesh, which scatters drop."""
    ids = np.asarray(reg.indices[k])
    rows = reg.registrations[k].points.shape[0]
    return jax.device_put(np.pad(ids, (0, rows - len(ids)), constant_values=len(reg.vertices)))


def _given_back(reg: SkeletonRegistration, vertices: Array, blend: Array) -> Array:
    """`vertices` (n, 3) with the volume the sections' motion lost given back along the
    blended vertices' normals (`restore`; `blend` (n,)): where some blend is positive and
    the registration has a surface (not a marker fit's chosen vertices)."""
    if reg.triangles.shape[0] == 0:
        return vertices
    args = (vertices, reg.vertices, reg.volume, reg.triangles, reg.corners, blend)
    if is_concrete(blend):  # (eagerly one program for every angle)
        return _restored_program(*args) if np.any(np.asarray(blend) > 0) else vertices
    return jax.lax.cond(jnp.any(blend > 0), restored_volume, lambda v, *_: v, *args)


BLEND_WIDTH = 0.3  # the blend's width, in `JointZone.margins`: done by k₁·d* ≈ 0.65 at most


def _sections_carried(registration, k: int, pose: LimbPose, images, valid, table=None,
                      tangent: bool = True):
    """`(images, valid, blend)` of limb `k`'s region with its vertices past the joint moved
    towards where the bent limb's cross-section at their arc length carries them
    (`PreparedBent.carried`: past the bend, the limb's rigid motion), all flagged:

    - wholly, the vertices not validly registered on the rest spine (near a focal point at
      rest: under an insect's bent knee), which the fleshing cannot place: left at rest they
      tore the mesh (23.6× on the insect's front leg bent 30°, 3.2× for one in the zone);
    - the others by one weight, rising smoothly from 0 where the radial map over the pose's
      zone stops being exact in the direction and twist asked (some vertex's `k₁·d*` reaches
      `maps.WHOLE_FROM`) to 1 at about twice that bend (`JointZone.margins`: the largest
      vertex's relative excess): past it the fleshing squeezes a thick joint's concave side (a
      head on its neck) into flaps; the sections' motion keeps the limb whole, not its
      volume. Continuous in the angle, the direction and the twist; 0, and the map's images
      bit for bit, wherever the map is exact. Nodded forwards, against the formulas
      continued: cheburashka's head (exact to 3.3°) at 30°, worst edge 16.4× → 2.6×, ΔV/V
      −1.5 % → −0.7 %; spot's at 45°, 6.2× → 2.6×, −1.7 % → −0.2 %; towards its side,
      −3.9 % → −4.2 %: the volume is then given back (`restore`) in proportion to `blend`
      (n,), the weight of each validly registered vertex (0 for the others).

    `table`: the bent spine's own table where the limb's pose already made it (a traced
    frame: `posed_limbs`), read rather than made again (`_carried_blend`). `tangent=False`:
    traced, differentiated as `images` alone (`_held_blend`). `images` (rows, 3), `valid`
    (rows,) and what it returns: eagerly the registration's padded rows (the padding's
    meaningless), traced the region's own."""
    n = registration.indices[k].shape[0]
    r = registration.registrations[k]
    concrete = is_concrete(pose, registration)
    rows = r.points.shape[0] if concrete else n  # (eagerly the padded rows: see `posed`)
    s, points = r.arc_length[:rows], r.points[:rows]
    inputs = _section_inputs(registration, k, pose, None if concrete else n)
    if not (tangent or concrete):  # (the weights' margins undifferentiated too)
        inputs = jax.lax.stop_gradient(inputs)
    weight = _section_weights(*inputs, n)[:rows]
    target = limb_target(registration, k, pose)
    if concrete:
        # Eagerly one program for every angle, within the range too (it then changes only the
        # unregistered vertices): a new angle compiles nothing. It runs on the registration's
        # padded rows (their weight 0: left as they are), so that every limb of a bucket
        # shares it too: at each region's own size, the tube's three limbs compiled three.
        images = _carried_blend_program(target, points, s, weight, images)
    else:  # a traced frame skips the sections where nothing is carried
        images = _held_blend(partial(_carried_blend, table=table), tangent, target, points, s,
                             weight, images)
    _, _, joint, stop, _ = inputs
    # (A weight is 0 before the joint.)
    return images, valid & ~(weight > 0), _restoring(weight, r.valid[:rows], s, joint, stop)


def _section_inputs(registration, k: int, pose: LimbPose, rows: int | None = None) -> tuple:
    """Limb `k`'s arguments of `_section_weights` for `pose` (but the region's size): on its
    zone's and registration's first `rows` rows if given (a traced frame: its own; the
    padding bounds nothing, and every limb is padded to the largest's bucket, 24,576 rows on
    spot's 100k vertices), else on all of them (one program for every limb of a bucket)."""
    rest, joint = registration.rests[k], registration.joints[k]
    zone, reg = registration.zones[k], registration.registrations[k]
    if rows is not None:
        zone = eqx.tree_at(lambda z: (z.arc, z.rests, z.moments, z.twisting), zone, unpad_batch(
            (zone.arc, zone.rests, zone.moments, zone.twisting), rows))
        reg = unpad_batch(reg, rows)
    return (zone, reg, joint, bend_stop(registration, k, pose),
            jnp.stack(pose.radians(rest, joint)))


def _section_weights(zone: JointZone, r: Registration, joint, stop, angles, n) -> Array:
    """(rows,) each registered row's weight towards its section's motion (`_sections_carried`)
    for a pose of `angles` (3,) radians (bend, direction, twist) bending through `[joint,
    stop]`: 0 before the joint and on the rows past the region's `n` (padding)."""
    # (Over the zone's padded rows too: they are zero, and bound nothing.)
    margins = zone.margins(*angles, joint, stop)
    # (The largest by its index: `jnp.max`'s derivative finds it again by equality, which an
    # unoptimised XLA, recomputing the margins in two fusions, missed: a NaN gradient.)
    u = jnp.clip(margins[jnp.argmax(margins)] / BLEND_WIDTH, 0, 1)
    blend = u * u * (3 - 2 * u)
    s = r.arc_length
    past = jnp.isfinite(s) & (s >= joint) & (jnp.arange(s.shape[0]) < n)
    return jnp.where(past, jnp.where(r.valid, blend, 1), 0).astype(joint.dtype)


def _restoring(weight, valid, s, joint, stop) -> Array:
    """(n,) the blend by which each vertex gives the volume back (`restore`): its weight
    towards its section's motion (`weight`, `valid` (n,)), validly registered, rising
    smoothly from 0 at the joint to the full weight at the bend's `stop` (arc lengths `s`):
    no step where the limb meets what stays."""
    u = jnp.clip((jnp.where(valid, s, joint) - joint) / (stop - joint), 0, 1)
    return jnp.where(valid, weight, 0) * u * u * (3 - 2 * u)


def _stacked_sections(registration: SkeletonRegistration, poses: dict, moved: dict,
                      tangent: bool = True) -> dict:
    """`_sections_carried` of the traced limbs posed by a `LimbPose` that share their
    structure and shapes (every limb of a fit: `posed_limbs`'s `stacked`), as one batch by
    `vmap`: dict limb index → `(images, valid, blend)` of its region. One limb's code in the
    program, not one per limb (each its bent spine's sections at every row: a third of a
    gradient's program on the tube, with its free child posed). `tangent`: `_held_blend`'s."""
    if is_concrete(poses):
        return {}
    args = {k: (*_section_inputs(registration, k, pose), limb_target(registration, k, pose),
                moved[k][0]) for k, pose in poses.items() if isinstance(pose, LimbPose)}
    sections = {}
    for ks, batch in _stacked_groups(args, smallest=2):
        ns = jnp.asarray([registration.indices[k].shape[0] for k in ks])
        zone, r, joint, stop, angles, target, images = batch
        if not tangent:  # (the weights' margins undifferentiated too)
            joint, stop, angles = jax.lax.stop_gradient((joint, stop, angles))
        weight = jax.vmap(_section_weights)(zone, r, joint, stop, angles, ns)
        # (One test for the batch: a traced frame skips the sections where none is carried.)
        images = _held_blend(jax.vmap(_carried_blend), tangent, target, r.points,
                             r.arc_length, weight, images)
        for i, k in enumerate(ks):
            n = registration.indices[k].shape[0]
            sections[k] = (images[i, :n], moved[k][1][:n] & ~(weight[i, :n] > 0),
                           _restoring(weight[i, :n], r.valid[i, :n], r.arc_length[i, :n],
                                      joint[i], stop[i]))
    return sections


def _held_blend(blend, tangent: bool, target, points, s, weight, images):
    """`blend(target, points, s, weight, images)` (`_carried_blend`) where some `weight` is
    positive, else `images`. `tangent=False`: differentiated as `images` alone, the blend's
    own derivative left out of the program (a fit's objective: the blend, its conditional
    and the weights' margins were a tenth of a shape fit's solve); its values the same
    formulas (compiled in another program, they may round otherwise). Within the joint's
    range (every weight 0) the derivative is exact; past it, a Gauss–Newton step is taken on
    the map's own slope, its loss the exact one."""
    args = (target, points, s, weight, images)
    if not tangent:
        args = jax.lax.stop_gradient(args)
    out = jax.lax.cond(jnp.any(weight > 0), blend, lambda *a: a[-1], *args)
    return out if tangent else _valued_as(out, images)


@jax.custom_jvp
def _valued_as(value: Array, like: Array) -> Array:
    """`value`, differentiated as `like` (of its shape)."""
    return value


@_valued_as.defjvp
def _valued_as_jvp(primals, tangents):
    return primals[0], tangents[1]


def _carried_blend(target, points, s, weight, images, table=None):
    """`images` (n, 3) moved by `weight` (n,) towards the sections' motion
    (`PreparedBent.carried`) at arc lengths `s` (n,); as they are where `weight` is 0.
    `table`: the bent spine's own table (`_table`), where the caller has it."""
    moved = weight > 0
    prepared = target._prepare()
    # In float32 the sections' positions are read from the bent spine's table (integrated a
    # point at a time: spot's head at 104,644 vertices bent 30°, 22 ms of a 27 ms frame).
    # (Its own table made again here, in the traced frame's conditional, was a limb's whole
    # preparation again: the pose's is passed in.)
    if table is None and tabulates(prepared):
        table = prepared._table(jet_only=True)  # (its positions alone are read)
    placed = jax.vmap(lambda x, s: prepared.carried(x, s, table))(points, jnp.where(moved, s, 0))
    blended = jnp.where((weight == 1)[:, None], placed,
                        images + weight[:, None] * (placed - images))
    return jnp.where(moved[:, None], blended, images)


_carried_blend_program = persistent(_carried_blend)
_restored_program = persistent(restored_volume)


def posed_limbs(registration: SkeletonRegistration, poses: dict, method: str, check: bool,
                stacked: bool) -> dict:
    """Each posed limb's region posed on its own (`_pose_limb`): dict limb index → `(images,
    valid, end motion, table)`, `table` the bent spine's own table its pose read (a traced
    frame's `LimbPose` on a looked-up rest spine: `_own_table`), for its sections
    (`_sections_carried`), else `None`. `stacked`: the limbs whose registrations and targets
    have one structure (every `LimbPose`: the limbs' registrations share a bucket size and
    their rest spines a padded shape) posed as one batch by `vmap`, so that a traced program
    holds one limb's code, not one per limb (a fit's objective, compiled with its
    derivatives)."""
    targets = {k: limb_target(registration, k, pose) for k, pose in poses.items()}
    # Traced poses (a jitted frame, a gradient) pose each limb at its own size, not the largest
    # limb's bucket it is padded to for the eager calls' shared programs (on spot's 100k
    # vertices a leg's 4.9k vertices were posed as 24.6k), nor its own bucket (its shapes are
    # the frame's program's alone: the head's 17.8k were posed as 24.6k).
    own = not (stacked or is_concrete(poses))
    # (Unchecked, no spine to check on: nor in the batches' structure, a fit's limbs grouped.)
    pairs = {k: (_limb_registration(registration, k, own), target,
                 limb_check(registration, k, poses[k]) if check else None)
             for k, target in targets.items()}
    if not stacked or len(pairs) < 2:
        # Eagerly, each limb is posed by one compiled program, shared by every limb of a
        # bucket and every angle: the sampled fallback of the projection check is in it
        # (run only where the reach bound leaves points pending). Posed by the two-phase
        # eager pipeline instead (`_fleshing.eager`), a new angle that left a point pending
        # compiled that fallback on the spot: the tube bent 60° then 90°, 0.09 s then 30 s.
        if is_concrete(poses):
            return {k: (*_pose_limb_eagerly(reg, target, method, check, on), None)
                    for k, (reg, target, on) in pairs.items()}
        posers = _stacked_posers(pairs, method, check)
        # (Unchecked, a pose does not read its table's own values: made in the sections'
        # conditional only where a limb is blended.)
        return {k: (*_posed_by(reg, posers[k]),
                    posers[k].target if check and _own_table(registration, k, poses[k]) else None)
                for k, (reg, _, _) in pairs.items()}
    moved = {}
    for ks, batch in _stacked_groups(pairs):
        out = jax.vmap(lambda p: _pose_limb(p[0], p[1], method, check, p[2]))(batch)
        moved.update({k: (*jax.tree.map(lambda x, i=i: x[i], out), None)
                      for i, k in enumerate(ks)})
    return moved


def _own_table(registration: SkeletonRegistration, k: int, pose) -> bool:
    """Whether limb `k`'s `pose` poses it on its bent spine's own table (static): a `LimbPose`
    on a looked-up rest spine with its node samples (float32), whose bent spine's table the
    `Poser` reads (`Poser.target`), made from those samples (`BentSpine._table_at_nodes`)."""
    rest = registration.rests[k]
    return (isinstance(pose, LimbPose) and isinstance(rest, LookedUpSpine)
            and rest.samples is not None)


def _stacked_posers(pairs: dict, method: str, check: bool) -> dict:
    """The traced limbs' targets prepared (`limb_poser`), those of one structure and shapes as
    one batch by `vmap` (every limb's table of a bent spine has its rest table's shapes, the
    same on every limb of a skeleton), their points then posed each at its own size: dict limb
    index → `Poser`. A bent limb's preparation is a few hundred small operations, each run
    one by one by XLA's CPU backend: batched, a frame of spot's 9 limbs runs them once."""
    args = {k: (reg.ends, reg.points[:1], target, on) for k, (reg, target, on) in pairs.items()}
    # One certificate for all, the largest region's (`certificate_samples`), as eagerly (every
    # limb padded to the largest's rows, a bucket): one batch still.
    certificate = certificate_samples(max(bucket(reg.points.shape[0])
                                          for reg, _, _ in pairs.values()))
    posers = {}
    for ks, batch in _stacked_groups(args):
        def prepared(ends, point, target, on):
            return _limb_poser(ends, point.dtype, target, method, check, on, certificate)

        if len(ks) == 1:
            posers[ks[0]] = prepared(*args[ks[0]])
            continue
        out = jax.vmap(prepared)(*batch)
        posers.update({k: jax.tree.map(lambda x, i=i: x[i], out) for i, k in enumerate(ks)})
    return posers


def _stacked_groups(args: dict, smallest: int = 1) -> list:
    """`args` (limb index → pytree) in groups of the limbs whose pytrees share their structure
    and their leaves' shapes, of `smallest` limbs or more: `[(limb indices, their pytrees
    stacked along a new first axis)]`, for `vmap`."""
    groups: dict = {}
    for k, tree in args.items():
        leaves, structure = jax.tree.flatten(tree)
        groups.setdefault((structure, tuple(jnp.shape(x) for x in leaves)), []).append(k)
    return [(ks, jax.tree.map(lambda *x: jnp.stack(x), *(args[k] for k in ks)))
            for ks in groups.values() if len(ks) >= smallest]


def _limb_registration(registration: SkeletonRegistration, k: int, own: bool) -> Registration:
    """Limb `k`'s `Registration`, at its own size if `own` (else as registered: padded)."""
    reg = registration.registrations[k]
    return unpad_batch(reg, registration.indices[k].shape[0]) if own else reg


def limb_target(registration: SkeletonRegistration, k: int, pose) -> AbstractSpine:
    """Limb `k`'s target: `pose` itself if it is a spine, else the limb's rest spine bent by
    the `LimbPose` in the zone past its joint that the angle needs (`joint_zone`)."""
    if isinstance(pose, AbstractSpine):
        _check_limb_spine(registration, k, pose)
        return pose
    return pose.spine(registration.rests[k], registration.joints[k],
                      bend_stop(registration, k, pose))


def limb_check(registration: SkeletonRegistration, k: int, pose) -> AbstractSpine | None:
    """What limb `k`'s projection check is built on (`Poser`'s `checked_on`), or `None` (on
    the target itself): in float64, the `LimbPose`'s bent spine read from the rest spine's
    table (`checks`). The check samples the bent spine at 384 arc lengths, each exactly a
    quadrature of the rest spine's tangent: two thirds of a float64 frame of spot's leg. The
    table's error (1e-9 relative, `_spines.table`) is far below the check's resolution
    (the samples' spacing, `region`); the points are still bent on the exact spine."""
    table = registration.checks[k]
    if table is None or not isinstance(pose, LimbPose):
        return None
    return pose.spine(table, registration.joints[k], bend_stop(registration, k, pose))


def bend_stop(registration: SkeletonRegistration, k: int, pose: LimbPose) -> Array:
    """Where limb `k`'s bend by `pose` is complete (scalar arc length): its joint plus the
    zone the angle needs (`joint_zone`); past it the limb moves rigidly."""
    joint, zone, stop = registration.joints[k], registration.zones[k], registration.stops[k]
    if is_concrete(pose.bend, joint):  # on the host (`JointZone.end`): the same bits
        degrees = np.asarray(pose.bend)
        degrees = degrees.astype(jax.dtypes.canonicalize_dtype(degrees.dtype))
        bend = degrees * np.asarray(np.pi / 180, degrees.dtype)  # (as `jnp.deg2rad`)
        return zone.end(bend.astype(np.asarray(joint).dtype), joint, stop)
    return zone.end(jnp.deg2rad(pose.bend).astype(joint.dtype), joint, stop)


def _check_limb_spine(registration: SkeletonRegistration, k: int, spine: AbstractSpine) -> None:
    """`ValueError` (eagerly) for a target spine given for limb `k` that is not as long as its
    rest spine or does not follow it up to the joint (points and tangents; its normals are
    carried from the rest's start anyway): the region's border would tear from the parent."""
    rest, joint = registration.rests[k], registration.joints[k]
    if not is_concrete(spine, rest, joint):
        return
    length = float(rest.length)
    tolerance = max(1e-6, 100 * float(jnp.finfo(registration.vertices.dtype).eps))
    if not abs(float(spine.length) - length) <= tolerance * length:
        raise ValueError(
            f"`poses[{k}]`: a spine given for limb {k} must be as long as its rest spine "
            f"({length:.6g}), got {float(spine.length):.6g}."
        )
    dtype = registration.vertices.dtype
    at = jnp.linspace(0.0, float(joint), 5, dtype=dtype)
    c0, t0, _ = jax.vmap(rest._prepare()._jet)(at)
    c1, t1, _ = jax.vmap(cast_floats(spine, dtype)._prepare()._jet)(at)
    apart = np.maximum(np.max(np.abs(np.asarray(c1 - c0)), axis=1) / length,
                       np.max(np.abs(np.asarray(t1 - t0)), axis=1))
    worst = int(np.argmax(apart))
    if not apart[worst] <= 10 * tolerance:
        raise ValueError(
            f"`poses[{k}]`: a spine given for limb {k} must follow its rest spine up to the "
            f"joint (arc length {float(joint):.6g}); it is {apart[worst]:.3g} away at "
            f"{float(at[worst]):.6g}. Bend the rest spine from its joint (fj.BentSpine, or an "
            "fj.LimbPose)."
        )


def limb_poser(registration: Registration, target: AbstractSpine, method: str,
               check: bool = True, checked_on: AbstractSpine | None = None) -> Poser:
    """`target` prepared for posing a limb's region (`registration`): the points past the end
    move rigidly, those not validly bent keep their continued image (`Poser`'s `fallback`),
    and the images are checked to project back onto it with no margin (the
    margin keeps edges whole on the rest side, the registration's: with the margin on the
    bent spine too, the region's bounds on a bend's changing curvature flagged most of a thin
    leg bent 60°). `checked_on`: see `limb_check`. The check's reach certificate on
    `certificate_samples` samples."""
    return _limb_poser(registration.ends, registration.points.dtype, target, method, check,
                       checked_on, certificate_samples(registration.points.shape[0]))


def _limb_poser(ends, dtype, target: AbstractSpine, method: str, check: bool,
                checked_on: AbstractSpine | None, certificate: int | None) -> Poser:
    """`limb_poser` of a region registered in `dtype` with its rest spine's `ends`, its
    reach certificate on `certificate` samples (`certificate_samples`)."""
    return prepare_target(target, dtype, method=method, check_projection=check, margin=0.0,
                          start=ends, beyond="rigid", fallback=True, checked_on=checked_on,
                          certificate=certificate)


def certificate_samples(rows: int) -> int | None:
    """The samples of the reach certificate of a bent limb's region of `rows` rows (static):
    `CERTIFICATE_SAMPLES` for a small one, the valid region's own (`None`: its samples,
    evaluated once for both) from `CERTIFIED_FROM` rows on."""
    return None if rows >= CERTIFIED_FROM else CERTIFICATE_SAMPLES


# The samples of a bent limb's reach certificate (`_fleshing.reach`), against the 384 of its
# valid region's test: the certificate only lets points skip the region's test (a point it
# leaves is tested there), and on 384 samples its 384² pairs and running minima were half of
# a checked float32 frame of spot's leg (CPU 2.0 → 1.1 ms at 128; all 9 limbs at 32 rather
# than 128: 7.6 → 6.7 ms bent 12°, 9.8 → 8.0 ms at 90°, the points it leaves costing less in
# the pruned test than its S² pairs). Spot's 9 limbs, each bent 0-180° in 3 directions (39
# poses, float32; limbs 0 and 8 in float64), and all 9 at once (15 poses): the same flags.
CERTIFICATE_SAMPLES = 32
# A large region's certificate is the valid region's own, on its 384 samples: its S² pairs
# cost a frame the same at any size, and at 32 samples it left nearly every point of a thick
# part to the pruned test (spot's head at 104,644 vertices bent 10°: 17,491 of its 17,812
# points, none at 384: 17.2 → 13.2 ms of CPU a frame, with `Poser.pose`'s placing apart).
CERTIFIED_FROM = 8192


def _pose_limb(registration, target, method, check=True, checked_on=None):
    """One limb's region posed onto `target`: `(images, valid, end motion)`, traced in a
    caller's program (eagerly: `_pose_limb_eagerly`)."""
    return _posed_by(registration, limb_poser(registration, target, method, check, checked_on))


def _posed_by(registration, poser):
    """`_pose_limb` with its target prepared (`limb_poser`)."""
    images, ok = pose_prepared(registration, poser)
    # The children move as the region's points past the end do (`beyond="rigid"`): with the
    # target's end frame the preparation made, not a second preparation of the target.
    return images, ok, motion_between(registration.ends, poser.ends)


def _pose_limb_eagerly(registration, target, method, check=True, checked_on=None):
    """`_pose_limb` called eagerly: two compiled programs, each shared by every limb of a
    bucket and every angle: the target's preparation (`limb_poser`: the program
    `pose_stretch` prepares its targets with too), and the pose, the projection check's
    sampled fallback inside (run only where points are pending). (As one program, the
    preparation was compiled into it, and again on its own for `pose_stretch`: 4 s of CPU
    on the tube's float64 limb.)"""
    return _posed_by_program(registration,
                             limb_poser(registration, target, method, check, checked_on))


_posed_by_program = persistent(_posed_by)


def _limb_rests(spine: AbstractSpine, lookup: bool):
    """Limb `spine`'s rest spines, made once: `(prepared, table, length)`.

    - `prepared`: the spine with its tables (a free-form spine's lengths, coefficients and
      frame nodes): in double precision a limb's bent spines evaluate it exactly from them
      (each frame built them again: the frame nodes' propagation is a loop, about a third of
      a float64 frame of spot's leg); its registration starts from them too;
    - `table`: its `LookedUpSpine` if `lookup` (static: `tabulable`), else `None`: in single
      precision the bent spines read the rest spine from it (preparing a frame's target 3×
      faster on spot) and the registration searches its table (`_limb_registered`); in
      double precision, the projection check's (`limb_check`);
    - `length`: scalar."""
    prepared = spine._prepare()
    return prepared, LookedUpSpine(prepared) if lookup else None, prepared.length


def _limb_registered(prepared: AbstractSpine, points: Array, margin: Array, table):
    """`(registrar, certified)`: the registration's fast path of a limb's region `points`
    (n, 3) on its `prepared` rest spine (`_fleshing.eager.certified_registration`), searching
    `table` (a `SpineTable`: the rest spine's, in single precision) if given, for
    `registered_pending`.

    Two programs a limb (each shared by every limb: their shapes are bucketed), not six: the
    registrar made its own copy of the table and each phase was a program of its own, each
    traced, lowered and compiled (the table's compile twice); in one program XLA's compile
    grew faster than its parts'."""
    registrar = Registrar(prepared, margin=margin, table=table)
    return registrar, certified_registration(registrar, points)


_rests = Program(_limb_rests, kept=True)
_registration = Program(_limb_registered, kept=True)


def limb_causes(registration: SkeletonRegistration, skeleton: Skeleton, poses: dict,
                method: str = "radial") -> dict:
    """The invalid vertices of each posed limb's region, by cause (`fj.diagnose`'s `Causes`):
    dict limb index → `Causes`, for the limbs posed with a `LimbPose` or a spine."""
    from .._fleshing.diagnose import diagnose

    reg, poses, _ = placed_poses(registration, skeleton, check_poses(poses, skeleton))
    causes = {}
    for k, pose in poses.items():
        n = reg.indices[k].shape[0]
        target = limb_target(reg, k, pose)
        causes[k] = diagnose(unpad_batch(reg.registrations[k], n), target,
                             method=check_method(method), beyond="rigid")
    return causes

"""`MedialRig`: a surface bound to its medial mesh, posed by a `MedialPose`.

Binding (NumPy/SciPy, once per shape) follows Lan et al. 2017: each vertex is bound to the
footprint sphere of its nearest primitive (`footprint.py`). Our own choices:

- **Rotation weights across primitives.** Rotations blended only over a vertex's own
  primitive jump where neighbouring vertices bind to primitives that share no sphere (the
  surface cracks or folds there). When `faces` are given, the footprint weights (as sparse
  weights over all spheres) are smoothed over the mesh one-ring, `smoothing` rounds of
  `W ← ½ W + ½ mean_{one-ring} W`, and the `slots` heaviest spheres kept (renormalised):
  these *rotation weights* blend the rotations (and are the LBS / DQS weights, so that every
  method uses the same handles). The footprint centre keeps the exact `β` of its primitive.
  Without faces the vertices are a point cloud: the rotation weights are the footprint's.
- **Invalid vertices.** Non-finite vertices, and vertices farther than `max_distance` from
  the envelope (default: the diagonal of the envelope's bounding box), are flagged invalid
  (`valid=False`, not an error); `pose` returns them at their rest position (non-finite
  coordinates as 0), so outputs are always finite.
- **Seams.** Coincident vertices (the copies a mesh read with `process=False` keeps at
  texture and normal seams, or an unwelded STL-like mesh) are welded by position (`weld`):
  bound, corrected and posed as one point, whose image every copy gets. The caller's vertex
  count and order are kept (`rest_vertices`, `valid` and the pose's output are per vertex as
  given); the arrays of the binding are per welded point.
- **Implicit correction** (`implicit.py`) works for every method (Vaillant et al. 2013 ran it
  on top of dual-quaternion skinning); the baselines' comparisons use `implicit=False`. Its
  contact test only sees each vertex's candidate primitives (the nearest at rest), so two
  parts far apart at rest that press together after a pose are not detected.
- **Still groups.** On rigs of up to `still.VERTICES` vertices, the correction skips the
  groups of `still.GROUP` vertices whose spheres all move as one rigid body (`still.py`):
  it would move them by round-off only; the others are corrected in chunks. The welded
  points are kept in a spatial order for it (`points`, the binding's arrays; `welded` maps
  the caller's vertices to them).

Volumes measured (capsule radius 0.5, cylinder 4, 1762 vertices, chain of 17 spheres, `ΔV/V`,
medial+implicit / medial / LBS / DQS): bent 90° onto an arc of its length −0.05 / −0.09 /
−0.03 / +0.19 %, 180° −0.22 / −0.34 / −0.14 / +0.78 %, twisted 180° +0.14 / +0.14 / −1.64 /
+0.14 %. With 5 spheres the arc's chords are shorter than the cones (the medial mesh itself
loses volume): 180° −2.4 / −4.3 / −0.6 / +4.8 %; bent keeping the cones' lengths (as ARAP
does) −0.20 / −2.2 / +1.4 / +7.1 %.
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int
from scipy import sparse

from .._batching.quick import Program
from .._checks import as_real_array, check_number, is_concrete
from .._medial_axis.medial_mesh import MedialMesh
from .._medial_axis.weld import weld
from .._mesh.volume import triangulate
from .._numerics import cast_floats
from .footprint import bind
from .implicit import Correction, correct
from .pose import MedialPose
from .quaternions import matrix_from_quaternion
from .skin import blend_quaternion, dqs_vertex, lbs_vertex, medial_vertex, sphere_motions
from .still import (
    GROUP as STILL_GROUP,
    VERTICES as STILL_VERTICES,
    block_size,
    block_spheres,
    morton_order,
    still_blocks,
)

METHODS = ("medial", "lbs", "dqs")
RING = 8  # neighbours per vertex in the relaxation's one-ring table


def check_method(method) -> None:
    """Raises `ValueError` unless `method` is one of `METHODS`."""
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"`method` must be one of {', '.join(map(repr, METHODS))}, got "
                         f"{method!r}")


def _check_vertices(vertices) -> np.ndarray:
    v = as_real_array(vertices, "vertices", "an (n, 3) array")
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise ValueError(f"`vertices` must have shape (n, 3) with n >= 1, got {v.shape}")
    return v.astype(np.float64)


def _check_faces(faces, n) -> np.ndarray:
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] not in (3, 4):
        raise ValueError(f"`faces` must have shape (f, 3) or (f, 4), got {f.shape}")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"`faces` must be integer vertex indices, got dtype {f.dtype}")
    f = triangulate(f.astype(np.int64))
    if f.size and (f.min() < 0 or f.max() >= n):
        raise ValueError(f"`faces` must index vertices in [0, {n}), got [{f.min()}, "
                         f"{f.max()}]")
    return f


# Bounds of the rig's options: where they mean something, and the Newton steps and
# relaxation rounds are unrolled when the pose is traced (200 Newton steps took 56 s and
# 2.3 GB to compile).
INTEGER_OPTIONS = {"smoothing": (0, 1000), "slots": (1, 16), "field_cones": (1, 16),
                   "field_slabs": (0, 8), "newton_steps": (0, 8), "relax_iterations": (0, 8)}
REAL_OPTIONS = {"blend": 1.0, "relax_step": 1.0, "contact_angle": 180.0}  # (0, bound]


def _check_options(max_distance, **options) -> dict:
    checked = {name: check_number(options[name], name, low, high, integer=True)
               for name, (low, high) in INTEGER_OPTIONS.items()}
    checked |= {name: check_number(options[name], name, 0, high, above=True)
                for name, high in REAL_OPTIONS.items()}
    checked["max_distance"] = None if max_distance is None else check_number(
        max_distance, "max_distance", 0, float(np.finfo(np.float64).max), above=True)
    return checked


def _one_ring(faces, n, valid):
    """Directed one-ring edges between valid vertices, sorted by destination: `(src, dst,
    weight = 1/valence, self_weight)` (self weight 1 where a vertex has no neighbour)."""
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    pairs = np.concatenate([pairs, pairs[:, ::-1]])
    keys = np.unique(pairs[:, 0] * np.int64(n) + pairs[:, 1])
    pairs = np.stack([keys // n, keys % n], 1)
    pairs = pairs[valid[pairs[:, 0]] & valid[pairs[:, 1]] & (pairs[:, 0] != pairs[:, 1])]
    order = np.lexsort((pairs[:, 0], pairs[:, 1]))
    src, dst = pairs[order, 0], pairs[order, 1]
    valence = np.bincount(dst, minlength=n).astype(np.float64)
    weight = 1.0 / valence[dst]
    return src, dst, weight, (valence == 0).astype(np.float64)


def _ring_table(src, dst, n, width):
    """The one-ring as a gather table: `(neighbours (n, width), weights (n, width))`, the
    first `width` neighbours of each vertex with equal weights (padding: the vertex itself
    with weight 0; a vertex with no neighbour: itself with weight 1). A table, not a
    scatter-add over edges, which XLA's CPU backend runs several times slower; vertices of
    higher valence (poles) average over `width` of their neighbours, the same at rest."""
    starts = np.r_[0, np.cumsum(np.bincount(dst, minlength=n))]
    rank = np.arange(len(dst)) - starts[dst]
    keep = rank < width
    table = np.repeat(np.arange(n)[:, None], width, axis=1)
    table[dst[keep], rank[keep]] = src[keep]
    count = np.minimum(np.diff(starts), width)
    weights = (np.arange(width)[None] < count[:, None]) / np.maximum(count, 1)[:, None]
    weights[count == 0, 0] = 1.0
    return table, weights


def _rotation_weights(spheres, beta, n_spheres, ring, smoothing, slots):
    """The `slots` heaviest spheres of the footprint weights smoothed over the one-ring."""
    n = len(spheres)
    w = sparse.csr_matrix((beta.reshape(-1), (np.repeat(np.arange(n), 3),
                                              spheres.reshape(-1))), shape=(n, n_spheres))
    if ring is not None and smoothing:
        src, dst, weight, self_weight = ring
        mean = sparse.csr_matrix((weight, (dst, src)), shape=(n, n)) + sparse.diags(self_weight)
        for _ in range(smoothing):
            w = 0.5 * w + 0.5 * (mean @ w)
    w = w.tocoo()
    keep = w.data > 0
    row, col, data = w.row[keep], w.col[keep], w.data[keep]
    order = np.lexsort((-data, row))
    row, col, data = row[order], col[order], data[order]
    starts = np.r_[0, np.flatnonzero(np.diff(row)) + 1]
    rank = np.arange(len(row)) - np.repeat(starts, np.diff(np.r_[starts, len(row)]))
    idx = np.repeat(spheres[:, :1], slots, axis=1)
    weights = np.zeros((n, slots))
    weights[:, 0] = 1.0  # rows with no weight (all-zero β cannot happen; kept safe)
    first = rank == 0
    weights[row[first], 0] = 0.0
    idx[row[first]] = col[first][:, None]
    top = rank < slots
    idx[row[top], rank[top]] = col[top]
    weights[row[top], rank[top]] = data[top]
    return idx, weights / weights.sum(axis=1, keepdims=True)


class MedialRig(eqx.Module):
    """A surface bound to its medial mesh (Lan et al. 2017), posed by `rig.pose`.

    **Arguments:**

    - `vertices`: `(n, 3)` rest vertices (non-finite rows are flagged invalid).
    - `medial`: the rest `MedialMesh` (at least one sphere).
    - `faces`: optional `(f, 3)` (or quads `(f, 4)`) vertex indices of the surface: enables the
      rotation-weight smoothing and the implicit step's tangential relaxation.
    - `smoothing`: rounds of one-ring smoothing of the rotation weights (default 8); `slots`:
      spheres kept per vertex (default 4).
    - `field_cones`, `field_slabs`: candidate primitives per vertex for the implicit field
      (defaults 4 and 1). One slab: on spot's head and leg poses (`benchmarks/medial_deform.py`)
      a second changed the volumes by ≤ 0.0013 points and the vertices by ≤ 8.7e-4 of the
      diagonal (99th percentile 2.4e-4), and left the vertices no nearer their rest distance
      to the exact posed envelope (99th percentile 0.85e-3 / 1.4e-3 of the diagonal with one,
      0.91e-3 / 1.5e-3 with two), for a sixth of a frame's time.
    - `max_distance`: vertices farther than this from the envelope are invalid (default: the
      envelope's bounding-box diagonal; finite, > 0).
    - `blend`: width of the implicit field's smooth union, relative to each vertex's footprint
      radius (default 0.1, in (0, 1]).
    - `newton_steps` (1), `relax_iterations` (1), `relax_step` (0.5), `contact_angle` (55°):
      the implicit correction's fixed iteration counts and thresholds. One Newton step, then
      the relaxation's projection: a second step changed none of the volumes of
      `benchmarks/medial_deform.py` in the digits shown and moved the 100k-vertex frame's
      vertices by at most 2.4e-7 (float32), for a third of the correction's time. Bounds
      (checked before binding, `TypeError`/`ValueError` naming the option): `newton_steps`
      and `relax_iterations` in [0, 8] (unrolled in the compiled pose), `relax_step` in
      (0, 1], `contact_angle` in (0, 180], `smoothing` in [0, 1000], `slots`, `field_cones`
      in [1, 16], `field_slabs` in [0, 8].

    Binding is NumPy/SciPy, in blocks of points (`footprint.bind`; 30,722 capsule vertices
    on medial meshes fitted by `medial_mesh`'s `refine`, idle 2-core machine: 1.7 s on 200
    spheres with 373 slabs, 2.3 s on 300 with 986, where all pairs at once took 3.8 s and
    6.4 s; binding grows with the slabs); the fields are JAX arrays (float64 when x64 is on),
    cast to the pose's dtype by `pose`.
    `rig.pose` is compiled (`eqx.filter_jit`, the rig's arrays traced); `jax.jit(rig.pose)`
    works too (the rig hashes by identity; its arrays then become constants of the program).
    """

    rest_vertices: Float[Array, "n 3"]
    valid: Bool[Array, " n"]
    welded: Int[Array, " n"]
    points: Float[Array, "m 3"]
    rest_centers: Float[Array, "s 3"]
    radii: Float[Array, " s"]
    spheres: Int[Array, "n 3"]
    beta: Float[Array, "n 3"]
    offset: Float[Array, "n 3"]
    rotation_spheres: Int[Array, "n k"]
    rotation_weights: Float[Array, "n k"]
    cones: Int[Array, "c 2"]
    medial_faces: Int[Array, "f 3"]
    correction: Correction
    faces: Int[Array, "F 3"] | None
    medial_key: np.ndarray
    n_spheres: int = eqx.field(static=True)
    newton_steps: int = eqx.field(static=True)
    relax_iterations: int = eqx.field(static=True)
    relax_step: float = eqx.field(static=True)
    contact_angle: float = eqx.field(static=True)

    def __init__(
        self,
        vertices: ArrayLike,
        medial: MedialMesh,
        *,
        faces: ArrayLike | None = None,
        smoothing: int = 8,
        slots: int = 4,
        field_cones: int = 4,
        field_slabs: int = 1,
        max_distance: float | None = None,
        blend: float = 0.1,
        newton_steps: int = 1,
        relax_iterations: int = 1,
        relax_step: float = 0.5,
        contact_angle: float = 55.0,
    ):
        if not isinstance(medial, MedialMesh):
            raise TypeError(f"`medial` must be a MedialMesh, got {type(medial).__name__}")
        centers, radii, edges, mfaces = medial.numpy()
        if len(centers) == 0:
            raise ValueError("`medial` must have at least one sphere, got none")
        v = _check_vertices(vertices)
        n = len(v)
        f = None if faces is None else _check_faces(faces, n)
        options = _check_options(smoothing=smoothing, slots=slots, field_cones=field_cones,
                                 field_slabs=field_slabs, newton_steps=newton_steps,
                                 relax_iterations=relax_iterations, blend=blend,
                                 relax_step=relax_step, contact_angle=contact_angle,
                                 max_distance=max_distance)

        points, welded = weld(v)
        m = len(points)
        b = bind(points, centers, radii, edges, mfaces, field_cones=options["field_cones"],
                 field_slabs=options["field_slabs"], max_distance=options["max_distance"],
                 blend=options["blend"])
        ring = None if f is None or len(f) == 0 else _one_ring(welded[f], m, b.valid)
        idx, weights = _rotation_weights(b.spheres, b.beta, len(centers), ring,
                                         options["smoothing"], options["slots"])
        rest = np.where(np.isfinite(points), points, 0.0)
        if ring is None:
            table = table_weights = laplacian = None
        else:
            table, table_weights = _ring_table(ring[0], ring[1], m, RING)
            laplacian = rest - np.einsum("nk,nkd->nd", table_weights, rest[table])
        # The points in a spatial (Morton) order, so that the correction's blocks are slices
        # of consecutive points (`still.py`). Permuted after binding, so that each point's
        # arrays are the same numbers as bound in the welded order; indices renumbered.
        order = morton_order(rest)
        rank = np.argsort(order)
        welded, rest = rank[welded], rest[order]
        b = b._replace(**{name: getattr(b, name)[order] for name in b._fields if name != "cones"})
        idx, weights = idx[order], weights[order]
        if table is not None:
            table, table_weights = rank[table[order]], table_weights[order]
            laplacian = laplacian[order]

        # Converted on the host and put on the device as they are: `jnp.asarray` with a
        # dtype compiles a conversion program per shape (half a second of a small rig).
        def f_(x):
            return None if x is None else jax.device_put(np.asarray(x))

        def i_(x):
            return None if x is None else jax.device_put(np.asarray(x, np.int32))

        self.rest_vertices = f_(np.where(np.isfinite(v), v, 0.0))
        self.valid = jax.device_put(b.valid[welded] & np.isfinite(v).all(axis=1))
        self.welded, self.points = i_(welded), f_(rest)
        self.rest_centers, self.radii = f_(centers), f_(radii)
        self.spheres, self.beta, self.offset = i_(b.spheres), f_(b.beta), f_(b.offset)
        self.rotation_spheres, self.rotation_weights = i_(idx), f_(weights)
        self.cones, self.medial_faces = i_(b.cones), i_(mfaces)
        size, blocks = block_size(m), None
        if m <= STILL_VERTICES:
            # The spheres each point reads, for the correction's skip of still groups.
            reads = np.concatenate([b.spheres, idx, b.cones[b.field_cones].reshape(m, -1),
                                    b.cones[b.edge_cones].reshape(m, -1),
                                    mfaces[b.field_slabs].reshape(m, -1)], axis=1)
            size = STILL_GROUP
            blocks = block_spheres(reads, table, size)
        self.correction = Correction(i_(b.field_cones), i_(b.edge_cones), i_(b.field_slabs),
                                     i_(b.edge_slots), f_(b.iso), f_(b.width), i_(table),
                                     f_(table_weights), f_(laplacian), i_(blocks), size)
        self.faces = i_(f)
        self.medial_key = np.frombuffer(bytes.fromhex(medial.fingerprint()), np.uint8).copy()
        self.n_spheres = len(centers)
        self.newton_steps = options["newton_steps"]
        self.relax_iterations = options["relax_iterations"]
        self.relax_step, self.contact_angle = options["relax_step"], options["contact_angle"]

    def fingerprint(self) -> str:
        """The `MedialMesh.fingerprint` of the medial mesh the rig was bound to."""
        return bytes(np.asarray(self.medial_key)).hex()

    # Identity hash and equality (not equinox's, over the array leaves, which cannot be
    # hashed): so that `jax.jit(rig.pose)` works, with the rig's arrays as constants.
    def __hash__(self):
        return id(self)

    def __eq__(self, other):
        return self is other

    def pose(
        self,
        posed: MedialPose,
        method: Literal["medial", "lbs", "dqs"] = "medial",
        *,
        implicit: bool = True,
    ) -> tuple[Float[Array, "n 3"], Bool[Array, " n"]]:
        """Poses the bound surface.

        **Arguments:**

        - `posed`: a `MedialPose` of the rig's medial mesh (same sphere count); its arrays may
          be traced (`jit`, `grad`).
        - `method`: `"medial"` (Lan et al. 2017), `"lbs"` or `"dqs"` (see `skin.py`).
        - `implicit`: apply the implicit-skinning correction (Vaillant et al. 2013) after the
          skin (any method).

        **Returns:** `(vertices (n, 3), valid (n,))` in the dtype of `posed.centers`; invalid
        vertices at their rest position.
        """
        return skinned(self, posed, method, implicit)


def skinned(rig: MedialRig, posed: MedialPose, method: str, implicit: bool, quick: bool = False):
    """`rig.pose(posed, method, implicit=implicit)`, its program compiled quickly if `quick`
    (`_batching.quick`: `deform_medial`'s one call on a small mesh)."""
    check_method(method)
    if not isinstance(posed, MedialPose):
        raise TypeError(f"`posed` must be a MedialPose, got {type(posed).__name__}")
    if posed.centers.shape[0] != rig.n_spheres:
        raise ValueError(f"`posed` must be a pose of the rig's medial mesh "
                         f"({rig.n_spheres} spheres), got {posed.centers.shape[0]}")
    if is_concrete(posed.medial) and posed.medial.fingerprint() != rig.fingerprint():
        raise ValueError("`posed` must be a pose of the rig's medial mesh; it is a pose of "
                         "another one (other spheres or topology)")
    return _pose(rig, posed.centers, posed.rotations, method, bool(implicit), quick=quick)


def _skin(rig: MedialRig, centers, rotations, method, implicit):
    dtype = centers.dtype
    rig = cast_floats(rig, dtype)
    rotations = rotations.astype(dtype)
    # The arrays of the welded points (`weld`), then each caller vertex reads its point's.
    quats, translations, dual = sphere_motions(rig.rest_centers, centers, rotations)
    q, w = quats[rig.rotation_spheres], rig.rotation_weights
    if method == "medial":
        x, r = jax.vmap(medial_vertex)(centers[rig.spheres], rig.beta, rig.offset, q, w)
    else:
        k = rig.rotation_spheres
        if method == "lbs":
            x = jax.vmap(lbs_vertex)(rotations[k], translations[k], w, rig.points)
        else:
            x = jax.vmap(dqs_vertex)(dual[k], w, rig.points)
        r = jax.vmap(lambda a, b: matrix_from_quaternion(blend_quaternion(a, b)))(q, w)
    if implicit:
        # Blocks whose spheres all move as one rigid body keep their skinned vertices (`still`).
        still = None if rig.correction.blocks is None else still_blocks(
            rig.correction.blocks, rig.rest_centers, centers, rotations)
        x, _ = correct(x, r, centers, rig.radii, rig.cones, rig.medial_faces, rig.correction,
                       newton_steps=rig.newton_steps, relax_iterations=rig.relax_iterations,
                       relax_step=rig.relax_step, contact_angle=rig.contact_angle,
                       still=still)
    # A vertex whose image is not finite (a pose far beyond the dtype's range, a traced pose
    # that was not checked) is invalid and stays at rest: never a NaN flagged valid.
    x = x[rig.welded]
    valid = rig.valid & jnp.all(jnp.isfinite(x), axis=-1)
    return jnp.where(valid[:, None], x, rig.rest_vertices), valid


_pose = Program(_skin, kept=True)

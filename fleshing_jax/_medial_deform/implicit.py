"""Implicit-skinning correction (after Vaillant et al. 2013), in JAX.

The field is the signed distance to the *posed envelope*: the union of the cones (lone
spheres as cones of length 0) and slabs built on the posed centres with the rest radii, in
the closed forms of `primitives.py` (derived there), written here for one primitive and one
point. Each closed form returns the distance and its gradient in the point, `(p − q)/|p − q|`
at the nearest footprint sphere's centre `q` (the envelope theorem: the minimising
parameter's own derivative drops out); a slab's tangent-plane part returns its plane's
normal, and its nearest edge cone's where the foot leaves the triangle. The union's field is
a smooth union (see `field`) over a fixed, small set of candidate primitives per vertex
chosen at bind time (`footprint.py`), so that a pose costs `O(vertices · candidates)` and
stays `jit`/`vmap` friendly. A slab's edges are cones, mostly among the vertex's cone
candidates already: each distinct cone is evaluated once per vertex and the slabs read
their edges' fields from it (`field`), and the vertices are evaluated in blocks (`correct`).

The correction (Vaillant et al. 2013): each skinned vertex is moved along the field's
gradient back to its rest iso-value (the rest envelope's field at its rest position) by a
fixed number of Newton steps `x ← x − (f(x) − iso) ∇f`; a vertex stops for good where the
gradient turns by more than `contact_angle` from the previous step (two parts pressing
together). Then, when the surface's faces are known, `relax_iterations` rounds of tangential
relaxation, each followed by one projection step. Our own choice for the relaxation target:
the posed one-ring mean plus the vertex's rest Laplacian vector (rest vertex minus rest
one-ring mean) turned by its blended rotation, projected onto the tangent plane — so the rest
pose and rigid motions are fixed points and rest details are kept (in the spirit of the
rest-pose coordinates of Vaillant et al. 2014), where a plain move to the one-ring mean would
smooth the mesh even at rest.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._numerics import dot, norm, safe_divide, safe_sqrt, weighted_sum
from .still import block_size

BLOCK = 1024  # vertices per block of the field's evaluation (see `correct`)


class Cones(eqx.Module):
    """Per-cone quantities of a posed envelope, each `(C, ...)`: first centre, unit axis,
    the lateral foot's slope `s/√(1 − s²)` (`s = (r0 − r1)/L`), the bounds `[lo, hi]` of the
    footprint's position along the axis (`[0, L]`; for nested spheres both at the larger
    sphere's centre), first radius and `s`. Everything that depends on the cone alone is
    computed here once per pose rather than once per (vertex, candidate)."""

    c0: Array
    u: Array
    slope: Array
    lo: Array
    hi: Array
    r0: Array
    s: Array


def cone_table(centers: Array, radii: Array, cones: Int[Array, "C 2"]) -> Cones:
    """`Cones` of segments `cones` (sphere index pairs; `(i, i)` a lone sphere)."""
    c0, c1 = centers[cones[:, 0]], centers[cones[:, 1]]
    r0, r1 = radii[cones[:, 0]], radii[cones[:, 1]]
    axis = c1 - c0
    length = safe_sqrt(dot(axis, axis))
    u = safe_divide(axis, length[:, None])
    s = safe_divide(r0 - r1, length)
    proper = length > jnp.abs(r0 - r1) * (1 + 1e-6)
    slope = safe_divide(s, safe_sqrt(1 - s * s))
    end = jnp.where(r0 >= r1, 0, length)
    return Cones(c0, u, slope, jnp.where(proper, 0, end), jnp.where(proper, length, end), r0, s)


def cone_field(p: Float[Array, " 3"], cone: Cones) -> tuple[Array, Array]:
    """Signed distance of `p` to one cone (fields of `cone` unbatched), and its gradient.

    The square roots are of `max(·, tiny)` (the dtype's smallest normal number): the same
    value wherever the argument is at least `tiny`, `√tiny` (~1e-19 in float32) below, with
    a zero derivative there, so that the gradient's division needs no guard; where
    `safe_sqrt`/`safe_divide`'s selects made a pose's field evaluation ~1.25× as long
    (measured on the 107k-vertex capsule). On the axis or at the foot itself the gradient is
    `v/√tiny` (`v` at most `√tiny` long), where the guarded form gave 0: either is a
    direction of a non-differentiable point."""
    tiny = jnp.finfo(p.dtype).tiny
    d0 = p - cone.c0
    x = dot(d0, cone.u)
    y = jnp.sqrt(jnp.maximum(dot(d0, d0) - x * x, tiny))
    # Clamped to [lo, hi]: on a proper cone the lateral foot clamped to the segment, for
    # nested spheres (lo = hi) the larger sphere's centre, without a select per evaluation.
    t = jnp.clip(x - y * cone.slope, cone.lo, cone.hi)
    v = d0 - t * cone.u
    dist = jnp.sqrt(jnp.maximum(dot(v, v), tiny))
    return dist - (cone.r0 - cone.s * t), v / dist


class Slabs(eqx.Module):
    """Per-slab quantities of a posed envelope, each `(F, ...)`: first centre `c0`, centres'
    plane normal `m`, in-plane part `a` and `γ` (and `1/γ`) of the tangent planes' normals
    `a ± γ m`, the rows `p1`, `p2` that map `d = x − c0` in the centres' plane to its
    barycentric coordinates over the edges `c1 − c0`, `c2 − c0` (the inverse Gram matrix
    applied to them), `k1 = a·p1`, `k2 = a·p2`, first radius, and whether the slab has
    tangent planes. Everything that depends on the slab alone is computed here once per pose
    rather than once per (vertex, candidate)."""

    c0: Array
    m: Array
    a: Array
    gamma: Array
    inv_gamma: Array
    p1: Array
    p2: Array
    k1: Array
    k2: Array
    r0: Array
    ok: Array


def slab_table(centers: Array, radii: Array, faces: Int[Array, "F 3"]) -> Slabs:
    """`Slabs` of the medial faces `faces`."""
    c0, c1, c2 = (centers[faces[:, k]] for k in range(3))
    r0, r1, r2 = (radii[faces[:, k]] for k in range(3))
    e1, e2 = c1 - c0, c2 - c0
    normal = jnp.cross(e1, e2)
    m = safe_divide(normal, safe_sqrt(dot(normal, normal))[:, None])
    g11, g12, g22 = dot(e1, e1), dot(e1, e2), dot(e2, e2)
    det = g11 * g22 - g12 * g12
    ok = det > 1e-10 * g11 * g22
    alpha = safe_divide(g22 * (r0 - r1) - g12 * (r0 - r2), jnp.where(ok, det, 0))
    beta = safe_divide(g11 * (r0 - r2) - g12 * (r0 - r1), jnp.where(ok, det, 0))
    a = alpha[:, None] * e1 + beta[:, None] * e2
    gamma2 = 1 - dot(a, a)
    ok = ok & (gamma2 > 1e-6)
    det = jnp.where(ok, det, 0)[:, None]
    p1 = safe_divide(g22[:, None] * e1 - g12[:, None] * e2, det)
    p2 = safe_divide(g11[:, None] * e2 - g12[:, None] * e1, det)
    gamma = safe_sqrt(gamma2)
    return Slabs(c0, m, a, gamma, safe_divide(1, gamma), p1, p2, dot(a, p1), dot(a, p2), r0, ok)


def slab_field(p: Float[Array, " 3"], slab: Slabs, edge_values: Float[Array, " 3"],
               edge_grads: Float[Array, "3 3"]) -> tuple[Array, Array]:
    """Signed distance of `p` to one whole slab (fields of `slab` unbatched), and its
    gradient, given the fields of its three edge cones at `p` (`cone_field`; the caller
    evaluates them, once per vertex even where several candidates share them): the tangent
    plane's where the foot of `p` is in the triangle of centres, else the nearest edge
    cone's (continuous across the boundary, and differentiable outside: the slab is
    convex).

    With `d = p − c0`, `h = d·m` and the tangent plane of `p`'s side, normal
    `n = a + sign(h) γ m`: the foot along `n` is `d − (|h|/γ) n`, whose barycentric
    coordinates are `d·p − (|h|/γ) a·p` (`m·p = 0`: `p1`, `p2` lie in the centres' plane),
    and the plane's distance is `n·d − r0 = a·d + γ|h| − r0`."""
    d = p - slab.c0
    h = dot(d, slab.m)
    q = jnp.abs(h) * slab.inv_gamma
    b1 = dot(d, slab.p1) - q * slab.k1
    b2 = dot(d, slab.p2) - q * slab.k2
    inside = slab.ok & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1)
    n = slab.a + jnp.where(h >= 0, slab.gamma, -slab.gamma) * slab.m
    # The nearest edge (the first on ties) by selects: a reduction over an axis of length 3
    # is slower on XLA's CPU backend.
    edge_value, edge_grad = edge_values[0], edge_grads[0]
    for k in (1, 2):
        nearer = edge_values[k] < edge_value
        edge_value = jnp.where(nearer, edge_values[k], edge_value)
        edge_grad = jnp.where(nearer, edge_grads[k], edge_grad)
    return (jnp.where(inside, dot(d, slab.a) + slab.gamma * jnp.abs(h) - slab.r0, edge_value),
            jnp.where(inside, n, edge_grad))


def smooth_union(a, ga, b, gb, width, half_inverse=None):
    """Polynomial smooth minimum of two fields (and its gradient): the minimum where they
    differ by more than `width`, a quadratic blend `mix(b, a, h) − width·h(1 − h)`,
    `h = clip(½ + (b − a)/(2 width), 0, 1)`, near their crease; continuously differentiable,
    with gradient `h ∇a + (1 − h) ∇b`. `half_inverse`: `1/(2 width)` if the caller has it
    (a fold over several fields then divides once rather than per field: the field's
    evaluation ~0.87× as long, measured; equal to round-off)."""
    if half_inverse is None:
        half_inverse = 0.5 / width
    h = jnp.clip(0.5 + (b - a) * half_inverse, 0, 1)
    return b + h * (a - b) - width * h * (1 - h), gb + h * (ga - gb)


def field(p: Float[Array, " 3"], width: Array, cones: Cones, extra: Cones,
          slabs: Slabs | None, edge_slots: Int[Array, "ks 3"]) -> tuple[Array, Array]:
    """The union's field over one vertex's candidates, and its gradient: a smooth union
    (`smooth_union`, folded over the candidates in their order: cones, then slabs).

    **Arguments:** `p (3,)`; `width` the union's width; `cones` the vertex's `kc` cone
    candidates and `extra` the `e` further cones its slabs need as edges (both `Cones`
    batched over their rows); `slabs` its `ks` slab candidates (or `None`); `edge_slots
    (ks, 3)` where each slab's three edges are in the concatenation `cones ++ extra`.

    Each distinct cone is evaluated once: a slab's edges are mostly among the vertex's cone
    candidates already (the `kc + 3 ks` cones a plain evaluation needs are `kc + e`, `e`
    small, set at bind time by `footprint.bind`), and each slab reads its edges' fields by
    those slots — the same values as evaluating them in place.

    A smooth union (our choice, in the spirit of Vaillant et al.'s composition operators)
    rather than the union's exact minimum: the minimum has creases where two primitives are
    equally near (on a chain of spheres, at every sphere), across which the projected
    vertices — and derivatives with respect to the pose — would jump. Away from the creases
    it is the exact distance; the rest iso-values use the same field, so the blend's offset
    near creases cancels.

    **Returns:** `(value (), gradient (3,))`."""
    # The candidates unrolled (Python loops, not `vmap`): batched over vertices, each
    # candidate's quantities are then (vertices,) vectors rather than (vertices, k) arrays
    # with a short minor axis, which XLA's CPU backend runs faster (measured: ~25 %).
    def row(table, k):
        return jax.tree.map(lambda a: a[k], table)

    fields = [cone_field(p, row(t, k)) for t in (cones, extra) for k in range(t.r0.shape[0])]
    candidates = fields[:cones.r0.shape[0]]
    if slabs is not None:
        values = jnp.stack([v for v, _ in fields])
        grads = jnp.stack([g for _, g in fields])
        candidates += [slab_field(p, row(slabs, j), values[edge_slots[j]],
                                  grads[edge_slots[j]]) for j in range(edge_slots.shape[0])]
    value, grad = candidates[0]
    half_inverse = 0.5 / width
    for v, g in candidates[1:]:
        value, grad = smooth_union(value, grad, v, g, width, half_inverse)
    return value, grad


def pack_rows(table) -> tuple[Array, tuple]:
    """The arrays of a per-primitive table (an equinox Module whose leaves share their first
    axis, `Cones` or `Slabs`) side by side as one `(rows, width)` array, and the static layout
    `unpack_rows` needs. Why: each vertex then gathers its candidates' rows with one gather
    of contiguous rows, where a gather per field costs XLA's CPU backend a kernel and a
    round trip through memory each (the field's evaluation 0.8× as long, measured)."""
    leaves, treedef = jax.tree.flatten(table)
    dtype = jnp.result_type(*(a for a in leaves if jnp.issubdtype(a.dtype, jnp.floating)))
    columns = [a.reshape(a.shape[0], -1).astype(dtype) for a in leaves]
    layout = (treedef, tuple((a.shape[1:], a.dtype == jnp.bool_) for a in leaves))
    return jnp.concatenate(columns, axis=1), layout


def unpack_rows(rows: Float[Array, "... width"], layout: tuple):
    """The table of `pack_rows` back from (gathered) rows `(..., width)`: its fields
    `(..., *shape)`, booleans restored."""
    treedef, fields = layout
    leaves, start = [], 0
    for shape, is_bool in fields:
        size = int(np.prod(shape, dtype=int))
        a = rows[..., start:start + size].reshape(rows.shape[:-1] + shape)
        leaves.append(a > 0.5 if is_bool else a)
        start += size
    return jax.tree.unflatten(treedef, leaves)


class Correction(eqx.Module):
    """What the correction needs per vertex, besides the pose: candidate indices
    (`field_cones` into the cone table, `field_slabs` into the medial faces), the further
    cones its slabs need as edges (`edge_cones`, padded by repeats) and where each slab's
    edges are among `field_cones ++ edge_cones` (`edge_slots`), the rest iso-values and the
    smooth union's widths, the one-ring as a gather table (`ring`, `ring_weights` summing to
    1 per row) and the rest Laplacian vectors (rest vertex minus its rest one-ring mean;
    `None` without faces); `blocks` the spheres each group of `block` consecutive vertices
    reads (`still.block_spheres`; `still.GROUP` vertices), or `None`."""

    field_cones: Int[Array, "n kc"]
    edge_cones: Int[Array, "n e"]
    field_slabs: Int[Array, "n ks"]
    edge_slots: Int[Array, "n ks 3"]
    iso: Float[Array, " n"]
    width: Float[Array, " n"]
    ring: Int[Array, "n w"] | None
    ring_weights: Float[Array, "n w"] | None
    laplacian: Float[Array, "n 3"] | None
    blocks: Int[Array, "b s"] | None = None
    block: int = eqx.field(static=True, default=0)


def correct(
    skinned: Float[Array, "n 3"],
    rotations: Float[Array, "n 3 3"],
    centers: Float[Array, "s 3"],
    radii: Float[Array, " s"],
    cones: Int[Array, "c 2"],
    faces: Int[Array, "f 3"],
    data: Correction,
    *,
    newton_steps: int,
    relax_iterations: int,
    relax_step: float,
    contact_angle: float,
    still: Bool[Array, " b"] | None = None,
) -> tuple[Array, Array]:
    """Implicit-skinning correction of skinned vertices on the posed envelope
    `(centers, radii)`. `still`: optional `(b,)` flags of the groups of `data.blocks` whose
    spheres move as one rigid body (`still.still_blocks`): their vertices are left as
    skinned (the correction would move them by round-off) and the field is evaluated on the
    others only, gathered into chunks of `still.block_size(n)` vertices. **Returns:**
    `(vertices (n, 3), contact (n,))`, `contact` where a vertex was stopped by the gradient test."""
    # The per-primitive tables are small (a few hundred rows), packed into one array each
    # (`pack_rows`) and gathered inside each evaluation, where XLA fuses the gathers with the
    # arithmetic (as fast as gathering the (vertices, candidates) rows once, measured,
    # without their memory).
    cone_rows, cone_layout = pack_rows(cone_table(centers, radii, cones))
    slab_rows = None
    if data.field_slabs.shape[1] and faces.shape[0]:
        slab_rows, slab_layout = pack_rows(slab_table(centers, radii, faces))

    def one(p, width, ic, ie, js, slots):
        rows = unpack_rows(cone_rows[jnp.concatenate([ic, ie])], cone_layout)
        kc = ic.shape[0]
        slabs = None if slab_rows is None else unpack_rows(slab_rows[js], slab_layout)
        return field(p, width, jax.tree.map(lambda a: a[:kc], rows),
                     jax.tree.map(lambda a: a[kc:], rows), slabs, slots)

    n = skinned.shape[0]
    skipping = still is not None and data.blocks is not None
    # The vertices padded to whole blocks (copies of the last one, dropped from the output):
    # `lax.map` then runs one traced block, where a remainder traced and compiled the field a
    # second time.
    block = min(BLOCK, n)
    pad = -n % block

    def blocked(a):
        if pad:
            a = jnp.concatenate([a, jnp.broadcast_to(a[-1:], (pad, *a.shape[1:]))])
        return a.reshape((n + pad) // block, block, *a.shape[1:])

    rows = (data.width, data.field_cones, data.edge_cones, data.field_slabs, data.edge_slots)
    if skipping:
        # Each vertex of a still group keeps its skinned position; the others are gathered
        # (in their order: the rig keeps its points in a spatial order, `still.py`) and
        # evaluated in chunks, as many as they fill.
        fixed = jnp.repeat(still, data.block)[:n]
        chunk = min(block_size(n), n)
        (order,) = jnp.nonzero(~fixed, size=n + (-n % chunk), fill_value=n)
    else:
        per_vertex = [blocked(a) for a in rows]

    def evaluate(x, g_prev):
        if not skipping:
            # In blocks of vertices (a loop, each block vectorised): the (block, candidates)
            # temporaries XLA materialises between its fused kernels then stay in cache, where
            # over all vertices at once they go through memory (measured in
            # benchmarks/README.md).
            f, g = jax.lax.map(lambda a: jax.vmap(one)(*a), (blocked(x), *per_vertex))
            return f.reshape(-1)[:n], g.reshape(-1, 3)[:n]

        # A still vertex keeps its place: its field is its iso-value, its gradient the
        # previous one (no Newton step, no turn for the angle test). A chunk past the last
        # moving vertex (its indices all the padding `n`) is skipped by its `lax.cond`; a
        # loop of fixed length (not a `while_loop` of the moving chunks' count), so that
        # reverse-mode derivatives exist.
        def chunk_of(at):
            def field_of():
                return jax.vmap(one)(*(a.at[at].get(mode="clip") for a in (x, *rows)))

            def skipped():
                return jnp.zeros(chunk, x.dtype), jnp.zeros((chunk, 3), x.dtype)

            return jax.lax.cond(at[0] < n, field_of, skipped)

        f, g = jax.lax.map(chunk_of, order.reshape(-1, chunk))
        return (data.iso.at[order].set(f.reshape(-1), mode="drop"),
                g_prev.at[order].set(g.reshape(-1, 3), mode="drop"))

    cos_max = jnp.cos(jnp.deg2rad(contact_angle)).astype(skinned.dtype)
    relaxing = data.ring is not None and relax_iterations > 0
    steps = newton_steps + (relax_iterations if relaxing else 0)
    x, active = skinned, jnp.ones(n, bool)
    if steps == 0:
        return x, ~active
    # The gradient of the previous evaluation: the first Newton step has none to compare with
    # (the angle test starts at the second step), relaxation without Newton steps evaluates it.
    g, tested_first = jnp.zeros_like(x), False
    if relaxing:
        if newton_steps == 0:
            (_, g), tested_first = evaluate(x, g), True
        # (Explicit sums of products, not `einsum` or `jnp.sum` over the short axes: see
        # `weighted_sum`.)
        delta = dot(rotations, data.laplacian[:, None, :])

    def step(k, state):
        # The Newton steps, then the rounds of relaxation, each followed by one projection
        # step, as one loop: the field is traced and compiled once for all of them.
        x, active, g_prev = state
        if relaxing:
            def relax(x):
                ring = jax.vmap(weighted_sum)(data.ring_weights, x[data.ring])
                move = ring + delta - x
                move = move - dot(move, g_prev)[:, None] * g_prev
                moving = active & ~fixed if skipping else active
                return jnp.where(moving[:, None], x + relax_step * move, x)

            # Only in the relaxation's rounds (the Newton steps' share of the loop skips it).
            x = jax.lax.cond(k >= newton_steps, relax, lambda x: x, x)
        f, g = evaluate(x, g_prev)
        # The angle test of Vaillant et al. on unit gradients; a smooth union's gradient can
        # be short where two primitives' gradients oppose, so the step's denominator is kept
        # away from 0 (it is 1 wherever one primitive dominates).
        tested = active & (dot(g, g_prev) >= cos_max * norm(g) * norm(g_prev))
        active = tested if tested_first else jnp.where(k > 0, tested, active)
        size = (f - data.iso) / jnp.maximum(dot(g, g), 0.25)
        return jnp.where(active[:, None], x - size[:, None] * g, x), active, g

    x, active, _ = jax.lax.fori_loop(0, steps, step, (x, active, g))
    return x, ~active


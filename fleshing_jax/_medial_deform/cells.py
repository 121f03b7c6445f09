"""The cells of the ARAP deformation of a medial mesh, and their linear systems (NumPy, once
per medial mesh and handle set).

Lan et al. 2017 (appendix, eq. 27) give every medial primitive (cone or slab) a rotation and
match the primitive's two or three sphere centres around its centroid. Those cells leave
degrees of freedom free: two points fix no rotation about a cone's axis (no resistance to
twist), and a chain of cones, each matched on its own, bends freely at every shared sphere (no
resistance to a hinge). *Our choice*, as in Sorkine & Alexa 2007: one cell per sphere, its
closed one-ring (the sphere and its neighbours in the medial graph, edges of cones and slabs
alike), matched around the cell's centroid as in eq. 27. Three points along a chain resist a
hinge; the rotation about a straight chain is still free, so the energy adds a rotation-
smoothness term between neighbouring cells (Levi & Gotsman 2014, "Smooth rotation enhanced
ARAP"), which makes every cell's fitting matrix full rank and carries a prescribed twist along
the chain:

    E = Σ_i Σ_{k ∈ cell(i)} |(c̃_k − t_i) − R_i (c⁰_k − t⁰_i)|²
      + Σ_{(i, j) ∈ edges} w_ij |R_i − R_j|²_F

with `t_i` the centroid of cell `i` (rest `t⁰_i`) and `w_ij = smoothness · |c⁰_i − c⁰_j|²`
(lengths squared, so that both terms scale alike and `smoothness` has no unit).

Everything here depends on the topology, the rest centres and the handles only: the padded
index arrays of the cells, a colouring of the medial graph (cells of one colour share no edge,
so their rotations are fitted together, exactly, in a Gauss–Seidel sweep), and the solutions
of the two systems the solver meets, as dense matrices (`_inverse`): the centres' normal
equations with the handles fixed, and the graph Laplacian that interpolates the handles'
rotations (as quaternions) for the first guess. Dense: fine for the few hundred to few
thousand spheres of a medial mesh (`MAX_SPHERES`).
"""

from __future__ import annotations

import equinox as eqx
import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.csgraph
from jaxtyping import Array, Float, Int

MAX_SPHERES = 4096  # dense n × n factors: 134 MB in float64 at this size
PROXIMAL = 1e-3  # weight of |R − R_old|² in a rotation fit, relative to the cell's size


class ArapCells(eqx.Module):
    """The precomputed data of one medial mesh and handle set (a pytree of NumPy arrays).

    **Fields** (`n` spheres, cells padded to `K = 1 + max degree` entries, `h` handles, `f`
    free spheres):

    - `rest`: `(n, 3)` rest centres `c⁰`.
    - `members`: `(n, K)` the spheres of each cell, the cell's own sphere first (padding:
      the own sphere again, with `mask` 0).
    - `mask`: `(n, K)` 1 for real entries, 0 for padding. Sphere `k` lies in exactly as many
      cells as cell `k` has members (its own and its neighbours'), so the same mask serves
      `owners` below.
    - `offsets`: `(n, K, 3)` rest offsets `c⁰_k − t⁰_i` of the members from their cell's
      centroid (0 on padding).
    - `handle_offsets`: `(h, K, 3)` for each handle's cell, the rest offsets of its members
      that are handles from their own centroid (0 for the others): what the handles alone
      say about the handle's rotation (the first guess).
    - `owners`, `owner_offsets`: `(n, K)` the cells that contain each sphere, and `(n, K, 3)`
      the sphere's rest offset in each of them.
    - `neighbours`, `weights`: `(n, K − 1)` the graph neighbours of each sphere and the
      smoothness weights `w_ij` (0 on padding).
    - `proximal`: `(n,)` weight of the proximal term of each rotation fit.
    - `colours`: `(C, m)` a colouring of the medial graph, one colour's spheres per row,
      padded with repeats of its first sphere (a sphere fitted twice in one colour gets
      the same rotation twice).
    - `handles`, `free`: `(h,)` and `(f,)` sphere indices.
    - `inverse`, `coupling`: the inverse `L_ff⁻¹` `(f, f)` of the centres' system restricted
      to the free spheres, and `L_ff⁻¹ L_fh` `(f, h)`, so that the free centres' solve is
      `inverse @ b_f − coupling @ u_h` (computed in float64, then cast).
    - `q_coupling`: the same `A_ff⁻¹ A_fh` `(f, h)` of the weighted graph Laplacian `A` of
      the smoothness term: the harmonic interpolation of the handles' rotations is
      `−q_coupling @ q_h`.
    """

    rest: Float[Array, "n 3"]
    members: Int[Array, "n K"]
    mask: Float[Array, "n K"]
    offsets: Float[Array, "n K 3"]
    handle_offsets: Float[Array, "h K 3"]
    owners: Int[Array, "n K"]
    owner_offsets: Float[Array, "n K 3"]
    neighbours: Int[Array, "n D"]
    weights: Float[Array, "n D"]
    proximal: Float[Array, " n"]
    colours: Int[Array, "C m"]
    handles: Int[Array, " h"]
    free: Int[Array, " f"]
    inverse: Float[Array, "f f"]
    coupling: Float[Array, "f h"]
    q_coupling: Float[Array, "f h"]


def _list(indices, limit: int = 10) -> str:
    indices = [int(i) for i in indices]
    more = f", … ({len(indices)} in all)" if len(indices) > limit else ""
    return ", ".join(map(str, indices[:limit])) + more


def graph(n: int, edges: np.ndarray) -> scipy.sparse.csr_matrix:
    """The medial graph's symmetric adjacency (duplicate edges merged), `(n, n)` CSR."""
    e = np.unique(np.sort(edges, axis=1), axis=0) if len(edges) else edges.reshape(0, 2)
    data = np.ones(2 * len(e))
    rows, cols = np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]])
    return scipy.sparse.csr_matrix((data, (rows, cols)), shape=(n, n))


def check_topology(n: int, edges: np.ndarray, handles: np.ndarray) -> None:
    """Raises `ValueError` naming the spheres when the deformation would be undetermined:
    spheres in no edge (isolated), or a connected component without a handle."""
    if n > MAX_SPHERES:
        raise ValueError(f"`medial` has {n} spheres; arap_medial factors dense n × n systems "
                         f"and takes at most {MAX_SPHERES} (simplify the medial mesh).")
    adjacency = graph(n, edges)
    degree = np.diff(adjacency.indptr)
    isolated = np.flatnonzero(degree == 0)
    if len(isolated):
        raise ValueError(f"`medial` has spheres in no edge (isolated: their rotation and "
                         f"position are undetermined): spheres {_list(isolated)}.")
    count, labels = scipy.sparse.csgraph.connected_components(adjacency, directed=False)
    held = np.zeros(count, bool)
    held[labels[handles]] = True
    for component in np.flatnonzero(~held):
        spheres = np.flatnonzero(labels == component)
        raise ValueError(f"`handles` must hold at least one sphere of every connected component "
                         f"of `medial` ({count} components); the component of spheres "
                         f"{_list(spheres)} has none, so its position would be undetermined.")


def _colouring(adjacency: scipy.sparse.csr_matrix) -> list[np.ndarray]:
    """A greedy colouring (largest degree first): no edge joins two spheres of one colour."""
    n = adjacency.shape[0]
    colour = np.full(n, -1)
    order = np.argsort(-np.diff(adjacency.indptr), kind="stable")
    for i in order:
        taken = set(colour[adjacency.indices[adjacency.indptr[i]:adjacency.indptr[i + 1]]])
        c = 0
        while c in taken:
            c += 1
        colour[i] = c
    return [np.flatnonzero(colour == c) for c in range(colour.max() + 1)]


def _colour_table(colours: list[np.ndarray]) -> np.ndarray:
    """The colours as rows of one `(C, m)` table, `m` the largest colour, each row padded with
    its first sphere (so that the solver loops over one row shape)."""
    width = max(len(c) for c in colours)
    return np.stack([np.r_[c, np.full(width - len(c), c[0])] for c in colours])


def _inverse(matrix: np.ndarray, free: np.ndarray, handles: np.ndarray):
    """`A⁻¹` and `A⁻¹ B` for `A = matrix[free, free]` (symmetric positive definite) and
    `B = matrix[free, handles]`, by a Cholesky factorisation in float64.

    Why an inverse, not the factor: the solver meets the same system at every iteration,
    with a few right-hand sides; two triangular solves of a 122-row factor (spot at 200
    spheres) took XLA's CPU backend 77 µs an iteration, a product with the inverse a few,
    and the inverse rounded once to float32 is as accurate as the solves in float32."""
    block = matrix[np.ix_(free, free)]
    coupling = matrix[np.ix_(free, handles)]
    if not len(free):
        return block, coupling
    factor = scipy.linalg.cho_factor(block, lower=True)
    return (scipy.linalg.cho_solve(factor, np.eye(len(free))),
            scipy.linalg.cho_solve(factor, coupling))


def arap_cells(rest: np.ndarray, edges: np.ndarray, handles: np.ndarray, smoothness: float,
               dtype) -> ArapCells:
    """Builds the `ArapCells` of a medial mesh (rest centres `(n, 3)`, edges `(e, 2)`) and a
    checked handle set, with arrays in `dtype`. See the module docstring for the energy."""
    n = len(rest)
    check_topology(n, edges, handles)
    adjacency = graph(n, edges)
    degree = np.diff(adjacency.indptr)
    k = 1 + int(degree.max())
    slot = np.arange(k)[None, :]
    mask = slot <= degree[:, None]
    members = np.repeat(np.arange(n)[:, None], k, axis=1)
    for i in range(n):  # one row per sphere: preprocessing, once per mesh
        members[i, 1:1 + degree[i]] = adjacency.indices[adjacency.indptr[i]:adjacency.indptr[i + 1]]
    points = rest[members]
    centroid = (points * mask[..., None]).sum(1) / mask.sum(1)[:, None]
    offsets = np.where(mask[..., None], points - centroid[:, None], 0.0)

    is_handle = np.zeros(n, bool)
    is_handle[handles] = True
    held = mask[handles] & is_handle[members[handles]]
    held_points = rest[members[handles]]
    held_centroid = (held_points * held[..., None]).sum(1) / held.sum(1)[:, None]
    handle_offsets = np.where(held[..., None], held_points - held_centroid[:, None], 0.0)

    # Sphere k lies in its own cell (slot 0) and in the cell of each neighbour j, at the slot
    # where k appears among j's members.
    owners = members.copy()
    owner_slot = np.zeros((n, k), np.int64)
    position = {(int(i), int(j)): s for i in range(n) for s, j in enumerate(members[i, 1:], 1)
                if mask[i, s]}
    for i in range(n):
        for s in range(1, 1 + degree[i]):
            owner_slot[i, s] = position[(int(members[i, s]), i)]
    owner_offsets = np.where(mask[..., None], offsets[owners, owner_slot], 0.0)

    neighbours = members[:, 1:]
    lengths = np.sum((rest[neighbours] - rest[:, None]) ** 2, axis=-1)
    # Coincident spheres would cut the smoothness graph: a floor keeps every edge in it.
    floor = 1e-12 * max(float(np.mean(lengths[mask[:, 1:]])), 1e-300)
    weights = np.where(mask[:, 1:], smoothness * np.maximum(lengths, floor), 0.0)
    size = np.sum(offsets**2, axis=(1, 2)) + weights.sum(1)
    proximal = PROXIMAL * size

    # Normal equations of the cell term in the centres: L = Σ_cells S_iᵀ (I − 11ᵀ/m_i) S_i.
    system = np.zeros((n, n))
    for i in range(n):
        idx = members[i, mask[i]]
        system[np.ix_(idx, idx)] += np.eye(len(idx)) - 1.0 / len(idx)
    laplacian = np.zeros((n, n))
    rows = np.repeat(np.arange(n), k - 1)
    np.add.at(laplacian, (rows, neighbours.ravel()), -weights.ravel())
    laplacian[np.arange(n), np.arange(n)] += weights.sum(1)

    free = np.flatnonzero(~is_handle)
    inverse, coupling = _inverse(system, free, handles)
    q_coupling = _inverse(laplacian, free, handles)[1]

    # NumPy leaves: the cells are cached across calls, also from inside traced functions,
    # and `solve` converts them (a JAX array made here under a trace would leak).
    def f(x):
        return np.asarray(x, dtype)

    def i(x):
        return np.asarray(x, np.int32)

    return ArapCells(
        rest=f(rest), members=i(members), mask=f(mask), offsets=f(offsets),
        handle_offsets=f(handle_offsets), owners=i(owners), owner_offsets=f(owner_offsets),
        neighbours=i(neighbours), weights=f(weights), proximal=f(proximal),
        colours=i(_colour_table(_colouring(adjacency))),
        handles=i(handles), free=i(free), inverse=f(inverse), coupling=f(coupling),
        q_coupling=f(q_coupling),
    )

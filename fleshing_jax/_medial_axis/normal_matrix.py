"""The fit's normal matrix `Jᵀ diag(w) J` (`refine`), compiled by numba.

Each Gauss-Newton step of `refine.refine_spheres` needs `Jᵀ diag(w) J` of its sparse
Jacobian (spot at 200 spheres: 45k rows, 800 columns, four a sphere). SciPy builds it from
two sparse products, each a pass over the rows with a linked list of each output row's
entries, and conversions between formats (7 ms a step on spot). A row of `J` touches the
spheres of one primitive (a sphere, a cone's two, a slab's three), of one sphere's
containment or of one edge's length, so `Jᵀ diag(w) J` is made of 4 × 4 blocks, one for
each sphere with itself and for each edge's two spheres both ways: here one pass over the
rows adds each row's products into its blocks.

The arithmetic is SciPy's (1.17: `csr_matmat`), in its order, so the values are the same
bit for bit (numba contracts no multiply-add without `fastmath`): `Jᵀ diag(w)` holds
`w_i J_ik`, and entry `(k, l)` of its product with `J` sums `J_il (w_i J_ik)` over the rows
`i` in ascending order, from zero. An entry whose sum is zero is not stored, as SciPy drops
it, so the sparsity pattern, on which SuperLU's ordering depends, is SciPy's too. The row
indices of each column ascend (SciPy leaves them in no particular order, which `spsolve`
sorts before factoring).
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sparse


def sphere_blocks(n: int, edges):
    """The blocks of `Jᵀ diag(w) J` for `n` spheres joined by `edges (e, 2)`: `(start (n +
    1,), rows (n + 2e,))`, the spheres `rows[start[b]:start[b + 1]]` (ascending: `b` itself
    and its neighbours) whose block with column sphere `b` may be non-zero."""
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    pairs = np.concatenate([np.repeat(np.arange(n), 2).reshape(-1, 2), edges, edges[:, ::-1]])
    key = np.unique(pairs[:, 1] * n + pairs[:, 0])  # by column sphere, then row sphere
    return np.searchsorted(key // n, np.arange(n + 1)), key % n


def weighted_gram(jac: sparse.csr_matrix, weight, blocks) -> sparse.csc_matrix:
    """`Jᵀ diag(weight) J` `(c, c)` of a CSR matrix `jac (r, c)` (`c = 4n`) without
    repeated entries (SciPy's canonical format), `weight (r,)`, as
    `(jac.T @ sparse.diags(weight) @ jac).tocsc()` gives it, bit for bit (see the module's
    notes). `blocks`: `sphere_blocks` of the spheres; a row that joins two spheres not in
    one of them falls back to SciPy's products. The row indices of each column ascend."""
    columns = jac.shape[1]
    out = _gram(np.ascontiguousarray(jac.indptr, np.int64),
                np.ascontiguousarray(jac.indices, np.int64),
                np.ascontiguousarray(jac.data, np.float64),
                np.ascontiguousarray(weight, np.float64), *blocks)
    if out is None:
        gram = (jac.T @ sparse.diags(weight) @ jac).tocsc()
        gram.sort_indices()
        return gram
    indptr, indices, data = out
    return sparse.csc_matrix((data, indices, indptr), shape=(columns, columns))


@numba.njit(cache=True, error_model="numpy")
def _block(start, rows, a, b):
    """The position of row sphere `a` in column sphere `b`'s blocks, or -1."""
    for q in range(start[b], start[b + 1]):
        if rows[q] == a:
            return q
    return -1


@numba.njit(cache=True, error_model="numpy")
def _group_end(indices, p, end):
    """The end of the run of a row's entries from `p` on that share one sphere (`>> 2`)."""
    sphere = indices[p] >> 2
    p += 1
    while p < end and indices[p] >> 2 == sphere:
        p += 1
    return p


@numba.njit(cache=True, error_model="numpy")
def _gram(indptr, indices, data, weight, start, rows):
    """`weighted_gram`'s CSC arrays `(indptr, indices, data)`, or None."""
    n = len(start) - 1
    values = np.zeros((len(rows), 4, 4))  # [block, row coordinate, column coordinate]
    for i in range(len(indptr) - 1):
        # The row's entries are grouped by sphere (its columns ascend): each pair of
        # groups adds into one block.
        end = indptr[i + 1]
        p0 = indptr[i]
        while p0 < end:
            a, p1 = indices[p0] >> 2, _group_end(indices, p0, end)
            q0 = indptr[i]
            while q0 < end:
                b, q1 = indices[q0] >> 2, _group_end(indices, q0, end)
                at = _block(start, rows, a, b)
                if at < 0:
                    return None
                block = values[at]
                for p in range(p0, p1):
                    scaled = weight[i] * data[p]
                    line = block[indices[p] & 3]
                    for q in range(q0, q1):
                        line[indices[q] & 3] += data[q] * scaled
                q0 = q1
            p0 = p1
    out_ptr = np.zeros(4 * n + 1, np.int64)
    out_idx = np.empty(16 * len(rows), np.int64)
    out_val = np.empty(16 * len(rows))
    count = 0
    for b in range(n):
        for cb in range(4):
            for at in range(start[b], start[b + 1]):
                for ca in range(4):
                    if values[at, ca, cb] != 0:
                        out_idx[count], out_val[count] = 4 * rows[at] + ca, values[at, ca, cb]
                        count += 1
            out_ptr[4 * b + cb + 1] = count
    return out_ptr, out_idx[:count], out_val[:count]

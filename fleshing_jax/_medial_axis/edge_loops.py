"""Loops over the edges of a medial mesh for its collapses (`simplify._edge_costs`), compiled
by numba.

Each round of collapses prices every edge next to a collapse (spot at 200 spheres: 288k
edges, then 88 rounds of up to 34k): the two spheres' quadrics summed, and the quadric's
value at four candidate spheres. In NumPy that was a gather of each sphere's 4 × 4 quadric,
then an `einsum` and a pass per option; here one loop per edge reads them in place.

The arithmetic is NumPy's (2.4), in its order on the same float64 numbers, so the values are
the same bit for bit (numba contracts no multiply-add without `fastmath`): a quadric
`m·A·m` as `einsum("ij,ijk,ik->i")` sums it, `(m_j A_jk) m_k` over `j` then `k` from the
first term; `b·m` as `einsum("ij,ij->i")` sums four terms, `(p0 + p2) + (p1 + p3)`; the
cheapest option as `np.argmin` picks it (the first of equals, a NaN first of all).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, error_model="numpy")
def edge_quadrics(spheres, A, b, c, i, j):
    """For edges `(i, j)` (each `(e,)`): `A[i] + A[j]` `(e, 4, 4)`, `b[i] + b[j]` `(e, 4)`,
    `c[i] + c[j]` `(e,)`, and the end spheres `spheres[i]`, `spheres[j]` `(e, 4)` each."""
    e = len(i)
    Ae, be, ce = np.empty((e, 4, 4)), np.empty((e, 4)), np.empty(e)
    si, sj = np.empty((e, 4)), np.empty((e, 4))
    for r in range(e):
        p, q = i[r], j[r]
        for u in range(4):
            for v in range(4):
                Ae[r, u, v] = A[p, u, v] + A[q, u, v]
            be[r, u] = b[p, u] + b[q, u]
            si[r, u], sj[r, u] = spheres[p, u], spheres[q, u]
        ce[r] = c[p] + c[q]
    return Ae, be, ce, si, sj


@numba.njit(cache=True, error_model="numpy")
def _error(A, b, c, m, r):
    """`simplify._error` of edge `r` at sphere `m[r]`, clamped as `_edge_costs` does: `inf`
    for a negative radius, else `np.maximum(error, 0)`."""
    if not m[r, 3] >= 0:
        return np.inf
    quadratic = 0.0
    for u in range(4):
        for v in range(4):
            quadratic += m[r, u] * A[r, u, v] * m[r, v]
    linear = (b[r, 0] * m[r, 0] + b[r, 2] * m[r, 2]) + (b[r, 1] * m[r, 1] + b[r, 3] * m[r, 3])
    error = quadratic + 2 * linear + c[r]
    return error if (error >= 0 or error != error) else 0.0


@numba.njit(cache=True, error_model="numpy")
def cheapest(A, b, c, best, si, sj, mid):
    """Each edge's cheapest of its four options `best, si, sj, mid` (`(e, 4)` each) under its
    quadric `(A, b, c)`: `(error (e,), chosen (e, 4))`."""
    e = len(c)
    error, chosen = np.empty(e), np.empty((e, 4))
    for r in range(e):
        pick, least = 0, _error(A, b, c, best, r)
        if least == least:  # (a NaN is np.argmin's pick: the first one)
            for k, option in enumerate((si, sj, mid)):
                value = _error(A, b, c, option, r)
                if value != value:
                    pick, least = k + 1, value
                    break
                if value < least:
                    pick, least = k + 1, value
        source = best if pick == 0 else si if pick == 1 else sj if pick == 2 else mid
        for u in range(4):
            chosen[r, u] = source[r, u]
        error[r] = least
    return error, chosen

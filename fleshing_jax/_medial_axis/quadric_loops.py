"""Loops over the spheres and edges of a medial mesh for its collapses (`simplify`), compiled
by numba: the contacts' quadrics, then each round's edge costs.

Each sphere's quadric sums its four contact planes' (`simplify.contact_quadrics`): in NumPy,
six `einsum`s over (spheres, contacts, coordinates) took 0.2–0.4 s on spot's 80k initial
spheres, here 0.01 s. Each round of collapses prices every edge next to a collapse (spot at
200 spheres: 288k edges, then 88 rounds of up to 34k): the two spheres' quadrics summed, and
the quadric's value at four candidate spheres; in NumPy a gather of each sphere's 4 × 4
quadric, then an `einsum` and a pass per option, here one loop per edge.

The arithmetic is NumPy's (2.4), in its order on the same float64 numbers, so the values are
the same bit for bit (numba contracts no multiply-add without `fastmath`): a contraction
`einsum` sums over its summed indices in their order (the last innermost) from the first
term, its factors multiplied left to right (`m·A·m` as `(m_j A_jk) m_k` over `j` then `k`);
a dot of two rows of four, `einsum("ij,ij->i")`, as `(p0 + p2) + (p1 + p3)`, of three as
`(p0 + p2) + p1` (`rows.dot`); every term written, zeros included (their signs count where a
sum is zero); the cheapest option as `np.argmin` picks it (the first of equals, a NaN first).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, error_model="numpy")
def _sliding(normal, a, k):
    """`M[a, k]` of `M = [I | n]` (3 × 4), for the contact normal `normal` (3,)."""
    if k < 3:
        return 1.0 if a == k else 0.0
    return normal[a]


@numba.njit(cache=True, error_model="numpy")
def contact_quadrics(normals, points, weights, contacts, slide: float):
    """`simplify.contact_quadrics`' sums for spheres with `contacts (n, 4)` (sample indices
    into `normals`, `points` `(s, 3)` and `weights (s,)`): `(A (n, 4, 4), b (n, 4), c (n,))`,
    each term as its `einsum` there sums it."""
    n = len(contacts)
    A, b, c = np.empty((n, 4, 4)), np.empty((n, 4)), np.empty(n)
    vec, delta, w = np.empty((4, 4)), np.empty(4), np.empty(4)
    for i in range(n):
        for j in range(4):  # the plane of contact j: d = vec·m + delta
            s = contacts[i, j]
            w[j] = weights[s]
            for a in range(3):
                vec[j, a] = -normals[s, a]
            vec[j, 3] = -1.0
            delta[j] = ((normals[s, 0] * points[s, 0] + normals[s, 2] * points[s, 2])
                        + normals[s, 1] * points[s, 1])
        for k in range(4):
            for m in range(4):
                plane = 0.0
                for j in range(4):
                    plane += w[j] * vec[j, k] * vec[j, m]
                near = 0.0
                for j in range(4):
                    normal = normals[contacts[i, j]]
                    for a in range(3):
                        near += w[j] * _sliding(normal, a, k) * _sliding(normal, a, m)
                A[i, k, m] = plane + slide * near
            plane = 0.0
            for j in range(4):
                plane += w[j] * delta[j] * vec[j, k]
            near = 0.0
            for j in range(4):
                s = contacts[i, j]
                for a in range(3):
                    near += w[j] * _sliding(normals[s], a, k) * points[s, a]
            b[i, k] = plane - slide * near
        near = 0.0
        for j in range(4):
            s = contacts[i, j]
            for a in range(3):
                near += w[j] * points[s, a] * points[s, a]
        c[i] = ((w[0] * delta[0] ** 2 + w[2] * delta[2] ** 2)
                + (w[1] * delta[1] ** 2 + w[3] * delta[3] ** 2)) + slide * near
    return A, b, c


@numba.njit(cache=True, error_model="numpy")
def edge_systems(spheres, A, b, i, j):
    """For edges `(i, j)` (each `(e,)`): the regularised system of `simplify._edge_costs`,
    its matrix `A[i] + A[j] + eps I` `(e, 4, 4)` and right-hand side `eps mid − (b[i] +
    b[j])` `(e, 4)` (`mid` the end spheres' midpoint, `eps = 1e-6 × trace / 4 + 1e-300`,
    the summed matrix's trace summed first to last); the centres' distance and the radii's
    difference `|r_i − r_j|` `(e,)` each. (The summed quadrics are not kept: `cheapest`
    sums them again, as it prices the options, cheaper than writing and reading them.)"""
    e = len(i)
    reg, rhs = np.empty((e, 4, 4)), np.empty((e, 4))
    length, dr = np.empty(e), np.empty(e)
    for r in range(e):
        p, q = i[r], j[r]
        eps = 1e-6 * ((((A[p, 0, 0] + A[q, 0, 0]) + (A[p, 1, 1] + A[q, 1, 1]))
                       + (A[p, 2, 2] + A[q, 2, 2])) + (A[p, 3, 3] + A[q, 3, 3])) / 4 + 1e-300
        for u in range(4):
            for v in range(4):
                reg[r, u, v] = (A[p, u, v] + A[q, u, v]) + eps * (1.0 if u == v else 0.0)
            rhs[r, u] = eps * ((spheres[p, u] + spheres[q, u]) / 2) - (b[p, u] + b[q, u])
        x = spheres[p, 0] - spheres[q, 0]
        y = spheres[p, 1] - spheres[q, 1]
        z = spheres[p, 2] - spheres[q, 2]
        length[r] = np.sqrt((x * x + y * y) + z * z)
        dr[r] = np.abs(spheres[p, 3] - spheres[q, 3])
    return reg, rhs, length, dr


@numba.njit(cache=True, error_model="numpy")
def cheapest(spheres, A, b, c, i, j, best):
    """Each edge's `(i, j)` cheapest of its four options, `best (e, 4)`, its end spheres
    `spheres[i]`, `spheres[j]` and their midpoint, under its summed quadric `(A[i] + A[j],
    b[i] + b[j], c[i] + c[j])`: `(error (e,), chosen (e, 4))`. An option's error is
    `simplify._error`, `inf` for a negative radius, else `np.maximum(error, 0)`; the four
    options' sums run side by side (four independent chains of additions, not one after
    another: each sum's terms still in their order)."""
    e = len(i)
    error, chosen = np.empty(e), np.empty((e, 4))
    Ae, be, option = np.empty((4, 4)), np.empty(4), np.empty((4, 4))
    value = np.empty(4)
    for r in range(e):
        p, q = i[r], j[r]
        for u in range(4):
            for v in range(4):
                Ae[u, v] = A[p, u, v] + A[q, u, v]
            be[u] = b[p, u] + b[q, u]
            option[0, u], option[1, u], option[2, u] = best[r, u], spheres[p, u], spheres[q, u]
            option[3, u] = (spheres[p, u] + spheres[q, u]) / 2
        ce = c[p] + c[q]
        value[:] = 0.0
        for u in range(4):
            for v in range(4):
                for k in range(4):
                    value[k] += option[k, u] * Ae[u, v] * option[k, v]
        for k in range(4):
            m = option[k]
            linear = (be[0] * m[0] + be[2] * m[2]) + (be[1] * m[1] + be[3] * m[3])
            total = value[k] + 2 * linear + ce
            total = total if (total >= 0 or total != total) else 0.0
            value[k] = total if m[3] >= 0 else np.inf
        pick = 0  # np.argmin's: a NaN first, else the first of the least
        if value[0] == value[0]:
            for k in range(1, 4):
                if value[k] != value[k]:
                    pick = k
                    break
                if value[k] < value[pick]:
                    pick = k
        for u in range(4):
            chosen[r, u] = option[pick, u]
        error[r] = value[pick]
    return error, chosen


@numba.njit(cache=True, error_model="numpy")
def renumbered_edges(edges, relabel, changed, alive, m: int):
    """A round's edges `(e, 2)` renumbered by `relabel (n,)` (each row sorted), whether each
    touches a `changed` or no longer `alive` sphere `(e,)`, and the positions `(l,)` and keys
    `(l,)` (`lo · m + hi`, `rows.row_keys`) of the rows on two spheres: `simplify`'s NumPy
    passes over the edges (gathers, `sorted_rows`, masks) in one loop, the same integers."""
    out = np.empty((len(edges), 2), np.int64)
    touched = np.empty(len(edges), np.bool_)
    live, key = np.empty(len(edges), np.int64), np.empty(len(edges), np.int64)
    count = 0
    for r in range(len(edges)):
        a, b = edges[r, 0], edges[r, 1]
        touched[r] = changed[a] or changed[b] or not alive[a] or not alive[b]
        lo, hi = min(relabel[a], relabel[b]), max(relabel[a], relabel[b])
        out[r, 0], out[r, 1] = lo, hi
        if lo != hi:
            live[count], key[count] = r, lo * m + hi
            count += 1
    return out, touched, live[:count], key[:count]

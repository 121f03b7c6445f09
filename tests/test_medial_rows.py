"""`_medial_axis.rows`: the column-wise forms equal NumPy's general routines bit for bit (the
medial meshes depend on it: a different rounding breaks ties between primitives)."""

import numpy as np
import pytest

from fleshing_jax._medial_axis.rows import (
    column_dot,
    cross,
    dot,
    gather_columns,
    norm,
    row_keys,
    sorted_order,
    sorted_rows,
)


@pytest.mark.parametrize("wider", [False, True])
def test_dot_cross_and_norm_are_numpy_s_bit_for_bit(wider):
    rng = np.random.default_rng(0)
    a, b = (rng.normal(size=(1000, 6)) * 10.0 ** rng.integers(-8, 8, (1000, 1)) for _ in "ab")
    # Columns of a wider table (as the primitives' rows), or contiguous rows.
    a, b = (x[:, 2:5] if wider else np.ascontiguousarray(x[:, :3]) for x in (a, b))
    assert np.array_equal(dot(a, b), np.einsum("ij,ij->i", a, b))
    assert np.array_equal(cross(a, b), np.cross(a, b))
    for x in (a, a.astype(np.float32)):  # (float32 stays float32)
        assert np.array_equal(norm(x), np.linalg.norm(x, axis=1))
        assert norm(x).dtype == x.dtype
    # By coordinates: the same sums.
    assert np.array_equal(column_dot(np.ascontiguousarray(a.T), b.T), dot(a, b))


@pytest.mark.parametrize("runs", [1, 3, 1000])
def test_gather_columns_is_take(runs):
    """Gathered by repeats (long runs of one index) or by `np.take`: the same columns."""
    rng = np.random.default_rng(runs)
    table = rng.normal(size=(5, 40))
    i = np.repeat(rng.integers(0, 40, 3000 // runs), runs)
    np.testing.assert_array_equal(gather_columns(table, i), table[:, i])
    assert gather_columns(table, i[:0]).shape == (5, 0)


@pytest.mark.parametrize("k", [2, 3, 4])
def test_sorted_rows_and_keys(k):
    rng = np.random.default_rng(k)
    n = 50
    rows = rng.integers(0, n, (500, k))
    np.testing.assert_array_equal(sorted_rows(rows), np.sort(rows, axis=1))
    keys = row_keys(rows.astype(np.int32), n)  # int32 indices: keys in int64, no overflow
    assert keys.dtype == np.int64
    np.testing.assert_array_equal(keys, rows @ (n ** np.arange(k - 1, -1, -1)))
    order = np.lexsort(rows.T[::-1])
    assert np.all(np.diff(keys[order]) >= 0)  # the rows' lexicographic order


@pytest.mark.parametrize("bound", [7, 5000, 2**60])
def test_sorted_order_is_a_stable_argsort(bound):
    # Many ties (bound 7), few (5000), and keys too large for the combined sort (its
    # fallback): the same permutation as NumPy's stable sort, and the keys in its order.
    rng = np.random.default_rng(bound % 1000)
    keys = rng.integers(0, bound, 3000)
    order = np.argsort(keys, kind="stable")
    got_keys, got = sorted_order(keys, bound)
    np.testing.assert_array_equal(got, order)
    np.testing.assert_array_equal(got_keys, keys[order])
    assert [len(x) for x in sorted_order(keys[:0], bound)] == [0, 0]


def test_quadric_loops_are_numpy_s_bit_for_bit():
    # The collapses' per-edge loops (`quadric_loops`) against the NumPy forms they replace:
    # the regularised systems, and the cheapest of four options (a negative radius never
    # chosen, a NaN error picked first as by `np.argmin`, ties to the first).
    from fleshing_jax._medial_axis.quadric_loops import cheapest, edge_systems
    from fleshing_jax._medial_axis.simplify import _error

    rng = np.random.default_rng(3)
    n, e = 50, 400
    spheres, b = rng.normal(size=(n, 4)), rng.normal(size=(n, 4))
    A, c = rng.normal(size=(n, 4, 4)) * 10.0 ** rng.integers(-6, 6, (n, 1, 1)), rng.normal(size=n)
    A[:, 0, 1] = -0.0  # (zeros' signs: the regularised matrix's `+ 0` makes them +0)
    spheres[40:45, 0] = np.nan  # NaN errors
    i, j = rng.integers(0, n, (e, 2)).T  # (columns of the edges, as `simplify` passes)
    j[:20] = i[:20]  # ties: both ends one sphere
    i, j = np.ascontiguousarray(i), np.ascontiguousarray(j)
    reg, rhs, length, dr = edge_systems(spheres, A, b, i, j)
    Ae, be, ce, si, sj = A[i] + A[j], b[i] + b[j], c[i] + c[j], spheres[i], spheres[j]
    eps = 1e-6 * np.trace(Ae, axis1=1, axis2=2) / 4 + 1e-300
    mid = (si + sj) / 2
    for x, y in ((reg, Ae + eps[:, None, None] * np.eye(4)), (rhs, eps[:, None] * mid - be),
                 (length, np.linalg.norm(si[:, :3] - sj[:, :3], axis=1)),
                 (dr, np.abs(si[:, 3] - sj[:, 3]))):
        np.testing.assert_array_equal(x.view(np.int64), y.view(np.int64))  # bit for bit
    best = rng.normal(size=(e, 4))
    best[20:30, 0] = np.nan  # a NaN error first
    options = [best, si, sj, mid]
    errors = np.stack([np.where(x[:, 3] >= 0, np.maximum(_error(Ae, be, ce, x), 0), np.inf)
                       for x in options], 1)
    assert np.isnan(errors[:, 1:]).any() and np.isinf(errors).any()
    pick = np.argmin(errors, axis=1)
    error, chosen = cheapest(spheres, A, b, c, i, j, best)
    np.testing.assert_array_equal(error.view(np.int64), errors[np.arange(e), pick].view(np.int64))
    np.testing.assert_array_equal(chosen, np.stack(options, 1)[np.arange(e), pick])


def test_contact_quadrics_are_the_einsums_bit_for_bit():
    # The contacts' quadrics (a numba loop) against the NumPy sums they replaced.
    from types import SimpleNamespace

    from fleshing_jax._medial_axis.simplify import contact_quadrics

    rng = np.random.default_rng(4)
    s, n = 300, 200
    normals = rng.normal(size=(s, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    axis = SimpleNamespace(normals=normals, points=rng.normal(size=(s, 3)),
                           weights=rng.uniform(0, 1e-3, s), contacts=rng.integers(0, s, (n, 4)))
    nn, p, w = (x[axis.contacts] for x in (axis.normals, axis.points, axis.weights))
    vec = np.concatenate([-nn, -np.ones((n, 4, 1))], axis=2)
    delta = np.einsum("ijk,ijk->ij", nn, p)
    M = np.concatenate([np.broadcast_to(np.eye(3), (n, 4, 3, 3)), nn[..., None]], -1)
    slide = 0.7
    A = np.einsum("ij,ijk,ijl->ikl", w, vec, vec) + slide * np.einsum("ij,ijak,ijal->ikl", w, M, M)
    b = np.einsum("ij,ij,ijk->ik", w, delta, vec) - slide * np.einsum("ij,ijak,ija->ik", w, M, p)
    c = np.einsum("ij,ij->i", w, delta**2) + slide * np.einsum("ij,ija,ija->i", w, p, p)
    for x, y in zip(contact_quadrics(axis, slide), (A, b, c)):
        np.testing.assert_array_equal(x, y)


def test_jacobian_rows_are_scipy_s_bit_for_bit():
    # The fit's Jacobian (`pairs.jacobian_rows`) against the CSR matrix SciPy makes of its
    # twelve entries a row, its repeated spheres summed (`sum_duplicates`): lone spheres
    # (one sphere thrice, weights 1, 0, 0), cones (the second sphere twice, weight 0 last),
    # slabs (three spheres in any order); a zero coordinate of `u` (zeros' signs).
    import scipy.sparse as sparse

    from fleshing_jax._medial_axis.pairs import jacobian_rows

    rng = np.random.default_rng(5)
    n, m = 40, 300
    spheres = rng.integers(0, n, (m, 3))
    weights = rng.dirichlet(np.ones(3), m)
    spheres[:100, 1:] = spheres[:100, :1]  # lone spheres
    weights[:100] = [1.0, 0.0, 0.0]
    spheres[100:200, 2] = spheres[100:200, 1]  # cones
    weights[100:200, 2] = 0.0
    weights[100:200, :2] = rng.dirichlet(np.ones(2), 100)
    u = rng.normal(size=(m, 3))
    u[::7, 1] = 0.0
    data, indices, indptr = jacobian_rows(spheres, weights, u)
    du = np.concatenate([u, np.ones((m, 1))], axis=1)
    expected = sparse.csr_matrix((-(weights[:, :, None] * du[:, None, :]).reshape(-1),
                                  (4 * spheres[:, :, None] + np.arange(4)).reshape(-1),
                                  np.arange(0, 12 * m + 1, 12)), shape=(m, 4 * n))
    expected.sum_duplicates()
    for got, want in ((data, expected.data), (indices, expected.indices),
                      (indptr, expected.indptr)):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got.view(np.uint8), want.view(np.uint8))


def test_weighted_gram_is_scipy_s_bit_for_bit():
    # The fit's normal matrix (`normal_matrix.weighted_gram`) against SciPy's products:
    # rows on one sphere, an edge's two or a face's three (of one to four columns each),
    # explicit zeros of both signs among the entries and a product that underflows to
    # zero; a row on two spheres in no edge falls back to SciPy's products.
    import scipy.sparse as sparse

    from fleshing_jax._medial_axis.normal_matrix import sphere_blocks, weighted_gram

    rng = np.random.default_rng(7)
    n, m = 30, 600
    edges = np.array([(i, i + 1) for i in range(n - 1)] + [(i, i + 2) for i in range(n - 2)])
    rows, cols = [], []
    for r in range(m):
        a = int(rng.integers(0, n - 2))
        for s in [[a], [a, a + 1], [a, a + 1, a + 2]][r % 3]:
            cols += list(4 * s + rng.choice(4, int(rng.integers(1, 5)), replace=False))
            rows += [r] * (len(cols) - len(rows))
    vals = rng.normal(size=len(rows))
    vals[::11], vals[::13], vals[5] = 0.0, -0.0, 1e-300
    weight = 1 + rng.random(m) ** 2
    for far in (False, True):
        # (Row 0 on one sphere; far: also on one three spheres away, in no edge.)
        extra = [4 * ((cols[0] // 4 + 3) % n)] if far else []
        jac = sparse.csr_matrix((np.r_[vals, [2.0] * len(extra)],
                                 (rows + [0] * len(extra), cols + extra)), shape=(m, 4 * n))
        want = (jac.T @ sparse.diags(weight) @ jac).tocsc()
        got = weighted_gram(jac, weight, sphere_blocks(n, edges))
        want.sort_indices()
        for x, y in ((got.indptr, want.indptr), (got.indices, want.indices),
                     (got.data, want.data)):
            assert x.dtype == y.dtype
            np.testing.assert_array_equal(x.view(np.uint8), y.view(np.uint8))


def test_around_order_is_lexsort():
    # The Voronoi faces' vertices by angle (`voronoi.around_order`): groups of one to 40,
    # equal angles, zeros of both signs and NaN, as `np.lexsort((angle, group))`.
    from fleshing_jax._medial_axis.voronoi import around_order

    rng = np.random.default_rng(3)
    group = np.repeat(np.arange(300), rng.integers(1, 41, 300))
    angle = np.round(rng.uniform(-np.pi, np.pi, len(group)), 1)
    angle[::17], angle[::19], angle[::23] = 0.0, -0.0, np.nan
    np.testing.assert_array_equal(around_order(group, angle), np.lexsort((angle, group)))


def test_renumbered_edges_are_numpy_s():
    # A round of collapses renumbering its edges (`quadric_loops.renumbered_edges`) against
    # the NumPy passes it replaces: spheres dropped into others (rows on one sphere left out
    # of the keys), changed ones, rows in any order.
    from fleshing_jax._medial_axis.quadric_loops import renumbered_edges

    rng = np.random.default_rng(9)
    n = 60
    edges = rng.integers(0, n, (400, 2))
    alive = rng.random(n) > 0.3
    target = np.where(alive, np.arange(n), rng.choice(np.flatnonzero(alive), n))
    changed = np.zeros(n, bool)
    changed[target[~alive]] = True
    relabel = (np.cumsum(alive) - 1)[target]
    m = int(alive.sum())
    out, touched, live, key = renumbered_edges(edges, relabel, changed, alive, m)
    np.testing.assert_array_equal(out, sorted_rows(relabel[edges]))
    np.testing.assert_array_equal(touched, changed[edges].any(axis=1) | ~alive[edges].all(axis=1))
    np.testing.assert_array_equal(live, np.flatnonzero(out[:, 0] != out[:, 1]))
    np.testing.assert_array_equal(key, row_keys(out, m)[live])

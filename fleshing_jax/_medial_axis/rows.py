"""Row-wise arithmetic on short rows, written out by columns.

NumPy's general routines (`einsum`, `np.cross`, `np.sort(axis=1)`, an integer `@`) pay a
per-row overhead that dominates on rows of two to four numbers; the medial pipeline calls
them on millions of rows. These give the same values, bit for bit, several times faster.
"""

import numpy as np


def dot(a, b):
    """Row-wise dot products `(M,)` of `(M, 3)` arrays, summed as NumPy's (2.4)
    `einsum("ij,ij->i")` does on rows of contiguous numbers, first and last terms first (the
    same values bit for bit, also for columns `x[:, j:j + 3]` of a wider array), at half its
    time. (On columns with a step, `x[:, ::2]`, einsum sums in another order.)"""
    return column_dot(a.T, b.T)


def column_dot(a, b):
    """`dot` of vectors given by their coordinates, `a (3, M)` and `b (3, M)` (`a[k]`:
    coordinate `k` of every vector): the same sums. Contiguous coordinates make its
    arithmetic about twice as fast as on the strided columns of `(M, 3)` arrays."""
    return (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]


def norm(a):
    """Row-wise Euclidean norms `(M,)` of an `(M, 3)` array: `np.linalg.norm(a, axis=1)`,
    whose squares NumPy (2.4) sums in order, first to last (the same values bit for bit),
    by columns: 4× faster (3.8 against 16.8 ms for 300k rows)."""
    x, y, z = a[:, 0], a[:, 1], a[:, 2]
    return np.sqrt((x * x + y * y) + z * z)


def gather_columns(table, i):
    """`table[:, i]` `(k, M)` for `table (k, P)` and indices `i (M,)`: each column's values
    gathered into contiguous rows (for `column_dot` and the like).

    Where `i` runs in long stretches of one value (the pairs of a search come sorted by
    primitive, thousands a cone on spot), each value is gathered once and repeated: 3× faster
    than `np.take`. The same values either way."""
    # (`np.concatenate`, not `np.r_`: its parsing cost 45 µs a call, a third of the time.)
    start = np.concatenate([[0], np.flatnonzero(i[1:] != i[:-1]) + 1])
    if 4 * len(start) > len(i):
        return np.take(table, i, axis=1)
    return np.repeat(np.take(table, i.take(start), axis=1),
                     np.diff(np.concatenate([start, [len(i)]])), axis=1)


def cross(a, b):
    """`np.cross` of `(M, 3)` arrays, by columns: the same products and differences (bit for
    bit), 3× faster."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    np.subtract(a[:, 1] * b[:, 2], a[:, 2] * b[:, 1], out=out[:, 0])
    np.subtract(a[:, 2] * b[:, 0], a[:, 0] * b[:, 2], out=out[:, 1])
    np.subtract(a[:, 0] * b[:, 1], a[:, 1] * b[:, 0], out=out[:, 2])
    return out


def sorted_rows(rows):
    """Integer `rows (m, k)` sorted within each row: `np.sort(rows, axis=1)`, by columns for
    `k` of 2 or 3 (several times faster on such short rows; the same values)."""
    if rows.shape[1] not in (2, 3):
        return np.sort(rows, axis=1)
    # (Each column written in place: `np.stack` of the columns took 3× as long.)
    out = np.empty(rows.shape, rows.dtype)
    a, b = rows[:, 0], rows[:, 1]
    low, high = out[:, 0], out[:, -1]
    np.minimum(a, b, out=low)
    np.maximum(a, b, out=high)
    if rows.shape[1] == 3:
        c = rows[:, 2]
        np.minimum(low, c, out=low)
        np.maximum(high, c, out=high)
        np.subtract(a + b + c - low, high, out=out[:, 1])
    return out


def row_keys(rows, n: int):
    """One integer `(m,)` per row of indices below `n` (`rows (m, k)`), in the rows'
    lexicographic order: `Σ rows[:, j] n^(k−1−j)`, by columns (an integer `@` is slow). The
    caller makes sure that `n^k` stays below `2^63`."""
    key = rows[:, 0].astype(np.int64)
    for k in range(1, rows.shape[1]):
        key = key * n + rows[:, k]
    return key


def sorted_order(keys, bound: int):
    """`(keys[order], order)` with `order = np.argsort(keys, kind="stable")`, for integer
    `keys (m,)` in `[0, bound)`: the same permutation, by one sort of `keys · m + position`
    (NumPy's vectorised quicksort, whose ties cannot occur: every value distinct). NumPy's
    stable sort of 64-bit integers is a merge sort, several times slower on keys in no
    order (spot's 780k Delaunay edges: 60 → 10 ms); where `bound · m` would overflow, it
    is used still."""
    m = len(keys)
    if float(bound) * max(m, 1) >= 2.0**62:
        order = np.argsort(keys, kind="stable")
        return keys.take(order), order
    combined = keys.astype(np.int64) * m + np.arange(m)
    combined.sort()
    return np.divmod(combined, m) if m else (combined, combined)

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

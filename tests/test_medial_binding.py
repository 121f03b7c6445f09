"""The binding's shortcuts (`footprint.bind`): the per-block search for the pairs within reach,
the distances in blocks and the pre-cut before the k-nearest sort give the same binding as
one block and no cut, the nearest primitive is the nearest of all; and the implicit field's
packed tables (`implicit.pack_rows`) unpack to the tables themselves.

A sheet of 4 × 3 spheres of equal radii (18 slabs, exact ties between primitives that share
a sphere) with a chain of cones hanging off it and a lone sphere; 1500 points around it.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fleshing_jax._medial_axis import primitives
from fleshing_jax._medial_axis.primitives import _Cones, _Slabs
from fleshing_jax._medial_deform import footprint
from fleshing_jax._medial_deform.footprint import _nearest_k, bind, slab_distance
from fleshing_jax._medial_deform.implicit import cone_table, pack_rows, slab_table, unpack_rows


def sheet_and_chain():
    """Centres, radii, edges, faces (NumPy) of the test's medial mesh."""
    x, y = np.meshgrid(np.arange(4.0), np.arange(3.0), indexing="ij")
    grid = np.stack([x.ravel(), y.ravel(), 0.1 * np.sin(x.ravel() + y.ravel())], 1)
    faces = []
    for i in range(3):
        for j in range(2):
            a, b, c, d = 3 * i + j, 3 * (i + 1) + j, 3 * i + j + 1, 3 * (i + 1) + j + 1
            faces += [[a, b, c], [b, d, c]]
    faces = np.array(faces)
    chain = np.array([[4.0, 1, 0], [5, 1, 0.3], [6, 1.2, 0.2], [8, 1, 0]])
    centers = np.concatenate([grid, chain])
    radii = np.r_[np.full(12, 0.4), 0.35, 0.3, 0.3, 0.5]
    edges = np.sort(faces[:, [[0, 1], [1, 2], [0, 2]]].reshape(-1, 2), axis=1)
    edges = np.unique(np.concatenate([edges, [[10, 12], [12, 13], [13, 14]]]), axis=0)
    return centers, radii, edges, faces  # sphere 15 is lone


@pytest.fixture(scope="module")
def medial_and_points():
    centers, radii, edges, faces = sheet_and_chain()
    rng = np.random.default_rng(0)
    points = rng.uniform([-0.6, -0.6, -0.7], [8.6, 2.6, 0.8], size=(1500, 3))
    points[:50] = centers[rng.integers(0, len(centers), 50)]  # ties: on the shared spheres
    return (centers, radii, edges, faces), points


def test_blocks_give_the_same_binding(medial_and_points, monkeypatch):
    medial, points = medial_and_points
    whole = bind(points, *medial, field_cones=4, field_slabs=2)
    monkeypatch.setattr(footprint, "CHUNK", 64)  # 24 blocks of points, the last one short
    monkeypatch.setattr(primitives, "PAIRS", 100)  # many blocks of pairs
    blocked = bind(points, *medial, field_cones=4, field_slabs=2)
    for name, a, b in zip(whole._fields, whole, blocked, strict=True):
        np.testing.assert_array_equal(a, b, err_msg=name)


def test_nearest_primitive_is_the_nearest_of_all(medial_and_points):
    (centers, radii, edges, faces), points = medial_and_points
    b = bind(points, centers, radii, edges, faces, field_cones=4, field_slabs=2)
    lone = np.setdiff1d(np.arange(len(centers)), edges.reshape(-1))
    cones = np.concatenate([edges, np.stack([lone, lone], 1)])
    seg = _Cones(centers[cones[:, 0]], radii[cones[:, 0]], centers[cones[:, 1]],
                 radii[cones[:, 1]])
    slabs = _Slabs(*(x for k in range(3) for x in (centers[faces[:, k]], radii[faces[:, k]])))
    edge_cones = footprint._SlabEdges(centers, radii, faces)
    m = len(points)
    every = [seg.distance(np.repeat(points, len(cones), 0), np.tile(np.arange(len(cones)), m))
             .reshape(m, -1),
             slab_distance(np.repeat(points, len(faces), 0), slabs, edge_cones,
                           np.tile(np.arange(len(faces)), m)).reshape(m, -1)]
    np.testing.assert_allclose(b.distance, np.concatenate(every, 1).min(1), rtol=0, atol=1e-12)
    # Its field candidates: distinct (every point has at least 4 cones and 2 slabs within
    # reach), in order of distance, the nearest cone first.
    for candidates, d in ((b.field_cones, every[0]), (b.field_slabs, every[1])):
        assert (np.sort(candidates, 1)[:, 1:] != np.sort(candidates, 1)[:, :-1]).all()
        assert (np.diff(np.take_along_axis(d, candidates, 1), axis=1) >= 0).all()
    np.testing.assert_allclose(every[0][np.arange(m), b.field_cones[:, 0]], every[0].min(1),
                               rtol=0, atol=1e-12)


def test_cut_before_the_sort_keeps_the_k_nearest():
    rng = np.random.default_rng(3)
    pts = np.repeat(np.arange(200), 30)
    prim = np.tile(np.arange(30), 200)
    dist = rng.integers(0, 8, len(pts)).astype(float)  # many ties
    order = rng.permutation(len(pts))  # pairs in any order
    pts, prim, dist = pts[order], prim[order], dist[order]
    for k in (1, 4):
        # A bound met by k pairs of each point: the k-th smallest of 6 of them.
        known = np.sort(dist.reshape(-1)[np.argsort(pts, kind="stable")].reshape(200, 30)[:, :6],
                        axis=1)[:, k - 1]
        cut = _nearest_k(pts, prim, dist, 200, k, 0, known)
        full = _nearest_k(pts, prim, dist, 200, k, 0, np.full(200, np.inf))
        np.testing.assert_array_equal(cut[0], full[0])
        np.testing.assert_array_equal(cut[1], full[1])


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_packed_tables_unpack_to_the_tables(medial_and_points, dtype):
    (centers, radii, edges, faces), _ = medial_and_points
    c, r = jnp.asarray(centers, dtype), jnp.asarray(radii, dtype)
    faces = np.r_[faces, [[0, 1, 2]]]  # a degenerate slab: its `ok` is False
    c = c.at[2].set(2 * c[1] - c[0])  # (spheres 0, 1, 2 collinear)

    @jax.jit  # (eagerly, each operation would compile on its own)
    def round_trips(c, r):
        """Per table: its packed rows, the rows at `index` unpacked, the table at `index`."""
        out = []
        for table in (cone_table(c, r, jnp.asarray(edges)), slab_table(c, r, jnp.asarray(faces))):
            rows, layout = pack_rows(table)
            index = jnp.array([3, 0, 3, len(rows) - 1])
            out.append((rows, unpack_rows(rows[index], layout),
                        jax.tree.map(lambda a: a[index], table)))
        return out

    trips = round_trips(c, r)
    for rows, back, table in trips:
        assert rows.dtype == dtype
        for name in table.__dataclass_fields__:
            want, got = getattr(table, name), getattr(back, name)
            assert got.dtype == want.dtype and got.shape == want.shape, name
            np.testing.assert_array_equal(got, want, err_msg=name)
    assert not bool(trips[1][2].ok[-1])  # (the slab table at its last row)

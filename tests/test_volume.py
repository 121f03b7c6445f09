import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import fleshing_jax as fj


def _closed_meshes():
    v, f = fj.box_grid([[0.0, -0.05, -0.25], [3.0, 0.45, 0.25]], 3)
    yield "box", v, f
    c = fj.creature(segments=16, around=8)
    yield "creature", np.asarray(c.vertices), np.asarray(c.faces)
    e = trimesh.creation.icosphere(2)
    yield "sphere", e.vertices + [3.0, -1.0, 2.0], e.faces


@pytest.mark.parametrize("name,vertices,faces", list(_closed_meshes()))
def test_volume_agrees_with_trimesh(name, vertices, faces):
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.is_watertight
    assert float(fj.volume(vertices, faces)) == pytest.approx(mesh.volume, rel=1e-12)
    assert float(fj.face_volumes(vertices, faces).sum()) == pytest.approx(mesh.volume, rel=1e-12)


def test_volume_sign_and_translation():
    v, f = fj.box_grid([[0, 0, 0], [1, 2, 3]], 1)
    assert float(fj.volume(v, f)) == pytest.approx(6.0)
    assert float(fj.volume(v, f[:, ::-1])) == pytest.approx(-6.0)
    assert float(fj.volume(v + 100.0, f)) == pytest.approx(6.0, rel=1e-12)


def test_quads_are_bilinear_and_diagonal_independent():
    v, q = fj.box_grid([[0, 0, 0], [1, 2, 3]], 2, quads=True)
    assert float(fj.volume(v, q)) == pytest.approx(6.0)
    # Twist the mesh so that its quads are no longer planar.
    rng = np.random.default_rng(0)
    w = v + 0.1 * rng.standard_normal(v.shape)
    rolled = np.roll(q, 1, axis=1)  # the other diagonal
    assert float(fj.volume(w, q)) == pytest.approx(float(fj.volume(w, rolled)), rel=1e-13)
    split_a = float(fj.volume(w, fj.triangulate(q)))
    split_b = float(fj.volume(w, fj.triangulate(rolled)))
    assert split_a != pytest.approx(split_b, rel=1e-8)  # the two splits differ …
    assert float(fj.volume(w, q)) == pytest.approx(0.5 * (split_a + split_b), rel=1e-13)  # … avg


def test_bilinear_quad_volume_matches_quadrature():
    # A hexahedron with one non-planar (bilinear) face: integrate x·n over the patch.
    corners = np.array(
        [
            [0, 0, 0],
            [1, 0, 0],
            [1, 1, 0],
            [0, 1, 0],
            [0, 0, 1],
            [1, 0, 1.3],
            [1, 1, 0.8],
            [0, 1, 1.1],
        ],
        float,
    )
    quads = np.array(
        [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
    )
    total = 0.0
    x, w = np.polynomial.legendre.leggauss(6)
    x, w = 0.5 * (x + 1), 0.5 * w
    for a, b, c, d in quads:
        pa, pb, pc, pd = corners[[a, b, c, d]]
        for u, wu in zip(x, w):
            for t, wt in zip(x, w):
                p = (1 - u) * (1 - t) * pa + u * (1 - t) * pb + u * t * pc + (1 - u) * t * pd
                du = (1 - t) * (pb - pa) + t * (pc - pd)
                dt = (1 - u) * (pd - pa) + u * (pc - pb)
                total += wu * wt * np.dot(p, np.cross(du, dt)) / 3
    assert float(fj.volume(corners, quads)) == pytest.approx(total, rel=1e-13)


def test_volume_gradient_matches_finite_differences():
    c = fj.creature(segments=8, around=6)
    v, f = np.asarray(c.vertices), np.asarray(c.faces)
    grad = np.asarray(jax.grad(fj.volume)(jnp.asarray(v), f))
    direction = np.random.default_rng(1).standard_normal(v.shape)
    h = 1e-6
    fd = (float(fj.volume(v + h * direction, f)) - float(fj.volume(v - h * direction, f))) / (2 * h)
    assert np.sum(grad * direction) == pytest.approx(fd, rel=1e-7)
    # Closed mesh: the gradient is the area-weighted vertex normal / 3, summing to zero.
    np.testing.assert_allclose(grad.sum(0), 0.0, atol=1e-12)


def test_volume_batches_jit_and_float32():
    cubes, faces = fj.cube_cloud([[0, 0, 0], [1, 1, 1]], 0.2)
    vols = jax.jit(fj.volume)(cubes, faces)
    assert vols.shape == (len(cubes),)
    np.testing.assert_allclose(np.asarray(vols), 0.2**3, rtol=1e-12)
    v32 = fj.volume(jnp.asarray(cubes, jnp.float32), faces)
    assert v32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(v32), 0.2**3, rtol=1e-5)
    change = fj.volume_change(cubes, 2 * cubes, faces)
    np.testing.assert_allclose(np.asarray(change), 7.0, rtol=1e-12)


def test_volume_rejects_bad_inputs():
    with pytest.raises(ValueError, match="vertices"):
        fj.volume(np.zeros((4, 2)), np.zeros((1, 3), int))
    with pytest.raises(ValueError, match="faces"):
        fj.volume(np.zeros((4, 3)), np.zeros((1, 5), int))
    with pytest.raises(TypeError, match="faces"):
        fj.volume(np.zeros((4, 3)), np.zeros((1, 3)))

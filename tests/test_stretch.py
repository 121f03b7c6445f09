"""`fj.edge_stretch`: how much a deformation changes each vertex's edges."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fleshing_jax as fj

# Two triangles sharing the edge 1–2, a vertex 4 in no face, and a degenerate face whose
# edge 0–5 has no length at rest (vertex 5 is a copy of vertex 0).
VERTICES = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [5, 5, 5], [0, 0, 0]], float)
FACES = np.array([[0, 1, 2], [1, 3, 2], [0, 5, 1]])


def _rotation(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_rigid_motions_keep_every_factor_at_one():
    moved = VERTICES @ _rotation(0.7).T + np.array([3.0, -2.0, 1.0])
    np.testing.assert_allclose(fj.edge_stretch((VERTICES, FACES), moved), 1.0, rtol=1e-12)


def test_a_stretched_and_a_squeezed_edge_give_their_factors_at_their_ends():
    moved = VERTICES.copy()
    moved[3] = [1.0, 4.0, 0.0]  # edges 1–3 (length 1 → 4) and 2–3 (1 → √10)
    moved[4] = [9.0, 9.0, 9.0]  # in no edge
    stretch = np.asarray(fj.edge_stretch((VERTICES, FACES), moved))
    np.testing.assert_allclose(stretch, [1, 4, np.sqrt(10), 4, 1, 1], rtol=1e-12)
    squeezed = VERTICES.copy()
    squeezed[2] = [0.0, 0.25, 0.0]  # edge 0–2: 1 → 1/4; edge 1–2: √2 → √(17)/4
    stretch = np.asarray(fj.edge_stretch((VERTICES, FACES), squeezed))
    assert stretch[0] == pytest.approx(4.0) and stretch[2] == pytest.approx(4.0)
    assert stretch[1] == pytest.approx(np.sqrt(2) / (np.sqrt(17) / 4))
    collapsed = VERTICES.copy()
    collapsed[3] = collapsed[1]
    assert np.isinf(np.asarray(fj.edge_stretch((VERTICES, FACES), collapsed))[3])


def test_float32_keeps_its_dtype_and_gradients_are_finite():
    moved = jnp.asarray(VERTICES, jnp.float32)
    assert fj.edge_stretch((VERTICES, FACES), moved).dtype == jnp.float32
    # At rest every factor is at its minimum 1 (a kink of max(l′/l, l/l′)): still finite.
    grad = jax.grad(lambda v: jnp.sum(fj.edge_stretch((VERTICES, FACES), v)))(VERTICES)
    assert np.all(np.isfinite(grad))
    stretched = VERTICES * np.array([2.0, 1.0, 1.0])
    grad = jax.grad(lambda v: fj.edge_stretch((VERTICES, FACES), v)[1])(stretched)
    # Vertex 1's worst edge is 0–1 (1 → 2): d(l′/l)/dx₁ = 1.
    np.testing.assert_allclose(grad[1], [1.0, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize(
    "deformed, error, words",
    [
        (VERTICES[:5], ValueError, "(6, 3)"),
        (np.ones((6, 3), int), TypeError, "floating"),
        (np.where(np.eye(6, 3, dtype=bool), np.nan, VERTICES), ValueError, "NaN"),
    ],
)
def test_bad_input_names_the_argument(deformed, error, words):
    with pytest.raises(error, match="deformed") as info:
        fj.edge_stretch((VERTICES, FACES), deformed)
    assert words in str(info.value)
    with pytest.raises(TypeError, match="mesh"):
        fj.edge_stretch(VERTICES, VERTICES)


def test_edge_stretch_counts_only_edges_between_valid_vertices():
    # A square of two triangles; vertex 3 flagged and torn away: with `valid`, its edges do
    # not count (the flags report it), the others' factors are as without it.
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    moved = vertices.copy()
    moved[1] = [2.0, 0, 0]  # edge 0-1 doubles
    moved[3] = [10.0, 10, 0]
    valid = np.array([True, True, True, False])
    every = np.asarray(fj.edge_stretch((vertices, faces), moved))
    counted = np.asarray(fj.edge_stretch((vertices, faces), moved, valid=valid))
    assert every[3] > 5 and counted[3] == 1
    assert counted[0] == counted[1] == 2.0
    assert counted[2] == pytest.approx(np.linalg.norm([2, -1]) / np.sqrt(2))
    with pytest.raises(ValueError, match="`valid`"):
        fj.edge_stretch((vertices, faces), moved, valid=valid[:3])

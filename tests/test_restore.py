"""The volume a pose past its exact range gives back (`_skeleton.restore`): on spot's mesh
shrunk where a limb would be, without posing anything (milliseconds)."""

import jax
import jax.numpy as jnp
import numpy as np

import fleshing_jax as fj
from fleshing_jax._skeleton.restore import corner_table, restored_volume, volume_gradient


def _spot():
    mesh = fj.data.spot()
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32)


def test_the_gathered_gradient_is_the_volume_s():
    """Each vertex's corners (`corner_table`) gather the volume's gradient that a scatter
    from the faces gives (`jax.grad` of `fj.volume`)."""
    vertices, faces = _spot()
    corners = corner_table(faces, len(vertices))
    assert corners.shape[0] == len(vertices) and np.sum(corners < 3 * len(faces)) == faces.size
    expected = jax.grad(lambda v: fj.volume(v, faces))(jnp.asarray(vertices))
    np.testing.assert_allclose(volume_gradient(vertices, faces, corners), expected,
                               rtol=0, atol=1e-15)


def test_the_volume_given_back_in_proportion_to_the_blend():
    """Spot's head shrunk by 5 % (its volume down 1.3 %): with a blend `b` on it, the mesh
    gives back `b` of the volume lost (1, 0.5, 1e-6), moving only the blended vertices, and
    by less the less it is blended (continuous as `b → 0`); with none, nothing moves."""
    vertices, faces = _spot()
    corners = corner_table(faces, len(vertices))
    rest_volume = float(fj.volume(vertices, faces))
    head = vertices[:, 2] > 0.35
    centre = vertices[head].mean(axis=0)
    shrunk = np.where(head[:, None], centre + 0.95 * (vertices - centre), vertices)
    lost = rest_volume - float(fj.volume(shrunk, faces))
    assert lost > 0.01 * rest_volume
    moves = []
    for b in (1.0, 0.5, 1e-6):
        blend = np.where(head, b, 0.0)
        out = np.asarray(restored_volume(shrunk, vertices, rest_volume, faces, corners, blend))
        given = float(fj.volume(out, faces)) - float(fj.volume(shrunk, faces))
        assert abs(given - b * lost) < 1e-12 * rest_volume
        np.testing.assert_array_equal(out[~head], shrunk[~head])
        moves.append(np.abs(out - shrunk).max())
    assert moves[0] > moves[1] > moves[2] and moves[2] < 1e-5 * moves[0]
    none = restored_volume(shrunk, vertices, rest_volume, faces, corners, np.zeros(len(head)))
    np.testing.assert_array_equal(np.asarray(none), shrunk)

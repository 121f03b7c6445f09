"""Issue 47's cases that the other bad-input tests do not hold: the stretch on every entry
point's result (item 4), mismatched meshes and skeletons (item 7), and its messages (item 9).
Small shapes only: the creature of `test_cli`, the posing tube (`_posing_shapes`)."""

import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._mesh.deform import longest_edge

SOURCE, TARGET = fj.Line(4.0), fj.Arc(1.6, 4.0, normal=(0.0, 0.0, -1.0))


@pytest.fixture(scope="module")
def creature():
    return fj.creature(segments=12, around=8)


def test_deform_mesh_carries_the_map_s_principal_stretch(creature):
    # Item 4: the API exposes the stretch the command line refuses beyond --max-stretch.
    bent = fj.deform_mesh(creature, SOURCE, TARGET, stretch=True)
    assert "stretch" not in fj.deform_mesh(creature, SOURCE, TARGET).vertex_attributes
    stretch = np.asarray(bent.vertex_attributes["stretch"])
    valid = np.asarray(bent.vertex_attributes["valid"])
    assert valid.all() and stretch.shape == (len(creature.vertices),)
    margin = 0.5 * longest_edge(creature.vertices, creature.faces)
    fleshing = fj.Fleshing(SOURCE, TARGET, margin=margin)
    expected = np.asarray(fj.principal_stretch(fleshing, np.asarray(creature.vertices)))
    np.testing.assert_allclose(stretch, expected, rtol=1e-6)
    assert stretch.max() > 1.1  # a real bend squeezes
    # The other forms carry it too; in chunks, the same values.
    vertices, faces, ok, pair = fj.deform_mesh((creature.vertices, creature.faces), SOURCE,
                                               TARGET, stretch=True, chunk_size=100)
    np.testing.assert_allclose(pair, stretch, rtol=1e-9)
    cloud = fj.deform_mesh(np.asarray(creature.vertices), SOURCE, TARGET, stretch=True)
    far = np.asarray(cloud.metadata["stretch"])
    assert np.all(np.isfinite(far) == np.asarray(cloud.metadata["valid"]))
    with pytest.raises(TypeError, match="`stretch`"):
        fj.deform_mesh(creature, SOURCE, TARGET, stretch="yes")


def test_deform_mesh_stretch_is_nan_where_invalid():
    # A point past the arc's centre is invalid: no stretch is reported for it.
    points = np.array([[1.0, 0.0, 0.1], [2.0, 0.0, -3.0]])
    cloud = fj.deform_mesh(points, SOURCE, TARGET, stretch=True)
    valid, stretch = np.asarray(cloud.metadata["valid"]), np.asarray(cloud.metadata["stretch"])
    assert valid[0] and not valid[1]
    assert np.isfinite(stretch[0]) and np.isnan(stretch[1])

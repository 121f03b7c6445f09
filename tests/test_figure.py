"""`plot_medial`'s vertical axis (`up=`): OBJ models (y up) stand upright in the picture."""

import matplotlib
import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._medial_axis.figure import default_up, upright

matplotlib.use("Agg")


def _drawn_centres(ax):
    (spheres,) = [c for c in ax.collections if hasattr(c, "_offsets3d")]
    return np.column_stack([np.asarray(v, float) for v in spheres._offsets3d])


def test_upright_turns_the_up_axis_to_z_without_mirroring():
    for up, axis in (("x", 0), ("y", 1), ("z", 2)):
        turned = upright(np.eye(3), up)
        np.testing.assert_array_equal(turned[axis], [0, 0, 1])
        assert np.linalg.det(turned) == pytest.approx(1.0)  # a rotation: the model not mirrored
    with pytest.raises(ValueError, match="up"):
        upright(np.eye(3), "w")


def test_plot_medial_stands_spot_upright():
    import matplotlib.pyplot as plt

    spot = fj.data.spot()  # an OBJ: y up
    assert default_up(spot) == "y" and default_up(None) == "z"
    centres = np.array([[0.0, -0.5, 0.2], [0.0, 0.6, -0.3]])
    medial = fj.MedialMesh(centres, np.array([0.1, 0.2]), np.array([[0, 1]]))
    ax = fj.plot_medial(medial, spot)
    drawn = _drawn_centres(ax)
    np.testing.assert_allclose(drawn[:, 2], centres[:, 1])  # the model's y is the picture's z
    ax = fj.plot_medial(medial, spot, up="z")  # as it was: z up, spot on its side
    np.testing.assert_allclose(_drawn_centres(ax), centres)
    plt.close("all")

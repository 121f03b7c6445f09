"""Reduced versions of the paper's experiments (benchmarks/paper): fleshing vs skinning."""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks" / "paper"))

import fig6_genus2  # noqa: E402
import fig7_sliding  # noqa: E402
import fig8_10_resolution as fig8  # noqa: E402
import table1_extrusion  # noqa: E402
from _spiral import Piece, conical_spiral  # noqa: E402

import fleshing_jax as fj  # noqa: E402


def test_table1_round_off_vs_skinning():
    rows, _ = table1_extrusion.run(samples=96, methods=("skinning", "radial"))
    errors = {name: eps for name, _, _, _, eps in rows}
    skinning = [abs(errors["Unbend"]), abs(errors["Bend"])]
    assert min(skinning) > 1e-2  # paper: 3–5 %
    for name, eps in errors.items():
        if name.split()[0] in ("Radial", "Normal", "Binormal"):
            assert abs(eps) < 1e-11  # paper (polyline spines): ≤ 3e-4
            assert abs(eps) * 100 < min(skinning)
    areas = {name: a for name, a, _, _, _ in rows}
    assert areas["Unbend"] == pytest.approx(areas["Original"], rel=1e-12)  # skinning: rigid
    assert areas["Radial Unbend"] != pytest.approx(areas["Original"], rel=1e-3)  # fleshing: not


def test_box_errors_shrink_with_resolution():
    errors, counts = fig8.resolution(levels=(4, 8, 16, 32), methods=("skinning", "radial"))
    radial, skinning = np.abs(errors["radial"]), np.abs(errors["skinning"])
    assert np.all(radial[1:] < radial[:-1] / 3)  # second order in the mesh size
    assert np.all(skinning > 0.1)  # skinning's error does not go away (paper: 12–15 %)
    assert radial[-1] * 100 < skinning[-1]


def test_cube_cloud_errors():
    errors, _ = fig8.cube_errors(sizes=(0.1, 0.05), methods=("skinning", "normal"))
    normal, skinning = np.asarray(errors["normal"]), np.asarray(errors["skinning"])
    assert normal[1] < normal[0] / 3  # per-cube error shrinks with the cube size
    assert np.all(normal * 100 < skinning)


@pytest.mark.slow  # 14 s (notebook 04 and `benchmarks/paper` run the same figure)
def test_sliding_frames():
    starts, deviations, _, _ = fig7_sliding.run(frames=3, methods=("skinning", "radial"))
    skin, radial = np.abs(deviations["skinning"]), np.abs(deviations["radial"])
    assert np.all(skin > 0.01)
    assert np.all(radial * 100 < skin)
    assert len(set(np.round(skin, 6))) == 3  # the volume changes frame by frame under skinning


def test_genus2_successive_bending():
    v0, volumes, _, _ = fig6_genus2.run(size=0.05, methods=("skinning", "binormal"))
    skin1, skin2 = (abs(v - v0) / v0 for v in volumes["skinning"])
    flesh2 = abs(volumes["binormal"][1] - v0) / v0
    assert skin1 < 1e-3 < 0.03 < skin2  # symmetric first bend; the second one changes volume
    assert flesh2 * 100 < skin2


def test_spiral_piece_is_an_arc_length_spine_with_its_own_frame():
    spiral = conical_spiral()
    piece = Piece(spiral, 7.0, 4.0)
    assert float(piece.torsion(2.0)) != 0  # a 3D curve
    (_, t0, _), (i0, _) = piece.jet_and_normals(0.0)
    np.testing.assert_allclose(i0, fj.initial_normal(t0), atol=1e-14)
    for s in (0.0, 1.3, 4.0):
        s = jnp.asarray(s)
        position, tangent, curvature = piece.jet(s)
        np.testing.assert_allclose(position, spiral(7.0 + s), atol=1e-12)
        np.testing.assert_allclose(jax.jacfwd(piece)(s), tangent, atol=1e-10)
        np.testing.assert_allclose(jax.jacfwd(piece.tangent)(s), curvature, atol=1e-8)
        i, j = piece.jet_and_normals(s)[1]
        np.testing.assert_allclose(
            [i @ tangent, j @ tangent, i @ i, j @ j], [0, 0, 1, 1], atol=1e-12
        )
        # The base's frame turned by a constant angle (still rotation minimising), which
        # `base_twist` undoes.
        base = fj.rotation_minimizing_frame(spiral, 7.0 + s)
        own = fj.rotation_minimizing_frame(piece, s, twist=piece.base_twist())
        np.testing.assert_allclose(own, base, atol=1e-12)

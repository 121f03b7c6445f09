"""Tests on the real meshes of ../shared/data (skipped when that folder is absent)."""

import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

import fleshing_jax as fj

DATA = Path(__file__).parents[1].parent / "shared" / "data"
pytestmark = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"shared data folder {DATA} is absent (real-mesh tests need it)"
)
sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks" / "paper"))


def _load(name, **kwargs):
    path = DATA / name
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    return trimesh.load(str(path), process=False, **kwargs)


def test_bunny_capped_volume_and_bending():
    import fig1_bunny

    bunny = _load("stanford-bunny.obj")
    assert not bunny.is_watertight
    closed = fj.cap_holes(bunny)
    assert closed.is_watertight and closed.is_winding_consistent
    assert float(fj.volume(closed.vertices, closed.faces)) == pytest.approx(closed.volume, 1e-12)
    results = fig1_bunny.run(closed, methods=("skinning", "radial"))
    skin, flesh = abs(results["skinning"][1]), abs(results["radial"][1])
    assert results["radial"][2] == 0 and results["skinning"][2] == 0
    assert skin > 0.05  # paper: 9 %
    assert flesh < 3e-3 and flesh * 100 < skin  # paper: < 0.3 %


def test_load_mesh_keeps_obj_vertex_lines():
    for name in ("stanford-bunny.obj", "spot.obj", "spot-quad.obj"):
        path = DATA / name
        if not path.is_file():
            pytest.skip(f"{path} is absent")
        lines = [ln for ln in path.read_text().splitlines() if ln.startswith("v ")]
        positions = np.array([ln.split()[1:4] for ln in lines], float)
        np.testing.assert_array_equal(fj.load_mesh(path).vertices, positions)


def test_spot_merged_is_closed_and_volume_agrees():
    spot = _load("spot.obj")
    spot.merge_vertices(merge_tex=True, merge_norm=True)
    assert spot.is_watertight
    assert float(fj.volume(spot.vertices, spot.faces)) == pytest.approx(spot.volume, rel=1e-12)


def test_spot_quad_mesh_deforms_in_file_order():
    path = DATA / "spot-quad.obj"
    quad = fj.load_mesh(path) if path.is_file() else pytest.skip(f"{path} is absent")
    lines = path.read_text().splitlines()
    positions = np.array([ln.split()[1:4] for ln in lines if ln.startswith("v ")], float)
    quads = np.array(
        [[int(t.split("/")[0]) - 1 for t in ln.split()[1:]] for ln in lines if ln.startswith("f ")]
    )
    assert quads.shape[1] == 4
    np.testing.assert_array_equal(quad.vertices, positions)  # the file's vertex order
    assert len(quad.faces) == 2 * len(quads)
    lo, hi = positions.min(0), positions.max(0)
    axis = int(np.argmax(hi - lo))
    tangent = np.eye(3)[axis]
    origin = (lo + hi) / 2 - tangent * (hi - lo)[axis] / 2
    normal = np.eye(3)[(axis + 1) % 3]
    length = float((hi - lo)[axis])
    source = fj.Line(length, origin=origin, tangent=tangent)
    target = fj.Arc(2 * length, length, origin=origin, tangent=tangent, normal=normal)
    bent = fj.deform_mesh(quad, source, target)
    np.testing.assert_array_equal(bent.faces, quad.faces)
    assert bent.vertex_attributes["valid"].all()
    # The quads themselves (bilinear volume) keep their volume as well as the triangles do.
    v0, v1 = float(fj.volume(positions, quads)), float(fj.volume(bent.vertices, quads))
    assert abs(v1 - v0) / abs(v0) < 1e-3

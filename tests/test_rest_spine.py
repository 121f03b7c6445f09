"""The rest spine found on the medial axis (`fj.rest_spine`) and its command-line use."""

import jax
import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._cli import main
from fleshing_jax._medial.medial_mesh import MedialMesh
from fleshing_jax._medial.rest_spine import rest_spine


@pytest.fixture(scope="module")
def capsule():
    # Subdivided along its length: trimesh's capsule has one long face per side, which no
    # bend of its vertices would keep flat-face accurate.
    return trimesh.creation.capsule(height=4.0, radius=0.5, count=[16, 16]).subdivide_to_size(0.25)


def _samples(spine, n=200):
    return np.asarray(jax.vmap(spine)(np.linspace(0.0, float(spine.length), n)))


def test_capsule_rest_spine_follows_the_axis(capsule):
    spine = rest_spine(capsule, spheres=40)
    diagonal = np.linalg.norm(np.ptp(capsule.vertices, axis=0))
    points = _samples(spine)
    assert np.max(np.linalg.norm(points[:, :2], axis=1)) < 0.01 * diagonal
    # From cap to cap: extended to the surface at both ends.
    assert sorted([points[0, 2], points[-1, 2]]) == pytest.approx([-2.5, 2.5], abs=0.01 * diagonal)
    assert isinstance(spine, fj.BSpline)
    # Exactly arc-length parameterised, as every free-form spine.
    assert float(np.linalg.norm(spine.tangent(1.0))) == pytest.approx(1.0, abs=1e-6)


def test_spike_ends_lose_to_the_main_axis():
    # A chain along x with a side spike of small spheres near its middle: the spine runs
    # along the chain (ends scored by geodesic distance plus radius), not into the spike.
    x = np.linspace(0.0, 4.0, 9)
    chain = np.c_[x, np.zeros(9), np.zeros(9)]
    spike = np.array([[2.0, 0.5, 0.0], [2.0, 1.0, 0.0], [2.0, 1.6, 0.0]])
    centers = np.concatenate([chain, spike])
    radii = np.r_[np.full(9, 0.8), [0.5, 0.2, 0.02]]
    edges = np.r_[np.c_[np.arange(8), np.arange(1, 9)], [[4, 9], [9, 10], [10, 11]]]
    spine = rest_spine(MedialMesh(centers, radii, edges))
    points = _samples(spine)
    assert np.max(np.abs(points[:, 1])) < 1e-3
    # Given only a medial mesh, the ends are continued by the end spheres' radii.
    assert sorted([points[0, 0], points[-1, 0]]) == pytest.approx([-0.8, 4.8], abs=1e-3)


def test_ends_choose_the_path():
    # An L-shaped chain: between the given ends the spine turns the corner.
    leg = np.linspace(0.0, 2.0, 5)
    centers = np.r_[np.c_[leg, 0 * leg, 0 * leg], np.c_[np.full(4, 2.0), leg[1:], 0 * leg[1:]]]
    edges = np.c_[np.arange(8), np.arange(1, 9)]
    medial = MedialMesh(centers, np.full(9, 0.3), edges)
    spine = rest_spine(medial, ends=[[2.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
    start, end = _samples(spine)[[0, -1]]
    np.testing.assert_allclose(start, [2.0, 2.3, 0.0], atol=0.01)  # starts near the first end
    np.testing.assert_allclose(end, [-0.3, 0.0, 0.0], atol=0.01)


@pytest.mark.parametrize(
    "medial,ends,words",
    [
        (MedialMesh(np.zeros((1, 3)), np.ones(1)), None, "no path"),
        (MedialMesh(np.eye(3), np.ones(3), [[0, 1]]), [[0, 0, 0]], "ends"),
        (MedialMesh(np.eye(3), np.ones(3), [[0, 1]]), [[1, 0, 0], [0, 0, 1]], "not connected"),
    ],
)
def test_bad_input(medial, ends, words):
    with pytest.raises(ValueError, match=words):
        rest_spine(medial, ends=ends)


def test_deform_without_a_rest_spine_file(tmp_path, capsys, capsule):
    capsule.export(str(tmp_path / "capsule.obj"))
    out = tmp_path / "bent.ply"
    code = main(["deform", str(tmp_path / "capsule.obj"), str(out), "--bend-angle", "90"])
    printed, err = capsys.readouterr()
    assert code == 0, err
    # The rest spine is printed as JSON, loadable as it is.
    line = next(ln for ln in printed.splitlines() if ln.startswith("rest spine"))
    (tmp_path / "rest.json").write_text(line.split(": ", 1)[1])
    rest = fj.load_spine(tmp_path / "rest.json")
    assert isinstance(rest, fj.BSpline)
    bent = trimesh.load(str(out), process=False)
    assert len(bent.vertices) == len(capsule.vertices)
    after = next(ln for ln in printed.splitlines() if ln.startswith("volume after"))
    change = float(after.split("(")[1].split("%")[0]) / 100
    assert abs(change) < 0.01
    assert "invalid vertices: 0 of" in printed


def test_medial_command(tmp_path, capsys, capsule):
    capsule.export(str(tmp_path / "capsule.obj"))
    args = ["medial", str(tmp_path / "capsule.obj"), str(tmp_path / "c.ma"), "--spheres", "20"]
    code = main([*args, "--envelope", str(tmp_path / "env.obj")])
    printed, err = capsys.readouterr()
    assert code == 0, err
    medial = fj.load_medial(tmp_path / "c.ma")
    counts = f"spheres: {len(medial.radii)}, edges: {len(medial.edges)}, faces: {len(medial.faces)}"
    assert counts in printed and len(medial.radii) == 20
    distances = printed.split("surface to envelope ")[1].split(", envelope to surface ")
    assert max(float(distances[0]), float(distances[1].split()[0])) < 0.01
    envelope = fj.load_mesh(tmp_path / "env.obj")
    assert envelope.is_watertight
    assert envelope.volume == pytest.approx(capsule.volume, rel=0.03)
    # A wrong output name is refused before any work.
    code = main(["medial", str(tmp_path / "capsule.obj"), str(tmp_path / "c.txt")])
    assert code == 2 and ".ma" in capsys.readouterr().err

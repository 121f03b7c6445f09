"""The rest spine found on the medial axis (`fj.rest_spine`) and its command-line use."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._cli import main
from fleshing_jax._medial_axis.medial_mesh import MedialMesh
from fleshing_jax._skeleton.rest_spine import rest_spine


@pytest.fixture(scope="module")
def capsule():
    # Subdivided along its length: trimesh's capsule has one long face per side, which no
    # bend of its vertices would keep flat-face accurate.
    return trimesh.creation.capsule(height=4.0, radius=0.5, count=[16, 16]).subdivide_to_size(0.25)


def _samples(spine, n=200):
    return np.asarray(jax.vmap(spine)(np.linspace(0.0, float(spine.length), n)))


def _follows_the_capsule_axis(spine, capsule):
    """The assertions on `rest_spine(capsule)`: along the axis, from cap to cap."""
    diagonal = np.linalg.norm(np.ptp(capsule.vertices, axis=0))
    points = _samples(spine)
    assert np.max(np.linalg.norm(points[:, :2], axis=1)) < 0.01 * diagonal
    # From cap to cap: extended to the surface at both ends.
    assert sorted([points[0, 2], points[-1, 2]]) == pytest.approx([-2.5, 2.5], abs=0.01 * diagonal)
    assert isinstance(spine, fj.BSpline)
    # Exactly arc-length parameterised, as every free-form spine.
    assert float(np.linalg.norm(spine.tangent(1.0))) == pytest.approx(1.0, abs=1e-6)


def test_a_mesh_gets_its_medial_mesh_with_the_spheres_and_seed_given(capsule, monkeypatch):
    # `rest_spine(mesh, spheres=…, seed=…)` builds the mesh's medial mesh with them: here a
    # stand-in, the capsule's axis as a chain of spheres (the real one is built by the
    # command's test below, whose rest spine follows the axis too).
    from fleshing_jax._medial_axis import construct

    z = np.linspace(-1.5, 1.5, 7)
    edges = np.c_[np.arange(6), 1 + np.arange(6)]
    chain = MedialMesh(np.c_[0 * z, 0 * z, z], np.full(7, 0.5), edges)
    calls = []

    def medial_mesh(mesh, **options):
        calls.append(options)
        return chain

    monkeypatch.setattr(construct, "medial_mesh", medial_mesh)
    spine = rest_spine(capsule, spheres=40, seed=3)
    assert [(c["spheres"], c["seed"]) for c in calls] == [(40, 3)]
    _follows_the_capsule_axis(spine, capsule)


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
    # The capsule's rest spine (`rest_spine(capsule)`, 100 spheres) follows its axis: checked
    # on the one the command found (its medial mesh is most of the time of either).
    _follows_the_capsule_axis(rest, capsule)
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


@pytest.fixture(scope="module")
def spot_medial():
    from fleshing_jax._medial_axis.construct import medial_mesh

    # As `rest_spine` computes it, with fewer spheres (seconds).
    return medial_mesh(fj.data.spot(), 40, refine=0, progress=False)


@eqx.filter_jit  # one program for the spines of one control-point bucket (not op by op)
def _points_and_curvature(spine):
    s = jnp.linspace(0.0, spine.length, 400)
    curvature = jnp.linalg.norm(jax.vmap(spine.curvature_vector)(s), axis=1)
    return jax.vmap(spine)(s), curvature


def _tightest_turn(spine, medial):
    """max over the spine of curvature × the radius of the nearest medial sphere."""
    points, curvature = map(np.asarray, _points_and_curvature(spine))
    centers, radii, _, _ = medial.numpy()
    nearest = np.argmin(np.linalg.norm(points[:, None] - centers[None], axis=2), axis=1)
    return float(np.max(curvature * radii[nearest]))


HEAD, TAIL = [0.0, 0.3, -0.6], [0.0, 0.2, 0.9]  # spot: y up, head towards −z


def test_spot_rest_spine_turns_no_tighter_than_the_shape_is_thick(spot_medial):
    spot = fj.data.spot()
    for ends in (None, [HEAD, TAIL]):
        spine = rest_spine(spot_medial, ends=ends, surface=spot)
        # Curvature below the inverse of the local medial radius: no cross-section folds.
        assert _tightest_turn(spine, spot_medial) < 1.0
        # The least-squares fit alone (as many control points as allowed) turns tighter.
        wavy = rest_spine(spot_medial, ends=ends, surface=spot, control_points=16)
        assert _tightest_turn(wavy, spot_medial) > 1.0
    # Between given ends, continued to the surface: from the nose to the tail's tip.
    start, end = _samples(spine)[[0, -1]]
    assert start[2] < spot.bounds[0, 2] + 0.05 and end[2] > 0.8
    with pytest.raises(ValueError, match="surface"):
        rest_spine(spot, surface=spot)


@pytest.mark.slow  # 16 s: spot bent by the command line (the capsule's test runs by default)
def test_deform_with_medial_ends_and_saved_spine(tmp_path, capsys, spot_medial):
    fj.save_medial(spot_medial, tmp_path / "spot.ma")
    spine_file = tmp_path / "rest.json"
    args = ["deform", str(fj.data.spot_path()), str(tmp_path / "bent.obj"), "--medial",
            str(tmp_path / "spot.ma"), "--ends", ",".join(map(str, HEAD)),
            ",".join(map(str, TAIL)), "--save-spine", str(spine_file), "--bend-angle", "20",
            "--cap-holes", "--allow-invalid"]  # fmt: skip
    code = main(args)
    printed, err = capsys.readouterr()
    assert code == 0, err
    # The saved spine is the one found on the given medial mesh between the given ends.
    saved = fj.load_spine(spine_file)
    expected = rest_spine(spot_medial, ends=[HEAD, TAIL], surface=fj.data.spot())
    np.testing.assert_allclose(saved.control_points, expected.control_points, atol=1e-12)
    assert f"wrote {spine_file}" in printed and not list(tmp_path.glob(".rest.json.*"))


def test_deform_refuses_rest_spine_options_with_from(tmp_path, capsys):
    # --medial and --ends find the rest spine: refused with --from, before any work.
    spine_file = tmp_path / "rest.json"
    args = ["deform", str(fj.data.spot_path()), str(tmp_path / "bent.obj")]
    code = main([*args[:3], "--from", str(spine_file), "--medial", str(tmp_path / "spot.ma"),
                 "--bend-angle", "20"])  # fmt: skip
    assert code == 2 and "--medial" in capsys.readouterr().err
    code = main([*args[:3], "--from", str(spine_file), "--ends", "0,0,0", "1,1,1", "--to", "x"])
    assert code == 2 and "--ends: not allowed with argument --from" in capsys.readouterr().err
    code = main([*args[:3], "--ends", "0,0", "1,1,1", "--bend-angle", "20"])
    assert code == 2 and "invalid point X,Y,Z value: '0,0'" in capsys.readouterr().err

"""`deform_medial`, handle files and the `medial-deform` command: the whole chain of Lan et
al. 2017 on a small capsule (binding, ARAP, skin), and its input checks."""

import json

import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._cli import main
from fleshing_jax._medial_deform.handle_files import load_handles

SPHERES = 9


@pytest.fixture(scope="module")
def capsule():
    """A capsule (radius 0.5, axis 4 along z) and its medial chain of spheres."""
    mesh = trimesh.creation.capsule(height=4.0, radius=0.5, count=[12, 12])
    # trimesh spans the cylinder with single long triangles: cut them so that it can bend.
    mesh = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, 0.3),
                           process=False)
    z = np.linspace(-2.0, 2.0, SPHERES)
    centers = np.column_stack([np.zeros(SPHERES), np.zeros(SPHERES), z])
    edges = np.column_stack([np.arange(SPHERES - 1), np.arange(1, SPHERES)])
    return mesh, fj.MedialMesh(centers, np.full(SPHERES, 0.5), edges)


def _bend(medial, degrees):
    """Handles (first and last two spheres) on an arc of the axis' length turning `degrees`."""
    z = np.asarray(medial.centers)[:, 2]
    radius = 4.0 / np.radians(degrees)
    t = (z + 2.0) / radius
    on_arc = np.column_stack([radius * (1 - np.cos(t)), np.zeros_like(t), radius * np.sin(t) - 2])
    handles = np.array([0, 1, SPHERES - 2, SPHERES - 1])
    return handles, on_arc[handles]


def test_rest_targets_give_the_rest_mesh_for_every_input_type(capsule):
    mesh, medial = capsule
    handles = np.array([0, SPHERES - 1])
    targets = np.asarray(medial.centers)[handles]
    out = fj.deform_medial(mesh, medial, handles, targets)
    assert isinstance(out, trimesh.Trimesh)
    assert out.vertices.shape == mesh.vertices.shape
    np.testing.assert_array_equal(out.faces, mesh.faces)
    assert out.vertex_attributes["valid"].all()
    diagonal = np.linalg.norm(mesh.extents)
    np.testing.assert_allclose(out.vertices, mesh.vertices, atol=1e-6 * diagonal)
    deformed, faces, valid = fj.deform_medial((mesh.vertices, mesh.faces), medial, handles,
                                              targets, "dqs")
    assert faces is not None and np.asarray(valid).all()
    points, valid = fj.deform_medial(np.asarray(mesh.vertices), medial, handles, targets, "lbs")
    np.testing.assert_allclose(points, mesh.vertices, atol=1e-6 * diagonal)


def test_a_bend_moves_the_end_and_keeps_the_volume(capsule):
    mesh, medial = capsule
    handles, targets = _bend(medial, 90)
    out = fj.deform_medial(mesh, medial, handles, targets)
    top = np.asarray(mesh.vertices)[:, 2] > 2.2  # the end cap follows its sphere
    moved = np.asarray(out.vertices)[top].mean(axis=0)
    assert moved[0] > 1.5 and moved[2] < 1.0
    change = fj.volume(out.vertices, out.faces) / fj.volume(mesh.vertices, mesh.faces) - 1
    assert abs(change) < 0.01


def test_deform_medial_rejects_bad_input(capsule):
    mesh, medial = capsule
    with pytest.raises(TypeError, match="`medial`"):
        fj.deform_medial(mesh, "medial.ma", [0], [[0, 0, 0]])
    with pytest.raises(TypeError, match="`mesh`"):
        fj.deform_medial("mesh.obj", medial, [0], [[0, 0, 0]])
    with pytest.raises(ValueError, match="method"):
        fj.deform_medial(mesh, medial, [0], [[0.0, 0.0, -2.0]], "skinning")


@pytest.mark.parametrize(
    "content, words",
    [
        ("{not json", ["not valid JSON"]),
        ('{"handles": [0]}', ["expected"]),
        ('{"handles": [0], "targets": [[0, 0, 0]], "twist": 1}', ["unknown fields"]),
        ('{"handles": [0.5], "targets": [[0, 0, 0]]}', ["integers"]),
        ('{"handles": [0, 1], "targets": [[0, 0, 0]]}', ["`targets`", "(2 × 3)"]),
        ('{"handles": [0], "targets": [["a", 0, 0]]}', ["`targets`", "numbers"]),
        ('{"handles": [0], "targets": [[0, 0, 0]], "rotations": [[1, 0, 0]]}', ["`rotations`"]),
    ],
)
def test_malformed_handle_files_name_the_problem(tmp_path, content, words):
    path = tmp_path / "h.json"
    path.write_text(content)
    with pytest.raises(ValueError) as error:
        load_handles(path)
    assert str(path) in str(error.value)
    for word in words:
        assert word in str(error.value)


def test_medial_deform_command(capsule, tmp_path, capsys):
    mesh, medial = capsule
    mesh.export(str(tmp_path / "in.obj"))
    fj.save_medial(medial, tmp_path / "in.ma")
    handles, targets = _bend(medial, 90)
    (tmp_path / "h.json").write_text(
        json.dumps({"handles": handles.tolist(), "targets": targets.tolist()})
    )
    argv = ["medial-deform", tmp_path / "in.obj", tmp_path / "out.obj", "--medial",
            tmp_path / "in.ma", "--handles", tmp_path / "h.json"]
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "volume before:" in out and "volume after:" in out and "invalid vertices: 0" in out
    bent = trimesh.load(str(tmp_path / "out.obj"), process=False)
    assert len(bent.vertices) == len(mesh.vertices)
    assert not list(tmp_path.glob(".*tmp*"))  # written atomically: no temporary file left
    (tmp_path / "bad.json").write_text('{"handles": [99], "targets": [[0, 0, 0]]}')
    code = main([str(a) for a in argv[:-1] + [tmp_path / "bad.json"]])
    _, err = capsys.readouterr()
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "handles" in err


def test_a_computed_medial_chain_bends_onto_the_arc():
    # The medial mesh computed from a capsule (not laid by hand): its spheres, moved by
    # handles at both ends onto an arc, all follow the arc (a chain folded by the fit, its
    # spheres slid past each other along the axis, left them up to 0.4 off it).
    capsule = trimesh.creation.capsule(height=4.0, radius=0.5, count=[24, 24])
    capsule = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(capsule.vertices, capsule.faces,
                                                                 0.2), process=False)  # fmt: skip
    medial = fj.medial_mesh(capsule, 60, progress=False)
    centers = np.asarray(medial.centers)
    handles = np.flatnonzero(np.abs(centers[:, 2]) > 1.0)
    radius = 4.0 / np.radians(90)
    t = (centers[:, 2] + 2.0) / radius
    on_arc = np.column_stack([radius * (1 - np.cos(t)), centers[:, 1], radius * np.sin(t) - 2])
    posed = np.asarray(fj.arap_medial(medial, handles, on_arc[handles]).centers)
    off = np.hypot(np.hypot(posed[:, 0] - radius, posed[:, 2] + 2.0) - radius, posed[:, 1])
    assert off.max() < 0.05

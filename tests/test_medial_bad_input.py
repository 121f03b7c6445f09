"""Medial-axis deformation under bad input (issue 29): every input checked before work, never a
silent NaN flagged valid, never a torn seam.

Each test fails if its defect comes back. Meshes are small (the 9-sphere capsule chain of
`test_medial_rig`, whose compiled pose programs are shared) and most checks run before any
binding or compilation.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._cli import main
from fleshing_jax._medial_axis import construct, distance, files
from fleshing_jax._medial_axis.medial_mesh import MedialMesh
from fleshing_jax._medial_axis.surface import closed_mesh_arrays
from fleshing_jax._medial_deform import deform
from fleshing_jax._medial_deform.handle_files import load_handles
from fleshing_jax._medial_deform.pose import MedialPose
from fleshing_jax._medial_deform.rig import MedialRig

SPHERES = 9
SPOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "spot.obj"


def chain(n=SPHERES, radius=0.5, shift=0.0):
    z = np.linspace(-2.0, 2.0, n) + shift
    centers = np.stack([np.zeros(n), np.zeros(n), z], 1)
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], 1)
    return MedialMesh(centers, np.full(n, radius), edges)


def capsule_mesh():
    mesh = trimesh.creation.capsule(height=4.0, radius=0.5, count=[12, 12])
    return trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, 0.3),
                           process=False)


def unwelded(mesh):
    """`mesh` with every face corner its own vertex (as an STL file is read)."""
    corners = np.asarray(mesh.vertices)[np.asarray(mesh.faces)].reshape(-1, 3)
    return trimesh.Trimesh(corners, np.arange(len(corners)).reshape(-1, 3), process=False)


@pytest.fixture(scope="module")
def capsule():
    mesh, medial = capsule_mesh(), chain()
    return mesh, medial, MedialRig(mesh.vertices, medial, faces=mesh.faces)


def bend_pose(medial, angle):
    """The chain bent onto an arc of its length, each sphere turned with the arc."""
    z = np.asarray(medial.centers)[:, 2] + 2.0
    radius = 4.0 / angle
    t = z / radius
    centers = np.stack([radius * (1 - np.cos(t)), 0 * t, radius * np.sin(t) - 2.0], 1)
    c, s = np.cos(t), np.sin(t)
    zero, one = np.zeros_like(t), np.ones_like(t)
    rotations = np.stack([np.stack([c, zero, s], -1), np.stack([zero, one, zero], -1),
                          np.stack([-s, zero, c], -1)], -2)
    return MedialPose(medial, centers, rotations)


# --- the pose: checked, never a NaN flagged valid ---------------------------------------------


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda c, r: (c.at[3, 0].set(jnp.nan), r), "centers must be finite.*spheres \\[3\\]"),
        (lambda c, r: (c, r.at[2].set(0.0)), "rotation matrices.*spheres \\[2\\]"),
        (lambda c, r: (c, r.at[2].multiply(2.0)), "rotation matrices.*spheres \\[2\\]"),
        (lambda c, r: (c, r.at[4, 2].multiply(-1.0)), "rotation matrices.*spheres \\[4\\]"),
        (lambda c, r: (c, r.at[5, 0, 0].set(jnp.inf)), "rotation matrices.*spheres \\[5\\]"),
        (lambda c, r: (c[:-1], r), "centers must have shape \\(9, 3\\)"),
    ],
)
def test_a_pose_is_checked(change, words):
    medial = chain()
    rest = MedialPose.rest(medial)
    centers, rotations = change(rest.centers, rest.rotations)
    with pytest.raises(ValueError, match=words):
        MedialPose(medial, centers, rotations)


def test_a_pose_refuses_what_is_not_an_array_or_a_medial_mesh():
    medial = chain()
    rest = MedialPose.rest(medial)
    with pytest.raises(TypeError, match="medial"):
        MedialPose("medial.ma", rest.centers, rest.rotations)
    with pytest.raises(TypeError, match="centers"):
        MedialPose(medial, [["a", "b", "c"]] * SPHERES, rest.rotations)
    with pytest.raises(TypeError, match="rotations"):
        MedialPose(medial, rest.centers, np.asarray(rest.rotations) + 0j)
    # Lists of numbers are arrays: converted, not refused.
    pose = MedialPose(medial, np.asarray(rest.centers).tolist(), rest.rotations)
    assert pose.centers.shape == (SPHERES, 3)


def test_a_traced_non_finite_pose_is_flagged_invalid_and_left_at_rest(capsule):
    # Under `jit` the pose's values cannot be checked: the vertices they make non-finite
    # are flagged invalid (they were NaN and valid) and stay at rest.
    mesh, medial, rig = capsule
    rest = MedialPose.rest(medial)

    @jax.jit
    def posed(centers):
        return rig.pose(MedialPose(medial, centers, rest.rotations), implicit=False)

    vertices, valid = posed(rest.centers.at[SPHERES - 1].set(jnp.nan))
    vertices, valid = np.asarray(vertices), np.asarray(valid)
    assert np.isfinite(vertices).all()
    assert 0 < (~valid).sum() < len(valid)
    np.testing.assert_array_equal(vertices[~valid], np.asarray(mesh.vertices)[~valid])


def test_targets_beyond_the_mesh_pose_no_vertex_to_nan(capsule):
    # The implicit correction's field overflows: those vertices were NaN and flagged valid.
    mesh, medial, _ = capsule
    handles = [0, 1, SPHERES - 2, SPHERES - 1]
    targets = np.asarray(medial.centers)[handles] + [0.0, 0.0, 1e300]
    out = fj.deform_medial(mesh, medial, handles, targets)
    vertices, valid = np.asarray(out.vertices), out.vertex_attributes["valid"]
    assert np.isfinite(vertices).all() and not valid.any()
    np.testing.assert_array_equal(vertices, mesh.vertices)
    with jax.enable_x64(False):  # a finite float64 value that float32 cannot hold
        with pytest.raises(ValueError, match="`targets` must be representable in float32"):
            fj.arap_medial(medial, handles, np.full((4, 3), 1e39))


def test_a_pose_of_another_medial_mesh_is_refused(capsule):
    mesh, medial, rig = capsule
    other = chain(shift=0.1)  # as many spheres, elsewhere
    with pytest.raises(ValueError, match="another"):
        rig.pose(MedialPose.rest(other))
    relinked = MedialMesh(medial.centers, medial.radii, np.asarray(medial.edges)[:, ::-1])
    rig.pose(MedialPose.rest(relinked), implicit=False)  # the same mesh, edges reversed
    with pytest.raises(ValueError, match="`medial` must be the rig's"):
        fj.fit_handles(rig, [0], [0], [[0.0, 0.0, 0.0]], medial=other)
    with jax.enable_x64(False):  # the same mesh in float32 is the same mesh
        assert MedialMesh(np.asarray(medial.centers, np.float32),
                          medial.radii).fingerprint() == MedialMesh(
                              medial.centers, medial.radii).fingerprint()


@pytest.mark.parametrize(
    "option, value, error",
    [
        ("blend", float("inf"), ValueError),
        ("blend", 0.0, ValueError),
        ("blend", "0.1", TypeError),
        ("max_distance", float("nan"), ValueError),
        ("max_distance", float("inf"), ValueError),
        ("max_distance", [1.0], TypeError),
        ("relax_step", 2.0, ValueError),
        ("contact_angle", 0.0, ValueError),
        ("contact_angle", 200.0, ValueError),
        ("newton_steps", 200, ValueError),
        ("newton_steps", 10**6, ValueError),
        ("newton_steps", 1.0, TypeError),
        ("relax_iterations", 9, ValueError),
        ("smoothing", True, TypeError),
        ("slots", 0, ValueError),
    ],
)
def test_rig_options_are_bounded_and_named(capsule, option, value, error):
    mesh, medial, _ = capsule
    with pytest.raises(error, match=f"`{option}`"):
        MedialRig(mesh.vertices, medial, faces=mesh.faces, **{option: value})


@pytest.mark.parametrize(
    "options, error, name",
    [
        ({"smoothness": "a"}, TypeError, "smoothness"),
        ({"smoothness": float("inf")}, ValueError, "smoothness"),
        ({"iterations": True}, TypeError, "iterations"),
        ({"iterations": 10**9}, ValueError, "iterations"),
    ],
)
def test_arap_options_are_bounded_and_named(options, error, name):
    with pytest.raises(error, match=f"`{name}`"):
        fj.arap_medial(chain(), [0], [[0.0, 0.0, -2.0]], **options)


@pytest.mark.parametrize(
    "options, error, name",
    [
        ({"max_steps": 0}, ValueError, "max_steps"),
        ({"max_steps": 2.5}, TypeError, "max_steps"),
        ({"rtol": -1.0}, ValueError, "rtol"),
        ({"atol": float("nan")}, ValueError, "atol"),
    ],
)
def test_fit_handles_options_are_bounded_and_named(capsule, options, error, name):
    _, _, rig = capsule
    with pytest.raises(error, match=f"`{name}`"):
        fj.fit_handles(rig, [0], [0], [[0.0, 0.0, 0.0]], **options)


@pytest.mark.parametrize("resolution, error", [(0, ValueError), (3000, ValueError),
                                               (1.5, TypeError), (-1, ValueError)])
def test_the_envelope_resolution_is_bounded(resolution, error):
    with pytest.raises(error, match="`resolution`"):
        chain().envelope(resolution)
    with pytest.raises(error, match="`resolution`"):
        chain().volume(resolution)


# --- seams ------------------------------------------------------------------------------------


@pytest.mark.skipif(not SPOT.exists(), reason="../shared/data/spot.obj is absent")
def test_spot_as_loaded_keeps_its_seams_closed():
    mesh = trimesh.load(str(SPOT), process=False)  # 295 copies of vertices at its seams
    vertices = np.asarray(mesh.vertices)
    _, index = np.unique(vertices, axis=0, return_inverse=True)
    index = index.reshape(-1)
    assert len(vertices) - index.max() - 1 > 200
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    diagonal = np.linalg.norm(hi - lo)
    # A crude medial chain along the body; the seams' copies used to part by 0.2 % of the
    # diagonal on it (4 % on spot's own medial mesh).
    medial = MedialMesh(np.linspace(lo + 0.3 * (hi - lo), hi - 0.3 * (hi - lo), 5),
                        np.full(5, 0.15), [[0, 1], [1, 2], [2, 3], [3, 4]])
    rig = MedialRig(vertices, medial, faces=mesh.faces)
    rest = MedialPose.rest(medial)
    turn = np.tile(np.eye(3), (5, 1, 1))
    c, s = np.cos(0.5), np.sin(0.5)
    turn[3:] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    centers = np.asarray(rest.centers).copy()
    centers[3:] = centers[2] + (centers[3:] - centers[2]) @ turn[3].T
    posed, valid = rig.pose(MedialPose(medial, centers, turn))
    posed = np.asarray(posed)
    first = np.zeros(index.max() + 1, int)
    first[index[::-1]] = np.arange(len(index))[::-1]
    assert np.abs(posed - posed[first[index]]).max() <= 1e-9 * diagonal
    assert np.abs(posed - vertices).max() > 0.05 * diagonal  # it did move
    assert posed.shape == vertices.shape and bool(np.asarray(valid).all())


def test_an_unwelded_closed_mesh_is_welded_not_sent_to_cap_holes():
    sphere = trimesh.creation.icosphere(1)
    with pytest.warns(UserWarning, match="unwelded.*welded"):
        vertices, faces = closed_mesh_arrays(unwelded(sphere))
    assert len(vertices) == len(sphere.vertices) and len(faces) == len(sphere.faces)
    cut = unwelded(trimesh.Trimesh(sphere.vertices, sphere.faces[:-1], process=False))
    with pytest.raises(ValueError, match="unwelded.*merge_vertices"):
        closed_mesh_arrays(cut)


def test_medial_deform_keeps_an_unwelded_mesh_whole(capsule, tmp_path, capsys):
    mesh, medial, _ = capsule
    loose = unwelded(mesh)
    loose.export(str(tmp_path / "in.stl"))
    files.save_medial(medial, tmp_path / "in.ma")
    handles = [0, 1, SPHERES - 2, SPHERES - 1]
    targets = np.asarray(bend_pose(medial, np.pi / 2).centers)[handles]
    (tmp_path / "h.json").write_text(json.dumps({"handles": handles,
                                                 "targets": targets.tolist()}))
    code, out, err = _command(["medial-deform", tmp_path / "in.stl", tmp_path / "out.stl",
                               "--medial", tmp_path / "in.ma", "--handles", tmp_path / "h.json",
                               "--no-implicit"], capsys)
    assert code == 0, err
    assert "unwelded" in out and "cap-holes" not in out and "not closed" not in out
    change = float(out.split("volume after:")[1].split("(")[1].split("%")[0])
    assert abs(change) < 2.0  # torn apart it lost 57 %
    bent = trimesh.load(str(tmp_path / "out.stl"), process=False)
    bent.merge_vertices()
    assert len(bent.vertices) == len(mesh.vertices)  # every copy went where its twins went


# --- types ------------------------------------------------------------------------------------


def test_complex_and_string_arrays_are_type_errors(capsule):
    mesh, medial, _ = capsule
    with pytest.raises(TypeError, match="`vertices`.*real"):
        MedialRig(np.asarray(mesh.vertices) + 1j, medial)
    with pytest.raises(TypeError, match="`vertices`"):
        MedialRig(np.asarray(mesh.vertices).astype(str), medial)
    with pytest.raises(TypeError, match="real"):
        MedialMesh(np.asarray(medial.centers) + 1j, medial.radii)
    with pytest.raises(TypeError, match="real"):
        MedialMesh(np.asarray(medial.centers).astype(str), medial.radii)


def test_wrong_objects_are_type_errors(capsule, tmp_path):
    mesh, medial, _ = capsule
    with pytest.raises(TypeError, match="`medial`"):
        files.save_medial("x", tmp_path / "x.ma")
    with pytest.raises(TypeError, match="`medial`"):
        fj.medial_distance("x", mesh)
    with pytest.raises(TypeError, match="`medial`"):
        fj.plot_medial("x")


# --- checks before work -----------------------------------------------------------------------


def test_deform_medial_checks_everything_before_binding(capsule, monkeypatch):
    mesh, medial, _ = capsule

    def no_binding(*args, **kwargs):
        raise AssertionError("bound before the arguments were checked")

    monkeypatch.setattr(deform, "MedialRig", no_binding)
    for handles, targets, method, error in [
        ([99], [[0.0, 0, 0]], "medial", "`handles`"),
        ([0], [[0.0, 0, 0], [1, 1, 1]], "medial", "`targets`"),
        ([0], [[np.nan, 0, 0]], "medial", "`targets`"),
        ([0], [[0.0, 0, 0]], "spline", "`method`"),
    ]:
        with pytest.raises(ValueError, match=error):
            fj.deform_medial(mesh, medial, handles, targets, method)


def _command(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_medial_command_checks_its_output_before_computing(tmp_path, monkeypatch, capsys):
    def no_work(*args, **kwargs):
        raise AssertionError("computed before the output was checked")

    monkeypatch.setattr(construct, "medial_mesh", no_work)
    trimesh.creation.icosphere(1).export(str(tmp_path / "in.obj"))
    (tmp_path / "folder.ma").mkdir()
    for output, words in [("missing/out.ma", "does not exist"), ("folder.ma", "is a folder")]:
        code, _, err = _command(["medial", tmp_path / "in.obj", tmp_path / output], capsys)
        assert code == 2 and words in err and output in err
        assert ".tmp" not in err and len(err.strip().splitlines()) == 1


def test_medial_command_lists_the_spheres(tmp_path, monkeypatch, capsys):
    medial = chain()
    monkeypatch.setattr(construct, "medial_mesh", lambda mesh, **options: medial)
    monkeypatch.setattr(distance, "medial_distance", lambda medial, mesh: (0.01, 0.02))
    trimesh.creation.icosphere(1).export(str(tmp_path / "in.obj"))
    code, out, err = _command(["medial", tmp_path / "in.obj", tmp_path / "out.ma", "--list"],
                              capsys)
    assert code == 0, err
    rows = [line.split() for line in out.splitlines() if line.split()[:1] in
            [[str(i)] for i in range(SPHERES)]]
    assert len(rows) == SPHERES
    np.testing.assert_allclose(np.array(rows, float)[:, 1:4], medial.centers, atol=1e-4)
    np.testing.assert_allclose(np.array(rows, float)[:, 4], medial.radii)


def test_nearest_spheres():
    medial = chain()
    points = np.array([[0.1, 0.0, -2.2], [0.0, 0.3, 0.05], [5.0, 0.0, 1.9]])
    np.testing.assert_array_equal(medial.nearest(points), [0, 4, 8])
    assert medial.nearest([0.0, 0.0, 1.4]).shape == () and int(medial.nearest([0, 0, 1.4])) == 7
    with pytest.raises(ValueError, match="`points`"):
        medial.nearest([[np.nan, 0, 0]])
    with pytest.raises(ValueError, match="`points`"):
        medial.nearest(np.zeros((2, 2)))
    with pytest.raises(TypeError, match="`points`"):
        medial.nearest("origin")


def test_handles_by_point(tmp_path):
    medial = chain()
    path = tmp_path / "h.json"
    path.write_text(json.dumps({"handles": [{"at": [0.2, 0, 1.9]}, 3],
                                "targets": [[0, 0, 2.5], [0, 0, -0.5]]}))
    handles, targets, _ = load_handles(path, medial)
    assert handles.tolist() == [SPHERES - 1, 3] and targets.shape == (2, 3)
    with pytest.raises(ValueError, match="medial mesh is needed"):
        load_handles(path)


@pytest.mark.parametrize(
    "content, words",
    [
        ('{"handles": ["0"], "targets": [[0, 0, 0]]}', "integers"),
        ('{"handles": [true], "targets": [[0, 0, 0]]}', "integers"),
        ('{"handles": [1e300], "targets": [[0, 0, 0]]}', "integers"),
        ('{"handles": [' + "9" * 30 + '], "targets": [[0, 0, 0]]}', "integers"),
        ('{"handles": [0], "targets": [[true, 0, 0]]}', "numbers"),
        ('{"handles": [0], "targets": [["1", 0, 0]]}', "numbers"),
        ('{"handles": [0], "targets": [[NaN, 0, 0]]}', "finite"),
        ('{"handles": [0], "targets": [[1e999, 0, 0]]}', "finite"),
        ('{"handles": [{"at": [0, 0]}], "targets": [[0, 0, 0]]}', "at"),
        ("[" * 100_000 + "]" * 100_000, "not valid JSON"),
    ],
)
def test_handle_files_refuse_what_is_not_a_number(tmp_path, content, words):
    path = tmp_path / "h.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=words) as error:
        load_handles(path, chain())
    assert str(path) in str(error.value) and "-9223372036854775808" not in str(error.value)


def test_handle_files_accept_a_byte_order_mark_and_name_bad_encodings(tmp_path):
    path = tmp_path / "h.json"
    path.write_bytes(b"\xef\xbb\xbf" + b'{"handles": [0], "targets": [[0, 0, 0]]}')
    assert load_handles(path)[0].tolist() == [0]
    path.write_bytes(b'{"handles": [0], "targets": [[0, 0, 0\xff]]}')
    with pytest.raises(ValueError, match="not valid JSON") as error:
        load_handles(path)
    assert str(path) in str(error.value)
    with pytest.raises(ValueError, match="folder"):
        load_handles(tmp_path)


# --- .ma files ---------------------------------------------------------------------------------


def test_ma_files_are_bounded_and_named(tmp_path, monkeypatch):
    path = tmp_path / "m.ma"
    path.write_text("2 1 0\nv 0 0 0 1\nv 1 0 0 1\ne 0 99999999999999999999999\n")
    with pytest.raises(ValueError, match=":4: sphere index out of range"):
        files.load_medial(path)
    path.write_bytes(b"2 1 0\nv 0 0 0 1\nv 1 0 0 \xff1\ne 0 1\n")
    with pytest.raises(ValueError, match="not a text .ma file") as error:
        files.load_medial(path)
    assert str(path) in str(error.value)
    with pytest.raises(ValueError, match="folder"):
        files.load_medial(tmp_path)
    path.write_text("2 1 0\nv 0 0 0 1\nv 1 0 0 1\ne 0 1\n")
    monkeypatch.setattr(files, "MAX_FILE_BYTES", 16)
    with pytest.raises(ValueError, match="more than a medial mesh file may hold"):
        files.load_medial(path)


def test_save_medial_removes_stale_temporary_files_and_keeps_links(tmp_path):
    medial = chain()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    stale = tmp_path / f".m.ma.{dead}.abcd.tmp"
    stale.write_text("half a file")
    alive = tmp_path / f".m.ma.{os.getppid()}.abcd.tmp"  # a running writer's: kept
    alive.write_text("being written")
    files.save_medial(medial, tmp_path / "m.ma")
    assert not stale.exists() and alive.exists()
    (tmp_path / "real").mkdir()
    (tmp_path / "link.ma").symlink_to(tmp_path / "real" / "target.ma")
    files.save_medial(medial, tmp_path / "link.ma")
    assert (tmp_path / "link.ma").is_symlink()
    assert files.load_medial(tmp_path / "real" / "target.ma").fingerprint() == \
        medial.fingerprint()


# --- the command line: one line, status 2 ------------------------------------------------------


def test_medial_deform_failures_are_one_line(capsule, tmp_path, capsys):
    mesh, medial, _ = capsule
    mesh.export(str(tmp_path / "in.obj"))
    files.save_medial(medial, tmp_path / "in.ma")
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (tmp_path / "h.json").write_text('{"handles": [0], "targets": [[0, 0, -2]]}')
    (tmp_path / "garbage.obj").write_bytes(bytes(range(256)) * 8)
    (tmp_path / "huge.ma").write_text("1 0 0\nv 0 0 0 1e400\n")
    for argv, words in [
        (["in.obj", "out.obj", "--medial", "in.ma", "--handles", "deep.json"], "deep.json"),
        (["garbage.obj", "out.obj", "--medial", "in.ma", "--handles", "h.json"], "garbage.obj"),
        ([".", "out.obj", "--medial", "in.ma", "--handles", "h.json"], "folder"),
        (["in.obj", "out.obj", "--medial", "huge.ma", "--handles", "h.json"], "huge.ma:2"),
    ]:
        code, _, err = _command(["medial-deform"] + [tmp_path / a if a[0] != "-" else a
                                                     for a in argv], capsys)
        assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
        assert "Traceback" not in err and "charset_normalizer" not in err
    assert not (tmp_path / "out.obj").exists()


def test_medial_deform_writes_no_nan(capsule, tmp_path, capsys):
    mesh, medial, _ = capsule
    mesh.export(str(tmp_path / "in.obj"))
    files.save_medial(medial, tmp_path / "in.ma")
    (tmp_path / "far.json").write_text(json.dumps({"handles": [0, 1, 7, 8],
                                                   "targets": [[0, 0, 1e300]] * 4}))
    code, out, err = _command(["medial-deform", tmp_path / "in.obj", tmp_path / "out.obj",
                               "--medial", tmp_path / "in.ma", "--handles",
                               tmp_path / "far.json"], capsys)
    assert code == 0, err
    assert "nan" not in out and f"invalid vertices: {len(mesh.vertices)} of" in out
    written = trimesh.load(str(tmp_path / "out.obj"), process=False)
    assert np.isfinite(written.vertices).all()


def test_overflowing_meshes_are_named_not_overflow_errors():
    mesh = trimesh.creation.icosphere(1)
    with pytest.raises(ValueError, match="coordinates reach 1e\\+150"):
        fj.medial_mesh(trimesh.Trimesh(mesh.vertices * 1e150, mesh.faces, process=False))

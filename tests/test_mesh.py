import numpy as np
import pytest
import trimesh

import fleshing_jax as fj

SOURCE = fj.Line(4.0)
TARGET = fj.Arc(1.6, 4.0, normal=(0.0, 0.0, -1.0))


@pytest.fixture(scope="module")
def small():
    return fj.creature(segments=12, around=8)


@pytest.fixture(scope="module")
def bent(small):
    return fj.deform_mesh(small, SOURCE, TARGET, method="radial")


def test_deform_mesh_keeps_faces_and_vertex_order(small, bent):
    assert isinstance(bent, trimesh.Trimesh)
    np.testing.assert_array_equal(bent.faces, small.faces)
    assert bent.vertices.shape == small.vertices.shape
    expected, valid = fj.flesh(np.asarray(small.vertices), SOURCE, TARGET, method="radial")
    np.testing.assert_allclose(bent.vertices, np.asarray(expected), atol=1e-12)
    assert bent.vertex_attributes["valid"].dtype == bool
    np.testing.assert_array_equal(bent.vertex_attributes["valid"], np.asarray(valid))
    assert bent.vertex_attributes["valid"].all()
    assert not np.allclose(bent.vertices, small.vertices)  # it did bend
    np.testing.assert_array_equal(small.vertices, fj.creature(segments=12, around=8).vertices)


def test_deform_mesh_volume_preserved_vs_skinning(small, bent):
    skinned = fj.deform_mesh(small, SOURCE, TARGET, method="skinning")
    flesh_change = abs(float(fj.volume_change(small.vertices, bent.vertices, small.faces)))
    skin_change = abs(float(fj.volume_change(small.vertices, skinned.vertices, small.faces)))
    assert skin_change > 0.03
    assert flesh_change < skin_change / 10  # a coarse mesh; the paper tests refine it


def test_invalid_vertices_stay_in_place():
    points = np.array([[1.0, 0.0, 0.1], [1.0, 0.0, -3.0], [1.0, 0.0, 0.0]])
    tight = fj.Arc(1.0, 4.0, normal=(0.0, 0.0, -1.0))  # offset 3 is far outside its reach
    cloud = fj.deform_mesh(points, SOURCE, tight)
    assert isinstance(cloud, trimesh.PointCloud)
    valid = cloud.metadata["valid"]
    np.testing.assert_array_equal(valid, [True, False, True])
    np.testing.assert_array_equal(cloud.vertices[1], points[1])


def test_point_cloud(small):
    cloud = trimesh.PointCloud(np.asarray(small.vertices))
    out = fj.deform_mesh(cloud, SOURCE, TARGET, method="radial")
    assert isinstance(out, trimesh.PointCloud)
    expected = fj.deform_mesh(small, SOURCE, TARGET, method="radial").vertices
    np.testing.assert_allclose(out.vertices, expected, atol=1e-12)
    assert out.metadata["valid"].all()
    with pytest.raises(TypeError, match="mesh"):
        fj.deform_mesh("not a mesh", SOURCE, TARGET)


def test_quad_mesh_as_vertices_and_faces():
    # The paper's §5.2: quads kept as quads (trimesh would split them), volume of the bilinear
    # patches preserved by fleshing and not by skinning.
    vertices, quads = fj.genus2_slab(size=0.1)
    # Along the spine (x ∈ [1, 3]) and off it in the bending plane, so that skinning's volume
    # change is first order (a slab centred on the spine keeps its volume under skinning too).
    vertices = vertices + np.array([1.0, 0.0, 0.2])
    out, faces, valid = fj.deform_mesh((vertices, quads), SOURCE, TARGET, method="normal")
    assert faces is quads or np.array_equal(faces, quads)
    assert out.shape == vertices.shape and valid.all()
    np.testing.assert_allclose(
        out, np.asarray(fj.flesh(vertices, SOURCE, TARGET, method="normal")[0])
    )
    skinned, _, _ = fj.deform_mesh((vertices, quads), SOURCE, TARGET, method="skinning")
    before = float(fj.volume(vertices, quads))
    flesh_change = abs(float(fj.volume(out, quads)) / before - 1)
    skin_change = abs(float(fj.volume(skinned, quads)) / before - 1)
    assert flesh_change * 10 < skin_change
    with pytest.raises(ValueError, match="faces must index"):
        fj.deform_mesh((vertices, quads + len(vertices)), SOURCE, TARGET)
    with pytest.raises(ValueError, match=r"\(F, k\) integer"):
        fj.deform_mesh((vertices, quads.astype(float)), SOURCE, TARGET)


def test_chunks_and_progress(small, bent):
    calls = []
    out, valid = fj.flesh_chunked(
        np.asarray(small.vertices),
        SOURCE,
        TARGET,
        chunk_size=40,
        progress=lambda done, total: calls.append((done, total)),
    )
    n = len(small.vertices)
    np.testing.assert_allclose(out, bent.vertices, atol=1e-12)
    assert valid.all() and valid.shape == (n,)
    assert [d for d, _ in calls] == list(range(40, n, 40)) + [n]
    assert all(t == n for _, t in calls)


def test_write_mesh_atomic(tmp_path, bent):
    path = tmp_path / "bent.ply"
    fj.write_mesh_atomic(bent, path)
    back = trimesh.load(str(path), process=False)
    np.testing.assert_array_equal(back.faces, bent.faces)
    np.testing.assert_allclose(back.vertices, bent.vertices, rtol=1e-6)
    assert "valid" in back.metadata["_ply_raw"]["vertex"]["data"].dtype.names
    # A failed export leaves an existing file intact and no temporary file behind.
    target = tmp_path / "keep.nosuchformat"
    target.write_text("old")
    with pytest.raises(Exception):
        fj.write_mesh_atomic(bent, target)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bent.ply", "keep.nosuchformat"]


def test_load_mesh(tmp_path, small):
    path = tmp_path / "m.obj"
    fj.write_mesh_atomic(small, path)
    back = fj.load_mesh(path)
    np.testing.assert_allclose(back.vertices, small.vertices, atol=1e-7)
    np.testing.assert_array_equal(back.faces, small.faces)
    with pytest.raises(FileNotFoundError):
        fj.load_mesh(tmp_path / "missing.obj")
    junk = tmp_path / "junk.obj"
    junk.write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match="junk.obj"):
        fj.load_mesh(junk)


@pytest.mark.parametrize("corners", ["plain", "texture seams", "normal seams"])
@pytest.mark.filterwarnings("ignore:All-NaN slice:RuntimeWarning")  # trimesh's texture merge
@pytest.mark.filterwarnings("ignore:invalid value encountered in cast:RuntimeWarning")
def test_obj_files_keep_one_vertex_per_v_line_in_file_order(tmp_path, corners):
    # A tetrahedron and a vertex no face uses, written in no particular order: trimesh's
    # default read drops the unused vertex and splits texture or normal seams.
    vertices = np.array([[5.0, 5, 5], [0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, 0]])
    faces = np.array([[5, 3, 4], [5, 4, 2], [5, 2, 3], [4, 3, 2]])  # 1-based, as in the file
    lines = [f"v {x} {y} {z}" for x, y, z in vertices]
    if corners == "texture seams":
        lines += ["vt 0 0", "vt 1 0", "vt 0 1", "vt 1 1"]
        lines += ["f " + " ".join(f"{v}/{(k + j) % 4 + 1}" for j, v in enumerate(f))
                  for k, f in enumerate(faces)]
    elif corners == "normal seams":
        lines += ["vn 1 0 0", "vn 0 1 0", "vn 0 0 1", "vn 1 1 1"]
        lines += ["f " + " ".join(f"{v}//{k + 1}" for v in f) for k, f in enumerate(faces)]
    else:
        lines += ["f " + " ".join(map(str, f)) for f in faces]
    path = tmp_path / "m.obj"
    path.write_text("\n".join(lines) + "\n")
    mesh = fj.load_mesh(path)
    np.testing.assert_array_equal(mesh.vertices, vertices)
    np.testing.assert_array_equal(mesh.faces, faces - 1)


def test_cap_holes_closes_and_keeps_order():
    closed = fj.extrusion(np.c_[np.cos(np.arange(12) / 2), np.sin(np.arange(12) / 2)], 2.0, 4)
    m = len(closed.faces)
    opened = trimesh.Trimesh(closed.vertices[:-2], closed.faces[: m - 24], process=False)
    opened.metadata["file_type"] = "obj"  # as read from an OBJ file: y up, kept
    assert not opened.is_watertight
    capped = fj.cap_holes(opened)
    assert capped.metadata["file_type"] == "obj" and capped.metadata is not opened.metadata
    assert capped.is_watertight and capped.is_winding_consistent
    np.testing.assert_array_equal(capped.vertices[: len(opened.vertices)], opened.vertices)
    np.testing.assert_array_equal(capped.faces[: len(opened.faces)], opened.faces)
    assert float(fj.volume(capped.vertices, capped.faces)) == pytest.approx(closed.volume)


def test_shapes_are_closed():
    for d in (1, 2, 5):
        v, f = fj.box_grid([[0, 0, 0], [1, 1, 1]], d)
        assert len(v) == 6 * d * d + 2
        assert trimesh.Trimesh(v, f, process=False).is_watertight
    v, q = fj.genus2_slab(size=0.1)
    mesh = trimesh.Trimesh(v, fj.triangulate(q), process=False)
    assert mesh.is_watertight and mesh.euler_number == -2  # genus 2
    assert float(fj.volume(v, q)) == pytest.approx(mesh.volume) and mesh.volume > 0
    cubes, faces = fj.cube_cloud([[0, 0, 0], [1, 1, 1]], 0.25)
    np.testing.assert_allclose(np.asarray(fj.volume(cubes, faces)), 0.25**3)
    c = fj.creature()
    assert c.is_watertight and c.volume > 0


def test_write_mesh_atomic_failure_mid_export(tmp_path, bent, monkeypatch):
    # An export that fails half-way leaves the previous file intact and no temporary file.
    target = tmp_path / "keep.ply"
    target.write_text("old")

    def failing_export(self, *args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(trimesh.Trimesh, "export", failing_export)
    with pytest.raises(RuntimeError):
        fj.write_mesh_atomic(bent, target)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.ply"]


def test_write_mesh_atomic_obj_without_materials(tmp_path, small):
    from PIL import Image

    textured = small.copy()
    uv = np.random.default_rng(0).uniform(0, 1, (len(small.vertices), 2))
    textured.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (4, 4)))
    path = tmp_path / "t.obj"
    fj.write_mesh_atomic(textured, path)
    assert "mtllib" not in path.read_text()  # no reference to a material file never written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.obj"]
    np.testing.assert_allclose(fj.load_mesh(path).vertices, small.vertices, atol=1e-7)


def test_flesh_chunked_default_progress_bar(monkeypatch, capsys, small):
    from fleshing_jax._mesh import deform

    points = np.asarray(small.vertices)
    monkeypatch.setattr(deform, "PROGRESS_POINTS", len(points))  # as for large inputs
    out, ok = deform.flesh_chunked(points, fj.Line(4.0), fj.Arc(1.6, 4.0), chunk_size=40)
    assert "vertices" in capsys.readouterr().err
    expected = fj.deform_mesh(small, fj.Line(4.0), fj.Arc(1.6, 4.0))
    np.testing.assert_allclose(out, expected.vertices, atol=1e-12)


def _prepared_in(monkeypatch):
    """Records the thread each target preparation of `register_and_prepare` runs in."""
    import threading

    from fleshing_jax._mesh import overlap

    threads = []

    def recorded(*args, **kwargs):
        threads.append(threading.get_ident())
        return prepare_target(*args, **kwargs)

    prepare_target = overlap.prepare_target
    monkeypatch.setattr(overlap, "prepare_target", recorded)
    return overlap.register_and_prepare, threads


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_target_prepared_beside_the_registration_poses_as_pose(small, monkeypatch, dtype):
    # The target's preparation runs in a second thread (its compilation overlaps the
    # registration's on a cold start); the pose is that of `register` then `pose`.
    import threading

    import jax.numpy as jnp

    from fleshing_jax._fleshing.pipeline import pose_prepared

    register_and_prepare, threads = _prepared_in(monkeypatch)
    points = jnp.asarray(np.asarray(small.vertices), dtype)
    registration, poser = register_and_prepare(points, SOURCE, TARGET, method="normal", twist=0.3)
    assert threads and threads[0] != threading.get_ident()
    out, ok = pose_prepared(registration, poser)
    expected, valid = fj.pose(fj.register(points, SOURCE), TARGET, method="normal", twist=0.3)
    assert out.dtype == dtype
    np.testing.assert_array_equal(np.asarray(out), np.asarray(expected))
    np.testing.assert_array_equal(np.asarray(ok), np.asarray(valid))


def test_thread_local_precision_prepares_in_the_callers_thread(small, monkeypatch):
    # `jax.enable_x64(False)` holds in this thread only: a second thread would prepare the
    # target in float64 for float32 points, so the preparation stays in the caller's thread.
    import threading

    import jax
    import jax.numpy as jnp

    from fleshing_jax._mesh.deform import flesh_chunked

    register_and_prepare, threads = _prepared_in(monkeypatch)
    with jax.enable_x64(False):
        points = jnp.asarray(np.asarray(small.vertices), np.float32)
        registration, poser = register_and_prepare(points, SOURCE, TARGET)
        assert threads == [threading.get_ident()]
        assert poser.frames.twist.dtype == np.float32
        out, _ = flesh_chunked(np.asarray(small.vertices, np.float32), SOURCE, TARGET)
    assert out.dtype == np.float32 and len(threads) == 2


def test_errors_of_the_preparation_reach_the_caller(small):
    with pytest.raises(TypeError, match="`target` must be a spine"):
        fj.deform_mesh(small, SOURCE, "arc")

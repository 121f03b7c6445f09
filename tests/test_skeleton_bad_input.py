"""Issue 47's cases that the other bad-input tests do not hold: the stretch on every entry
point's result (item 4), mismatched meshes and skeletons (item 7), and its messages (item 9).
Small shapes only: the creature of `test_cli`, the posing tube (`_posing_shapes`)."""

import json
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._cli import main
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


# Item 9: messages. (`tube`, `skeleton`, `registration`: the posing tube of `conftest.py`.)


def test_a_skeleton_file_with_a_region_entry_past_int64_names_the_file(tmp_path, skeleton):
    path = tmp_path / "sk.json"
    fj.save_skeleton(skeleton, path)
    data = json.loads(path.read_text())
    data["region"][3] = 2**70
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"sk\.json: field 'region' .* got 1180591620717411303424"):
        fj.load_skeleton(path)


def test_a_skeleton_with_non_finite_vertices_is_refused_at_construction(skeleton):
    vertices = np.array(skeleton.vertices)
    vertices[5, 1] = np.nan
    with pytest.raises(ValueError, match="`vertices` must be finite"):
        fj.Skeleton(skeleton.limbs, skeleton.region, vertices)


def test_a_skeleton_with_a_region_entry_out_of_range_is_refused(skeleton):
    count = len(skeleton.limbs)
    for wrong, seen in ((count, f"[-1, {count}]"), (-2, f"[-2, {count - 1}]")):
        region = np.array(skeleton.region)
        region[7] = wrong
        with pytest.raises(ValueError, match=rf"limb indices in \[-1, {count}\), got \{seen}"):
            fj.Skeleton(skeleton.limbs, region, skeleton.vertices)


def test_faces_with_a_repeated_vertex_are_named_degenerate(tube):
    faces = np.array(tube.faces)
    faces[[4, 9], 1] = faces[[4, 9], 0]
    for call in (fj.skeleton, fj.medial_mesh):
        with pytest.raises(ValueError, match=r"2 degenerate faces .* faces \[4, 9\]"):
            call((np.asarray(tube.vertices), faces))


def test_a_mesh_output_in_a_format_of_points_is_refused_before_the_work(tmp_path, tube,
                                                                        skeleton, capsys):
    tube.export(str(tmp_path / "in.obj"))
    fj.save_skeleton(skeleton, tmp_path / "sk.json")
    fj.save_spine(SOURCE, tmp_path / "a.json")
    out = tmp_path / "out.xyz"
    for argv in (["pose", tmp_path / "in.obj", out, "--skeleton", tmp_path / "sk.json",
                  "--limb", "0", "--bend", "10"],
                 ["deform", tmp_path / "in.obj", out, "--from", tmp_path / "a.json",
                  "--bend-angle", "10"]):
        started = time.perf_counter()
        assert main([str(a) for a in argv]) == 2
        err = capsys.readouterr().err
        assert "out.xyz" in err and "the output is a mesh" in err and ".ply" in err
        assert time.perf_counter() - started < 2 and not out.exists()  # before any posing


@pytest.mark.parametrize("options, error, name", [
    (dict(vertex_ids=[], targets=np.zeros((0, 3))), ValueError, "vertex_ids"),
    (dict(max_steps="a"), TypeError, "max_steps"),
    (dict(max_steps=1.7), TypeError, "max_steps"),
    (dict(max_steps=0), ValueError, "max_steps"),
    (dict(rtol=float("nan")), ValueError, "rtol"),
    (dict(atol=-1.0), ValueError, "atol"),
])
def test_fit_skeleton_pose_names_a_bad_option(registration, skeleton, options, error, name):
    ids = np.flatnonzero(np.asarray(skeleton.region) == 0)[:3]
    args = dict(vertex_ids=ids, targets=np.asarray(registration.vertices)[ids]) | options
    with pytest.raises(error, match=f"`{name}`"):
        fj.fit_skeleton_pose(registration, skeleton, args.pop("vertex_ids"), args.pop("targets"),
                             **args)


# Item 7: mismatches.


def _sphere(radius, centre, inward=False):
    sphere = trimesh.creation.icosphere(2, radius)
    faces = sphere.faces[:, ::-1] if inward else sphere.faces
    return sphere.vertices + centre, faces


def _joined(*parts):
    vertices, faces, offset = [], [], 0
    for v, f in parts:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def test_two_characters_side_by_side_are_refused_by_skeleton(tube):
    # Two tubes side by side (one mesh): the second was made a limb of the first.
    other = np.asarray(tube.vertices) + [0.0, 2.0, 0.0]
    two = _joined((np.asarray(tube.vertices), tube.faces), (other, tube.faces))
    started = time.perf_counter()
    with pytest.raises(ValueError, match="`mesh` holds 2 separate bodies .* its own mesh"):
        fj.skeleton(two)
    assert time.perf_counter() - started < 5  # before any medial mesh is computed


def test_bodies_are_shells_not_inside_others():
    from fleshing_jax._medial_axis.shells import bodies

    def volumes(mesh):
        return [volume for _, volume in bodies(*mesh)]

    def ball(radius):
        return pytest.approx(trimesh.creation.icosphere(2, radius).volume, rel=1e-9)

    hollow = _joined(_sphere(1.0, 0.0), _sphere(0.5, 0.0, inward=True))  # one body, a cavity
    assert volumes(hollow) == [ball(1.0)]
    assert volumes(_joined(_sphere(0.5, [3.0, 0, 0]), _sphere(1.0, 0.0))) == [ball(1.0),
                                                                             ball(0.5)]
    # A ball inside the cavity is a body of its own.
    assert volumes(_joined(hollow, _sphere(0.2, 0.0))) == [ball(1.0), ball(0.2)]


def test_riders_are_the_shells_that_cross_a_larger_one():
    from fleshing_jax._medial_axis.shells import riders

    head = _sphere(1.0, 0.0)
    eyes = _joined(head, _sphere(0.2, [1.0, 0, 0]), _sphere(0.2, [0, 1.0, 0]))
    assert riders(*eyes).tolist() == [1, 2]
    # A cavity, a ball inside it and a ball apart cross nothing; the larger shell stays.
    assert riders(*_joined(_sphere(0.2, [1.0, 0, 0]), head)).tolist() == [0]
    hollow = _joined(head, _sphere(0.5, 0.0, inward=True), _sphere(0.2, 0.0))
    assert riders(*_joined(hollow, _sphere(0.3, [3.0, 0, 0]))).tolist() == []


def test_a_loose_piece_of_a_coarse_envelope_is_no_second_character():
    from fleshing_jax._medial_axis.surface import closed_mesh_arrays
    from fleshing_jax._skeleton.build import _one_body

    # Two balls, one 1.6 % of the other's volume (a tail's tip come loose): one character;
    # 6.4 %: two.
    big = _sphere(1.0, 0.0)
    _one_body(*closed_mesh_arrays(_joined(big, _sphere(0.25, [3.0, 0, 0]))))
    with pytest.raises(ValueError, match="2 separate bodies"):
        _one_body(*closed_mesh_arrays(_joined(big, _sphere(0.4, [3.0, 0, 0]))))


def test_deform_s_largest_bend_names_the_vertices_no_bend_keeps_valid(tmp_path, creature,
                                                                       capsys):
    # The largest valid bend is counted over the vertices a bend can keep valid: the line
    # says how many lie outside the rest spine's reach (it claimed "every vertex").
    creature.export(str(tmp_path / "in.obj"))
    rest = fj.Arc(0.8, 4.0, normal=(0.0, 0.0, -1.0))  # tighter than the creature's belly
    fj.save_spine(rest, tmp_path / "a.json")
    code = main([str(a) for a in ("deform", tmp_path / "in.obj", tmp_path / "out.obj",
                                  "--from", tmp_path / "a.json", "--bend-angle", 10)])
    out = capsys.readouterr().out
    margin = 0.5 * longest_edge(creature.vertices, creature.faces)
    stuck = int(np.sum(~np.asarray(fj.register(np.asarray(creature.vertices), rest,
                                                   margin=margin).valid)))
    assert code == 3 and stuck > 0
    line = next(x for x in out.splitlines() if x.startswith("largest bend"))
    assert line.endswith(f"but the {stuck} outside the rest spine's reach, invalid at any bend")


def test_flesh_carries_the_map_s_principal_stretch(creature):
    points = np.asarray(creature.vertices)[::7]
    images, valid, stretch = fj.flesh(points, SOURCE, TARGET, stretch=True)
    np.testing.assert_array_equal(images, fj.flesh(points, SOURCE, TARGET)[0])
    expected = fj.principal_stretch(fj.Fleshing(SOURCE, TARGET), points)
    np.testing.assert_array_equal(stretch, expected)
    assert np.asarray(valid).all() and float(np.max(stretch)) > 1.1
    with pytest.raises(TypeError, match="`stretch`"):
        fj.flesh(points, SOURCE, TARGET, stretch=1)


def test_a_registration_refuses_a_skeleton_of_another_mesh_or_edited_spines(skeleton,
                                                                            registration):
    # The same regions and parents: the registration's own mesh and spines would be posed.
    scaled = fj.Skeleton(skeleton.limbs, skeleton.region, np.asarray(skeleton.vertices) * 1.5)
    with pytest.raises(ValueError, match="`skeleton` was built on another mesh than the one"):
        fj.pose_skeleton(registration, scaled, {0: fj.LimbPose(10)})
    spine = skeleton.limbs[2].spine
    moved = fj.BSpline(np.asarray(spine.control_points) - [0.1, 0, 0], subdivisions=32)
    limbs = list(skeleton.limbs)
    limbs[2] = fj.Limb(moved, limbs[2].joint, limbs[2].parent)
    edited = fj.Skeleton(limbs, skeleton.region, skeleton.vertices)
    with pytest.raises(ValueError, match="rest spines or joints differ"):
        fj.pose_skeleton(registration, edited, {0: fj.LimbPose(10)})
    # The skeleton itself, or a copy of it (read back from its file), is the one registered.
    same = fj.Skeleton(skeleton.limbs, np.asarray(skeleton.region), np.array(skeleton.vertices))
    assert fj.pose_skeleton(registration, same, {}).valid.shape == (len(skeleton.region),)


# The property: random poses of the tube's limbs (combined, any bend, direction and
# twist within a turn), at three scales: no edge between two valid vertices changes length
# more than 4× and 2 % of the diagonal, and no valid vertex is non-finite.


def _torn(rest, edges, vertices, valid):
    """Edges between two valid vertices stretched or shrunk more than 4× and 2 % of the
    diagonal; valid non-finite vertices."""
    before = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    after = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    both = valid[edges[:, 0]] & valid[edges[:, 1]]
    factor = np.maximum(after / before, before / np.maximum(after, 1e-300))
    far = np.abs(after - before) > 0.02 * np.linalg.norm(np.ptp(rest, axis=0))
    finite = np.isfinite(vertices).all(axis=1)
    return int(np.sum(both & (factor > 4) & far)), int(np.sum(valid & ~finite))


@pytest.mark.parametrize("scale", [1.0, 1e-3, 1e3])
def test_random_poses_never_tear_a_valid_edge(tube, skeleton, registration, scale):
    rest = np.asarray(tube.vertices) * scale
    if scale != 1:  # (the same programs: only the values differ)
        skeleton = fj.Skeleton([fj.Limb(fj.BSpline(np.asarray(limb.spine.control_points) * scale,
                                                   subdivisions=32), limb.joint * scale,
                                        limb.parent) for limb in skeleton.limbs],
                               skeleton.region, rest)
        registration = fj.register_skeleton((rest, tube.faces), skeleton, margin=0.06 * scale)
    rng = np.random.default_rng(47)
    for _ in range(6):
        limbs = [k for k in range(3) if rng.random() < 0.6] or [2]
        poses = {k: fj.LimbPose(*rng.uniform([-180, 0, -180], [180, 360, 180])) for k in limbs}
        posed = fj.pose_skeleton(registration, skeleton, poses)
        torn = _torn(rest, tube.edges_unique, np.asarray(posed.vertices), np.asarray(posed.valid))
        assert torn == (0, 0), poses


@pytest.mark.slow  # one jitted program of three posed limbs under vmap: its compile
def test_random_poses_never_tear_a_valid_edge_under_jit(tube, skeleton, registration):
    rng = np.random.default_rng(4747)
    angles = rng.uniform([-180, 0, -180], [180, 360, 180], (8, 3, 3))
    angles[0, 0, 0], angles[1, 1, 2], angles[2, 2, 0] = np.nan, np.inf, 1e9  # flagged
    frame = jax.jit(jax.vmap(lambda a: fj.pose_skeleton(
        registration, skeleton, {k: fj.LimbPose(*a[k]) for k in range(3)})))
    vertices, valid = (np.asarray(x) for x in frame(jnp.asarray(angles)))
    rest = np.asarray(tube.vertices)
    for v, ok in zip(vertices, valid, strict=True):
        assert _torn(rest, tube.edges_unique, v, ok) == (0, 0)
    region = np.asarray(skeleton.region)
    for row, limb in ((0, 0), (1, 1), (2, 2)):  # the limb given a NaN, inf or 1e9 angle
        assert not valid[row][region == limb].any()

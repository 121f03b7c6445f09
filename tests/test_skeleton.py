"""The skeleton found on the medial axis (`fj.skeleton`): limbs, spines, regions, files."""

import json

import jax
import numpy as np
import pytest
import trimesh
from _skeleton_rigs import quadruped_rig
from conftest import spot_skeleton
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

import fleshing_jax as fj
from fleshing_jax._medial_axis.table import table
from fleshing_jax._skeleton.regions import mesh_adjacency, spine_samples

# Few spheres and samples: seconds per medial mesh (the default takes 5–10 s on spot).
FEW = dict(refine=0, progress=False)


@pytest.fixture(scope="module")
def spot(spot_rig):  # (conftest: shared with the skeleton figures' tests)
    return spot_rig


@pytest.fixture(scope="module")
def table_case():
    mesh = table()
    medial = fj.medial_mesh(mesh, 40, samples=4000, **FEW)
    return mesh, medial, fj.skeleton(mesh, medial=medial)


@pytest.fixture(scope="module")
def capsule_case():
    mesh = trimesh.creation.capsule(height=4.0, radius=0.5, count=[16, 16])
    mesh = mesh.subdivide_to_size(0.25)
    medial = fj.medial_mesh(mesh, 30, samples=4000, **FEW)
    return mesh, medial, fj.skeleton(mesh, medial=medial)


@pytest.fixture(scope="module")
def quadruped_case():  # quadruped(32): its legs of a pair two grid cells apart
    return quadruped_rig()  # (shared with the skeleton figures' tests)


CASES = ["spot", "table_case", "capsule_case", "quadruped_case"]


def _tips(skeleton):
    return np.array([np.asarray(spine_samples(limb.spine, 2)[1])[-1] for limb in skeleton.limbs])


def test_spot_has_a_head_with_ears_and_horns_and_four_legs(spot):
    mesh, _, skeleton = spot
    tips = _tips(skeleton)
    body = [i for i, limb in enumerate(skeleton.limbs) if limb.parent == -1]
    legs = [i for i in body if tips[i, 1] < -0.6]  # y up: hooves at the bottom
    # The head: the upper limb whose region holds the snout (the foremost vertex, towards −z;
    # its spine may end at the snout or at the crown, as the medial mesh's branches go).
    heads = [i for i in body if tips[i, 1] > 0]
    snout = int(np.argmin(np.asarray(mesh.vertices)[:, 2]))
    assert len(legs) == 4 and len(heads) == 1 and len(body) == 5
    assert int(skeleton.region[snout]) == heads[0]
    # One leg per quarter: left/right (x) × front/back (z).
    assert {(bool(tips[i, 0] > 0), bool(tips[i, 2] > 0.4)) for i in legs} == {
        (a, b) for a in (False, True) for b in (False, True)
    }
    head = heads[0]
    assert len(skeleton.children(head)) == 4  # two ears, two horns, all above the snout
    assert all(tips[c, 1] > 0.6 for c in skeleton.children(head))
    # The tail is a tuft on the rump: no limb (the body holds it).
    assert skeleton.limb_at([0.0, -0.05, 1.05]) == -1
    assert skeleton.limb_at([0.0, 0.3, 0.6]) == -1  # the back
    # Leg regions are the legs: every vertex near the floor is in one.
    region = np.asarray(skeleton.region)
    low = np.asarray(mesh.vertices)[:, 1] < -0.65
    assert np.isin(region[low], legs).all()


def _chain_ends(skeleton):
    """Each of the body's limbs → the deepest limb below it (its chain's last, the tip's)."""
    ends = {}
    for k in range(len(skeleton.limbs)):
        chain = skeleton.chain(k)
        if chain[0] not in ends or len(chain) > len(skeleton.chain(ends[chain[0]])):
            ends[chain[0]] = k
    return ends


def test_table_has_four_legs(table_case):
    """Each leg a chain from the top (long and thin: split in its middle, where a knee would
    be), its last limb's tip on the floor."""
    mesh, _, skeleton = table_case
    tips = _tips(skeleton)
    ends = _chain_ends(skeleton)
    assert len(ends) == 4 and all(skeleton.limbs[top].parent == -1 for top in ends)
    feet = tips[list(ends.values())]
    assert sorted(map(tuple, np.sign(feet[:, :2]).astype(int).tolist())) == [
        (-1, -1), (-1, 1), (1, -1), (1, 1)
    ]  # fmt: skip
    assert np.all(feet[:, 2] < 0.05)  # down to the floor
    vertices, region = np.asarray(mesh.vertices), np.asarray(skeleton.region)
    assert np.all(region[vertices[:, 2] < 0.5] >= 0)  # the legs below the top
    assert np.all(region[vertices[:, 2] > 0.8] == -1)  # the top is the body


def test_quadruped_has_four_legs_a_tail_and_horns_and_poses_one_leg(quadruped_case):
    """A four-legged animal with thin legs side by side (`quadruped`): each leg a chain of
    at least two limbs (hip, then a knee: 10 radii long) whose regions hold its own foot and
    no other's, the tail and each horn a limb; one leg lifted at its hip carries its lower
    leg and leaves the three others, the tail, the horns and the body bit for bit still,
    with no torn edge at its border and the volume kept."""
    mesh, _, skeleton = quadruped_case
    tips = _tips(skeleton)
    vertices, region = np.asarray(mesh.vertices), np.asarray(skeleton.region)
    ends = _chain_ends(skeleton)
    legs = {top: end for top, end in ends.items() if tips[end, 2] < 0}  # z up: feet below
    assert {(bool(tips[e, 0] > 0.5), bool(tips[e, 1] > 0)) for e in legs.values()} == {
        (a, b) for a in (False, True) for b in (False, True)
    } and len(legs) == 4  # fmt: skip
    for top, end in legs.items():  # the foot's vertices are its own, the other feet's are not
        chain = skeleton.chain(end)
        assert len(chain) >= 2 and chain[0] == top
        foot = (vertices[:, 2] < -0.05) & (np.linalg.norm(vertices[:, :2] - tips[end, :2],
                                                          axis=1) < 0.06)  # fmt: skip
        assert foot.any() and np.all(region[foot] == end)
        assert np.all(region[(vertices[:, 2] < 0.05) & np.isin(region, chain)] != top)
    assert sum(tips[e, 0] < 0 for e in ends.values()) == 1  # the tail
    assert np.all(region[vertices[:, 0] < -0.08] >= 0)  # its tip moves with it
    horns = (vertices[:, 2] > 0.8) & (np.abs(vertices[:, 1]) > 0.06)
    assert np.all(region[horns] >= 0) and len({skeleton.chain(r)[0] for r in region[horns]}) >= 2
    # One leg lifted 30° towards the front, at its hip: its whole chain moves.
    leg = next(top for top, end in legs.items() if tips[end, 0] > 0.5 and tips[end, 1] > 0)
    chain = np.isin(region, [leg, *(k for k in range(len(skeleton.limbs))
                                    if leg in skeleton.chain(k))])  # fmt: skip
    posed = fj.pose_skeleton(mesh, skeleton, {leg: fj.LimbPose(bend=30.0)})
    moved = np.asarray(posed.vertices)
    assert np.asarray(posed.valid).all()
    assert np.array_equal(moved[~chain], vertices[~chain])
    diagonal = np.linalg.norm(np.ptp(vertices, axis=0))
    foot = (region == legs[leg]) & (vertices[:, 2] < -0.05)
    assert np.linalg.norm(moved[foot] - vertices[foot], axis=1).min() > 0.04 * diagonal
    edges = np.asarray(mesh.edges_unique)
    stretch = np.linalg.norm(moved[edges[:, 0]] - moved[edges[:, 1]], axis=1) / (
        np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1))
    # (The bend concentrated at the hip squeezes the joint's inner side: 1.59x on this leg.)
    assert stretch.max() < 2.5 and stretch.min() > 1 / 2.5
    change = float(fj.volume(moved, mesh.faces) / fj.volume(vertices, mesh.faces)) - 1
    assert abs(change) < 1e-3


def test_capsule_is_a_body_at_one_end_and_one_chain(capsule_case):
    """A tube 8 radii long: a body at one end and one limb, jointed in its middle."""
    mesh, _, skeleton = capsule_case
    assert [limb.parent for limb in skeleton.limbs] == [-1, 0]
    z = np.asarray(mesh.vertices)[:, 2]
    body = np.asarray(skeleton.region) == -1
    # The body is a cap at one end (its sphere: a radius 0.5 beyond the hemisphere at most).
    end = np.sign(np.mean(z[body]))
    assert body.any() and np.all(end * z[body] > 2.5 - 1.6)
    for limb in skeleton.limbs:
        points = np.asarray(spine_samples(limb.spine)[1])
        assert np.abs(points[:, :2]).max() < 0.05  # along the axis
        assert abs(points[-1, 2] + end * 2.5) < 0.05  # to the far end's surface
    # The joint near the middle: the second limb's region is the far half.
    far = np.asarray(skeleton.region) == 1
    assert np.all(-end * z[far] > -0.6) and np.all(-end * z[~far] < 0.6)


@pytest.mark.parametrize("case", CASES)
def test_limbs_order_joints_and_arc_length(case, request):
    _, _, skeleton = request.getfixturevalue(case)
    for i, limb in enumerate(skeleton.limbs):
        assert -1 <= limb.parent < i
        assert isinstance(limb.spine, fj.BSpline) and limb.spine.control_points.dtype == np.float64
        assert 0 < float(limb.joint) < float(limb.spine.length)
        s, points, _ = map(np.asarray, spine_samples(limb.spine, 257))
        steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
        np.testing.assert_allclose(steps, s[1] - s[0], rtol=1e-3)  # unit speed
    assert skeleton.children(-1) == tuple(
        i for i, limb in enumerate(skeleton.limbs) if limb.parent == -1
    )


@pytest.mark.parametrize("case", CASES)
def test_regions_are_contiguous_and_cut_at_the_joint(case, request):
    mesh, _, skeleton = request.getfixturevalue(case)
    welded = mesh.copy()
    welded.merge_vertices(merge_tex=True, merge_norm=True)
    region = np.asarray(skeleton.region)
    # On the welded mesh (copies of a vertex share their region).
    index = cKDTree(np.asarray(welded.vertices)).query(np.asarray(mesh.vertices))[1]
    labels = np.full(len(welded.vertices), -2)
    labels[index] = region
    adjacency = mesh_adjacency(np.asarray(welded.vertices), np.asarray(welded.faces))
    for i in range(-1, len(skeleton.limbs)):
        member = labels == i
        assert member.any()
        inside = adjacency[member][:, member]
        assert csgraph.connected_components(inside, directed=False)[0] == 1, f"region {i}"
    vertices = np.asarray(welded.vertices)
    for i, limb in enumerate(skeleton.limbs):
        member = labels == i
        parent = labels == limb.parent
        border = np.flatnonzero(member & (adjacency @ parent.astype(float) > 0))
        assert len(border)
        s, points, _ = map(np.asarray, spine_samples(limb.spine))
        along = s[cKDTree(points).query(vertices[border])[1]]
        assert along.max() <= float(limb.joint)


@pytest.mark.parametrize("case", CASES)
def test_curvature_below_the_medial_radius_and_regions_in_reach(case, request):
    mesh, medial, skeleton = request.getfixturevalue(case)
    centers, radii, _, _ = medial.numpy()
    vertices, region = np.asarray(skeleton.vertices), np.asarray(skeleton.region)
    for i, limb in enumerate(skeleton.limbs):
        _, points, curvature = map(np.asarray, spine_samples(limb.spine))
        nearest = cKDTree(centers).query(points)[1]
        assert np.max(curvature * radii[nearest]) < 1.0
        distance, foot = cKDTree(points).query(vertices[region == i])
        assert np.all(distance * curvature[foot] < 1.0), f"limb {i}: a vertex beyond reach"


_REGISTERED = {}


def _registered(case, mesh, skeleton):
    """`register_skeleton` of a case, once per worker (its skeleton and mesh: the fixtures')."""
    if case not in _REGISTERED:
        _REGISTERED[case] = fj.register_skeleton(mesh, skeleton)
    return _REGISTERED[case]


@pytest.mark.parametrize("case", ["spot", "table_case"])
def test_every_region_vertex_is_valid_at_rest(case, request):
    """A limb's spine is straight at both ends (its continuations past them, where points move
    rigidly, are its tangent lines) and bounded in curvature by the radius plus the margin:
    no vertex of its region lies near its cut locus or focal set, so a small bend moves them
    all (on spot, a circle continuing a curved start used to flag 3–13 vertices of five
    limbs at rest)."""
    mesh, _, skeleton = request.getfixturevalue(case)
    registration = _registered(case, mesh, skeleton)
    for k, limb in enumerate(skeleton.limbs):
        ends = [limb.spine.curvature_vector(s) for s in (0.0, limb.spine.length)]
        np.testing.assert_allclose(np.asarray(ends), 0.0, atol=1e-9)
        n = registration.indices[k].shape[0]
        valid = np.asarray(registration.registrations[k].valid)[:n]
        assert valid.all(), f"limb {k}: {int(np.sum(~valid))} of {n} vertices invalid at rest"


def test_limb_at_and_children(spot):
    _, _, skeleton = spot
    vertices, region = np.asarray(skeleton.vertices), np.asarray(skeleton.region)
    for i in range(len(skeleton.limbs)):
        assert skeleton.limb_at(vertices[region == i][0] + 1e-9) == i
    assert skeleton.limb_at(vertices[region == -1][0]) == -1
    head = skeleton.limbs[skeleton.children(-1)[0]]
    assert head.parent == -1
    for c in skeleton.children(0):
        assert skeleton.limbs[c].parent == 0
    with pytest.raises(ValueError, match="index"):
        skeleton.children(len(skeleton.limbs))
    with pytest.raises(ValueError, match="point"):
        skeleton.limb_at([np.nan, 0, 0])


def test_json_round_trip_is_bit_identical(spot, tmp_path):
    _, _, skeleton = spot
    path = tmp_path / "spot.json"
    fj.save_skeleton(skeleton, path)
    loaded = fj.load_skeleton(path)
    assert len(loaded.limbs) == len(skeleton.limbs)
    for a, b in zip(skeleton.limbs, loaded.limbs):
        assert a.parent == b.parent and float(a.joint) == float(b.joint)
        for x, y in zip(jax.tree.leaves(a.spine), jax.tree.leaves(b.spine)):
            assert np.array_equal(np.asarray(x), np.asarray(y))
        assert (a.spine.degree, a.spine.subdivisions) == (b.spine.degree, b.spine.subdivisions)
    assert np.array_equal(loaded.region, skeleton.region) and loaded.region.dtype == np.int32
    assert np.array_equal(loaded.vertices, skeleton.vertices)
    assert not list(tmp_path.glob(".*.tmp"))  # the temporary file was renamed


def test_bad_skeleton_files(spot, tmp_path):
    _, _, skeleton = spot
    good = tmp_path / "good.json"
    fj.save_skeleton(skeleton, good)
    data = json.loads(good.read_text())

    def write(name, value):
        path = tmp_path / name
        path.write_text(value if isinstance(value, str) else json.dumps(value))
        return path

    with pytest.raises(FileNotFoundError):
        fj.load_skeleton(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="not valid JSON"):
        fj.load_skeleton(write("broken.json", "{"))
    with pytest.raises(ValueError, match="'vertices'"):
        fj.load_skeleton(write("no_vertices.json", {k: v for k, v in data.items()
                                                     if k != "vertices"}))  # fmt: skip
    child = next(i for i, limb in enumerate(skeleton.limbs) if limb.parent >= 0)
    late = json.loads(json.dumps(data))
    late["limbs"][child]["parent"] = child
    with pytest.raises(ValueError, match="parent"):
        fj.load_skeleton(write("late_parent.json", late))
    far = json.loads(json.dumps(data))
    far["limbs"][0]["joint"] = 1e3
    with pytest.raises(ValueError, match="joint"):
        fj.load_skeleton(write("far_joint.json", far))
    wrong = json.loads(json.dumps(data))
    wrong["region"][0] = len(skeleton.limbs)
    with pytest.raises(ValueError, match="region"):
        fj.load_skeleton(write("region.json", wrong))
    from fleshing_jax._skeleton import files

    original, files.MAX_FILE_BYTES = files.MAX_FILE_BYTES, 1000
    try:
        with pytest.raises(ValueError, match="bytes"):
            fj.load_skeleton(good)
    finally:
        files.MAX_FILE_BYTES = original
    with pytest.raises(TypeError, match="Skeleton"):
        fj.save_skeleton("not a skeleton", tmp_path / "x.json")
    with pytest.raises(ValueError, match="folder"):
        fj.save_skeleton(skeleton, tmp_path / "no" / "x.json")


def test_bad_input(table_case, spot):
    mesh, medial, _ = table_case
    with pytest.raises(TypeError, match="mesh"):
        fj.skeleton("not a mesh")
    bad = mesh.copy()
    bad.vertices[0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        fj.skeleton(bad, medial=medial)
    with pytest.raises(ValueError, match="spheres"):
        fj.skeleton(mesh, spheres=1)
    with pytest.raises(TypeError, match="spheres"):
        fj.skeleton(mesh, spheres="200")
    with pytest.raises(TypeError, match="seed"):
        fj.skeleton(mesh, seed=0.5)
    with pytest.raises(TypeError, match="medial"):
        fj.skeleton(mesh, medial="medial.ma")
    with pytest.raises(ValueError, match="does not belong"):
        fj.skeleton(mesh, medial=spot[1])  # spot's medial mesh on the table
    moved = fj.MedialMesh(medial.centers * 0.3, medial.radii * 0.3, medial.edges, medial.faces)
    with pytest.raises(ValueError, match="does not belong"):
        fj.skeleton(mesh, medial=moved)


def test_data_classes_check_their_fields(spot):
    _, _, skeleton = spot
    limb = skeleton.limbs[0]
    with pytest.raises(ValueError, match="joint"):
        fj.Limb(limb.spine, float(limb.spine.length) + 1.0, -1)
    with pytest.raises(ValueError, match="joint"):
        fj.Limb(limb.spine, 0.0, -1)
    with pytest.raises(TypeError, match="spine"):
        fj.Limb("spine", 0.1, -1)
    with pytest.raises(ValueError, match="parent"):
        fj.Skeleton((fj.Limb(limb.spine, limb.joint, 0),), skeleton.region * 0, skeleton.vertices)
    with pytest.raises(ValueError, match="vertices"):
        fj.Skeleton(skeleton.limbs, skeleton.region[:-1], skeleton.vertices)
    with pytest.raises(TypeError, match="region"):
        fj.Skeleton(skeleton.limbs, np.zeros(len(skeleton.region)), skeleton.vertices)


def test_unwelded_mesh_copies_share_their_region(spot):
    mesh, medial, welded = spot
    unwelded = fj.data.spot(weld=False)
    with pytest.warns(UserWarning, match="unwelded"):
        skeleton = fj.skeleton(unwelded, medial=medial)
    assert np.array_equal(np.asarray(skeleton.vertices), np.asarray(unwelded.vertices))
    copy_of = cKDTree(np.asarray(mesh.vertices)).query(np.asarray(unwelded.vertices))[1]
    assert np.array_equal(np.asarray(skeleton.region), np.asarray(welded.region)[copy_of])


def test_a_child_with_no_room_before_it_joins_its_parent_or_takes_its_place():
    """`fj.skeleton` never returns a skeleton that `register_skeleton` refuses. Where a
    child limb's region begins where its parent's leaves the body, the shorter gives way: a
    short child (a horn's tip split from its base, the quadruped at 200 spheres) joins its
    parent's region; a short parent (the bunny's head, before its long ears) leaves its
    region to the body and its child to it. A child with room stays a limb."""
    from _posing_shapes import tube_mesh

    from fleshing_jax._skeleton.build import _room_to_bend

    mesh = tube_mesh()
    vertices = np.asarray(mesh.vertices)
    x = vertices[:, 0]
    adjacency = mesh_adjacency(vertices, np.asarray(mesh.faces))

    def straight(start, end):
        return fj.BSpline(np.linspace([start, 0, 0], [end, 0, 0], 8), subdivisions=32)

    def case(parent_end, child_start, child_from):
        region = np.full(len(x), -1)
        region[x < 2.0 - 1e-9] = 0  # a limb with no child, listed first
        region[x > 4.0 + 1e-9] = 1
        region[x > child_from + 1e-9] = 2
        limbs = [fj.Limb(straight(2.5, 0), 0.2, -1), fj.Limb(straight(3.5, parent_end), 0.5, -1),
                 fj.Limb(straight(child_start, 6), 0.3, 1)]
        return limbs, region

    def registers(limbs, region):
        fj.register_skeleton(mesh, fj.Skeleton(limbs, region, mesh.vertices), margin=0.06)

    for parent_end, child_start, parents, renumbered in (
        (6.0, 5.0, [-1, -1], {-1: -1, 0: 0, 1: 1, 2: 1}),  # the child (1 long) joins
        (4.6, 3.7, [-1, -1], {-1: -1, 0: 0, 1: -1, 2: 1}),  # the parent (1.1 long) gives way
    ):
        limbs, region = case(parent_end, child_start, 4.1)  # one ring past the parent's
        with pytest.raises(ValueError, match="no room to bend"):
            registers(limbs, region)
        fixed, fixed_region = _room_to_bend(limbs, region.copy(), vertices, adjacency)
        assert [limb.parent for limb in fixed] == parents
        assert np.array_equal(fixed_region, np.vectorize(renumbered.get)(region))
        registers(fixed, fixed_region)  # accepted
    limbs, region = case(6.0, 4.8, 5.2)  # room: kept
    kept, kept_region = _room_to_bend(limbs, region.copy(), vertices, adjacency)
    assert [limb.parent for limb in kept] == [-1, -1, 1]
    assert np.array_equal(kept_region, region)


def test_a_skeleton_built_on_its_own_medial_mesh_is_never_refused():
    """An unfitted medial mesh (`fj.skeleton`'s own) may hold a merged sphere that stands
    out of the surface: the check that a medial mesh belongs to the mesh refused spot's at
    seed 1 (a sphere 2.4 times as large as its distance to the nearest vertex). It still
    refuses one of another shape (`test_bad_input`). At that seed the head's straighter
    refit (for its ears, beyond the first spine's reach) left it a knob, and the head, its
    ears and horns stayed in the body: a gentler straightening keeps it, every vertex valid
    at rest."""
    mesh = fj.data.spot()
    skeleton = spot_skeleton(1)  # (conftest: shared with the characters' test at seed 1)
    registration = fj.register_skeleton(mesh, skeleton)
    snout = int(np.argmin(np.asarray(mesh.vertices)[:, 2]))
    head = int(skeleton.region[snout])
    assert head >= 0 and len(skeleton.children(head)) >= 2
    assert len(skeleton.limbs) >= 6
    for k in range(len(skeleton.limbs)):
        n = registration.indices[k].shape[0]
        assert np.asarray(registration.registrations[k].valid)[:n].all(), f"limb {k}"


def test_an_arm_hanging_beside_the_torso_bends_from_its_armpit():
    """An arm hanging down beside the torso, a gap of 0.02 between them below the armpit
    (cheburashka's arms): the arm's region, within its spine's reach, missed the upper
    arm's outer side and took part of the flank facing it, so the body ran down the arm to
    its wrist; levelling the border across the arm then grew over the flank as well, down
    past the hand, and was refused. The flank faces the arm's spine and stays the body's:
    the chain's top bends from the armpit (z ≈ 0.62), not halfway down the arm (0.55)."""
    from fleshing_jax._medial_axis.characters import _Builder

    b = _Builder()  # a torso of radius 0.12 along z, arms of ~0.035 at y = ±0.18
    torso = b.chain(None, [(0, 0, 0.3, 0.12), (0, 0, 0.5, 0.12), (0, 0, 0.7, 0.12)])
    for side in (-1, 1):
        b.chain(torso, [(0, side * 0.13, 0.74, 0.05), (0, side * 0.18, 0.64, 0.04),
                        (0, side * 0.18, 0.52, 0.036), (0, side * 0.18, 0.4, 0.033),
                        (0, side * 0.18, 0.3, 0.033)])  # fmt: skip
    medial = b.medial()
    mesh = medial.envelope(34)  # 8,686 vertices; the gap 1.1 grid cells
    skeleton = fj.skeleton(mesh, medial=medial)
    tops = skeleton.children(-1)
    assert len(tops) == 2
    for top in tops:
        limb = skeleton.limbs[top]
        assert float(np.asarray(limb.spine(limb.joint))[2]) > 0.58, top


def test_a_head_bends_its_unposed_ears_and_horns_with_it(spot):
    """Spot's head has four children (ears, horns) a fifth of the way along its spine. Posed
    alone, it is registered with them (`WholeLimb`): its zone runs on past them, its exact
    range grows, and they ride on its map. Posed with one of them, its zone ends before them."""
    mesh, _, skeleton = spot
    head = next(k for k, limb in enumerate(skeleton.limbs) if len(skeleton.children(k)) > 1)
    registration = _registered("spot", mesh, skeleton)
    whole = registration.wholes[head]
    below = sorted(whole.below)
    assert below == sorted(skeleton.children(head)), below
    region = np.asarray(skeleton.region)
    np.testing.assert_array_equal(np.sort(np.asarray(whole.indices)), np.flatnonzero(np.isin(
        region, [head, *below])))
    assert np.asarray(whole.registration.valid)[: whole.indices.shape[0]].all()
    # Its children within its own reach about its spine (else carried rigidly: cheburashka's
    # ears, `test_real_meshes`).
    own = np.asarray(registration.indices[head]).shape[0]
    reach = [np.linalg.norm(np.asarray(r.offset)[:n], axis=1).max() for r, n in (
        (registration.registrations[head], own), (whole.registration, whole.indices.shape[0]))]
    assert reach[1] <= reach[0], reach
    alone = float(fj.joint_range(registration, head, 0.0))
    with_ears = float(fj.joint_range(registration, head, 0.0, children_posed=True))
    assert alone > with_ears + 2, (alone, with_ears)  # (37° and 31° on this 60-sphere rig)
    bend = 0.5 * (alone + with_ears)
    rest = np.asarray(mesh.vertices)
    posed = fj.pose_skeleton(registration, skeleton, {head: fj.LimbPose(bend)})
    moved = np.asarray(posed.vertices)
    assert np.asarray(posed.valid).all()
    np.testing.assert_array_equal(moved[region == -1], rest[region == -1])  # the body still
    ears = np.isin(region, below)
    assert np.linalg.norm(moved[ears] - rest[ears], axis=1).min() > 0  # carried by the map
    edges = mesh.edges_unique
    stretch = (np.linalg.norm(moved[edges[:, 0]] - moved[edges[:, 1]], axis=1)
               / np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1))
    assert stretch.max() < 2.5, stretch.max()
    volume = trimesh.Trimesh(moved, mesh.faces, process=False).volume
    assert abs(volume / mesh.volume - 1) < 1e-3
    # An ear posed too (by nothing): the head's zone ends before the ears, past its range.
    both = fj.pose_skeleton(registration, skeleton,
                            {head: fj.LimbPose(bend), below[0]: fj.LimbPose(0.0)})
    assert not np.asarray(both.valid)[region == head].all()


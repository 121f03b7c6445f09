"""A skeleton from chains of joints a user places (`fj.skeleton(mesh, chains=…)`)."""

import warnings

import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._medial_axis.animal import quadruped

# On `quadruped(32)` (z up): a front leg hip → knee → foot, a hind leg likewise, the tail,
# and the head from the base of its neck.
CHAINS = [
    [(0.75, 0.08, 0.40), (0.75, 0.08, 0.17), (0.75, 0.08, -0.06)],
    [(0.25, -0.08, 0.40), (0.25, -0.08, 0.17), (0.25, -0.08, -0.06)],
    [(0.10, 0.0, 0.52), (-0.08, 0.0, 0.50)],
    [(0.86, 0.0, 0.50), (0.95, 0.0, 0.60)],
]


@pytest.fixture(scope="module")
def given():
    mesh = quadruped(32)
    return mesh, fj.skeleton(mesh, chains=CHAINS)


@pytest.fixture(scope="module")
def legs(given):
    """The legs' and the tail's chains, the head left in the body. Posed, every limb's region
    is padded to the largest's bucket: the legs' 286 vertices to 384 (the head's 532 vertices
    compiled a pose of 768 for these tests alone: 12.6 s), as the quadruped's own rig in
    `test_skeleton` (`_skeleton_rigs`: its largest region 372 vertices): the same programs."""
    mesh, _ = given
    return mesh, fj.skeleton(mesh, chains=CHAINS[:3])


def test_each_chain_is_its_limbs_cut_at_its_points(given):
    mesh, skeleton = given
    assert [limb.parent for limb in skeleton.limbs] == [-1, 0, -1, 2, -1, -1]
    vertices, region = np.asarray(mesh.vertices), np.asarray(skeleton.region)
    for top, foot_at in ((0, CHAINS[0][-1]), (2, CHAINS[1][-1])):
        # The foot in the chain's last limb, the thigh above the knee in its first.
        foot = np.linalg.norm(vertices - foot_at, axis=1) < 0.06
        assert foot.any() and np.all(region[foot] == top + 1)
        knee = np.asarray(CHAINS[top // 2][1])
        leg = np.linalg.norm(vertices[:, :2] - knee[:2], axis=1) < 0.06
        assert np.all(region[leg & (vertices[:, 2] > knee[2] + 0.06) & (vertices[:, 2] < 0.3)]
                      == top)  # fmt: skip
        assert np.all(region[leg & (vertices[:, 2] < knee[2] - 0.06)] == top + 1)
    assert np.all(region[vertices[:, 0] < -0.05] == 4)  # the tail's end
    assert np.all(region[vertices[:, 2] > 0.75] == 5)  # the head's top, horns and all
    # Each spine runs from inside its parent through its points to the surface.
    for limb in skeleton.limbs:
        assert 0 < float(limb.joint) < float(limb.spine.length)


def test_joints_on_a_mirror_plane_or_a_tube_s_axis_are_inside():
    # Rays along the model's axes ran through the tube's seams of edges from its axis (and
    # a mirrored model's from its mirror plane): every point on the axis was outside.
    from fleshing_jax._skeleton.inside import moved_inside

    angle = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    tube = fj.extrusion(0.3 * np.stack([np.cos(angle), np.sin(angle)], 1), 6.0, 60)
    vertices, faces = np.asarray(tube.vertices), np.asarray(tube.faces)
    axis = np.stack([np.linspace(0.1, 5.9, 30), np.zeros(30), np.zeros(30)], 1)
    assert np.all(moved_inside(axis, vertices, faces)[1] == 0)
    assert np.all(moved_inside(axis + [0, 0.31, 0], vertices, faces)[1] > 0)


def test_a_joint_off_its_limb_s_axis_is_moved_onto_it_across_the_limb():
    # A knee placed at the front of a leg (a third of the way across), as animators do: its
    # distance to the surface was the leg's radius there, and the leg's region began far
    # below it. Centred joints, and one just off the axis, stay where they are placed.
    from fleshing_jax._skeleton.inside import bisectors, on_axis

    angle = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    tube = fj.extrusion(0.3 * np.stack([np.cos(angle), np.sin(angle)], 1), 6.0, 60)
    vertices, faces = np.asarray(tube.vertices), np.asarray(tube.faces)
    joints = np.array([[2.0, 0.2, 0.0], [3.0, -0.1, 0.15], [4.0, 0.05, 0.0], [5.0, 0.0, 0.0]])
    before, after = joints - [0.5, 0.0, 0.0], joints + [0.5, 0.0, 0.1]
    axes = bisectors(before, joints, after)
    assert np.allclose(np.linalg.norm(axes, axis=1), 1.0)
    with pytest.warns(UserWarning, match=r"`bones`: 2 joints off their limb's axis .* moved "
                      r"across the limb to its middle \(knee by 0\.2, elbow by 0\.18"):
        moved = on_axis(joints, axes, vertices, faces, ["knee", "elbow", "ankle", "hip"], "bones")
    # Across the limb only: no joint slides along it.
    assert np.allclose(np.einsum("ij,ij->i", moved - joints, axes), 0.0, atol=1e-12)
    assert np.all(np.linalg.norm(moved[:2, 1:], axis=1) < 0.02)  # on the 16-gon's axis
    assert np.array_equal(moved[2:], joints[2:])


def _turned(profile, x):
    """Points on the surface of revolution about the x axis of radius `profile(x)`."""
    angle = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    r = profile(x)
    return np.stack([np.repeat(x, 24), np.outer(r, np.cos(angle)).ravel(),
                     np.outer(r, np.sin(angle)).ravel()], 1)


def test_a_bone_from_a_head_s_middle_leaves_it_at_its_ear_s_root():
    # A bone from the head's middle to an ear's tip (a Blender horse's and kangaroo's ears):
    # its region was cut at its head, the half of the head on the ear's side, and the other
    # ear's bone got 4 vertices. It leaves the head at the ear's root, the waist a skin
    # makes there; a horn modelled as a cone from the head's middle has none, and a tail's
    # bone from its root (as thick) is not cut at a waist on its way.
    from scipy.spatial import cKDTree

    from fleshing_jax._skeleton.given import leaves_part

    x = np.linspace(-0.1, 0.3, 401)
    head = np.sqrt(np.clip(0.01 - x**2, 0.0, None))
    ear = np.interp(x, [0.09, 0.105, 0.115, 0.13], [0.0436, 0.012, 0.012, 0.035])
    eared = np.where(x < 0.09, head, ear)
    horned = np.where(x < 0.06, head, np.interp(x, [0.06, 0.3], [0.08, 0.005]))
    bone = np.array([[0.0, 0.0, 0.0], [0.28, 0.0, 0.0]])
    root = leaves_part(bone, cKDTree(_turned(lambda t: np.interp(t, x, eared), x)))
    assert 0.1 < root[0] < 0.12 and np.allclose(root[1:], 0.0)
    cone = cKDTree(_turned(lambda t: np.interp(t, x, horned), x))
    assert np.array_equal(leaves_part(bone, cone), bone[0])
    tail = cKDTree(_turned(lambda t: np.interp(t, x, ear), x))  # a tube, waisted
    assert np.array_equal(leaves_part(bone, tail), bone[0])


def test_only_bones_from_a_shared_point_are_cut_where_they_leave_its_part(monkeypatch):
    # `bone_limbs` asks `chain_limb` for the cut at the part's waist (`at_root`) for the bones
    # that start at one point (a head's ears), not for a lone chain's root (a user's bone
    # placed where its limb leaves the body: a tail's, which hugs its curved surface).
    from fleshing_jax._skeleton import bones

    asked = {}

    def chain_limb(points, i, parent, *args, at_root=False):
        asked[args[-1]] = at_root
        return None

    monkeypatch.setattr(bones, "chain_limb", chain_limb)
    angle = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    tube = fj.extrusion(0.3 * np.stack([np.cos(angle), np.sin(angle)], 1), 6.0, 60)
    vertices, faces = np.asarray(tube.vertices), np.asarray(tube.faces)
    heads = np.array([[0.5, 0, 0], [2.0, 0, 0], [2.0, 0, 0], [4.0, 0, 0]])
    tails = np.array([[2.0, 0, 0], [3.5, 0.1, 0], [3.5, -0.1, 0], [5.5, 0, 0]])
    checked = bones.check_bones((heads, tails, np.array([-1, 0, 0, 0])), vertices, faces)
    bones.bone_limbs(checked, vertices, None, 0.01)
    assert asked == {"bone 0": False, "bone 1": True, "bone 2": True, "bone 3": False}


def test_joints_just_past_the_surface_are_moved_to_the_middle_of_the_shape(given):
    # An armature's tip at the sole or a joint where a subdivided skin shrank away from its
    # cage lies just outside: moved to the centre of the largest ball inside touching its
    # closest surface point; far outside, refused.
    from fleshing_jax._skeleton.inside import moved_inside

    angle = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    tube = fj.extrusion(0.3 * np.stack([np.cos(angle), np.sin(angle)], 1), 6.0, 60)
    past = np.array([(6.01, 0.0, 0.0), (3.0, 0.32, 0.01), (3.0, 0.0, 0.0)])
    moved, outside, diameter = moved_inside(past, np.asarray(tube.vertices), tube.faces)
    # Near the middle of the 16-sided tube (inscribed radius 0.294), the point inside kept.
    assert np.linalg.norm(moved[:2, 1:], axis=1) == pytest.approx([0, 0], abs=0.1)
    assert moved[0, 0] == pytest.approx(5.7, abs=0.1) and moved[1, 0] == 3.0
    assert np.array_equal(moved[2], past[2])
    np.testing.assert_allclose(outside, [0.01, 0.02, 0], atol=0.01)
    assert np.all(diameter[:2] > 0.4) and diameter[2] == np.inf
    # Tips: one 0.01 within the end moved as one 0.01 past it, one on the axis kept.
    tips, _, _ = moved_inside([(5.99, 0, 0), (3.0, 0, 0)], np.asarray(tube.vertices),
                              tube.faces, tips=[True, True])
    np.testing.assert_allclose(tips, [moved[0], (3.0, 0, 0)], atol=1e-6)
    mesh, _ = given
    vertices = np.asarray(mesh.vertices)
    foot = (np.linalg.norm(vertices[:, :2] - (0.75, 0.08), axis=1) < 0.06) & (
        vertices[:, 2] < -0.03)
    # The tip 0.01 below the foot's sole (z = -0.1), then 0.02 above it: a tip's distance to
    # the surface is its radius, and that left the leg no region.
    for z in (-0.11, -0.08):
        sole = [list(CHAINS[0][:2]) + [(0.75, 0.08, z)]]
        with pytest.warns(UserWarning, match=r"1 points .* moved to the middle .*chains\[0\]\[2\]"):
            skeleton = fj.skeleton(mesh, chains=sole)
        region = np.asarray(skeleton.region)
        assert len(skeleton.limbs) == 2 and foot.any() and np.all(region[foot] == 1)


def test_parts_pushed_through_the_body_ride_on_the_nearest_limb(given):
    # An eye pushed through the head: medial meshes refuse the two crossing shells; a
    # skeleton sets the eye apart and gives each of its vertices the region of the nearest
    # vertex of the rest, whose regions are those found without it.
    import trimesh
    from scipy.spatial import cKDTree

    mesh, alone = given
    vertices = np.asarray(mesh.vertices)
    side = vertices[np.asarray(alone.region) == 5]
    ball = trimesh.creation.icosphere(2, 0.03)
    eye = (np.concatenate([vertices, ball.vertices + side[np.argmax(side[:, 1])]]),
           np.concatenate([mesh.faces, ball.faces + len(vertices)]))
    with pytest.raises(ValueError, match="shells 0 and 1 .* cross each other"):
        fj.medial_mesh(eye, 8)
    with pytest.warns(UserWarning, match=r"shells \[1\] .* cross a larger one: 320 faces"):
        ridden = fj.skeleton(eye, chains=CHAINS)
    n = len(vertices)
    assert np.array_equal(np.asarray(ridden.region)[:n], np.asarray(alone.region))
    nearest = cKDTree(vertices).query(eye[0][n:])[1]
    assert np.array_equal(np.asarray(ridden.region)[n:], np.asarray(alone.region)[nearest])
    assert set(np.asarray(ridden.region)[n:].tolist()) == {5}


def test_a_chain_posed_at_its_hip_and_knee_keeps_the_rest_still(legs):
    mesh, skeleton = legs
    _check_leg_posed(mesh, skeleton, {0: fj.LimbPose(30.0), 1: fj.LimbPose(45.0)}, [0, 1])


def _check_leg_posed(mesh, skeleton, poses, moving, registration=None):
    """Posed by `poses` (on `registration` where the test made one, else on `mesh`): every
    vertex valid, only the limbs `moving` moved (the rest bit for bit), the first chain's foot
    moved by 4 % of the diagonal, the volume kept to 0.1 %."""
    vertices, region = np.asarray(mesh.vertices), np.asarray(skeleton.region)
    posed = fj.pose_skeleton(mesh if registration is None else registration, skeleton, poses)
    moved = np.asarray(posed.vertices)
    assert np.asarray(posed.valid).all()
    inside = np.isin(region, moving)
    assert np.array_equal(moved[~inside], vertices[~inside])
    diagonal = np.linalg.norm(np.ptp(vertices, axis=0))
    foot = np.linalg.norm(vertices - CHAINS[0][-1], axis=1) < 0.05
    assert np.linalg.norm(moved[foot] - vertices[foot], axis=1).min() > 0.04 * diagonal
    change = float(fj.volume(moved, mesh.faces) / fj.volume(vertices, mesh.faces)) - 1
    assert abs(change) < 1e-3


def test_bad_chains_are_refused_by_name(given):
    mesh, _ = given
    leg = CHAINS[0]
    cases = [
        ([], TypeError, "`chains`"),
        ("leg", TypeError, "`chains`"),
        ([[leg[0]]], ValueError, r"`chains\[0\]` must hold at least 2 points"),
        ([[leg[0], leg[0], leg[2]]], ValueError, r"points 0 and 1 are the same"),
        ([leg, [leg[0], (0.75, 0.08, -0.5)]], ValueError, r"`chains\[1\]\[1\]`.*outside"),
        ([[leg[0], (np.nan, 0, 0)]], ValueError, r"`chains\[0\]` must be finite"),
        # From the middle of the body towards its flank: less than a radius to bend.
        ([[(0.5, 0.0, 0.47), (0.5, 0.02, 0.47)]], ValueError, r"`chains\[0\]`.*no part"),
    ]
    for chains, error, message in cases:
        with pytest.raises(error, match=message):
            fj.skeleton(mesh, chains=chains)
    medial = fj.MedialMesh(np.zeros((2, 3)), np.ones(2), np.array([[0, 1]]))
    with pytest.raises(ValueError, match="`medial` and `chains`"):
        fj.skeleton(mesh, chains=CHAINS, medial=medial)


def test_merge_gives_a_limb_s_region_and_children_to_its_parent(given):
    mesh, skeleton = given
    region = np.asarray(skeleton.region)
    merged = skeleton.merge(0)  # the front leg's hip: the knee's limb hangs from the body
    assert [limb.parent for limb in merged.limbs] == [-1, -1, 1, -1, -1]
    new = np.asarray(merged.region)
    assert np.all(new[region == 0] == -1) and np.all(new[region == 1] == 0)
    assert np.all(new[region >= 2] == region[region >= 2] - 1)
    assert merged.limbs[0].spine is skeleton.limbs[1].spine
    for bad in (-1, 6, 1.0, True):
        with pytest.raises(ValueError, match="`index`"):
            skeleton.merge(bad)


def test_a_limb_a_bend_would_not_visibly_move_joins_its_parent(given):
    """`fj.skeleton` never returns a limb of a few vertices (an insect's limbs of 3–33
    vertices moved nothing a user sees) nor one whose vertices all lie near its joint."""
    from fleshing_jax._skeleton.visible import FEWEST, visible

    mesh, skeleton = given
    vertices, region = np.asarray(mesh.vertices), np.asarray(skeleton.region).copy()
    tail = np.flatnonzero(region == 4)
    region[tail[FEWEST - 1 :]] = -1  # the tail keeps FEWEST − 1 vertices
    limbs, kept = visible(list(skeleton.limbs), region, vertices)
    assert len(limbs) == 5 and np.all(kept[tail] == -1) and np.all(kept[region == 5] == 4)
    # The legs, with their knees, are kept as they are.
    limbs, kept = visible(list(skeleton.limbs), np.asarray(skeleton.region), vertices)
    assert len(limbs) == 6 and np.array_equal(kept, np.asarray(skeleton.region))


def _bones(chains):
    """The armature of `chains`: one bone per pair of consecutive points, each chain's first
    a root bone, the others connected to the one before."""
    heads, tails, parents = [], [], []
    for chain in chains:
        for i in range(len(chain) - 1):
            parents.append(len(heads) - 1 if i else -1)
            heads.append(chain[i])
            tails.append(chain[i + 1])
    return np.array(heads), np.array(tails), np.array(parents)


def test_bones_of_chains_of_joints_are_the_chains_limbs(given):
    mesh, skeleton = given
    bones = fj.skeleton(mesh, bones=_bones(CHAINS))
    assert [limb.parent for limb in bones.limbs] == [limb.parent for limb in skeleton.limbs]
    assert np.array_equal(np.asarray(bones.region), np.asarray(skeleton.region))
    for ours, theirs in zip(bones.limbs, skeleton.limbs, strict=True):
        assert np.array_equal(ours.spine.control_points, theirs.spine.control_points)
        assert float(ours.joint) == float(theirs.joint)


def test_a_bone_starting_inside_its_parent_hangs_from_it():
    """The shin's head below the thigh's tail: a chain of its own, cut out of the thigh's
    region; a bone whose parent's region does not hold its head (a rig's root bone) hangs
    from the nearest ancestor's that does: the body for a leg under the tail bone."""
    mesh = quadruped(32)
    heads = np.array([(0.75, 0.08, 0.40), (0.75, 0.08, 0.15), (0.10, 0.0, 0.52),
                      (0.25, -0.08, 0.40)])  # fmt: skip
    tails = np.array([(0.75, 0.08, 0.17), (0.75, 0.08, -0.06), (-0.08, 0.0, 0.50),
                      (0.25, -0.08, -0.06)])  # fmt: skip
    skeleton = fj.skeleton(mesh, bones=(heads, tails, np.array([-1, 0, -1, 2])))
    assert [limb.parent for limb in skeleton.limbs] == [-1, 0, -1, -1]
    vertices, region = np.asarray(mesh.vertices), np.asarray(skeleton.region)
    for k in (1, 3):
        foot = np.linalg.norm(vertices - tails[k], axis=1) < 0.06
        assert foot.any() and np.all(region[foot] == k)
    leg = fj.skeleton(mesh, bones=(heads[:2], tails[:2], np.array([-1, 0])))
    assert np.array_equal(np.asarray(leg.region) == 1, region == 1)
    # Registered whole (its largest region, the hind leg's 534 vertices, padded to spot's 768:
    # in float64 the skeleton tests' compiled registration; the leg alone padded to 256,
    # programs of its own). In float64 only: a float32 registration keeps its dtype in
    # `test_a_split_limb_poses_with_the_rest_still` (padded to 384); padded to 768 it
    # compiled a registration no other test used.
    registration = fj.register_skeleton(mesh, skeleton, dtype=np.float64)
    assert registration.vertices.dtype == np.float64
    # Each limb named as its bone ("bone b" without names): a limb index's stand-in.
    assert float(fj.joint_range(registration, "bone 3")) == float(
        fj.joint_range(registration, 3))
    with pytest.raises(ValueError, match=r"`limb`: no limb of this registration is named 'x'"):
        fj.joint_range(registration, "x")


def test_an_armature_s_limbs_are_named_as_its_bones(given, tmp_path):
    from fleshing_jax._skeleton.posing import check_poses

    mesh, _ = given
    heads, tails, parents = _bones(CHAINS)
    names = ["hip", "knee", "rump", "hock", "tail", "neck"]
    skeleton = fj.skeleton(mesh, bones=(heads, tails, parents, names))
    assert skeleton.names == tuple(names) and skeleton.index("hock") == 3
    assert skeleton.children("hip") == (1,)
    pose = fj.LimbPose(30.0)
    assert list(check_poses({"hock": pose, 0: pose}, skeleton)) == [0, 3]
    for poses, message in [({"hoof": pose}, r"no limb of this skeleton is named 'hoof' "
                            r"\(named: hip, knee"),
                           ({"hock": pose, 3: pose}, "limb 3 is posed twice")]:
        with pytest.raises(ValueError, match=message):
            check_poses(poses, skeleton)
    # Split, merged, saved and loaded: the names go with their limbs.
    split = skeleton.split(0, at=float(skeleton.limbs[0].joint) + 0.15)
    assert split.names == ("hip", "hip.1", *names[1:]) and split.merge(1).names == skeleton.names
    fj.save_skeleton(split, tmp_path / "named.json")
    assert fj.load_skeleton(tmp_path / "named.json").names == split.names
    limbs = skeleton.limbs
    with pytest.raises(ValueError, match="two limbs are named 'hip'"):
        fj.Skeleton((limbs[0], fj.Limb(limbs[1].spine, limbs[1].joint, 0, "hip")),
                    np.zeros(len(mesh.vertices), int), mesh.vertices)
    with pytest.raises(ValueError, match=r"`bones\[3\]` \(the names\) must be distinct"):
        fj.skeleton(mesh, bones=(heads, tails, parents, ["hip"] * len(heads)))


def test_a_bone_from_the_body_s_middle_lies_inside_it(given):
    # A rig's bone from the body's middle to the tail's base (as from a rump), then the tail
    # bone: the first took the body's back and left the tail bone nothing; the deeper of the
    # two (the first) now lies inside the body, and the tail bone is the tail's limb.
    mesh, skeleton = given
    heads = np.array([(0.3, 0.0, 0.45), CHAINS[2][0]])
    tails = np.array([CHAINS[2][0], CHAINS[2][1]])
    with pytest.warns(UserWarning, match=r"1 bones lie inside the body \(bone 0\)"):
        tail = fj.skeleton(mesh, bones=(heads, tails, np.array([-1, 0])))
    region = np.asarray(tail.region)
    assert [limb.parent for limb in tail.limbs] == [-1]
    assert np.array_equal(region == 0, np.asarray(skeleton.region) == 4)  # the chains' tail


def test_the_deeper_of_a_bone_left_nothing_and_the_limb_before_it_joins_the_body(monkeypatch):
    # A Blender cow's bone from the rump's middle took the rump's back and a little of the
    # tail; the tail bone after it got nothing. The deeper of the two at its head (the rump
    # bone) joins the body and the limbs are found again: the tail bone is then a limb.
    import trimesh

    from fleshing_jax._skeleton import build

    ball = trimesh.creation.icosphere(2, 1.0)
    heads, tails = np.array([(0.0, 0, 0), (0.9, 0, 0)]), np.array([(0.9, 0, 0), (0.98, 0, 0)])
    found = []

    def bone_limbs(checked, vertices, adjacency, margin, body=frozenset()):
        found.append(set(body))
        if 0 in body:  # (limbs, region, names, kept, before)
            return ["tail"], None, ["bone 1"], [1], {}
        return ["rump"], None, ["bone 0"], [0], {1: 0}

    monkeypatch.setattr(build, "bone_limbs", bone_limbs)
    monkeypatch.setattr(build, "_conflict", lambda *args: None)
    checked = (heads, tails, np.array([-1, 0]), ["bone 0", "bone 1"])
    with pytest.warns(UserWarning, match=r"1 bones lie inside the body \(bone 0\)"):
        limbs, _, names = build._bones_in_the_body(checked, np.asarray(ball.vertices), None, 0)
    assert limbs == ["tail"] and names == ["bone 1"] and found == [set(), {0}]


def test_a_bone_left_nothing_above_a_child_with_no_room_is_settled_first(monkeypatch):
    # A dinosaur's hip bone from the pelvis's middle took the thigh's part (the thigh got
    # nothing), and below them the shin leaves the foot no room. The cause is above: the
    # deeper of the hip bone and the thigh joins the body first (the hip bone), and the limbs
    # found again are the thigh, the shin and the foot; the shin, settled first, went into
    # the body instead.
    import trimesh

    from fleshing_jax._skeleton import build

    ball = trimesh.creation.icosphere(2, 1.0)
    x = np.array([0.0, 0.5, 0.7, 0.85, 0.95])
    heads, tails = np.c_[x[:-1], 0 * x[:-1], 0 * x[:-1]], np.c_[x[1:], 0 * x[1:], 0 * x[1:]]
    found = []

    def bone_limbs(checked, vertices, adjacency, margin, body=frozenset()):
        found.append(set(body))
        if 0 in body:  # (limbs, region, labels, kept, before)
            return ["thigh", "shin", "foot"], None, ["bone 1", "bone 2", "bone 3"], [1, 2, 3], {}
        return ["hip", "shin", "foot"], None, ["bone 0", "bone 2", "bone 3"], [0, 2, 3], {1: 0}

    monkeypatch.setattr(build, "bone_limbs", bone_limbs)
    # (The shin, limb 1 while the hip bone is a limb, leaves its child the foot no room.)
    monkeypatch.setattr(build, "_conflict", lambda *args: None if found[-1] else (1, 2, 0.0))
    checked = (heads, tails, np.array([-1, 0, 1, 2]), [f"bone {b}" for b in range(4)])
    with pytest.warns(UserWarning, match=r"1 bones lie inside the body \(bone 0\)"):
        limbs, _, _ = build._bones_in_the_body(checked, np.asarray(ball.vertices), None, 0)
    assert limbs == ["thigh", "shin", "foot"] and found == [set(), {0}]


def test_a_short_bone_bent_into_its_limb_goes_before_the_deeper_thigh(monkeypatch):
    # An insect's coxa bone from the thorax's middle to the hip, shorter than the thorax is
    # thick, then the thigh up to the knee: the coxa's spine through the bent hip took part of
    # the leg (its region begins past its tail), the thigh little, and the thigh leaves the
    # shin no room. The thigh's joint is deeper in the body than the coxa's, and it went into
    # the body (the leg's thigh lost); the coxa, which lost its bone, goes first now.
    import trimesh

    from fleshing_jax._skeleton import build
    from fleshing_jax._skeleton.skeleton import Limb

    ball = trimesh.creation.icosphere(2, 1.0)
    joints = np.array([(0.0, 0, 0), (0.6, 0, 0), (0.75, 0, 0.35), (0.9, 0, 0.1)])
    heads, tails = joints[:-1], joints[1:]

    def limb(a, b, joint):
        return Limb(fj.BSpline(np.linspace(a, b, 6)), joint)

    coxa, thigh = limb(joints[0], (1.0, 0, 0), 0.8), limb(joints[1], joints[2], 0.05)
    shin = limb(joints[2], joints[3], 0.05)
    found = []

    def bone_limbs(checked, vertices, adjacency, margin, body=frozenset()):
        found.append(set(body))
        if body:  # (limbs, region, labels, kept, before)
            return [thigh, shin], None, ["bone 1", "bone 2"], [1, 2], {}
        return [coxa, thigh, shin], None, ["bone 0", "bone 1", "bone 2"], [0, 1, 2], {}

    monkeypatch.setattr(build, "bone_limbs", bone_limbs)
    monkeypatch.setattr(build, "_conflict", lambda *args: None if found[-1] else (1, 2, 0.0))
    checked = (heads, tails, np.array([-1, 0, 1]), [f"bone {b}" for b in range(3)])
    with pytest.warns(UserWarning, match=r"1 bones lie inside the body \(bone 0\)"):
        build._bones_in_the_body(checked, np.asarray(ball.vertices), None, 0)
    assert found == [set(), {0}]


def test_bad_bones_are_refused_by_name(given):
    mesh, _ = given
    heads, tails, parents = _bones(CHAINS)
    names = [f"b{k}" for k in range(len(heads))]
    flank = (np.array([(0.5, 0.0, 0.47)]), np.array([(0.5, 0.02, 0.47)]), np.array([-1]))
    cases = [
        ("bones", TypeError, "`bones` must be a tuple"),
        ((heads, tails), TypeError, "`bones` must be a tuple"),
        ((heads, tails[:-1], parents), ValueError, r"`bones\[1\]`.*shape"),
        ((heads, tails, parents[:-1]), ValueError, r"`bones\[2\]`"),
        ((heads, tails, parents + 0.5), ValueError, r"`bones\[2\]`"),
        ((heads, tails, np.r_[parents[:-1], 9]), ValueError, r"bone 5's parent 9 is not"),
        ((heads, tails, np.r_[3, parents[1:3], 1, parents[4:]]), ValueError,
         "cycle: bone 0 → bone 3 → bone 1 → bone 0"),
        ((heads, np.r_[tails[:2], heads[2:3], tails[3:]], parents, names), ValueError,
         r"bone 2 \('b2'\) has zero length"),
        ((heads, np.r_[tails[:1], [(0.75, 0.08, -0.5)], tails[2:]], parents), ValueError,
         r"bone 1's tail .* outside the mesh"),
        (flank, ValueError, "bone 0 gets no part of the surface .* nor does any other"),
    ]  # fmt: skip
    for bones, error, message in cases:
        with pytest.raises(error, match=message):
            fj.skeleton(mesh, bones=bones)
    # The knee's bone from just below the hip: no room to bend the thigh, which joins the
    # body (an armature's pelvis bone alike); the shin a limb from the body.
    short = (heads[:2] + [(0, 0, 0), (0, 0, 0.2)], tails[:2] + [(0, 0, 0.2), (0, 0, 0)],
             parents[:2])
    with pytest.warns(UserWarning, match=r"1 bones lie inside the body \(bone 0\)"):
        shin = fj.skeleton(mesh, bones=short)
    assert [limb.parent for limb in shin.limbs] == [-1]
    foot = np.linalg.norm(np.asarray(mesh.vertices) - tails[1], axis=1) < 0.06
    assert foot.any() and np.all(np.asarray(shin.region)[foot] == 0)
    with pytest.raises(ValueError, match="`chains` and `bones` exclude"):
        fj.skeleton(mesh, chains=CHAINS, bones=(heads, tails, parents))


THIGH = (0.75, 0.08, 0.29)  # the front leg's thigh (limb 0), halfway from hip to knee


@pytest.fixture(scope="module")
def split(legs):
    mesh, skeleton = legs
    return skeleton.split(0, THIGH)


def test_split_makes_the_part_past_a_point_a_child_limb(legs, split):
    mesh, skeleton = legs
    # The knee's limb (its joint below the split) goes to the new limb; the rest renumbered.
    assert [limb.parent for limb in split.limbs] == [-1, 0, 1, -1, 3, -1]
    vertices, region, new = (np.asarray(a) for a in (mesh.vertices, skeleton.region,
                                                     split.region))  # fmt: skip
    assert np.array_equal(new[region >= 1], region[region >= 1] + 1)
    thigh = region == 0
    assert np.all(new[thigh & (vertices[:, 2] > THIGH[2] + 0.03)] == 0)
    assert np.all(new[thigh & (vertices[:, 2] < THIGH[2] - 0.03)] == 1)
    assert np.isin(new[thigh], [0, 1]).all()
    # The new limb bends on the thigh's spine from the split on.
    assert split.limbs[1].spine is skeleton.limbs[0].spine
    at = float(split.limbs[1].joint)
    assert np.linalg.norm(np.asarray(skeleton.limbs[0].spine(at)) - THIGH) < 0.01
    assert np.array_equal(np.asarray(skeleton.split(0, at=at).region), new)
    merged = split.merge(1)
    assert np.array_equal(np.asarray(merged.region), region)
    assert [limb.parent for limb in merged.limbs] == [limb.parent for limb in skeleton.limbs]


def test_a_split_limb_poses_with_the_rest_still(legs, split):
    mesh, _ = legs
    for dtype in (np.float32, np.float64):
        registration = fj.register_skeleton(mesh, split, dtype=dtype)
        assert registration.vertices.dtype == dtype
    # The lower thigh bent: it and the knee's limb below it move (float64's registration).
    _check_leg_posed(mesh, split, {1: fj.LimbPose(30.0)}, [1, 2], registration)


def test_bad_splits_are_refused_by_name(given):
    _, skeleton = given
    cases = [
        ((6, THIGH), {}, "`index`"),
        ((0,), {}, "`point` or its arc length `at`"),
        ((0, THIGH), {"at": 0.2}, "`point` or its arc length `at`"),
        ((0, (0.75, 0.3, 0.29)), {}, "outside limb 0"),
        ((0, (0.75, 0.08, 0.39)), {}, "too near an end of limb 0"),
        ((1, (0.75, 0.08, -0.085)), {}, "too near an end of limb 1"),
        ((0, (0.75, 0.08)), {}, r"`point` must have shape"),
        ((0, [THIGH, THIGH]), {}, r"`point` must have shape \(3,\)"),
        ((0,), {"at": -1.0}, "`at`"),
    ]
    for args, kwargs, message in cases:
        with pytest.raises(ValueError, match=message):
            skeleton.split(*args, **kwargs)


def test_bones_and_split_skeletons_save_and_load(given, split, tmp_path):
    mesh, _ = given
    bones = fj.skeleton(mesh, bones=_bones(CHAINS))
    for k, skeleton in enumerate((bones, split)):
        path = tmp_path / f"skeleton{k}.json"
        fj.save_skeleton(skeleton, path)
        loaded = fj.load_skeleton(path)
        assert np.array_equal(np.asarray(loaded.region), np.asarray(skeleton.region))
        for ours, theirs in zip(loaded.limbs, skeleton.limbs, strict=True):
            assert ours.parent == theirs.parent and float(ours.joint) == float(theirs.joint)
            assert np.array_equal(ours.spine.control_points, theirs.spine.control_points)


@pytest.mark.parametrize("neck_from", [0.6, 0.1])
@pytest.mark.parametrize("case", ["no room", "left nothing"])
def test_a_muzzle_from_a_head_s_middle_moves_with_the_head(monkeypatch, case, neck_from):
    # A horse's short head bone (the neck's top to the head's middle) has no room to bend
    # before its muzzle's bone, which starts at the head's middle with the ears'; a kangaroo's
    # head bone took its snout's part, and the snout's bone got nothing. In a neck (its joint
    # less than half as deep as the torso's middle) the muzzle moves with the head, and the
    # neck and head stay limbs; from the torso's middle the neck bone joins the body (the
    # deepest of the head and its ancestors at their joints, or of the muzzle and its
    # ancestors at their heads).
    import trimesh

    from fleshing_jax._skeleton import build
    from fleshing_jax._skeleton.skeleton import Limb

    ball = trimesh.creation.icosphere(2, 1.0)
    joints = np.array([(0.0, 0, 0), (neck_from, 0, 0), (0.8, 0, 0), (0.85, 0, 0)])
    heads = np.concatenate([joints[:3], joints[3:], joints[3:]])  # spine, neck, head, muzzle, ear
    tails = np.concatenate([joints[1:], [(0.97, 0, 0), (0.9, 0.1, 0)]])
    neck = Limb(fj.BSpline(np.linspace(joints[1], joints[2], 6)), 0.05)
    head = Limb(fj.BSpline(np.linspace(joints[2], (0.97, 0, 0), 6)), 0.02)
    limbs = {1: neck, 2: head, 3: "muzzle", 4: "ear"}
    muzzle = 3 if case == "no room" else None  # (else: a bone left nothing by the head's)
    found = []

    def bone_limbs(checked, vertices, adjacency, margin, body=frozenset()):
        found.append(set(body))
        kept = [b for b in (1, 2, muzzle, 4) if b is not None and b not in body]
        before = {} if body or muzzle else {3: 2}
        return [limbs[b] for b in kept], None, [f"bone {b}" for b in kept], kept, before

    monkeypatch.setattr(build, "bone_limbs", bone_limbs)
    # (No room: the head, limb 1 while the neck is one, leaves the muzzle, limb 2, none.)
    conflict = (1, 2, 0.0) if muzzle else None
    monkeypatch.setattr(build, "_conflict", lambda *args: None if found[-1] else conflict)
    checked = (heads, tails, np.array([-1, 0, 1, 2, 2]), [f"bone {b}" for b in range(5)])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        build._bones_in_the_body(checked, np.asarray(ball.vertices), None, 0)
    said = " ".join(str(w.message) for w in caught)
    if neck_from > 0.5:
        assert found == ([set(), {3}] if muzzle else [set()])
        assert "bone 3: no limb, moving with its parent's" in said
    else:
        assert found == [set(), {1}] and "moving with" not in said

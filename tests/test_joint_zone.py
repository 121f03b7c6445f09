"""A limb bent at its joint (`_skeleton.joint_zone`): the bend concentrated in the shortest zone
past the joint that keeps the map's curvature bound, the limb past it rigid, continuous in the
angle. On the posing tests' tube (`_posing_shapes`: radius 0.3, its left limb 2 bendable over
2 units), in float64."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _posing_shapes import RADIUS
from conftest import mapped

import fleshing_jax as fj
from fleshing_jax._skeleton.joint_zone import JOINT_CURVATURE, ZONE_LENGTHS, joint_zone
from fleshing_jax._skeleton.posing import limb_target, posed
from fleshing_jax._skeleton.spill import SHARE


def _straight_frames(n):
    """`joint_zone`'s frames of a straight spine along z, its normals x and y."""
    axes = np.eye(3)[[2, 0, 1]]
    return dict(frames=tuple(np.tile(axis, (n, 1)) for axis in axes), axes=axes)


def test_a_zone_is_as_long_as_its_angle_needs_on_a_straight_tube():
    # Rings of radius 0.3 every 0.01 along a straight spine, bendable from 1 to 3.
    s = np.repeat(np.linspace(0, 4, 401), 8)
    angle = np.tile(np.linspace(0, 2 * np.pi, 8, endpoint=False), 401)
    offset = RADIUS * np.stack([np.cos(angle), np.sin(angle)], 1)
    zone = joint_zone(s, offset, np.zeros_like(offset), np.ones(len(s), bool), 1.0, 3.0,
                      np.float64, **_straight_frames(len(s)))
    # κ = 4θ/(3L) on the ramp's plateau, κ·ρ = JOINT_CURVATURE: L = 4θρ/(3 JOINT_CURVATURE).
    for degrees in (20.0, 45.0, 90.0):
        theta = np.radians(degrees)
        needed = 4 * theta * RADIUS / (3 * JOINT_CURVATURE)
        length = float(zone.length(theta))
        # (The cubic between tabulated zones starts flat at the shortest: 3 % short at most.)
        assert 0.97 * needed <= length <= needed + 2.0 / ZONE_LENGTHS + 1e-12
        assert float(zone.length(-theta)) == length  # either way
    np.testing.assert_allclose(float(zone.range), 3 * JOINT_CURVATURE * 2.0 / (4 * RADIUS))
    # Past the range: the whole room, as a bend spread over the limb.
    assert float(zone.length(zone.range + 1)) == 2.0


def test_a_zone_read_eagerly_is_read_on_the_host_as_traced():
    # Concrete, `length` and `end` run on the host (numpy: an eager pose reads each limb's zone
    # up to four times, 4 ms of CPU a call as one-by-one device operations); traced, in the
    # program. The same formula: equal but for a compiled program's fused multiply-adds, and
    # in the zone's dtype.
    s = np.repeat(np.linspace(0, 4, 101), 8)
    angle = np.tile(np.linspace(0, 2 * np.pi, 8, endpoint=False), 101)
    offset = RADIUS * np.stack([np.cos(angle), np.sin(angle)], 1)
    for dtype in (np.float64, np.float32):
        zone = joint_zone(s, offset, np.zeros_like(offset), np.ones(len(s), bool), 1.0, 3.0,
                          dtype, **_straight_frames(len(s)))
        joint, stop = np.asarray(1.0, dtype), np.asarray(3.0, dtype)
        bends = np.linspace(-7, 7, 57).astype(dtype)
        eager = np.array([zone.end(b, joint, stop) for b in bends])
        traced = jax.jit(jax.vmap(lambda b, zone=zone: zone.end(b, joint, stop)))(bends)
        assert eager.dtype == dtype and traced.dtype == dtype
        np.testing.assert_allclose(eager, traced, rtol=4 * np.finfo(dtype).eps)


def test_a_thick_part_lengthens_the_zone_continuously():
    # The same tube, twice as thick from arc length 1.5: zones reaching it are bounded by it.
    s = np.repeat(np.linspace(0, 4, 401), 8)
    angle = np.tile(np.linspace(0, 2 * np.pi, 8, endpoint=False), 401)
    radius = np.where(s > 1.5, 2 * RADIUS, RADIUS)[:, None]
    offset = radius * np.stack([np.cos(angle), np.sin(angle)], 1)
    zone = joint_zone(s, offset, np.zeros_like(offset), np.ones(len(s), bool), 1.0, 3.0,
                      np.float64, **_straight_frames(len(s)))
    capacities, lengths = np.asarray(zone.capacities), np.asarray(zone.lengths)
    assert np.all(np.diff(capacities) >= 0) and np.all(np.diff(lengths) >= 0)
    # Every tabulated zone keeps the bound for its capacity.
    rho = np.where(1.0 + lengths > 1.5, 2 * RADIUS, RADIUS)
    assert np.all(4 * capacities * rho / (3 * lengths) <= JOINT_CURVATURE * (1 + 1e-9))
    # The zone's length is smooth in the angle: no kink for a fit of the angle to stop at.
    knots = np.unique(capacities)
    slope = jax.vmap(jax.grad(zone.length))
    left, right = (np.asarray(slope(jnp.asarray(knots + step))) for step in (-1e-9, 1e-9))
    np.testing.assert_allclose(left, right, rtol=1e-5, atol=1e-6)
    assert np.all(left >= 0) and np.all(right >= 0)
    # The length grows without a jump: a fine sweep of the angle moves it by small steps.
    sweep = np.asarray(jax.vmap(zone.length)(jnp.linspace(0, float(zone.range), 2001)))
    assert np.max(np.abs(np.diff(sweep))) < 2.0 / ZONE_LENGTHS


def _rigid_error(before, after):
    """The largest change of a distance between two of the points (0 for a rigid motion)."""
    d0 = np.linalg.norm(before[:, None] - before[None], axis=-1)
    d1 = np.linalg.norm(after[:, None] - after[None], axis=-1)
    return np.max(np.abs(d1 - d0))


def test_the_limb_past_its_zone_moves_rigidly(tube, skeleton, registration):
    posed = fj.pose_skeleton(registration, skeleton, {2: fj.LimbPose(60.0, 30.0)})
    assert np.asarray(posed.valid).all()
    rest, after = np.asarray(tube.vertices), np.asarray(posed.vertices)
    length = float(registration.zones[2].length(np.radians(60.0)))
    assert length < 0.6 * float(registration.stops[2] - registration.joints[2])
    # Limb 2 runs towards -x from its bend's start at x = 2.
    start = 2.0 - (float(registration.joints[2]) - 0.5)
    past = rest[:, 0] < start - length - 0.05
    inside = (rest[:, 0] < start) & (rest[:, 0] > start - length)
    assert past.sum() > 100
    assert _rigid_error(rest[past], after[past]) < 1e-9
    assert _rigid_error(rest[inside], after[inside]) > 1e-2  # the zone itself is bent
    # The tip turned by the whole angle.
    tip = after[rest[:, 0] < 1e-9].mean(axis=0) - after[past].mean(axis=0)
    axis = rest[rest[:, 0] < 1e-9].mean(axis=0) - rest[past].mean(axis=0)
    turned = np.degrees(np.arccos(tip @ axis / np.linalg.norm(tip) / np.linalg.norm(axis)))
    np.testing.assert_allclose(turned, 60.0, atol=1e-6)


def test_a_sweep_of_the_angle_moves_every_vertex_continuously(tube, skeleton, registration):
    # Through the exact range, in 1/2° steps, the frames batched in one program (without the
    # global projection check: the vertices are what is compared); then angles a traced pose
    # cannot refuse, in the same batch.
    # Past the range (129°), the vertices outside the map's conditions are placed by the
    # whole map (`Poser`'s `fallback`): flagged, but the mesh stays whole.
    # Then the direction, in 1/2° steps, at a bend where the blend past the range is partly
    # in, and varies with the direction (by the vertices' place on the rings). Over 45°: the
    # tube's rings have 16 vertices, so its poses repeat every 22.5° of direction, turned
    # about its axis (over half a turn: the same step lengths and flags in each 22.5°, the
    # frames each other's turns to 1e-15), and two periods show all of them.
    largest = np.degrees(float(registration.zones[2].range))
    angles = np.linspace(0.0, 180.0, 361)
    absurd = np.array([np.nan, np.inf, -np.inf, 1e9, 361.0])
    directions = np.linspace(0.0, 45.0, 91)
    blended = 1.1 * float(fj.joint_range(registration, 2, 0.0))
    # (Compiled at the suite's backend optimisation level 0: at level 1 its 457 frames ran in
    # 1.1 s against 2.5, but compiled in 18.4 s against 6.4 s of CPU.)
    sweep = jax.jit(jax.vmap(lambda bend, direction: posed(
        registration, skeleton, {2: fj.LimbPose(bend, direction)}, "radial", check=False)))
    bends = np.r_[angles, absurd, np.full(len(directions), blended)]
    vertices, valid = (np.asarray(x) for x in sweep(
        jnp.asarray(bends), jnp.asarray(np.r_[np.zeros(len(angles) + len(absurd)), directions])))
    rest = np.asarray(tube.vertices)
    edges = tube.edges_unique
    shortest = np.min(np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1))
    steps = np.linalg.norm(np.diff(vertices[: len(angles)], axis=0), axis=-1)
    # The tip turns 1/2° a step at 2.3 units from the joint: 0.02; no vertex jumps an edge.
    assert steps.max() < 0.3 * shortest
    turned = vertices[len(angles) + len(absurd):]
    assert np.linalg.norm(np.diff(turned, axis=0), axis=-1).max() < 0.3 * shortest
    assert not valid[len(angles) + len(absurd):].any(axis=0).all()  # (blended: inexact)
    # Whole at every angle: no edge stretched 4×, none crushed (past the range the concave
    # side is compressed towards the centre of curvature, `maps.radial_bend_whole`; the exact
    # map's continuation folded it across: edges down to 2 % of their length at 160°).
    lengths = [np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=-1)
               for v in (rest, *vertices[: len(angles)])]
    stretch = np.stack(lengths[1:]) / lengths[0]
    assert stretch.max() < 4 and stretch.min() > 0.1
    np.testing.assert_allclose(vertices[0], rest, atol=1e-12)  # (traced: to round-off)
    assert valid[: len(angles)][angles <= largest].all() and not valid[len(angles) - 1].all()
    # A NaN, infinite or past-a-full-turn angle flags the whole limb, and nothing else.
    region = np.asarray(skeleton.region)
    for row in valid[len(angles): len(angles) + len(absurd)]:
        assert not row[region == 2].any() and row[region != 2].all()


def test_towards_bends_a_limb_towards_a_world_direction(tube, skeleton, registration):
    rest = np.asarray(tube.vertices)
    tip, base = rest[:, 0] < 1e-9, np.abs(rest[:, 0] - 0.8) < 1e-9  # rings of the rigid part
    for towards in ([0.0, 0.0, 1.0], [0.3, -1.0, 1.0]):
        pose = fj.LimbPose(60.0, towards=towards)
        after = np.asarray(fj.pose_skeleton(registration, skeleton, {2: pose}).vertices)
        axis = after[tip].mean(axis=0) - after[base].mean(axis=0)
        axis /= np.linalg.norm(axis)
        # Limb 2 runs along -x: it turns 60° towards the part of `towards` across x.
        across = np.array([0.0, *towards[1:]]) / np.linalg.norm(towards[1:])
        expected = np.cos(np.radians(60)) * np.array([-1.0, 0, 0]) + np.sin(np.radians(60)) * across
        np.testing.assert_allclose(axis, expected, atol=1e-6)


def test_joint_range_and_bad_poses(registration):
    ranges = [float(fj.joint_range(registration, k)) for k in range(3)]
    np.testing.assert_allclose(ranges[2], np.degrees(float(registration.zones[2].range)))
    assert 60 < ranges[2] < 360
    with pytest.raises(ValueError, match="`limb`: 3 is not a limb index"):
        fj.joint_range(registration, 3)
    with pytest.raises(ValueError, match="runs along the limb's tangent"):
        fj.LimbPose(30.0, towards=(-2.0, 0.0, 0.0)).spine(registration.rests[2],
                                                          registration.joints[2],
                                                          registration.stops[2])
    with pytest.raises(ValueError, match="`direction` or `towards`, not both"):
        fj.LimbPose(30.0, 90.0, towards=(0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="`towards` must be a finite non-zero"):
        fj.LimbPose(30.0, towards=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="at most a full turn"):
        fj.LimbPose(1e9)
    with pytest.raises(ValueError, match="`twist` must be at most a full turn"):
        fj.LimbPose(10.0, twist=-400.0)
    with pytest.raises(TypeError, match="`bend` must be an angle in degrees, got True"):
        fj.LimbPose(True)


def test_aim_points_a_limb_at_a_point(tube, skeleton, registration):
    # Limb 2 (along -x from x = 2) aimed at a point above and behind its tip.
    point = np.array([0.5, 0.0, 1.5])
    pose = fj.aim(registration, skeleton, 2, point)
    assert 0 < float(pose.bend) < 90
    bent = limb_target(registration, 2, pose)
    # (Each spine read by one compiled program, `conftest.mapped`: eagerly, the bent spine's
    # point ran, and compiled, some 80 operations one by one.)
    origin = np.asarray(mapped(registration.rests[2], registration.joints[2][None]))[0]
    chord = np.asarray(mapped(bent, registration.stops[2][None]))[0] - origin
    towards = point - origin
    np.testing.assert_allclose(chord / np.linalg.norm(chord),
                               towards / np.linalg.norm(towards), atol=1e-6)
    # Another point: the chord's program is traced once per limb, not once per call.
    from fleshing_jax._skeleton.aim import _chord

    traced = _chord._cached._cache_size()
    fj.aim(registration, skeleton, 2, [0.4, 0.3, 1.2])
    assert _chord._cached._cache_size() == traced
    with pytest.raises(ValueError, match="`limb`: 7 is not a limb index"):
        fj.aim(registration, skeleton, 7, point)
    with pytest.raises(ValueError, match="`point` must be finite"):
        fj.aim(registration, skeleton, 2, [np.nan, 0, 0])
    # Straight back past the joint: no bend's chord reaches it; said, not a pose 30° off.
    with pytest.raises(ValueError, match="cannot point at .* comes within"):
        fj.aim(registration, skeleton, 2, [3.0, 0.0, 0.3])


def test_turn_and_nod_in_the_world_s_terms(skeleton, registration):
    # Limb 2 runs along -x; with z up, a nod raises its end, a turn swings it about z.
    up = (0.0, 0.0, 1.0)
    origin = np.asarray(registration.rests[2](registration.joints[2]))

    def chord(pose):
        end = limb_target(registration, 2, pose)(registration.stops[2])
        return (np.asarray(end) - origin) / np.linalg.norm(np.asarray(end) - origin)

    rest = chord(fj.LimbPose())
    for degrees, moved in ((30.0, 2), (-30.0, 2)):
        after = chord(fj.nod(registration, skeleton, 2, degrees, up=up))
        assert np.sign(after[moved] - rest[moved]) == np.sign(degrees) and abs(after[1]) < 1e-9
    after = chord(fj.turn(registration, skeleton, 2, 30.0, up=up))
    # Counter-clockwise seen from above: -x turns towards -y.
    assert after[1] < -0.1 and abs(after[2]) < 1e-9
    with pytest.raises(ValueError, match="runs along `up`"):
        fj.nod(registration, skeleton, 2, 30.0, up=(1.0, 0.0, 0.0))


def test_turn_rotates_the_limb_past_its_zone_about_the_world_s_up(tube, skeleton, registration):
    # A turn is the rotation about `up` split into a swing and a twist about the limb's
    # tangent: the part past the zone turns by exactly that rotation, whether `up` is across
    # the limb (a quadruped's head: a swing), along it (a biped's: a twist, looking aside) or
    # between.
    rest = np.asarray(tube.vertices)
    past = rest[:, 0] < 0.3  # limb 2's end, past any zone of these angles
    # A nod about a given side: the same, for a limb along `up` (a biped's head).
    turns = [(up, lambda d, up=up: fj.turn(registration, skeleton, 2, d, up=up))
             for up in ((0.0, 0.0, 1.0), (-1.0, 0.0, 0.0), (-1.0, 0.0, 1.0))]
    turns.append(((0.0, 1.0, 1.0), lambda d: fj.nod(registration, skeleton, 2, d,
                                                    up=(-1.0, 0.0, 0.0), side=(0, 1, 1))))
    for up, posing in turns:
        up = np.asarray(up) / np.linalg.norm(up)
        for degrees in (40.0, -25.0):
            pose = posing(degrees)
            after = np.asarray(fj.pose_skeleton(registration, skeleton, {2: pose}).vertices)
            phi = np.radians(degrees)
            cross = np.array([[0, -up[2], up[1]], [up[2], 0, -up[0]], [-up[1], up[0], 0]])
            rotation = np.eye(3) + np.sin(phi) * cross + (1 - np.cos(phi)) * cross @ cross
            before = rest[past] - rest[past].mean(axis=0)
            moved = after[past] - after[past].mean(axis=0)
            np.testing.assert_allclose(moved, before @ rotation.T, atol=1e-6)


def _tip_tangent(vertices, rest):
    """The unit normal of the tube's last ring (x = 6 at rest), oriented as x is there."""
    ring = np.flatnonzero(np.abs(rest[:, 0] - 6.0) < 1e-9)
    a, b = ring[0], ring[len(ring) // 4]
    centre = vertices[ring].mean(axis=0)
    normal = np.cross(vertices[a] - centre, vertices[b] - centre)
    sign = np.sign(np.cross(rest[a] - rest[ring].mean(0), rest[b] - rest[ring].mean(0))[0])
    return sign * normal / np.linalg.norm(normal)


def test_a_bend_past_a_joint_s_range_is_carried_on_by_its_free_child(tube, skeleton,
                                                                     registration):
    # Limb 0 (room 1.2 at radius 0.3) has one child, limb 1, left free: bent past its exact
    # range (twisted too), the bend is carried on by the child in the same plane. No vertex
    # inexact, and the tip turned by the whole angle towards the bend's direction at rest.
    own, below = (np.degrees(float(registration.zones[k].reach(
        0.0, registration.joints[k], registration.stops[k]))) for k in (0, 1))
    angle, direction, twist = SHARE * (own + 0.5 * below), 30.0, 40.0
    rest = np.asarray(tube.vertices)
    posed = fj.pose_skeleton(registration, skeleton,
                             {0: fj.LimbPose(angle, direction, twist)})
    assert angle > own and np.asarray(posed.valid).all()
    t, first, second = np.asarray(registration.zones[0].axes)
    phi = np.radians(direction)
    towards = np.cos(phi) * first + np.sin(phi) * second
    theta = np.radians(angle)
    np.testing.assert_allclose(_tip_tangent(np.asarray(posed.vertices), rest),
                               np.cos(theta) * t + np.sin(theta) * towards, atol=1e-9)
    # Continuous where the child starts taking its share (eagerly unposed below it).
    start = SHARE * own
    before, after = (np.asarray(fj.pose_skeleton(registration, skeleton, {
        0: fj.LimbPose(a, direction, twist)}).vertices) for a in (start - 1e-7, start + 1e-7))
    assert np.abs(after - before).max() < 1e-6
    # A posed child keeps its own pose: the parent is then inexact past its range.
    both = fj.pose_skeleton(registration, skeleton, {0: fj.LimbPose(angle), 1: fj.LimbPose()})
    assert not np.asarray(both.valid).all()
    # `fj.joint_range` counts the free child's part: exact up to it, inexact past it; with
    # the child posed, the limb's own range.
    carried = float(fj.joint_range(registration, 0, direction, twist=twist))
    alone = float(fj.joint_range(registration, 0, direction, twist=twist, children_posed=True))
    assert alone < angle < carried
    for bend, exact in ((carried - 0.05, True), (carried + 0.05, False)):
        valid = fj.pose_skeleton(registration, skeleton,
                                 {0: fj.LimbPose(bend, direction, twist)}).valid
        assert bool(np.asarray(valid).all()) == exact

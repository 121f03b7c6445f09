"""Posing a shape limb by limb (`fj.pose_skeleton`, `fj.LimbPose`, `fj.BentSpine`).

One tube along x (`_posing_shapes`), cut by hand into a body (2 ≤ x ≤ 4), a right limb with a
child at its tip and a left limb, is posed in float64 throughout, its limbs' spines built as
`fj.skeleton` builds them, so that the tests share their compiled programs.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import fleshing_jax as fj
from fleshing_jax._fleshing.maps import WHOLE_FROM
from fleshing_jax._fleshing.reach import REACH_SAMPLES
from fleshing_jax._skeleton.posing import (
    CERTIFICATE_SAMPLES,
    CERTIFIED_FROM,
    _limb_poser,
    certificate_samples,
    limb_poser,
    limb_target,
)
from fleshing_jax._spines.bent import ramp, sorted_by_rank
from fleshing_jax._spines.table import SpineTable


def _pose(registration, skeleton, poses):
    posed = fj.pose_skeleton(registration, skeleton, poses)
    return np.asarray(posed.vertices), np.asarray(posed.valid)


def _stretch(tube, before, after, edges=None):
    e = tube.edges_unique if edges is None else edges
    length = np.linalg.norm(before[e[:, 0]] - before[e[:, 1]], axis=1)
    return np.linalg.norm(after[e[:, 0]] - after[e[:, 1]], axis=1) / length


def test_bent_spine_is_the_base_up_to_the_joint_and_rigid_past_its_stop():
    base = fj.BSpline(np.array([[0, 0, 0], [1, 0.2, 0], [2, 0.1, 0.3], [3, -0.2, 0.2],
                                [4, 0, 0], [5, 0.1, 0.1]]))
    bent = fj.BentSpine(base, joint=1.0, stop=3.5, bend=1.2, direction=0.7, twist=0.5)
    assert float(bent.length) == float(base.length)

    # (The checks compiled as one program: evaluated eagerly, a spine is many small ones. The
    # bent spine prepared once in it, as the batched paths prepare it (each of its methods
    # prepares it, and is checked on it below): each evaluation of `bent` traced its
    # preparation again, 35k lines of program against 27k. The jet differentiated once, not
    # its position and tangent each by `jacfwd`: 24.6k lines against 18.9k, its compile 11.7
    # -> 6.8 s at load 5.)
    @jax.jit
    def values(before, inside, past):
        prepared = bent._prepare()

        def derivatives(s):  # (C, T, k) and their derivatives in s, by one forward pass
            (_, tangent, k), (dc, dt, _) = jax.jvp(prepared.jet, (s,), (jnp.ones_like(s),))
            return dc, tangent, dt, k

        return ((bent(before), prepared.jet_and_normals(before)),
                (base(before), base.jet_and_normals(before)),
                jax.vmap(derivatives)(inside), jax.vmap(prepared)(past), jax.vmap(base)(past),
                jax.vmap(prepared.jet)(zone))

    inside = jnp.asarray([1.2, 2.0, 3.0, 3.6, float(base.length) - 0.1])
    past = jnp.linspace(3.5, float(base.length), 5)
    zone = jnp.linspace(1.0, 3.5, 1601)
    bent_before, base_before, (dc, tangent, dt, k), a, b, (c, t, _) = values(0.8, inside, past)
    # The position is the integral of the tangent (Simpson's rule on a fine grid as the
    # reference): on a free-form base the quadrature is taken in its parameter.
    h = float(zone[1] - zone[0])
    simpson = np.cumsum(h / 3 * (t[:-2:2] + 4 * t[1:-1:2] + t[2::2]), axis=0)
    np.testing.assert_allclose(c[2::2] - c[0], simpson, rtol=0, atol=1e-11)
    for x, y in zip(jax.tree.leaves(bent_before), jax.tree.leaves(base_before)):
        np.testing.assert_array_equal(x, y)
    # Exactly arc length, with the jet's derivatives consistent to round-off (det J = 1).
    np.testing.assert_allclose(dc, tangent, atol=1e-14)
    np.testing.assert_allclose(dt, k, atol=1e-13)
    np.testing.assert_allclose(np.linalg.norm(tangent, axis=1), 1, atol=1e-14)
    # Past the stop, the base moved rigidly: distances kept, and moved.
    np.testing.assert_allclose(np.linalg.norm(a[:, None] - a[None], axis=-1),
                               np.linalg.norm(b[:, None] - b[None], axis=-1), atol=1e-13)
    assert float(jnp.max(jnp.abs(a - b))) > 0.5
    # The bend's angle: the tangent turns by `bend` about the joint's axis on a straight base.
    line = fj.BentSpine(fj.Line(3.0), joint=0.5, bend=1.0, direction=0.3)
    tangents = jax.jit(jax.vmap(line.tangent))(jnp.asarray([3.0, 0.5]))
    assert np.degrees(np.arccos(float(tangents[0] @ tangents[1]))) == pytest.approx(
        np.degrees(1.0), abs=1e-9)


def test_bent_spine_fleshing_has_unit_jacobian_and_gradients():
    base = fj.Line(3.0)
    bent = fj.BentSpine(base, joint=0.5, bend=0.9, direction=1.0, twist=0.4)
    points = np.random.default_rng(0).uniform([0.2, -0.25, -0.25], [2.8, 0.25, 0.25], (32, 3))
    det = fj.jacobian_determinant(fj.Fleshing(base, bent), points)
    assert np.all(np.isfinite(det)) and float(jnp.max(jnp.abs(det - 1))) < 1e-12

    @jax.jit
    def image(angles):
        spine = fj.BentSpine(base, joint=0.5, bend=angles[0], twist=angles[1])
        return spine(2.5)

    check_grads(image, (jnp.asarray([0.9, 0.4]),), order=1, modes=["rev"])


def test_bent_spine_bad_input():
    base = fj.Line(2.0)
    with pytest.raises(TypeError, match="`base`"):
        fj.BentSpine("line", joint=0.5)
    with pytest.raises(ValueError, match="`joint`"):
        fj.BentSpine(base, joint=2.5)
    with pytest.raises(ValueError, match="`stop`"):
        fj.BentSpine(base, joint=1.0, stop=0.5)
    with pytest.raises(ValueError, match="`bend`"):
        fj.BentSpine(base, joint=1.0, bend=np.nan)


def test_rest_pose_and_unposed_parts_stay_bit_for_bit(tube, skeleton, registration):
    rest = np.asarray(tube.vertices)
    region = np.asarray(skeleton.region)
    vertices, valid = _pose(registration, skeleton, {0: fj.LimbPose()})
    assert valid.all()
    np.testing.assert_allclose(vertices, rest, atol=1e-12)  # zero pose: the identity
    vertices, valid = _pose(registration, skeleton, {0: fj.LimbPose(60, 90, 20)})
    still = region != 0
    still &= region != 1
    np.testing.assert_array_equal(vertices[still], rest[still])  # body and the left limb
    assert np.max(np.abs(vertices[region == 1] - rest[region == 1])) > 0.5


def test_a_region_s_bucket_padding_is_never_posed(skeleton, registration):
    # All regions are padded to one bucket with copies of their last vertex, marked invalid so
    # that a pose leaves them and runs no check on them (`invalid_past`).
    for reg, ids in zip(registration.registrations, registration.indices):
        n = ids.shape[0]
        assert reg.valid.shape[0] > n
        assert not np.asarray(reg.valid)[n:].any() and np.asarray(reg.valid)[:n].all()


def test_a_child_follows_its_parent_rigidly_then_bends(tube, skeleton, registration):
    rest = np.asarray(tube.vertices)
    child = np.asarray(skeleton.region) == 1
    carried, _ = _pose(registration, skeleton, {0: fj.LimbPose(60, 90)})

    def distances(v):
        return np.linalg.norm(v[child][:, None] - v[child][None], axis=-1)

    np.testing.assert_allclose(distances(carried), distances(rest), atol=1e-12)
    both, valid = _pose(registration, skeleton, {0: fj.LimbPose(60, 90), 1: fj.LimbPose(30, 0)})
    assert valid.all()
    assert np.max(np.abs(distances(both) - distances(rest))) > 0.05  # bent, not rigid
    # The child's own bend starts at its joint: the part of it before the joint is carried.
    x = rest[:, 0]
    near = child & (x < 4.8 + 0.4 - 0.05)
    np.testing.assert_allclose(both[near], carried[near], atol=1e-12)


def test_volume_kept_and_no_crack(tube, skeleton, registration):
    rest = np.asarray(tube.vertices)
    poses = {0: fj.LimbPose(60, 90, 30), 1: fj.LimbPose(30, 180), 2: fj.LimbPose(50, 0)}
    vertices, valid = _pose(registration, skeleton, poses)
    assert valid.all()
    change = float(fj.volume_change(rest, vertices, tube.faces))
    assert abs(change) < 1.5e-3  # flat faces only: 2.1e-4 at twice the resolution
    region = np.asarray(skeleton.region)
    edges = tube.edges_unique
    across = region[edges[:, 0]] != region[edges[:, 1]]
    assert np.max(_stretch(tube, rest, vertices, edges[across])) < 1.01
    assert np.max(_stretch(tube, rest, vertices)) < 1.5


@pytest.fixture(scope="module")
def single(tube, skeleton):
    """The tube registered in float32 (the per-frame path's dtype)."""
    return fj.register_skeleton(tube, skeleton, margin=0.06, dtype=jnp.float32)


def test_float32_posing_reads_its_rest_spines_from_tables(tube, skeleton, registration, single):
    # The per-frame path: float32 vertices, the bent spines built on tabulated rest spines.
    poses = {0: fj.LimbPose(60, 90, 30), 1: fj.LimbPose(30, 180), 2: fj.LimbPose(50, 0)}
    assert all(isinstance(rest, fj.LookedUpSpine) for rest in single.rests)
    # In float64 the rest spines are exact, and tabulated only for the projection check.
    assert all(check is None for check in single.checks)
    assert all(isinstance(check, fj.LookedUpSpine) and check.length.dtype == jnp.float64
               for check in registration.checks)
    assert not any(isinstance(rest, fj.LookedUpSpine) for rest in registration.rests)
    # A looked-up rest spine is its spine, continuation included, to single precision.
    s = jnp.linspace(-0.3, 2.8, 32, dtype=jnp.float32)
    reference = jax.jit(jax.vmap(skeleton.limbs[0].spine.jet_and_normals))(s.astype(jnp.float64))
    looked_up = jax.jit(jax.vmap(single.rests[0].jet_and_normals))(s)
    for a, b in zip(jax.tree.leaves(looked_up), jax.tree.leaves(reference)):
        assert a.dtype == jnp.float32
        np.testing.assert_allclose(a, b, atol=2e-5)
    # Its values where a bent spine's table reads them each frame, kept from registration: the
    # table's at its nodes, and its tangents at the quadrature points that tile its range.
    table, at = single.rests[0].table, single.rests[0].samples
    flat = at.arc_length.reshape(-1)
    kept = jax.tree.leaves((at.jet, at.normals, at.tangents))
    read = jax.jit(lambda: (jax.vmap(table.jet_and_normals)(flat),
                            jax.vmap(jax.vmap(lambda s: table.jet(s)[1]))(at.points)))()
    for a, b in zip(kept, jax.tree.leaves(read)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)  # (float32: a few ulps)
    assert float(table.lo) + 2 * float(jnp.sum(at.half)) == pytest.approx(float(flat[-1]))
    posed = fj.pose_skeleton(single, skeleton, poses)
    assert posed.vertices.dtype == jnp.float32
    # A bent limb's target table holds its jet alone (all its valid region reads: 9 values a
    # node fit, not 21), and says so where the search's terms are asked (the pose's program).
    table = jax.eval_shape(lambda: limb_poser(
        single.registrations[0], limb_target(single, 0, poses[0]), "radial")).target
    assert isinstance(table, SpineTable) and not table.searchable
    with pytest.raises(ValueError, match="jet .C, T, k. alone"):
        table._foot_terms(jnp.ones(3, jnp.float32), jnp.float32(0.5))
    exact, valid = _pose(registration, skeleton, poses)
    np.testing.assert_array_equal(np.asarray(posed.valid), valid)
    np.testing.assert_allclose(np.asarray(posed.vertices), exact, atol=2e-5)  # (length 6)
    # Folded past its range, limb 2's sections are carried: their positions read from the
    # bent spine's table in float32, integrated in float64.
    folded = fj.pose_skeleton(single, skeleton, {2: fj.LimbPose(175, 0)})
    exact, valid = _pose(registration, skeleton, {2: fj.LimbPose(175, 0)})
    assert not valid.all()
    np.testing.assert_array_equal(np.asarray(folded.valid), valid)
    np.testing.assert_allclose(np.asarray(folded.vertices), exact, atol=2e-5)
    region = np.asarray(skeleton.region)
    rest = np.asarray(tube.vertices, np.float32)
    np.testing.assert_array_equal(np.asarray(posed.vertices)[region == -1], rest[region == -1])


def test_the_sampled_test_is_compiled_ahead(tube, skeleton, single, monkeypatch):
    # `register_skeleton` starts compiling the valid region's sampled test (run where a point
    # is unclear) beside its other programs, for the arguments it would be called with: the
    # same pytrees, shapes, dtypes and weak types (else it would be compiled twice).
    from fleshing_jax._fleshing import eager
    from fleshing_jax._skeleton import posing

    def signature(args, quick):
        leaves, tree = jax.tree.flatten(args)
        return repr((tree, quick, [(np.shape(a), np.dtype(a.dtype).name,
                                    bool(getattr(a, "weak_type", False))) for a in leaves]))

    program, pending, prepared, needed = eager._register_clear, posing.registered_pending, [], []

    class Spy:
        def prepare(self, *args, quick=True):
            prepared.append(signature(args, quick))
            return program.prepare(*args, quick=quick)

    def registered(registrar, points, certified):
        index = eager.pending_index(np.ones(certified[2].shape, bool))  # (any point unclear)
        needed.append(signature((registrar, certified[0], index), True))
        return pending(registrar, points, certified)

    monkeypatch.setattr(eager, "_register_clear", Spy())
    monkeypatch.setattr(posing, "registered_pending", registered)
    fj.register_skeleton(tube, skeleton, margin=0.06, dtype=jnp.float32)
    assert len(needed) == len(skeleton.limbs) and set(needed) == set(prepared)


def test_a_bent_limb_s_frames_are_fit_from_its_table_s_values_at_its_nodes(single):
    """In float32 a bent limb's frames' table is fit from the values its spine's table was fit
    to at its nodes (`fast_evaluator_at_nodes`), not from that table read back there: the same
    frames, to single precision's round-off, over the whole search range."""
    from fleshing_jax._fleshing.target import TargetFrames

    @jax.jit
    def frames(target):
        table, at_nodes = target._prepare()._table_at_nodes()
        s = jnp.linspace(table.lo, table.hi, 101)
        return [jax.vmap(TargetFrames(table, jnp.float32(0.3), True, nodes))(s)
                for nodes in (at_nodes, None)]

    fit, read = frames(limb_target(single, 2, fj.LimbPose(50.0, 30.0, 10.0)))
    for a, b in zip(fit, read, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=2e-6)  # (the tube: 6 long, 0.3 across)


def test_a_bent_limb_s_table_turns_its_nodes_by_polynomial_sines_and_cosines(single, monkeypatch):
    """In float32 a bent limb's table takes its nodes' sines and cosines from polynomials
    (`held_trig(bounded=True)`, 5× faster than XLA's): its values at the nodes within a few
    ulps of those turned by XLA's own (the tube's: 6 long; spot's vertices within 1.2e-7)."""
    from fleshing_jax import _numerics

    target = limb_target(single, 2, fj.LimbPose(50.0, 30.0, 10.0))
    fast = jax.jit(lambda t: t._prepare()._table_at_nodes(jet_only=True)[1])(target)
    monkeypatch.setattr(_numerics, "sincos", lambda x: (jnp.sin(x), jnp.cos(x)))
    xla = jax.jit(lambda t: t._prepare()._table_at_nodes(jet_only=True)[1])(target)
    apart = [float(jnp.max(jnp.abs(a - b))) for a, b in zip(*map(jax.tree.leaves, (fast, xla)))]
    assert 0 < max(apart) <= 1e-6, apart


def test_a_bent_spine_s_breaks_are_sorted_by_rank():
    # Ties (the cuts clipped to the joint and the stop) in order; NaN everywhere with a NaN.
    rng = np.random.default_rng(0)
    for values in (rng.normal(size=69), rng.choice([0.0, 0.25, 1.0], 69), np.zeros(5)):
        values = values.astype(np.float32)
        np.testing.assert_array_equal(np.asarray(sorted_by_rank(values)), np.sort(values))
    assert np.isnan(np.asarray(sorted_by_rank(jnp.asarray([1.0, jnp.nan, 0.0])))).all()


@pytest.mark.parametrize("posed_child", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_gradients_of_the_angles(skeleton, registration, posed_child):
    # Limb 0's three angles, its child carried by its end motion; with `-m slow` the child's
    # own bend too (two limbs' programs differentiated: 66 s of the suite, against 30).
    tip = int(np.argmax(np.asarray(skeleton.vertices)[:, 0]))

    def tip_height(angles):
        poses = {0: fj.LimbPose(angles[0], angles[1], angles[2])}
        if posed_child:
            poses[1] = fj.LimbPose(angles[3])
        posed = fj.pose_skeleton(registration, skeleton, poses)
        return posed.vertices[tip, 2], posed

    angles = np.array([40.0, 90.0, 10.0, 20.0][: 4 if posed_child else 3])
    # (Jitted: one program for the value and gradient; unjitted, value_and_grad compiled the
    # pose's linearisation and transpose as programs of their own, 5 s more.)
    (value, posed), gradient = jax.jit(jax.value_and_grad(tip_height, has_aux=True))(
        jnp.asarray(angles))
    # Traced, each limb is posed at its own size (limb 0's rows, not the 384 its registration
    # is padded to for the eager calls, nor their bucket): the eager pose's vertices and flags.
    from fleshing_jax._skeleton.posing import _limb_registration

    own = _limb_registration(registration, 0, True).points.shape[0]
    assert own == registration.indices[0].shape[0] < registration.registrations[0].points.shape[0]
    eager_value, eager = tip_height(angles)
    assert float(value) == pytest.approx(float(eager_value), rel=0, abs=1e-12)
    np.testing.assert_allclose(posed.vertices, eager.vertices, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(posed.valid, eager.valid)
    eps = 1e-3
    for i, step in enumerate(eps * np.eye(len(angles))):  # central differences, eager path
        difference = (tip_height(angles + step)[0] - tip_height(angles - step)[0]) / (2 * eps)
        assert float(gradient[i]) == pytest.approx(float(difference), rel=1e-6, abs=1e-9)
    assert abs(float(gradient[0])) > 1e-3 and abs(float(gradient[1])) > 1e-4


def test_bad_poses(tube, skeleton, registration):
    with pytest.raises(ValueError, match="not a limb index"):
        fj.pose_skeleton(registration, skeleton, {7: fj.LimbPose(10)})
    with pytest.raises(ValueError, match="not a limb index"):
        fj.pose_stretch(registration, skeleton, {7: fj.LimbPose(10)})
    with pytest.raises(ValueError, match="`method`"):
        fj.pose_stretch(registration, skeleton, {0: fj.LimbPose(10)}, method="bent")
    with pytest.raises(TypeError, match="`poses`"):
        fj.pose_skeleton(registration, skeleton, [fj.LimbPose(10)])
    with pytest.raises(TypeError, match=r"`poses\[0\]`"):
        fj.pose_skeleton(registration, skeleton, {0: 30.0})
    with pytest.raises(ValueError, match="`bend`"):
        fj.LimbPose(np.nan)
    other = fj.Skeleton(skeleton.limbs, np.full(10, -1), np.zeros((10, 3)))
    with pytest.raises(ValueError, match="another mesh"):
        fj.register_skeleton(tube, other)
    # The same count of vertices, moved: another mesh too, said so before any work.
    moved = (np.asarray(tube.vertices) * 1.5, np.asarray(tube.faces))
    with pytest.raises(ValueError, match="built on another mesh: its rest vertices differ"):
        fj.register_skeleton(moved, skeleton)
    # A skeleton whose regions differ from the registration's (limb 0's first ring given to
    # the body).
    region = np.array(skeleton.region)
    region[(region == 0) & (np.asarray(tube.vertices)[:, 0] < 4.15)] = -1
    edited = fj.Skeleton(skeleton.limbs, region, tube.vertices)
    with pytest.raises(ValueError, match="not the one `mesh_or_registration` was registered on"):
        fj.pose_skeleton(registration, edited, {0: fj.LimbPose(10)})
    # A spine for a limb must be its rest spine bent past the joint.
    with pytest.raises(ValueError, match=r"`poses\[0\]`: a spine given for limb 0 must be as long"):
        fj.pose_skeleton(registration, skeleton, {0: fj.Line(0.1)})
    rest = skeleton.limbs[0].spine
    shifted = fj.BSpline(np.asarray(rest.control_points) + [0.0, 0.05, 0.0], subdivisions=32)
    with pytest.raises(ValueError, match="must follow its rest spine up to the joint"):
        fj.pose_skeleton(registration, skeleton, {0: shifted})


def test_a_bend_beyond_the_limb_s_reach_is_flagged(skeleton, registration):
    # The left limb folded back on itself within its short ramp: its inner side crosses.
    poses = {2: fj.LimbPose(175, 0)}
    _, valid = _pose(registration, skeleton, poses)
    region = np.asarray(skeleton.region)
    assert not valid[region == 2].all()
    assert valid[region != 2].all()
    # The map has no stretch at the vertices left in place: NaN exactly there.
    stretch = np.asarray(fj.pose_stretch(registration, skeleton, poses))
    np.testing.assert_array_equal(np.isnan(stretch), ~valid)
    # The check's reach certificate is the coarse one (the region's test keeps its samples):
    # traced only, nothing compiled.
    poser = jax.eval_shape(lambda: limb_poser(
        registration.registrations[2], limb_target(registration, 2, poses[2]), "radial"))
    assert poser.region.reach.bounds.shape == (CERTIFICATE_SAMPLES,)
    assert poser.region.positions.shape == (3, REACH_SAMPLES) != (3, CERTIFICATE_SAMPLES)


def test_past_its_range_a_limb_stays_whole_and_is_flagged_inexact(tube, skeleton,
                                                                   registration):
    """Past a joint's exact range the limb's sections are carried whole, blended in from the
    range to twice it: no torn edge (folded 175°, the formulas continued left edges 13×
    longer), every vertex past the joint flagged inexact, none before it; within the range,
    the exact pose. The volume the sections' motion loses is given back along the blended
    vertices' normals (`_skeleton.restore`) in proportion to the blend (0.994 at 175°): the
    mesh then keeps its volume to 1e-5 (−0.17 % before), inexact all the same."""
    k = 2
    exact = float(fj.joint_range(registration, k))
    region = np.asarray(skeleton.region)
    rest = np.asarray(tube.vertices)
    s = np.full(len(rest), np.nan)
    s[np.asarray(registration.indices[k])] = np.asarray(
        registration.registrations[k].arc_length)[: int(np.sum(region == k))]
    past = region == k
    past[past] = s[past] >= float(registration.joints[k])
    within, valid_within = _pose(registration, skeleton, {k: fj.LimbPose(0.9 * exact)})
    assert valid_within.all()
    folded, valid = _pose(registration, skeleton, {k: fj.LimbPose(175)})
    assert _stretch(tube, rest, folded).max() < 5
    np.testing.assert_array_equal(valid, ~past)
    np.testing.assert_array_equal(folded[region != k], rest[region != k])
    assert abs(float(fj.volume_change(rest, folded, tube.faces))) < 2e-5


def test_a_traced_frame_weighs_the_sections_on_the_limb_s_own_rows(registration):
    """Traced, a limb's weights towards its sections' motion are computed on its own rows, not
    on the padding its zone and registration share with the largest limb (`_section_inputs`'
    `rows`): the same weights, some of them positive (limb 2 folded past its range)."""
    from fleshing_jax._skeleton.posing import _section_inputs, _section_weights

    k, n = 2, registration.indices[2].shape[0]

    @jax.jit
    def weights(pose):
        return [_section_weights(*_section_inputs(registration, k, pose, rows), n)
                for rows in (None, n)]

    padded, own = map(np.asarray, weights(fj.LimbPose(175.0, 0.0)))
    assert own.shape == (n,) and padded.shape[0] > n and own.max() > 0
    np.testing.assert_array_equal(own, padded[:n])


def test_a_large_region_s_check_gives_the_sampled_test_s_flags(single, monkeypatch):
    """A region of `CERTIFIED_FROM` rows or more is certified on its valid region's own
    samples; on looked-up frames (float32) its points are bent, the pending ones tested at
    images placed from there, and all placed (`Poser.pose`, `PLACED_APART_FROM` points on):
    the flags are those of the sampled test run on every point, folded (some fail it) and
    bent less (none do); the images are those placed point by point in the frames looked up
    (`Poser.place` places them a coordinate at a time)."""
    from fleshing_jax._fleshing import pipeline

    monkeypatch.setattr(pipeline, "PLACED_APART_FROM", 0)  # (read when tracing)
    k, reg = 0, single.registrations[0]
    assert certificate_samples(CERTIFIED_FROM - 1) == CERTIFICATE_SAMPLES

    @jax.jit
    def flags(target):
        poser = _limb_poser(reg.ends, jnp.float32, target, "radial", True, None,
                            certificate_samples(CERTIFIED_FROM))
        assert poser.region.reach.bounds.shape == (REACH_SAMPLES,)
        images, valid = poser.pose(reg)
        bent = poser.bend(reg)
        clear = jax.vmap(poser.region.clear)(images, bent.arc_length)  # every point's
        sampled = (bent.certified | bent.pending) & clear
        placed = jax.vmap(poser._placed)((bent.arc_length, bent.x, bent.y))[0]
        kept = poser._kept(valid, reg)[:, None]
        one_by_one = poser.rigid(reg, jnp.where(kept, placed, reg.points), valid)[0]
        return (valid, poser.rigid(reg, images, sampled)[1], bent.certified, bent.pending,
                images, one_by_one)

    for angle, rejected in ((175.0, True), (60.0, False)):
        valid, expected, certified, pending, images, one_by_one = map(np.asarray, flags(
            limb_target(single, k, fj.LimbPose(angle, 0))))
        np.testing.assert_array_equal(valid, expected)
        np.testing.assert_allclose(images, one_by_one, rtol=0, atol=1e-6)
        assert np.abs(images - reg.points).max() > 0.1
        assert (pending & ~valid).any() == rejected
        # (Both ways of passing are taken: at 60°, 79 points certified, 113 tested.)
        assert pending.any() and certified.any() != rejected


@pytest.fixture(scope="module")
def flat():
    """The tube pressed flat: its cross-section an ellipse, 0.3 across in y, 0.1 in z; the same
    limbs (the same shapes: the tube's compiled programs serve it). `(mesh, skeleton,
    registration)`."""
    from _posing_shapes import RADIUS, tube_registration, tube_skeleton

    angle = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    mesh = fj.extrusion(RADIUS * np.stack([np.cos(angle), np.sin(angle) / 3], 1), 6.0, 60)
    skeleton = tube_skeleton(mesh)
    return mesh, skeleton, tube_registration(mesh, skeleton)


def test_an_exact_pose_in_a_thin_direction_is_the_map_s_own(flat):
    """The blend past the range starts where the map over the zone stops being exact in the
    direction asked, not at each vertex's worst one: the flat limb bends towards its thin side
    about three times as far as towards its wide side exactly; between the two, a bend towards
    the thin side is the map's, bit for bit and unflagged, and one towards the wide side is
    blended (all flagged past the joint)."""
    from fleshing_jax._skeleton.posing import posed_limbs

    mesh, skeleton, registration = flat
    k, region = 2, np.asarray(skeleton.region)
    thin, wide = (float(fj.joint_range(registration, k, towards=up))
                  for up in ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)))
    assert float(fj.joint_range(registration, k)) <= wide and 2.5 * wide < thin < 3.5 * wide
    ids, n = np.asarray(registration.indices[k]), int(np.sum(region == k))
    bend = 0.5 * (wide + thin)
    for up, exact in (((0.0, 0.0, 1.0), True), ((0.0, 1.0, 0.0), False)):
        poses = {k: fj.LimbPose(bend, towards=up)}
        vertices, valid = _pose(registration, skeleton, poses)
        own = np.asarray(posed_limbs(registration, poses, "radial", True, False)[k][0])[:n]
        assert np.array_equal(vertices[ids], own) == exact
        assert valid.all() == exact and valid[region != k].all()
    # At the largest exact bend (floored) towards its wide side, exact still.
    poses = {k: fj.LimbPose(wide - 1e-6, towards=(0.0, 1.0, 0.0))}
    assert _pose(registration, skeleton, poses)[1].all()
    # The blend's weight is continuous in the direction: its measure, the largest vertex's
    # excess, swept over a full turn in 1/10° steps at that bend, from exact to blended.
    zone, joint = registration.zones[k], registration.joints[k]
    theta = jnp.radians(bend)
    stop = zone.end(theta, joint, registration.stops[k])
    excess = np.asarray(jax.jit(jax.vmap(lambda phi: jnp.max(zone.margins(
        theta, phi, 0.0, joint, stop))))(jnp.radians(jnp.linspace(0, 360, 3601))))
    assert excess.min() < -0.3 and excess.max() > 0.3
    assert np.max(np.abs(np.diff(excess))) < 0.01
    # Each vertex's margin, with a twist too, is the formula's (`JointZone.margins`), here
    # in NumPy, vertex by vertex.
    phi, psi = 1.1, 0.4
    margins = np.asarray(zone.margins(theta, phi, psi, joint, stop))
    width = float(stop - joint)
    r, slope = map(np.asarray, ramp(jnp.clip((zone.arc - joint) / width, 0, 1)))
    t, first, second = np.asarray(zone.axes)
    axis = np.cross(t, np.cos(phi) * first + np.sin(phi) * second)
    rests, moments = np.asarray(zone.rests), np.asarray(zone.moments)
    angle = -psi * r[:, None]  # (Rodrigues: `axis` turned about `t`)
    turned = (np.cos(angle) * axis + np.sin(angle) * np.cross(t, axis)
              + (1 - np.cos(angle)) * (t @ axis) * t)
    rate = np.einsum("nc,nc->n", moments, turned)
    bent = slope / width * (float(theta) * rate + psi * np.asarray(zone.twisting))
    room = np.maximum(WHOLE_FROM - rests, WHOLE_FROM / 2)
    np.testing.assert_allclose(margins, (rests + bent - WHOLE_FROM) / room, rtol=1e-9, atol=1e-12)
    assert margins.max() > 0 and (rate != 0).sum() > 10


def test_pose_stretch_is_the_posed_map_s_and_one_elsewhere(skeleton, registration):
    np.testing.assert_array_equal(fj.pose_stretch(registration, skeleton, {}), 1.0)
    stretch = np.asarray(fj.pose_stretch(registration, skeleton, {0: fj.LimbPose(40, 90)}))
    # The body and the still limb untouched, the child carried rigidly: 1 there.
    region = np.asarray(skeleton.region)
    np.testing.assert_array_equal(stretch[region != 0], 1.0)
    inside = stretch[region == 0]
    assert np.all(np.isfinite(inside)) and np.all(inside >= 1) and inside.max() > 1.2


def test_pose_command(tube, skeleton, tmp_path, capsys):
    from fleshing_jax._cli import main

    mesh, saved = tmp_path / "tube.obj", tmp_path / "tube.json"
    tube.export(mesh)
    fj.save_skeleton(skeleton, saved)
    out = tmp_path / "posed.obj"
    arguments = ["pose", str(mesh), str(out), "--skeleton", str(saved)]
    assert main([*arguments, "--limb", "0", "--bend", "40", "--direction", "90",
                 "--at", "0.2,0,0", "--bend", "30"]) == 0
    printed = capsys.readouterr().out
    assert "volume after" in printed and "invalid vertices: 0 of" in printed
    posed = fj.load_mesh(out)
    stretch = np.asarray(fj.edge_stretch(tube, posed.vertices))
    worst = int(np.argmax(stretch))
    # (Both bent limbs' zones squeeze their inner sides alike: either may hold the largest.)
    ties = {int(skeleton.region[v]) for v in np.flatnonzero(stretch > stretch[worst] - 1e-6)}
    assert any(f"largest edge stretch: {stretch[worst]:.3g}× (limb {limb}," in printed
               for limb in ties)
    rest, region = np.asarray(tube.vertices), np.asarray(skeleton.region)
    np.testing.assert_allclose(posed.vertices[region == -1], rest[region == -1], atol=1e-6)
    moved = np.linalg.norm(posed.vertices - rest, axis=1)
    assert moved[region == 2].max() > 0.3 and moved[region == 1].max() > 0.3  # --at: limb 2
    # The same poses from a file.
    poses = tmp_path / "poses.json"
    poses.write_text('[{"limb": 0, "bend": 40, "direction": 90}, {"at": [0.2, 0, 0], "bend": 30}]')
    again = tmp_path / "again.obj"
    assert main(["pose", str(mesh), str(again), "--skeleton", str(saved),
                 "--poses", str(poses)]) == 0
    np.testing.assert_array_equal(fj.load_mesh(again).vertices, posed.vertices)
    # The map's own principal stretch, and the vertex where it is largest.
    principal = np.asarray(fj.pose_stretch(tube, skeleton, {0: fj.LimbPose(40, 90),
                                                            2: fj.LimbPose(30)}))
    most = int(np.argmax(principal))
    assert (f"largest principal stretch of the map: {principal[most]:.3g}× (limb "
            f"{skeleton.region[most]}, vertex ") in printed  # (ties: the file's rounding)
    # Valid but more distorted than allowed: not written, status 3.
    distorted = tmp_path / "distorted.obj"
    assert main([*arguments[:2], str(distorted), *arguments[3:], "--poses", str(poses),
                 "--max-stretch", f"{0.99 * principal[most]:.6f}"]) == 3
    assert "stretches or squeezes the shape" in capsys.readouterr().err
    assert not distorted.exists()
    # Too far: not written, status 3, the causes printed.
    folded = tmp_path / "folded.obj"
    assert main([*arguments[:2], str(folded), *arguments[3:], "--limb", "2", "--bend", "175"]) == 3
    captured = capsys.readouterr()
    assert "limb 2:" in captured.out and "not written" in captured.err and not folded.exists()
    # The advice names the largest bend that works in the direction asked: exact there.
    registered = fj.register_skeleton(tube, skeleton)
    largest = np.floor(100 * float(fj.joint_range(registered, 2, 0.0))) / 100
    assert f"advice: bend limb 2 at most {largest:.2f} degrees" in captured.out
    assert largest > float(fj.joint_range(registered, 2))
    assert np.asarray(fj.pose_skeleton(registered, skeleton, {2: fj.LimbPose(largest)}).valid).all()
    # Written anyway (inexact past the range, each section carried whole: no torn edge).
    assert main([*arguments[:2], str(folded), *arguments[3:], "--limb", "2", "--bend", "175",
                 "--allow-inexact", "--max-stretch", "8"]) == 0
    assert np.asarray(fj.edge_stretch(tube, fj.load_mesh(folded).vertices)).max() < 8


def test_pose_and_skeleton_commands_close_holes_when_asked(tube, skeleton, tmp_path, capsys):
    # The tube open at x = 0: `skeleton` says to pass --cap-holes; `pose --cap-holes` poses
    # the capped mesh (one vertex added, on limb 2) and writes the input's own faces.
    import trimesh

    from fleshing_jax._cli import main

    # (Its cap's centre dropped: capped again, a vertex at the same place ends the list, and
    # the posing programs are the tube's.)
    vertices, faces = np.asarray(tube.vertices), np.asarray(tube.faces)
    cap = np.all(vertices[faces][..., 0] == 0, axis=1)
    centre = np.setdiff1d(faces[cap], faces[~cap])
    keep = np.delete(np.arange(len(vertices)), centre)
    opened = trimesh.Trimesh(vertices[keep], np.searchsorted(keep, faces[~cap]), process=False)
    path, saved, out = tmp_path / "open.obj", tmp_path / "capped.json", tmp_path / "out.obj"
    opened.export(path)
    assert main(["skeleton", str(path), str(tmp_path / "sk.json")]) == 2
    assert "not closed" in (err := capsys.readouterr().err) and "pass --cap-holes" in err
    capped = fj.cap_holes(opened)
    region = np.r_[np.asarray(skeleton.region)[keep], 2]
    fj.save_skeleton(fj.Skeleton(skeleton.limbs, region, capped.vertices), saved)
    arguments = ["pose", str(path), str(out), "--skeleton", str(saved), "--limb", "0",
                 "--bend", "40", "--direction", "90"]
    assert main(arguments) == 2
    assert "pass --cap-holes" in capsys.readouterr().err
    assert main([*arguments, "--cap-holes"]) == 0
    posed = trimesh.load(out, process=False)
    expected = fj.pose_skeleton(fj.register_skeleton(tube, skeleton), skeleton,
                                {0: fj.LimbPose(40.0, 90.0)}).vertices
    assert np.array_equal(posed.faces, opened.faces)
    np.testing.assert_allclose(posed.vertices, np.asarray(expected)[keep], atol=1e-6)


@pytest.mark.slow  # (the command's diagnosis and stretch of a second limb: 16 s, cold)
def test_pose_command_names_the_child_carrying_a_bend_on(tube, skeleton, tmp_path, capsys):
    from fleshing_jax._cli import main

    mesh, saved = tmp_path / "tube.obj", tmp_path / "tube.json"
    tube.export(mesh)
    fj.save_skeleton(skeleton, saved)
    # Limb 0 past its and its free child's ranges: both inexact, the child named as carrying
    # the bend on (it has no pose of the user's to advise on).
    assert main(["pose", str(mesh), str(tmp_path / "posed.obj"), "--skeleton", str(saved),
                 "--limb", "0", "--bend", "175"]) == 3
    printed = capsys.readouterr().out
    assert "limb 0:" in printed and "advice: limb 1 carries its parent's bend on" in printed
    # Limb 0's advice counts its free child's part (`fj.joint_range`): exact at that bend.
    largest = float(printed.split("advice: bend limb 0 at most ")[1].split()[0])
    assert f"{largest:.2f} degrees (its exact range at its joint in this direction, limb 1 " \
        "carrying the rest on)" in printed
    registration = fj.register_skeleton(tube, skeleton)
    assert largest > float(fj.joint_range(registration, 0, 0.0, children_posed=True))
    posed = fj.pose_skeleton(registration, skeleton, {0: fj.LimbPose(largest)})
    assert np.asarray(posed.valid).all()


@pytest.mark.parametrize(
    "options, message",
    [
        (["--bend", "30"], "must follow --limb"),
        (["--limb", "9", "--bend", "30"], "no limb 9"),
        (["--limb", "knee", "--bend", "30"], "no limb 'knee'"),
        (["--limb", "0"], "has no --bend"),
        (["--limb", "0", "--bend", "10", "--bend", "20"], "given twice"),
        (["--at", "3,0,0", "--bend", "10"], "on the body"),
        (["--limb", "0", "--bend", "10", "--limb", "0", "--bend", "5"], "posed twice"),
        ([], "--limb/--at groups or with --poses"),
        (["--limb", "0", "--bend", "10", "--max-stretch", "0.5"], "--max-stretch"),
    ],
)
def test_pose_command_refuses_bad_poses(tube, skeleton, tmp_path, capsys, options, message):
    from fleshing_jax._cli import main

    mesh, saved = tmp_path / "tube.obj", tmp_path / "tube.json"
    tube.export(mesh)
    fj.save_skeleton(skeleton, saved)
    out = tmp_path / "out.obj"
    assert main(["pose", str(mesh), str(out), "--skeleton", str(saved), *options]) == 2
    assert message in capsys.readouterr().err and not out.exists()


def test_pose_command_takes_a_limb_s_name(skeleton):
    from fleshing_jax._cli import _limb_key, _limb_poses

    named = fj.Skeleton([fj.Limb(limb.spine, limb.joint, limb.parent, f"bone{k}")
                         for k, limb in enumerate(skeleton.limbs)],
                        skeleton.region, skeleton.vertices)  # fmt: skip
    groups = [{"limb": _limb_key("bone2"), "bend": 30}, {"limb": _limb_key("0"), "bend": 10}]
    assert sorted(_limb_poses(groups, named, "poses")) == [0, 2]
    with pytest.raises(ValueError, match="no limb 'bone9'; the skeleton has limbs 0 to 2, "
                                         "named bone0, bone1, bone2"):
        _limb_poses([{"limb": "bone9", "bend": 30}], named, "poses")


def test_pose_command_reads_a_negative_point_and_refuses_no_pose(tube, skeleton, tmp_path,
                                                                 capsys):
    from fleshing_jax._cli import _values_attached, main

    # A point starting with a minus is the value of --at, not an option.
    assert _values_attached(["pose", "a", "b", "--at", "-2.9,0,0", "--bend", "-10"]) == [
        "pose", "a", "b", "--at=-2.9,0,0", "--bend", "-10"]
    mesh, saved, poses = tmp_path / "tube.obj", tmp_path / "tube.json", tmp_path / "p.json"
    tube.export(mesh)
    fj.save_skeleton(skeleton, saved)
    poses.write_text("[]")
    out = tmp_path / "posed.obj"
    assert main(["pose", str(mesh), str(out), "--skeleton", str(saved), "--poses",
                 str(poses)]) == 2
    assert "lists no pose" in capsys.readouterr().err and not out.exists()


def test_vertices_not_registered_past_the_bend_move_with_the_limb(tube, skeleton, registration):
    """A vertex of a limb's region not validly registered on its rest spine (near a focal
    point at rest, as under an insect's bent knee) but projecting past the bend moves with the
    limb's rigid part, flagged: left at rest, it tore its edges (23.6× on the insect)."""
    import equinox as eqx

    k = 2
    ids = np.asarray(registration.indices[k])
    x = np.asarray(tube.vertices)[ids, 0]
    far = np.flatnonzero(x < 0.5)[:3]  # limb 2 runs along −x from x = 2: far past a 30° zone
    valid = np.asarray(registration.registrations[k].valid).copy()  # (padded past the region)
    valid[far] = False
    broken = eqx.tree_at(lambda r: r.registrations[k].valid, registration, jnp.asarray(valid))
    pose = {k: fj.LimbPose(30.0, 20.0)}
    exact = fj.pose_skeleton(registration, skeleton, pose)
    moved = fj.pose_skeleton(broken, skeleton, pose)
    assert not np.asarray(moved.valid)[ids[far]].any()  # flagged, not certified
    # Placed as the exact pose places them (the rigid part's motion), not left at rest.
    np.testing.assert_allclose(np.asarray(moved.vertices)[ids[far]],
                               np.asarray(exact.vertices)[ids[far]], atol=1e-9)
    rest = np.asarray(tube.vertices)[ids[far]]
    assert np.linalg.norm(np.asarray(moved.vertices)[ids[far]] - rest, axis=1).min() > 0.1


def test_vertices_not_registered_in_the_zone_move_with_their_cross_section(tube, skeleton,
                                                                            registration):
    """A vertex not validly registered whose projection falls inside the joint's zone moves
    as the bent limb's cross-section there does (`BentSpine.carried`), flagged: left at rest,
    it tore its edges (3.2× on the insect's front leg bent 30°)."""
    import equinox as eqx

    from fleshing_jax._skeleton.posing import bend_stop

    k, pose = 2, fj.LimbPose(30.0, 20.0)
    ids = np.asarray(registration.indices[k])
    s = np.asarray(registration.registrations[k].arc_length)[: ids.size]
    joint, stop = float(registration.joints[k]), float(bend_stop(registration, k, pose))
    zone = np.flatnonzero((s > joint + 0.3 * (stop - joint)) & (s < stop))[:4]
    assert zone.size == 4
    valid = np.asarray(registration.registrations[k].valid).copy()
    valid[zone] = False
    broken = eqx.tree_at(lambda r: r.registrations[k].valid, registration, jnp.asarray(valid))
    exact = np.asarray(fj.pose_skeleton(registration, skeleton, {k: pose}).vertices)[ids[zone]]
    moved = fj.pose_skeleton(broken, skeleton, {k: pose})
    assert not np.asarray(moved.valid)[ids[zone]].any()
    rest = np.asarray(tube.vertices)[ids[zone]]
    # Near where the fleshing places them (up to its change of their section, which the
    # bend's concave side needs), not at rest: their edges hold.
    travel = np.linalg.norm(exact - rest, axis=1)
    assert travel.min() > 0.02
    off = np.linalg.norm(np.asarray(moved.vertices)[ids[zone]] - exact, axis=1)
    assert np.all(off < 0.25 * travel), (off, travel)
    edges = tube.edges_unique[np.isin(tube.edges_unique, ids[zone]).any(axis=1)]
    stretch = _stretch(tube, np.asarray(tube.vertices), np.asarray(moved.vertices), edges)
    assert 1 / 1.5 < stretch.min() and stretch.max() < 1.5, (stretch.min(), stretch.max())


def test_a_fit_s_blend_is_its_value_differentiated_as_the_images_it_moves():
    """`posing._held_blend` without its tangent (a shape fit's objective: `posed`'s
    `blend_tangent=False`): the blend's value where some weight is positive, else the images
    themselves; differentiated as the images alone, whatever the blend's own derivative."""
    from fleshing_jax._skeleton.posing import _held_blend

    def blend(target, points, s, weight, images):
        return images + weight[:, None] * (target * points - images) + s[:, None]

    points, s = jnp.arange(6.0).reshape(2, 3), jnp.asarray([0.5, 2.0])
    images = points + 1

    def held(target, weight, images, tangent):
        return _held_blend(blend, tangent, target, points, s, weight, images)

    for weight in (jnp.asarray([0.0, 0.25]), jnp.zeros(2)):
        args = (jnp.asarray(3.0), weight, images)
        ones = jax.tree.map(jnp.ones_like, args)
        (v, dv), (w, dw) = (jax.jvp(lambda *a, t=t: held(*a, t), args, ones)
                            for t in (True, False))
        np.testing.assert_array_equal(v, w)
        np.testing.assert_array_equal(v, blend(*args[:1], points, s, *args[1:])
                                      if weight.any() else images)
        np.testing.assert_array_equal(dw, jnp.ones_like(images))
        assert np.array_equal(dv, dw) != bool(weight.any())

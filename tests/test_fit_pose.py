"""Fitting a skeleton's pose to target positions (`fj.fit_skeleton_pose`).

On the posing tests' tube (`_posing_shapes`), float64: every fit chooses the same number of
vertices and fits all three limbs, so that the tests share one compiled solve.

The solve's one XLA program (Levenberg–Marquardt through three limbs' fleshing and its forward
derivatives) took about 4 minutes to compile on the shared 2-core machine, and every fit was
`slow`; with the limbs posed as one batch and the Jacobian materialised (`_fit.jacobian`) it
takes about 20 s. The first two fits share it and run by default; the two that compile
programs of their own (fewer steps, other limbs: 15–20 s each) are `slow`, for the suite's
time.
"""

import re

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import fleshing_jax as fj

TRUTH = {0: fj.LimbPose(40, 60, 15), 1: fj.LimbPose(25, -30, 0), 2: fj.LimbPose(35, 120, -10)}


@pytest.fixture(scope="module")
def ids(skeleton):
    """Five vertices on each limb's far end, off its axis (so that its twist shows)."""
    region = np.asarray(skeleton.region)
    # (Farthest from the body, at x = 3: past each limb's bending zone.)
    far = np.argsort(-np.abs(np.asarray(skeleton.vertices)[:, 0] - 3.0), kind="stable")
    return np.concatenate([far[region[far] == k][:40:9] for k in range(3)])


def _targets(registration, skeleton, ids, poses):
    posed = fj.pose_skeleton(registration, skeleton, poses)
    assert np.asarray(posed.valid).all()
    return np.asarray(posed.vertices)[ids]


def _angles(pose):
    return np.array([float(pose.bend), float(pose.direction), float(pose.twist)])


def test_fit_recovers_the_angles_from_the_rest_pose(skeleton, registration, ids):
    targets = _targets(registration, skeleton, ids, TRUTH)
    fit = fj.fit_skeleton_pose(registration, skeleton, ids, targets)
    assert fit.converged, fit.message
    assert fit.message == "" and fit.num_invalid == 0 and 0 < int(fit.num_steps) < 64
    assert float(fit.rms) < 1e-9
    for k, pose in TRUTH.items():
        np.testing.assert_allclose(_angles(fit.poses[k]), _angles(pose), atol=1e-6)
    # The fitted poses are `pose_skeleton`'s: they put the vertices on the targets.
    vertices = np.asarray(fj.pose_skeleton(registration, skeleton, fit.poses).vertices)
    np.testing.assert_allclose(vertices[ids], targets, atol=1e-9)
    np.testing.assert_array_equal(np.asarray(fit.posed.vertices), vertices)


def test_unreachable_targets_are_not_reported_as_a_fit(skeleton, registration, ids):
    # Limb 2 folded back on itself (the posing tests' invalid bend): its vertices inside the
    # fold (0.8 < x < 1.2, flagged there) are sent where the map would tear them to, which no
    # valid pose reaches. (Its vertices chosen by `ids`, near its joint, are valid even there.)
    from fleshing_jax._skeleton.posing import posed

    truth = {**TRUTH, 2: fj.LimbPose(175, 0)}
    x = np.asarray(skeleton.vertices)[:, 0]
    inside = np.flatnonzero((np.asarray(skeleton.region) == 2) & (x > 0.8) & (x < 1.2))
    chosen = np.concatenate([ids[:10], inside[:: len(inside) // 5][:5]])
    # (Posed as the fit's objective poses, as one batch: the program the batch's test builds.)
    torn = posed(registration, skeleton, truth, "radial", check=False, stacked=True).vertices
    targets = np.asarray(torn)[chosen]
    fit = fj.fit_skeleton_pose(registration, skeleton, chosen, targets)
    assert not fit.converged
    assert fit.message
    assert float(fit.rms) > 1e-3


def test_a_solve_stopped_short_of_its_minimum_is_not_converged(skeleton, registration, ids):
    # A solver told to stop at once (rtol = atol = 1: its Cauchy test passes on its first step)
    # reports success where it started, limb 0 bent 0.7° too far: its trust region never
    # shrank (no stall), but the Gauss-Newton step says it is no minimum. (The default fit's
    # compiled solve: the tolerances are values.)
    targets = _targets(registration, skeleton, ids, TRUTH)
    start = {**TRUTH, 0: fj.LimbPose(40.7, 60, 15)}
    fit = fj.fit_skeleton_pose(registration, skeleton, ids, targets, init=start, rtol=1.0,
                               atol=1.0)
    assert fit.result == optx.RESULTS.successful and not fit.converged
    assert "stopped short of a minimum" in fit.message, fit.message
    assert "limb 0 by 0.7" in fit.message and "limb 2" not in fit.message, fit.message


@pytest.mark.slow
def test_a_solve_cut_short_is_not_converged(skeleton, registration, ids):
    targets = _targets(registration, skeleton, ids, TRUTH)
    fit = fj.fit_skeleton_pose(registration, skeleton, ids, targets, max_steps=2)
    assert not fit.converged
    assert "steps" in fit.message


@pytest.mark.slow
def test_default_limbs_and_held_poses(skeleton, registration, ids):
    region = np.asarray(skeleton.region)
    child = ids[region[ids] == 1]
    # Only limb 1's vertices: it and its parent 0 are fitted, limb 2 is held where `init` put it.
    targets = _targets(registration, skeleton, child, TRUTH)
    fit = fj.fit_skeleton_pose(registration, skeleton, child, targets, init={2: TRUTH[2]})
    assert fit.converged, fit.message
    assert sorted(fit.poses) == [0, 1, 2]
    np.testing.assert_array_equal(_angles(fit.poses[2]), _angles(TRUTH[2]))
    assert float(fit.rms) < 1e-9


def test_limbs_posed_as_one_batch_are_posed_as_one_by_one(skeleton, registration):
    # The fit's objective poses its limbs as one batch (`stacked`), without the global
    # projection check: the vertices of `pose_skeleton` (one by one, checked), every one valid
    # both ways at these poses. (Against `pose_skeleton`'s program, which the fits build
    # anyway, rather than an unchecked one-by-one program of its own: 5-7 s of compile.)
    from fleshing_jax._skeleton.posing import posed

    one_by_one = fj.pose_skeleton(registration, skeleton, TRUTH)
    batched = posed(registration, skeleton, TRUTH, "radial", check=False, stacked=True)
    np.testing.assert_allclose(np.asarray(batched.vertices), np.asarray(one_by_one.vertices),
                               rtol=0, atol=1e-13)
    assert np.asarray(batched.valid).all() and np.asarray(one_by_one.valid).all()
    moved = np.any(np.asarray(one_by_one.vertices) != np.asarray(registration.vertices), axis=1)
    region = np.asarray(skeleton.region)
    assert all(moved[region == k].any() for k in TRUTH) and not moved[region == -1].any()


def test_a_solve_poses_only_the_rows_its_limbs_bend(skeleton, registration):
    # A shape fit's solve fleshes only the rows between each limb's joint and its room's end
    # (`restricted(bent=)`); the others move with the limb's end motion, or are still
    # (`rigid_rows`): the vertices of `pose_skeleton`, to round-off.
    from fleshing_jax._skeleton.fit_pose import restricted, rigid_rows
    from fleshing_jax._skeleton.posing import posed

    ids = np.arange(registration.vertices.shape[0])
    small, rows, rigid = restricted(registration, ids, bucketed=False, bent=tuple(TRUTH))
    region = np.asarray(skeleton.region)
    for k, (past, before) in rigid.items():
        kept = small.indices[k].shape[0]
        assert kept + len(past) + len(before) == np.sum(region == k)
    assert sum(len(p) for p, _ in rigid.values())  # (some limb moves rigidly past its room)
    out, carried = posed(small, skeleton, TRUTH, "radial", check=False, stacked=True,
                         motions=True)
    vertices = rigid_rows(out.vertices, small.vertices, carried, rigid, skeleton)
    whole = fj.pose_skeleton(registration, skeleton, TRUTH)
    np.testing.assert_allclose(np.asarray(vertices)[np.asarray(rows)],
                               np.asarray(whole.vertices), rtol=0, atol=1e-12)


def test_bad_input(tube, skeleton, registration, ids):
    targets = np.zeros((len(ids), 3))

    def fit(**kwargs):
        args = dict(vertex_ids=ids, targets=targets) | kwargs
        return fj.fit_skeleton_pose(registration, skeleton, args.pop("vertex_ids"),
                                    args.pop("targets"), **args)

    n = len(tube.vertices)
    with pytest.raises(ValueError, match="`vertex_ids`"):
        fit(vertex_ids=np.array([0, n]))
    with pytest.raises(ValueError, match="`vertex_ids`"):
        fit(vertex_ids=np.array([], int), targets=np.zeros((0, 3)))
    with pytest.raises(TypeError, match="`vertex_ids`"):
        fit(vertex_ids=np.array([0.5]))
    with pytest.raises(ValueError, match="`targets`"):
        fit(targets=np.zeros((len(ids) + 1, 3)))
    with pytest.raises(ValueError, match="`targets`"):
        fit(targets=np.full((len(ids), 3), np.nan))
    with pytest.raises(ValueError, match="`limbs`: 3 is not a limb index"):
        fit(limbs=[0, 3])
    with pytest.raises(ValueError, match="`init`: 5 is not a limb index"):
        fit(init={5: fj.LimbPose()})
    with pytest.raises(ValueError, match="nothing to fit"):
        fit(limbs=[])
    body = np.flatnonzero(np.asarray(skeleton.region) == -1)[:3]
    with pytest.raises(ValueError, match="nothing to fit"):
        fit(vertex_ids=body, targets=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="`method`"):
        fit(method="bent")


# Fitting to a shape without correspondences (`target=`): limbs 0 and 2 of the tube bent,
# recovered from 5,000 samples of the posed surface. (The tube is round: its twists are held.
# Limb 1, its tip's cap, is too small for 0.5 % noise to resolve: not fitted here.)
SHAPE_TRUTH = {0: fj.LimbPose(50.0, 60.0), 2: fj.LimbPose(60.0, 120.0)}


@pytest.fixture(scope="module")
def samples(tube, registration, skeleton):
    """5,000 samples of the tube posed by `SHAPE_TRUTH` (K, 3), their normals (K, 3), and the
    samples' diagonal."""
    import trimesh

    vertices = np.asarray(fj.pose_skeleton(registration, skeleton, SHAPE_TRUTH).vertices)
    mesh = trimesh.Trimesh(vertices, tube.faces, process=False)
    points, faces = trimesh.sample.sample_surface(mesh, 5000, seed=1)
    return points, mesh.face_normals[faces], float(np.linalg.norm(np.ptp(points, axis=0)))


def _angle_errors(fit):
    return np.array([[float(fit.poses[k].bend) - float(pose.bend),
                      float(fit.poses[k].direction) - float(pose.direction)]
                     for k, pose in SHAPE_TRUTH.items()])


def _shape_fit(registration, skeleton, points):
    return fj.fit_skeleton_pose(registration, skeleton, target=points, limbs=[0, 2])


def test_shape_fit_recovers_the_angles_of_a_clean_sample(skeleton, registration, samples):
    fit = _shape_fit(registration, skeleton, samples[0])
    assert fit.converged, fit.message
    assert np.abs(_angle_errors(fit)).max() < 1.0, _angle_errors(fit)
    assert float(fit.poses[0].twist) == 0.0  # held: a round limb's twist does not show
    assert fit.num_invalid == 0 and fit.posed.vertices.shape == registration.vertices.shape


def test_a_shape_fit_stopped_short_of_its_minimum_is_not_converged(skeleton, registration,
                                                                   samples):
    # A solver told to stop at once (rtol = atol = 1: its Cauchy test passes on its first
    # step) reports success where it started, limb 0 bent 0.7° too far: the posed surface
    # explains the clean sample there as well as at the truth (a residual test cannot tell),
    # but the Gauss-Newton step says it is no minimum. (The clean fit's compiled solve: the
    # tolerances are values.)
    start = {**SHAPE_TRUTH, 0: fj.LimbPose(50.7, 60.0)}
    fit = fj.fit_skeleton_pose(registration, skeleton, target=samples[0], limbs=[0, 2],
                               init=start, rtol=1.0, atol=1.0)
    assert fit.result == optx.RESULTS.successful and not fit.converged
    assert "stopped short of a minimum" in fit.message, fit.message
    # (0.68°: the last stage's points, each fitted limb's part of the sample, place the
    # sampled loss's minimum within 0.02° of the truth.)
    assert re.search(r"limb 0 by 0\.(7|6[89])", fit.message), fit.message
    assert "limb 2" not in fit.message, fit.message
    assert fit.stats["predicted_decrease"] > 0.9  # the loss is nearly all that 0.7°
    # Stopped at once at the truth, the same solve is at its minimum: converged.
    fit = fj.fit_skeleton_pose(registration, skeleton, target=samples[0], limbs=[0, 2],
                               init=SHAPE_TRUTH, rtol=1.0, atol=1.0)
    assert fit.converged, fit.message


@pytest.mark.slow
def test_shape_fit_of_a_noisy_sample(skeleton, registration, samples):
    points, _, diagonal = samples
    noisy = points + np.random.default_rng(2).normal(0, 0.005 * diagonal, points.shape)
    fit = _shape_fit(registration, skeleton, noisy)
    assert fit.converged, fit.message
    assert np.abs(_angle_errors(fit)).max() < 2.0, _angle_errors(fit)


@pytest.mark.slow
def test_shape_fit_of_a_partial_scan(skeleton, registration, samples):
    points, normals, _ = samples
    fit = _shape_fit(registration, skeleton, points[normals[:, 1] > 0])  # one side seen
    assert fit.converged, fit.message
    assert np.abs(_angle_errors(fit)).max() < 3.0, _angle_errors(fit)


def test_shape_fit_to_another_shape_is_not_converged(skeleton, registration):
    import trimesh

    sphere = trimesh.creation.icosphere(3, radius=1.5)
    sphere.apply_translation([3.0, 0.0, 0.0])
    fit = _shape_fit(registration, skeleton, sphere)  # a mesh: its surface is sampled
    assert not fit.converged
    assert "does not explain the target" in fit.message


def test_a_limb_the_target_does_not_show_is_not_converged(skeleton, registration, samples):
    # The clean sample without limb 2's part (the points nearest its posed vertices): nothing
    # in the target says how limb 2 is bent, so the fit may not call it converged. (The same
    # limbs and solve sizes as the clean fit: its compiled solve.)
    from scipy.spatial import cKDTree

    posed = np.asarray(fj.pose_skeleton(registration, skeleton, SHAPE_TRUTH).vertices)
    owner = np.asarray(skeleton.region)[cKDTree(posed).query(samples[0])[1]]
    fit = _shape_fit(registration, skeleton, samples[0][owner != 2])
    assert not fit.converged
    assert "limb 2" in fit.message and "limb 0" not in fit.message, fit.message


def test_shape_fit_bad_input(skeleton, registration):
    with pytest.raises(ValueError, match="nothing to fit to"):
        fj.fit_skeleton_pose(registration, skeleton)
    with pytest.raises(ValueError, match="`target`"):
        fj.fit_skeleton_pose(registration, skeleton, target=np.full((10, 3), np.nan))
    with pytest.raises(ValueError, match="`vertex_ids` and `targets`"):
        fj.fit_skeleton_pose(registration, skeleton, [0, 1], target=np.zeros((10, 3)))
    with pytest.raises(ValueError, match="at least 4 points"):
        fj.fit_skeleton_pose(registration, skeleton, target=np.zeros((3, 3)), limbs=[0])


def test_a_small_limb_fitted_wrongly_is_not_explained():
    # 1 % of the target nearest to limb 3, half of it far from the posed surface: the whole
    # target is explained (99.5 % near), limb 3's part is not.
    from fleshing_jax._skeleton.fit_shape import _unexplained

    rest = np.stack([np.arange(100.0), np.zeros(100), np.zeros(100)], axis=1)  # spacing 1
    owner = np.full(10_000, -1)
    owner[:100] = 3
    distances = np.zeros(10_000)
    distances[:50] = 5.0
    message = _unexplained(distances, 0.01, rest, owner, [3])
    assert message.startswith("the posed surface does not explain limb 3's part of it: 50.0 %")
    assert _unexplained(distances, 0.01, rest, owner, []) == ""


def test_a_solve_traces_its_residuals_once():
    # The solver evaluates and linearises the residuals where it starts and in its step: one
    # trace of the posing serves both, so that a fit's posing is traced once. Its Jacobian
    # from one forward pass for both parameters, each moving its own row (`dependence`).
    import uuid

    import equinox as eqx
    import jax.numpy as jnp
    import optimistix as optx

    from fleshing_jax._skeleton.fit_pose import _solve

    traced = []

    class Toy(eqx.Module):
        target: jnp.ndarray
        seeds: jnp.ndarray = eqx.field(default_factory=lambda: jnp.ones((1, 2), bool))
        moves: jnp.ndarray = eqx.field(default_factory=lambda: jnp.eye(2, dtype=bool))
        # A new program each run: the solve is kept on disk, and a second run of the suite
        # loaded it from there without tracing (the count below then read 0).
        run: str = eqx.field(default_factory=lambda: uuid.uuid4().hex)

        def vertices(self, y):
            traced.append(None)
            return jnp.stack([jnp.sin(y), y**3], axis=-1)

        def residuals(self, vertices):
            return vertices[:, 0] - self.target

    solver = optx.LevenbergMarquardt(1e-10, 1e-10)
    y, _, result, _, (jacobian, _) = _solve(Toy(jnp.asarray([0.3, -0.2])), solver,
                                            jnp.zeros(2), 16, False, True)
    assert result == optx.RESULTS.successful
    np.testing.assert_allclose(np.sin(np.asarray(y)), [0.3, -0.2], atol=1e-9)
    np.testing.assert_allclose(jacobian, np.diag(np.cos(np.asarray(y))), atol=1e-12)
    assert len(traced) == 1


def test_a_limb_posed_where_the_target_has_nothing_is_not_explained():
    # Every target point near the posed surface, but 30 % of limb 3's vertices far from the
    # target, against 10 % of the body's (the side a scan does not see): not explained. The
    # same share as the body's is a partial scan's, and passes.
    from fleshing_jax._skeleton.fit_shape import _unexplained

    rest = np.stack([np.arange(100.0), np.zeros(100), np.zeros(100)], axis=1)  # spacing 1
    region = np.full(100, -1)
    region[:50] = 3
    ahead = np.zeros(100)
    ahead[50:55] = 5.0  # the body: 5 of 50
    ahead[:15] = 5.0  # limb 3: 15 of 50
    near = np.zeros(1000)
    owner = np.full(1000, -1)
    message = _unexplained(near, 0.01, rest, owner, [3], ahead, region)
    assert message.startswith("limb 3 is posed where the target has no surface: 30.0 %")
    assert "10.0 % of the body's" in message
    ahead[5:15] = 0.0  # limb 3: 5 of 50, as the body
    assert _unexplained(near, 0.01, rest, owner, [3], ahead, region) == ""


def test_the_angle_spread_is_the_sandwich_standard_error():
    # Linear least squares y = a + b x with known residuals: the sandwich covariance by its
    # formula, and a parameter the residuals do not depend on gets an enormous spread.
    from fleshing_jax._fit.uncertainty import block_spread, covariance
    from fleshing_jax._skeleton.fit_shape import ANGLE_SPREAD, _spreads, _undetermined

    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, 200)
    jac = np.stack([np.ones_like(x), x], axis=1)
    r = rng.normal(0, 0.1, 200)
    inverse = np.linalg.inv(jac.T @ jac)
    expected = inverse @ (jac.T * r**2) @ jac @ inverse
    np.testing.assert_allclose(covariance(jac, r), expected, rtol=1e-10)
    np.testing.assert_allclose(block_spread(expected, [[0], [1]]),
                               np.sqrt(np.diag(expected)), rtol=1e-10)
    # Rows in pairs that share their noise (a point's components): each pair's score squared.
    scores = (jac * r[:, None]).reshape(100, 2, 2).sum(axis=1)
    paired = inverse @ scores.T @ scores @ inverse
    np.testing.assert_allclose(covariance(jac, r, group=2), paired, rtol=1e-10)
    with pytest.raises(ValueError, match="group"):
        covariance(jac, r, group=3)
    # Two limbs of (b₁, b₂, ψ); the second's bend columns are zero (a limb the target misses).
    blind = np.stack([np.ones_like(x), x, x**2, 0 * x, 0 * x, np.cos(3 * x)], axis=1)
    spread = _spreads((blind[:198], r[:198] / 10), (4, 7), 3)  # (b₁, b₂, ψ) per limb
    assert spread[4] < ANGLE_SPREAD and spread[7] > 1e3
    message = _undetermined(spread)
    assert "limb 7 ±" in message and "limb 4" not in message and "markers" in message
    assert _undetermined({4: spread[4]}) == ""


def test_the_gauss_newton_step_of_a_linear_problem_is_its_offset():
    # Linear residuals r = J (y - y*) + e, e orthogonal to J's columns: the step is y* - y
    # exactly, predicting the decrease |J (y - y*)|² of |r|²; a column the residuals do not
    # depend on (a limb the target does not show) takes no step.
    from fleshing_jax._fit.stationarity import gauss_newton_step

    rng = np.random.default_rng(0)
    jac = np.concatenate([rng.normal(size=(60, 3)), np.zeros((60, 1))], axis=1)
    offset = np.array([0.3, -0.2, 0.1, 5.0])
    noise = rng.normal(size=60)
    noise -= jac[:, :3] @ np.linalg.lstsq(jac[:, :3], noise, rcond=None)[0]
    r = jac @ offset + noise
    step, decrease = gauss_newton_step(jac, r)
    np.testing.assert_allclose(step, [-0.3, 0.2, -0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(decrease, np.sum((jac @ offset) ** 2) / np.sum(r**2))
    assert gauss_newton_step(jac, noise)[1] < 1e-20  # at the minimum: no decrease
    with pytest.raises(ValueError, match="jacobian"):
        gauss_newton_step(jac, r[:-1])


def test_the_distance_to_a_surface_is_to_its_closest_triangle_point():
    # A shape fit measures the target to the posed triangles (`_fit.surface`): the closest
    # point of a triangle against a dense sample of it, and a sphere's distances against
    # trimesh's, with finite gradients in the vertices.
    import jax
    import jax.numpy as jnp
    import trimesh

    from fleshing_jax._fit.surface import (
        NEAREST,
        closest_weights,
        covers,
        pool,
        rings,
        to_surface,
    )

    rng = np.random.default_rng(0)
    u = rng.uniform(size=(20000, 2))
    u = u[u.sum(axis=1) <= 1]
    nearest = jax.jit(jax.vmap(closest_weights))
    triangles, points = rng.normal(size=(50, 3, 3)), 2 * rng.normal(size=(50, 3))
    weights = np.asarray(nearest(points, *np.moveaxis(triangles, 1, 0)))
    assert np.all(weights >= -1e-12) and np.allclose(weights.sum(axis=1), 1)
    for tri, y, w in zip(triangles, points, weights):
        dense = np.concatenate([tri, tri[0] + u @ (tri[1:] - tri[0])])  # corners too
        best = np.sqrt(np.min(np.sum((dense - y) ** 2, axis=1)))
        assert best - 0.05 <= np.linalg.norm(y - w @ tri) <= best + 1e-12
    # Beside the sphere, a long triangle with a folded neighbour whose far corner is the
    # nearest vertex of a point on the long one (the last of `y`): its own triangle must be
    # among the candidates still (the rings of its nearest vertices, not of the nearest alone).
    fan = np.array([[0, 0, 0], [4, 0, 0], [2, 1, 0], [2, -0.2, -0.5]]) + [10, 0, 0]
    ball = trimesh.creation.icosphere(2)
    pair = len(ball.vertices) + np.array([[0, 1, 2], [1, 0, 3]])
    ball = trimesh.Trimesh(np.concatenate([ball.vertices, fan]),
                           np.concatenate([ball.faces, pair]), process=False)
    faces = jnp.asarray(ball.faces)
    ring = jnp.asarray(rings(ball.faces, len(ball.vertices)))
    y = np.concatenate([rng.normal(size=(40, 3)), [[12, 0.05, 0]]])

    # Each point's nearest vertices chosen in the program among a pool found on the host: a
    # pool found on the surface moved a little still holds them (`covers`, told by the first
    # columns of the moved surface's own pools, nearest first), one found far from it does not.
    candidates = pool(y, ball.vertices)
    moved = pool(y, ball.vertices + 0.01)
    np.testing.assert_array_equal(moved[:, :NEAREST], pool(y, ball.vertices + 0.01, NEAREST))
    assert covers(candidates, moved)
    assert not covers(pool(y + 3.0, ball.vertices), candidates)

    def squared(v):  # (the distances and their gradient as one program: eagerly, op by op)
        d = to_surface(jnp.asarray(y), v, faces, ring, jnp.asarray(candidates))
        return jnp.sum(d**2), d

    (_, d), grad = jax.jit(jax.value_and_grad(squared, has_aux=True))(jnp.asarray(ball.vertices))
    _, expected, _ = trimesh.proximity.closest_point_naive(ball, y)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(d), axis=1), expected, atol=1e-12)
    assert np.isfinite(np.asarray(grad)).all() and np.any(np.asarray(grad) != 0)


def test_only_a_limb_left_unexplained_is_tried_from_other_starts():
    # A short, thick limb can stop at a minimum of its own (spot's hind leg at 15° for 30°):
    # the limbs whose part of the target stays farther from the posed surface than the body's
    # are tried again (`_stuck`), from more and less bent starts in their direction, or in
    # four directions when barely bent (`_starts`). Noise everywhere alike tries none.
    from types import SimpleNamespace

    from fleshing_jax._skeleton.fit_shape import RESTART, SETTLED_FLOOR, _starts, _stuck

    surface = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    region = np.array([-1, -1, 4, 7])  # the body, then limbs 4 and 7
    cloud = surface + [0, 0.01, 0]  # each target point nearest its own vertex
    problem = SimpleNamespace(cloud=cloud, weights=np.ones(len(cloud)), limbs=(4, 7))

    def linear(off):  # residuals as the solve lays them out: the target's, over √K
        return None, np.concatenate([off.reshape(-1) / np.sqrt(len(cloud)), [0.0, 0.0]])

    body_level = np.array([[0, 0.01, 0]] * 4)
    assert _stuck(problem, linear(body_level), surface, region) == []
    leg_off = body_level.copy()
    leg_off[3] = [0, 0.3, 0]  # limb 7's part left far from the posed surface
    assert _stuck(problem, linear(leg_off), surface, region) == [1]
    # After the last stage, a clean target's limb left a little off while every other part
    # lies on the posed surface (spot's leg seen from one side, 1.5° off): stuck at
    # `SETTLED_FLOOR` (tried again, `_resettled`), not before it.
    clean = np.zeros((4, 3))
    clean[3] = [0, 0.005, 0]
    assert _stuck(problem, linear(clean), surface, region) == []
    assert _stuck(problem, linear(clean), surface, region, SETTLED_FLOOR) == [1]

    b = np.deg2rad(30.0) * np.array([0.6, 0.8])
    starts = np.array(_starts(b))
    np.testing.assert_allclose(np.hypot(*starts.T), np.deg2rad(30) + RESTART * np.array(
        [0.5, 1, -0.5, -1]))
    np.testing.assert_allclose(starts / np.hypot(*starts.T)[:, None], [[0.6, 0.8]] * 4)
    barely = np.array(_starts(np.array([1e-3, 0.0])))
    np.testing.assert_allclose(np.hypot(*barely.T), RESTART)
    assert len({tuple(np.round(s / RESTART, 6)) for s in barely}) == 4


def test_a_partial_scan_explains_the_limbs_it_shows_one_side_of(skeleton, registration, samples):
    # A scan of the whole body but one side of the limbs, the limbs at the truth: their far
    # sides lie away from the target, behind what it shows, and pass (`_ahead`); without limb
    # 2's part, limb 2 is posed where the target has nothing, whichever way it is bent.
    from scipy.spatial import cKDTree

    from fleshing_jax._skeleton.fit_shape import _ahead, _unexplained, local_planes

    points, normals, _ = samples
    region, rest = np.asarray(skeleton.region), np.asarray(registration.vertices)

    def verdict(target, poses):
        vertices = np.asarray(fj.pose_skeleton(registration, skeleton, poses).vertices)
        planes, noise = local_planes(target)
        near = cKDTree(target).query(vertices)[1]
        ahead = _ahead(vertices, np.asarray(registration.triangles), target, near, planes)
        owner = region[cKDTree(vertices).query(target)[1]]
        return _unexplained(np.zeros(len(target)), noise, rest, owner, [0, 1, 2], ahead,
                            region, [0, 2])

    posed = np.asarray(fj.pose_skeleton(registration, skeleton, SHAPE_TRUTH).vertices)
    owner = region[cKDTree(posed).query(points)[1]]
    assert verdict(points[(normals[:, 1] > 0) | (owner < 0)], SHAPE_TRUTH) == ""
    bent_otherwise = {0: SHAPE_TRUTH[0], 2: fj.LimbPose(60.0, -60.0)}
    message = verdict(points[owner != 2], bent_otherwise)
    assert message.startswith("limb 2 is posed where the target has no surface"), message


def test_a_vertex_behind_its_own_limbs_surface_is_not_away():
    # `_ahead`: a posed vertex whose nearest target point lies outside it along its normal is
    # away by that distance, unless that point lies on the vertex's own limb's posed surface
    # (`own`: a one-sided scan's rim points are nearest to the far side's vertices too).
    import trimesh

    from fleshing_jax._skeleton.fit_shape import _ahead

    ball = trimesh.creation.icosphere(1)
    cloud = 1.5 * ball.vertices[:1]  # outside vertex 0, along its normal
    near = np.zeros(len(ball.vertices), int)
    ahead = _ahead(ball.vertices, ball.faces, cloud, near, cloud / 1.5)
    assert ahead[0] == pytest.approx(0.5)
    own = np.zeros(len(ball.vertices), bool)
    own[0] = True
    excused = _ahead(ball.vertices, ball.faces, cloud, near, cloud / 1.5, own)
    assert excused[0] == 0.0 and np.array_equal(excused[1:], ahead[1:])


def test_the_solve_reads_every_point_of_a_small_limbs_part():
    # Only a limb's own points depend on its angles: the solve's points are shared out by part
    # (`_shares`), a small limb's all of its points, not a uniform sample's fraction (spot's
    # legs with 0.5 % noise: 270 of their 820 points, fitted 6-8 deg off). A fitted limb's
    # part holds its unfitted descendants' points; a fitted descendant keeps its own.
    from types import SimpleNamespace

    from fleshing_jax._skeleton.fit_shape import _owners, _shares

    parents = [-1, 0, 1, -1, 0]  # limbs 1 and 2 below 0; 3 on the body; 4 below 0
    skeleton = SimpleNamespace(limbs=[SimpleNamespace(parent=p) for p in parents])
    owners = _owners(skeleton, (0, 2))
    np.testing.assert_array_equal(owners, [0, 0, 2, -1, 0, -1])  # the last: the body (-1)
    region = np.repeat([-1, 0, 1, 2, 3, 4], [3000, 900, 100, 150, 500, 50])
    owner = owners[region]
    kept = _shares(owner, 1500, np.random.default_rng(0))
    assert len(kept) == 1500 and len(np.unique(kept)) == 1500
    assert np.sum(owner[kept] == 2) == 150  # limb 2's part, all of it
    # The rest shared equally between limb 0's part (1,050 points) and the body's (3,500).
    assert np.sum(owner[kept] == 0) == 675 and np.sum(owner[kept] == -1) == 675
    np.testing.assert_array_equal(_shares(owner, 10_000, None), np.arange(len(owner)))


def test_a_shape_solve_reads_the_rest_spines_from_their_tables(registration):
    # In double precision the solve's posing looks each rest spine up in its table (the one
    # the projection check reads), not the exact spine, whose arc-length inverse made the
    # solve's program twice as large (`_on_tables`); the result is posed exactly.
    from fleshing_jax._skeleton.fit_shape import _on_tables

    tabled = _on_tables(registration)
    tables = [c for c in registration.checks if c is not None]
    assert len(tables) == 3  # (float64: the tube's rest spines are B-splines)
    assert all(type(r) is type(c) for r, c in zip(tabled.rests, tables))
    leaves = jax.tree.leaves(tabled.rests)
    assert all(a is b for a, b in zip(leaves, jax.tree.leaves(tables), strict=True))
    assert jax.tree.leaves(tabled.registrations)[0] is jax.tree.leaves(
        registration.registrations)[0]


def test_a_shape_solve_starts_damped_at_its_own_curvature():
    # A shape fit's solver starts its damping λ = 1 / step size at `SHAPE_DAMPING` times the
    # largest diagonal entry of JᵀJ (`_fit.problem._ScaledTrustRegion`), not at 1: a leg's
    # curvature, in units of σ, is 1e-4 to 1e-3, and from λ = 1 it crept until λ had come
    # down to it. After the first step, the classical trust region's rule, unchanged.
    import jax.numpy as jnp
    import lineax as lx

    from fleshing_jax._fit.problem import default_solver
    from fleshing_jax._skeleton.fit_shape import SHAPE_DAMPING

    search = default_solver("least_squares", np.float64, 1e-8, 1e-8,
                            damping=SHAPE_DAMPING).search
    y = jnp.zeros(2)
    jac = jnp.array([[1e-2, 0.0], [0.0, 1e-1], [0.0, 0.0]])
    info = optx.FunctionInfo.ResidualJac(jnp.array([1.0, 1.0, 1.0]), lx.MatrixLinearOperator(jac))
    state = search.init(y, info)
    step = search.step
    size, accept, _, state = step(jnp.array(True), y, y, info, info, state)
    np.testing.assert_allclose(size, 1 / (SHAPE_DAMPING * 1e-2))
    assert bool(accept) and float(state.step_size) == float(size)
    # A step that raised the loss: rejected, its size a quarter, as optimistix's.
    worse = optx.FunctionInfo.ResidualJac(jnp.array([2.0, 2.0, 2.0]), info.jac)
    again, accept, _, _ = step(jnp.array(False), y, y + 1, info, worse, state)
    assert not bool(accept) and float(again) == float(size) / 4
    assert float(default_solver("least_squares", np.float64, 1e-8, 1e-8).search.init(
        y, info).step_size) == 1.0


def test_a_shape_fit_poses_its_limbs_at_their_own_size(registration):
    # The shape fit's registration keeps the largest limb's rows, not a bucket's
    # (`restricted(bucketed=False)`): every padded row cost the solve its forward derivative.
    # The limbs' rows are the bucketed registration's first ones.
    from fleshing_jax._batching.buckets import bucket
    from fleshing_jax._skeleton.fit_pose import restricted

    ids = np.arange(0, registration.vertices.shape[0], 3)
    own, rows, _ = restricted(registration, ids, bucketed=False)
    padded, same_rows, _ = restricted(registration, ids)
    largest = max(int(np.isin(np.asarray(i), ids).sum()) for i in registration.indices)
    assert bucket(largest) > largest
    for a, b in zip(own.registrations, padded.registrations):
        assert a.points.shape[0] == largest and b.points.shape[0] == bucket(largest)
        np.testing.assert_array_equal(np.asarray(a.points), np.asarray(b.points)[:largest])
    np.testing.assert_array_equal(np.asarray(rows), np.asarray(same_rows))


def test_a_shape_fit_run_past_a_full_turn_is_held_at_half_a_turn():
    # The shape fit's solve has no bound: a target that is not the character posed (a ball
    # beside the tube, with XLA's default flags) sent a limb's bend to 1,609 degrees, and the
    # result's `LimbPose` refused it. Such a limb is held at half a turn and named.
    from fleshing_jax._skeleton.fit_shape import _within_half_a_turn

    y = jnp.asarray([[0.3, 0.4, 0.1], [-20.0, 21.0, 0.2], [0.1, 0.0, -7.0]])
    held, wound = _within_half_a_turn(y)
    assert held.dtype == y.dtype and [i for i, _ in wound] == [1, 2]
    np.testing.assert_allclose(wound[0][1], np.degrees(29.0))
    np.testing.assert_array_equal(held[0], y[0])  # within a turn: as it was
    np.testing.assert_allclose(np.linalg.norm(held[1, :2]), np.pi)
    np.testing.assert_allclose(held[1, :2] / np.pi, y[1, :2] / 29.0)  # its direction kept
    np.testing.assert_allclose(held[2], [0.1, 0.0, -np.pi])
    same, none = _within_half_a_turn(y[:1, :2])  # held twists: (L, 2)
    assert none == [] and same is not None and np.array_equal(same, y[:1, :2])

"""ARAP deformation of medial meshes (`arap_medial`): identity, rigid motions, a bend, a twist,
the two solvers against each other, derivatives (on a perfectly straight chain too), dtypes
and bad input. Meshes are built by hand: a chain of 20 spheres (capsule of radius 0.5 and
length 4) and a 6 × 5 sheet of spheres with faces. Handle sets and iteration counts are shared
between tests so that compiled programs are reused.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import fleshing_jax as fj
from fleshing_jax._medial_axis.medial_mesh import face_edges
from fleshing_jax._medial_deform.arap import arap_energies, fit_rotation, fit_rotations
from fleshing_jax._medial_deform.cells import arap_cells
from fleshing_jax._medial_deform.quaternions import matrix_from_quaternion, quaternion_from_matrix

LENGTH = 4.0


def _chain(n=20):
    x = np.linspace(0, LENGTH, n)
    centers = np.stack([x, 0 * x, 0 * x], 1)
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], 1)
    return fj.MedialMesh(centers, np.full(n, 0.5), edges)


def _sheet(nx=6, ny=5, h=0.5):
    x, y = np.meshgrid(np.arange(nx) * h, np.arange(ny) * h, indexing="ij")
    centers = np.stack([x.ravel(), y.ravel(), 0 * x.ravel()], 1)
    idx = np.arange(nx * ny).reshape(nx, ny)
    faces = []
    for i in range(nx - 1):
        for j in range(ny - 1):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            faces += [[a, b, c], [a, c, d]]
    faces = np.array(faces)
    return fj.MedialMesh(centers, np.full(len(centers), 0.2), np.unique(face_edges(faces), axis=0),
                         faces)


CHAIN = _chain()
SHEET = _sheet()
ENDS = np.r_[0:5, 15:20]  # first and last quarter of the chain
SIDES = np.r_[0:10, 20:30]  # the first two and last two rows of the sheet


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _bend_targets(angle):
    """The last quarter of the chain on an arc of the same length turning by `angle` in the
    xy-plane, starting at the end of the first quarter: `(targets, tangents)`."""
    centers = np.asarray(CHAIN.centers)
    start = centers[4, 0]
    radius = (LENGTH - start) / angle
    s = centers[ENDS, 0] - start
    theta = s.clip(0) / radius
    targets = np.stack([np.where(s > 0, start + radius * np.sin(theta), centers[ENDS, 0]),
                        radius * (1 - np.cos(theta)), 0 * theta], 1)
    tangents = np.stack([np.cos(theta), np.sin(theta), 0 * theta], 1)
    return targets, tangents


def _diagonal(medial):
    return float(np.linalg.norm(np.ptp(np.asarray(medial.centers), axis=0)))


# --- the rotation fit ------------------------------------------------------------------------


def _svd_rotation(m):
    u, _, vt = np.linalg.svd(m)
    d = np.diag([1, 1, np.sign(np.linalg.det(u @ vt))])
    return u @ d @ vt


def test_fit_rotation_matches_svd_with_reflections_fixed():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(64, 3, 3))
    m[:8] = m[:8] @ np.diag([1.0, 1e-3, 1e-6])  # ill-conditioned
    m[8:12] = np.eye(3) * [1, 1, -1]  # reflection with a double singular value
    # Jitted: eagerly, each of the fit's operations would compile on its own.
    fit = jax.jit(jax.vmap(fit_rotation))
    r = np.asarray(fit(jnp.asarray(m)))
    expected = np.stack([_svd_rotation(x) for x in m])
    assert (np.linalg.det(m) < 0).sum() > 20
    np.testing.assert_allclose(np.linalg.det(r), 1, atol=1e-12)
    # On the fourth block any rotation about z by π is as good: compare the objective there.
    np.testing.assert_allclose(r[12:], expected[12:], atol=1e-8)
    np.testing.assert_allclose(np.einsum("nab,nab->n", r[:12], m[:12]),
                               np.einsum("nab,nab->n", expected[:12], m[:12]), rtol=1e-9)
    # The batched fit skips the reflection's fix only where no matrix needs it (none once the
    # reflected ones are negated): the same rotations either way.
    positive = jnp.asarray(np.where(np.linalg.det(m)[:, None, None] < 0, -m, m))
    batched = jax.jit(fit_rotations)
    np.testing.assert_array_equal(batched(jnp.asarray(m)), r)
    np.testing.assert_array_equal(batched(positive), fit(positive))


def test_fit_rotation_derivatives():
    rng = np.random.default_rng(1)
    fit = jax.jit(fit_rotation)
    check_grads(fit, (jnp.asarray(rng.normal(size=(3, 3))),), order=2, modes=("fwd",),
                atol=1e-5, rtol=1e-5)
    # The batched fit's own rule, to second order, in both of its branches (a reflected
    # matrix among them, and none).
    batched = jax.jit(fit_rotations)
    m = rng.normal(size=(3, 3, 3))
    m[1] *= -np.sign(np.linalg.det(m[1]))  # det < 0
    for batch in (m, m * np.sign(np.linalg.det(m))[:, None, None]):
        check_grads(batched, (jnp.asarray(batch),), order=2, modes=("fwd",), atol=1e-5,
                    rtol=1e-5)
        check_grads(batched, (jnp.asarray(batch),), order=1, modes=("rev",), atol=1e-5,
                    rtol=1e-5)
    # Repeated singular values (the identity; a rank-one matrix plus a multiple of it), where
    # the SVD's derivative is not finite.
    for m in (jnp.eye(3), jnp.outer(jnp.array([1.0, 0, 0]), jnp.array([1.0, 0, 0])) + 0.1 *
              jnp.eye(3)):
        check_grads(fit, (m,), order=1, modes=("fwd", "rev"), atol=1e-5, rtol=1e-5)
    # Reverse over reverse inside `lax.scan` (as in the solver) differentiates the forward
    # computation itself: finite, and equal to forward over reverse, at repeated singular
    # values too.
    def in_scan(m):
        r, _ = jax.lax.scan(lambda m, _: (fit_rotation(m), None), m, None, length=1)
        return jnp.sum(jnp.sin(r) * jnp.arange(9.0).reshape(3, 3))

    rev, fwd = jax.jit(jax.jacrev(jax.grad(in_scan))), jax.jit(jax.jacfwd(jax.grad(in_scan)))
    for m in (2 * jnp.eye(3), jnp.diag(jnp.array([3.0, 1.0, 1.0]))):
        np.testing.assert_allclose(rev(m), fwd(m), atol=1e-6)


def test_quaternions_round_trip():
    rng = np.random.default_rng(2)
    rotations = [_rotation(rng.normal(size=3), a) for a in (0.0, 1.0, 3.0, np.pi)]
    rotations += [np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]
    to_quaternion, to_matrix = jax.jit(quaternion_from_matrix), jax.jit(matrix_from_quaternion)
    for r in rotations:
        q = to_quaternion(jnp.asarray(r))
        np.testing.assert_allclose(np.linalg.norm(q), 1, atol=1e-12)
        np.testing.assert_allclose(to_matrix(q), r, atol=1e-12)


# --- poses -----------------------------------------------------------------------------------


@pytest.mark.parametrize("medial, handles", [(CHAIN, ENDS), (SHEET, SIDES)])
def test_identity(medial, handles):
    centers = np.asarray(medial.centers)
    pose = fj.arap_medial(medial, handles, centers[handles])
    assert isinstance(pose, fj.MedialPose)
    assert np.abs(np.asarray(pose.centers) - centers).max() <= 1e-6 * _diagonal(medial)
    np.testing.assert_allclose(pose.rotations, np.broadcast_to(np.eye(3), (len(centers), 3, 3)),
                               atol=1e-9)


def test_rigid_motion():
    """Both end spheres of the chain moved rigidly, with the motion's rotation prescribed."""
    centers = np.asarray(CHAIN.centers)
    q = _rotation([1.0, 2.0, -0.5], 2.0)
    moved = centers @ q.T + np.array([0.3, -1.0, 2.0])
    ends = np.array([0, 19])
    pose = fj.arap_medial(CHAIN, ends, moved[ends], rotations=np.stack([q, q]))
    assert np.abs(np.asarray(pose.centers) - moved).max() <= 1e-4
    assert np.abs(np.asarray(pose.rotations) - q).max() <= 1e-4


def test_rigid_motion_without_prescribed_rotations():
    """Two rows of handles at each end of the sheet fix a rigid motion: it is found."""
    centers = np.asarray(SHEET.centers)
    q = _rotation([0.0, 1.0, 1.0], 0.7)
    moved = centers @ q.T + 1.0
    pose = fj.arap_medial(SHEET, SIDES, moved[SIDES])
    assert np.abs(np.asarray(pose.centers) - moved).max() <= 1e-4
    assert np.abs(np.asarray(pose.rotations) - q).max() <= 1e-4


def test_bend_keeps_lengths_and_follows_the_arc():
    targets, tangents = _bend_targets(np.pi / 2)
    pose = fj.arap_medial(CHAIN, ENDS, targets)
    c = np.asarray(pose.centers)
    r = np.asarray(pose.rotations)
    rest = np.diff(np.asarray(CHAIN.centers), axis=0)
    ratio = np.linalg.norm(np.diff(c, axis=0), axis=1) / np.linalg.norm(rest, axis=1)
    assert np.abs(ratio - 1).max() < 0.02
    np.testing.assert_allclose(c[ENDS], targets, atol=1e-12)
    # The bend stays in its plane, and each sphere's rotation turns the rest axis onto the
    # tangent of the posed chain (central differences; the arc's tangent at the handles).
    assert np.abs(c[:, 2]).max() < 1e-9
    np.testing.assert_allclose(np.einsum("nab,nb->na", r[:, :, 2:], np.ones((20, 1))),
                               np.broadcast_to([0, 0, 1.0], (20, 3)), atol=1e-9)
    axis = r[:, :, 0]
    chord = c[2:] - c[:-2]
    chord /= np.linalg.norm(chord, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(np.sum(axis[1:-1] * chord, 1), -1, 1)))
    assert angle.max() < 5
    at_arc = np.degrees(np.arccos(np.clip(np.sum(axis[15:] * tangents[5:], 1), -1, 1)))
    assert at_arc.max() < 5
    # Rotations turn monotonically from the fixed quarter to the bent one.
    turn = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    assert (np.diff(turn) > -1e-9).all() and turn[-1] > np.radians(80)


def test_twist_is_carried_along_a_straight_chain():
    """180° prescribed at the last sphere, none at the first: centres stay, rotations about the
    axis whose angle grows monotonically from 0 to 180°."""
    centers = np.asarray(CHAIN.centers)
    handles = np.array([0, 19])
    rotations = np.stack([np.eye(3), _rotation([1, 0, 0], np.pi)])
    pose = fj.arap_medial(CHAIN, handles, centers[handles], rotations=rotations)
    assert np.abs(np.asarray(pose.centers) - centers).max() <= 1e-6 * _diagonal(CHAIN)
    r = np.asarray(pose.rotations)
    np.testing.assert_allclose(r[:, :, 0], np.broadcast_to([1.0, 0, 0], (20, 3)), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(r), 1, atol=1e-9)
    angle = np.unwrap(np.arctan2(r[:, 2, 1], r[:, 1, 1]))
    angle *= np.sign(angle[-1])
    assert np.diff(angle).min() > 0
    np.testing.assert_allclose([angle[0], angle[-1]], [0, np.pi], atol=1e-9)
    assert np.diff(angle).max() < 3 * np.pi / 19  # spread along the chain, not a jump


def test_solvers_reach_the_same_minimum():
    targets, _ = _bend_targets(np.pi / 2)
    exact, e_global = arap_energies(CHAIN, ENDS, targets, iterations=200)
    local, e_local = arap_energies(CHAIN, ENDS, targets, iterations=3000, solver="local")
    e_global, e_local = np.asarray(e_global), np.asarray(e_local)
    # Neither increases the energy.
    assert np.diff(e_global).max() <= 1e-12 * e_global[0]
    assert np.diff(e_local).max() <= 1e-12 * e_local[0]
    # The local solver, run for long enough, lands on the global solver's minimum ...
    minimum = e_global[-1]
    assert abs(e_local[-1] - minimum) < 1e-9 * minimum
    np.testing.assert_allclose(local.centers, exact.centers, atol=1e-6)
    np.testing.assert_allclose(local.rotations, exact.rotations, atol=1e-6)
    # ... and the global one gets there in far fewer iterations (the default is enough for a
    # gap of 1e-3 of the minimum energy).
    gap_global, gap_local = (e_global - minimum) / minimum, (e_local - minimum) / minimum
    assert gap_global[fj_default_iterations() - 1] < 1e-3
    assert np.argmax(gap_local < 1e-4) > 3 * np.argmax(gap_global < 1e-4)


def test_warm_start_tracks_a_bend_in_few_iterations():
    """A bend animated 10° a frame, each frame 3 iterations from the previous one: every
    frame at least as near its minimum energy as 3 iterations from the first guess, the
    last under 0.6 times as far (measured: 1.8e-3 against 3.9e-3 of the minimum); a
    converged pose is a fixed point of the warm start."""
    pose = fj.arap_medial(CHAIN, ENDS, np.asarray(CHAIN.centers)[ENDS])
    for angle in np.radians(np.arange(10, 91, 10)):
        targets, _ = _bend_targets(angle)
        pose, warm = arap_energies(CHAIN, ENDS, targets, iterations=3, start=pose)
        # The energy after 3 iterations from the first guess: the third of the default
        # run's (the program the other tests compile, rather than one of 3 iterations).
        # (Energies read in NumPy: indexing JAX arrays compiles eagerly.)
        cold = np.asarray(arap_energies(CHAIN, ENDS, targets)[1])[2]
        converged, energies = arap_energies(CHAIN, ENDS, targets, iterations=200)
        minimum = np.asarray(energies)[-1]
        gap_warm, gap_cold = np.asarray(warm)[-1] - minimum, cold - minimum
        assert gap_warm <= gap_cold * (1 + 1e-9)
    assert gap_warm < 0.6 * gap_cold
    again = fj.arap_medial(CHAIN, ENDS, targets, iterations=3, start=converged)
    np.testing.assert_allclose(again.centers, converged.centers, atol=1e-9)
    np.testing.assert_allclose(again.rotations, converged.rotations, atol=1e-9)


def test_colour_table_rows_are_colours():
    # The solver sweeps the colours as rows of one table: every sphere in exactly one row,
    # the padding repeats a sphere of its own row, and no edge joins two spheres of a row.
    padded = []
    for medial, handles in [(CHAIN, ENDS), (SHEET, SIDES)]:
        rest, _, edges, _ = medial.numpy()
        table = arap_cells(rest, edges, handles, 0.1, np.float64).colours
        rows = [np.unique(row) for row in table]
        np.testing.assert_array_equal(np.sort(np.concatenate(rows)), np.arange(len(rest)))
        colour = np.empty(len(rest), int)
        for k, row in enumerate(rows):
            colour[row] = k
        assert (colour[edges[:, 0]] != colour[edges[:, 1]]).all()
        padded += [len(row) < table.shape[1] for row in rows]
    assert any(padded)  # (the sheet's last colour; the chain's two are equal)


def fj_default_iterations():
    import inspect

    return inspect.signature(fj.arap_medial).parameters["iterations"].default


# --- transformations, dtypes -----------------------------------------------------------------


def _loss(pose):
    weights = jnp.linspace(0.5, 1.5, pose.centers.size).reshape(pose.centers.shape)
    return (jnp.sum(jnp.sin(pose.centers) * weights)
            + jnp.sum(pose.rotations * jnp.arange(9.0).reshape(3, 3)))


@pytest.mark.parametrize("bent", [False, True], ids=["straight", "bent"])
def test_gradients_match_finite_differences(bent):
    """On a perfectly straight chain (collinear cells: an SVD derivative would be NaN) and on
    a bent one, `jax.grad` of a loss of centres and rotations is finite and matches finite
    differences; under `jax.jit` too (second derivatives, checked by hand: Hessian-vector
    products match finite differences of the gradient to 5e-7; a test would take 15 s to
    compile)."""
    targets = jnp.asarray(_bend_targets(np.pi / 2)[0] if bent else np.asarray(CHAIN.centers)[ENDS])

    def f(t):
        return _loss(fj.arap_medial(CHAIN, ENDS, t))

    grad = jax.grad(f)(targets)
    assert np.isfinite(np.asarray(grad)).all() and np.abs(np.asarray(grad)).max() > 0
    check_grads(f, (targets,), order=1, modes=("rev",), atol=1e-4, rtol=1e-4, eps=1e-5)
    np.testing.assert_allclose(jax.jit(f)(targets), f(targets), rtol=1e-12)


def test_gradients_with_prescribed_rotations():
    centers = np.asarray(CHAIN.centers)
    handles = np.array([0, 19])

    def f(t, r):
        return _loss(fj.arap_medial(CHAIN, handles, t, rotations=r))

    t = jnp.asarray(centers[handles])
    r = jnp.asarray(np.stack([np.eye(3), _rotation([1, 0, 0], 1.0)]))
    grads = jax.grad(f, argnums=(0, 1))(t, r)
    assert all(np.isfinite(np.asarray(g)).all() for g in grads)
    check_grads(lambda t: f(t, r), (t,), order=1, modes=("rev",), atol=1e-4, rtol=1e-4,
                eps=1e-5)


def test_jit_and_float32():
    targets, _ = _bend_targets(np.pi / 2)
    eager = fj.arap_medial(CHAIN, ENDS, targets)
    jitted = jax.jit(lambda t: fj.arap_medial(CHAIN, ENDS, t))
    single = jitted(jnp.asarray(targets, jnp.float32))
    assert single.centers.dtype == jnp.float32 and single.rotations.dtype == jnp.float32
    np.testing.assert_allclose(single.centers, eager.centers, atol=1e-4)
    np.testing.assert_allclose(single.rotations, eager.rotations, atol=1e-4)
    # A float32 medial mesh with float32 targets: float32 throughout.
    medial32 = fj.MedialMesh(np.asarray(CHAIN.centers, np.float32), np.float32(CHAIN.radii),
                             CHAIN.edges)
    pose = fj.arap_medial(medial32, ENDS, np.float32(targets))
    assert pose.centers.dtype == np.float32
    np.testing.assert_allclose(pose.centers, single.centers, atol=1e-6)


# --- bad input -------------------------------------------------------------------------------


def _raises(match, *args, **kwargs):
    with pytest.raises(ValueError, match=match):
        fj.arap_medial(*args, **kwargs)


def test_bad_input():
    c = np.asarray(CHAIN.centers)
    t = c[ENDS]
    _raises("handles.*in \\[0, 20\\)", CHAIN, np.r_[ENDS[:-1], 20], t)
    _raises("handles.*in \\[0, 20\\)", CHAIN, np.r_[ENDS[:-1], -1], t)
    _raises("handles.*repeat", CHAIN, np.r_[ENDS[:-1], 0], t)
    _raises("handles.*non-empty", CHAIN, np.zeros(0, int), np.zeros((0, 3)))
    _raises("handles.*integer", CHAIN, ENDS.astype(float), t)
    _raises("targets.*shape \\(h, 3\\) = \\(10, 3\\)", CHAIN, ENDS, t[:-1])
    _raises("targets.*finite", CHAIN, ENDS, np.where(np.arange(10)[:, None] == 3, np.nan, t))
    eye = np.broadcast_to(np.eye(3), (10, 3, 3))
    _raises("rotations.*shape", CHAIN, ENDS, t, rotations=eye[:, :2])
    _raises("rotations.*rotation matrices.*\\[4\\]", CHAIN, ENDS, t,
            rotations=np.where(np.arange(10)[:, None, None] == 4, 2 * eye, eye))
    _raises("rotations.*rotation matrices", CHAIN, ENDS, t, rotations=-eye)
    _raises("rotations.*finite", CHAIN, ENDS, t, rotations=eye * np.nan)
    _raises("solver", CHAIN, ENDS, t, solver="newton")
    _raises("iterations", CHAIN, ENDS, t, iterations=0)
    _raises("smoothness", CHAIN, ENDS, t, smoothness=0.0)
    # Isolated spheres, components without a handle: the spheres are named.
    isolated = fj.MedialMesh(c, CHAIN.radii, CHAIN.edges[:-1])
    _raises("isolated.*spheres 19", isolated, ENDS[:5], t[:5])
    split = fj.MedialMesh(c, CHAIN.radii, np.delete(CHAIN.edges, 9, axis=0))
    _raises("handles.*component of spheres 10, 11.*has none", split, ENDS[:5], t[:5])
    with pytest.raises(TypeError, match="medial"):
        fj.arap_medial(c, ENDS, t)
    with pytest.raises(TypeError, match="start.*MedialPose"):
        fj.arap_medial(CHAIN, ENDS, t, start=np.eye(3))
    _raises("start.*pose of `medial`", CHAIN, ENDS, t, start=fj.MedialPose(
        _chain(21), np.asarray(_chain(21).centers), np.broadcast_to(np.eye(3), (21, 3, 3))))
    with pytest.raises(ValueError, match="handles.*concrete"):
        jax.jit(lambda h: fj.arap_medial(CHAIN, h, t))(ENDS)


# --- fit_handles -----------------------------------------------------------------------------


def _capsule_rig():
    """A capsule around CHAIN (cylinder from x = 0 to 4, radius 0.5), bound to it."""
    import trimesh

    a = np.linspace(-np.pi / 2, 0, 4)
    cap = np.stack([0.5 * np.cos(a), 0.5 * np.sin(a)], 1)
    x = np.linspace(0, LENGTH, 13)[1:-1]
    profile = np.concatenate([cap, np.stack([np.full_like(x, 0.5), x], 1),
                              cap[::-1] * [1, -1] + [0, LENGTH]])
    profile[[0, -1], 0] = 0
    mesh = trimesh.creation.revolve(profile, sections=10)
    vertices = np.asarray(mesh.vertices)[:, [2, 0, 1]]  # the revolution axis z becomes x
    return vertices, fj.MedialRig(vertices, CHAIN, faces=mesh.faces)


def test_fit_handles_recovers_a_known_pose():
    vertices, rig = _capsule_rig()
    truth, _ = _bend_targets(np.pi / 3)
    posed, valid = rig.pose(fj.arap_medial(CHAIN, ENDS, truth), implicit=False)
    assert np.asarray(valid).all()
    ids = np.arange(0, len(vertices), 3)
    fit = fj.fit_handles(rig, ENDS, ids, np.asarray(posed)[ids], medial=CHAIN)
    assert fit.converged, fit.message
    assert float(fit.loss) < 1e-12 and float(fit.rms) < 1e-6
    np.testing.assert_allclose(fit.targets, truth, atol=1e-5)
    np.testing.assert_allclose(fit.vertices, np.asarray(posed)[ids], atol=1e-6)
    # Bad input names the argument.
    with pytest.raises(ValueError, match="vertex_ids"):
        fj.fit_handles(rig, ENDS, [len(vertices)], np.zeros((1, 3)))
    with pytest.raises(ValueError, match="vertex_targets"):
        fj.fit_handles(rig, ENDS, ids, np.zeros((len(ids) + 1, 3)))
    with pytest.raises(ValueError, match="method"):
        fj.fit_handles(rig, ENDS, ids, np.asarray(posed)[ids], method="skinning")

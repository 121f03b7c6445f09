"""MedialRig: footprint binding, medial / LBS / DQS skinning and the implicit correction.

Poses are built by hand: rigid motions, a capsule's chain of spheres bent onto an arc (the
arc's rotation at each sphere) or twisted about its axis. Meshes are small (a few hundred
vertices, a chain of 9 spheres) and the pose programs few (one per method and implicit flag,
shared across tests), so that the file runs in well under a minute.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from jax.test_util import check_grads

import fleshing_jax as fj
from fleshing_jax._medial_axis.medial_mesh import MedialMesh
from fleshing_jax._medial_axis.primitives import union_distance
from fleshing_jax._medial_deform.footprint import segment_footprint, slab_footprint
from fleshing_jax._medial_deform.implicit import cone_field, cone_table, slab_field, slab_table
from fleshing_jax._medial_deform.pose import MedialPose
from fleshing_jax._medial_deform.rig import METHODS, MedialRig
from fleshing_jax._medial_deform.still import still_blocks

RADIUS, LENGTH, SPHERES = 0.5, 4.0, 9


def capsule_mesh(rings=24, sections=16, cap=5):
    """A watertight capsule along z (cylinder length 4, radius 0.5) whose cylinder is cut into
    `rings` bands (trimesh's own capsule spans the cylinder with single long triangles,
    which no skin can bend)."""
    a = np.linspace(-np.pi / 2, 0, cap)
    bottom = np.stack([RADIUS * np.cos(a), -LENGTH / 2 + RADIUS * np.sin(a)], 1)
    z = np.linspace(-LENGTH / 2, LENGTH / 2, rings + 1)[1:-1]
    profile = np.concatenate([bottom, np.stack([np.full_like(z, RADIUS), z], 1),
                              bottom[::-1] * [1, -1]])
    profile[[0, -1], 0] = 0
    return trimesh.creation.revolve(profile, sections=sections)


def chain(n=SPHERES):
    z = np.linspace(-LENGTH / 2, LENGTH / 2, n)
    centers = np.stack([np.zeros(n), np.zeros(n), z], 1)
    return MedialMesh(centers, np.full(n, RADIUS), np.stack([np.arange(n - 1),
                                                           np.arange(1, n)], 1))


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def bent(medial, angle):
    """The chain bent onto an arc of its own length in the xz plane."""
    s = np.asarray(medial.centers)[:, 2] + LENGTH / 2
    radius = LENGTH / angle
    theta = s / radius
    centers = np.stack([radius * (1 - np.cos(theta)), 0 * s, -LENGTH / 2
                        + radius * np.sin(theta)], 1)
    return MedialPose(medial, jnp.asarray(centers), jnp.asarray(np.stack(list(map(rot_y,
                                                                                 theta)))))


def twisted(medial, angle):
    s = np.asarray(medial.centers)[:, 2] + LENGTH / 2
    rotations = np.stack([rot_z(angle * t / LENGTH) for t in s])
    return MedialPose(medial, jnp.asarray(medial.centers), jnp.asarray(rotations))


@pytest.fixture(scope="module")
def capsule():
    mesh = capsule_mesh()
    medial = chain()
    return mesh, medial, MedialRig(mesh.vertices, medial, faces=mesh.faces)


volume = jax.jit(fj.volume)  # (eagerly, each of its operations would compile on its own)


def diagonal(vertices):
    return float(np.linalg.norm(np.ptp(vertices, axis=0)))


# --- binding --------------------------------------------------------------------------


def test_footprints_minimise_the_power_distance():
    rng = np.random.default_rng(0)
    m = 200
    c = rng.normal(size=(m, 3, 3)) * 2
    r = rng.uniform(0.2, 0.6, size=(m, 3))
    p = rng.normal(size=(m, 3)) * 2
    beta = slab_footprint(p, c, r)
    assert np.all(beta >= -1e-12) and np.allclose(beta.sum(1), 1)

    def energy(b):  # b (..., 3)
        cen = np.einsum("...k,mkd->...md", b, c)
        rad = np.einsum("...k,mk->...m", b, r)
        return ((p - cen) ** 2).sum(-1) - rad**2

    g = np.linspace(0, 1, 61)
    bi, bj = np.meshgrid(g, g)
    keep = bi + bj <= 1
    grid = np.stack([bi[keep], bj[keep], 1 - bi[keep] - bj[keep]], 1)
    brute = energy(grid[:, None, :]).min(axis=0)
    ours = ((p - np.einsum("mk,mkd->md", beta, c)) ** 2).sum(-1) - ((beta * r).sum(1)) ** 2
    assert np.all(ours <= brute + 1e-9)  # never worse than the grid's best
    t, e = segment_footprint(p, c[:, 0], r[:, 0], c[:, 1], r[:, 1])
    ts = np.linspace(0, 1, 2001)[:, None, None]
    line = ((p - (c[:, 0] + ts * (c[:, 1] - c[:, 0]))) ** 2).sum(-1) - (
        r[:, 0] + ts[..., 0] * (r[:, 1] - r[:, 0])) ** 2
    assert np.all(e <= line.min(axis=0) + 1e-9) and np.all((t >= 0) & (t <= 1))


def test_jax_field_matches_the_numpy_union_distance():
    rng = np.random.default_rng(1)
    centers = rng.normal(size=(5, 3))
    radii = rng.uniform(0.3, 0.6, 5)
    edges = np.array([[0, 1], [1, 2], [0, 2], [2, 3], [3, 4]])
    faces = np.array([[0, 1, 2]])
    points = rng.normal(size=(300, 3)) * 1.5
    expected = union_distance(points, centers, radii, edges, faces, cutoff=100.0)
    # Jitted: eagerly, each of the tables' and fields' operations would compile on its own.
    cones = jax.jit(cone_table)(jnp.asarray(centers), jnp.asarray(radii), jnp.asarray(edges))
    slabs = jax.jit(slab_table)(jnp.asarray(centers), jnp.asarray(radii), jnp.asarray(faces))
    cv, cg = jax.jit(jax.vmap(jax.vmap(cone_field, (None, 0)), (0, None)))(jnp.asarray(points),
                                                                        cones)
    # The slab's edges (0, 1), (1, 2), (0, 2) are cones 0, 1, 2.
    sv, sg = jax.jit(jax.vmap(jax.vmap(slab_field, (None, 0, None, None)), (0, None, 0, 0)))(
        jnp.asarray(points), slabs, cv[:, :3], cg[:, :3])
    ours = np.minimum(np.asarray(cv).min(1), np.asarray(sv).min(1))
    assert np.allclose(ours, expected, atol=1e-9)
    # The gradients are the distance's: unit vectors, equal to finite differences.
    value = jax.jit(jax.vmap(lambda q: jnp.min(jax.vmap(cone_field, (None, 0))(q, cones)[0])))
    h = np.array([1e-6, 0, 0])
    fd = value(jnp.asarray(points + h)) - value(jnp.asarray(points - h))
    nearest = np.argmin(np.asarray(cv), axis=1)
    grad = np.asarray(cg)[np.arange(300), nearest]
    assert np.allclose(np.linalg.norm(grad, axis=1), 1)
    assert np.allclose(grad[:, 0], np.asarray(fd) / 2e-6, atol=1e-5)


def test_binding_of_the_capsule(capsule):
    mesh, medial, rig = capsule
    assert bool(rig.valid.all())
    at = np.asarray(rig.welded)  # the binding's arrays are per welded point
    beta = np.asarray(rig.beta)[at]
    assert np.all(beta >= 0) and np.allclose(beta.sum(1), 1)
    # On a chain of equal spheres the footprint is the projection onto the axis: offsets
    # are radial on the cylinder, of length 0.5 everywhere.
    offset = np.asarray(rig.offset)[at]
    assert np.allclose(np.linalg.norm(offset, axis=1), RADIUS, atol=1e-9)
    cylinder = np.abs(mesh.vertices[:, 2]) < LENGTH / 2 - 1e-9
    assert np.allclose(offset[cylinder, 2], 0, atol=1e-9)


# --- poses ----------------------------------------------------------------------------


@pytest.mark.parametrize("implicit", [False, True])
@pytest.mark.parametrize("method", METHODS)
def test_rest_and_rigid_poses(capsule, method, implicit):
    mesh, medial, rig = capsule
    v = np.asarray(mesh.vertices)
    x, valid = rig.pose(MedialPose.rest(medial), method, implicit=implicit)
    assert np.abs(np.asarray(x) - v).max() <= 1e-6 * diagonal(v) and bool(valid.all())
    rotation = trimesh.transformations.rotation_matrix(1.1, [0.3, -0.5, 0.8])[:3, :3]
    shift = np.array([0.4, -1.2, 2.0])
    posed = MedialPose(medial, jnp.asarray(np.asarray(medial.centers) @ rotation.T + shift),
                       jnp.asarray(np.broadcast_to(rotation, (SPHERES, 3, 3))))
    x, _ = rig.pose(posed, method, implicit=implicit)
    assert np.abs(np.asarray(x) - (v @ rotation.T + shift)).max() <= 1e-4


def test_still_blocks_keep_their_skinned_vertices(capsule):
    """Spheres 0-6 held at rest, 7-8 turned about sphere 7 as one body: the blocks whose
    spheres all move as one (`still`) keep their skinned vertices, where the full correction
    (a rig without blocks) moves them by round-off only; the others are corrected."""
    mesh, medial, rig = capsule
    c = np.asarray(medial.centers)
    turn = rot_y(0.6)
    centers = np.concatenate([c[:7], (c[7:] - c[7]) @ turn.T + c[7]])
    posed = MedialPose(medial, jnp.asarray(centers),
                       jnp.asarray(np.stack([np.eye(3)] * 7 + [turn] * 2)))
    still = np.asarray(jax.jit(still_blocks)(rig.correction.blocks, rig.rest_centers,
                                             posed.centers, posed.rotations))
    assert still.any() and not still.all()
    kept = still[np.asarray(rig.welded) // rig.correction.block]
    skinned = np.asarray(rig.pose(posed, "medial", implicit=False)[0])
    x = np.asarray(rig.pose(posed, "medial")[0])
    np.testing.assert_array_equal(x[kept], skinned[kept])
    full = eqx.tree_at(lambda r: r.correction, rig,
                       dataclasses.replace(rig.correction, blocks=None))
    np.testing.assert_allclose(x, full.pose(posed, "medial")[0], rtol=0,
                               atol=1e-12 * diagonal(mesh.vertices))
    assert np.abs(x - skinned)[~kept].max() > 1e-4 * diagonal(mesh.vertices)


@pytest.mark.parametrize("angle", [np.pi / 2, np.pi])
def test_bent_capsule_keeps_its_volume(capsule, angle):
    mesh, medial, rig = capsule
    faces = np.asarray(mesh.faces)
    before = float(volume(mesh.vertices, faces))
    posed = bent(medial, angle)
    change = {}
    for method in METHODS:
        x, valid = rig.pose(posed, method, implicit=method == "medial")
        assert bool(valid.all()) and np.isfinite(np.asarray(x)).all()
        change[method] = float(volume(x, faces)) / before - 1
    assert abs(change["medial"]) <= 0.01, change
    # The skin follows the arc: the end cap's centre lands at the arc's end.
    x = np.asarray(rig.pose(posed)[0])
    top = mesh.vertices[:, 2] > LENGTH / 2 + 0.49
    tip = np.asarray(posed.centers)[-1] + np.asarray(posed.rotations)[-1] @ [0, 0, RADIUS]
    assert np.linalg.norm(x[top].mean(0) - tip) < 0.02


def test_twisted_capsule_keeps_its_volume(capsule):
    mesh, medial, rig = capsule
    faces = np.asarray(mesh.faces)
    before = float(volume(mesh.vertices, faces))
    x, _ = rig.pose(twisted(medial, np.pi))
    assert abs(float(volume(x, faces)) / before - 1) <= 0.01
    # Cross-sections turn rigidly: every vertex keeps its distance to the axis and its height.
    x = np.asarray(x)
    v = np.asarray(mesh.vertices)
    assert np.allclose(np.linalg.norm(x[:, :2], axis=1), np.linalg.norm(v[:, :2], axis=1),
                       atol=2e-3)
    assert np.allclose(x[:, 2], v[:, 2], atol=2e-3)


def test_implicit_correction_restores_the_iso_values(capsule):
    # After a bend, the skinned vertices' distances to the posed envelope drift from their
    # rest values (the inner side is pressed, the outer stretched); the correction brings
    # them back, and the surface stays smooth: no edge stretched or squashed much.
    mesh, medial, rig = capsule
    posed = bent(medial, np.pi)
    dm = MedialMesh(np.asarray(posed.centers), np.asarray(medial.radii),
                    np.asarray(medial.edges))

    def drift(x):
        d = union_distance(np.asarray(x), *dm.numpy(), cutoff=10.0)
        d0 = union_distance(mesh.vertices, *medial.numpy(), cutoff=10.0)
        return np.abs(d - d0).max()

    raw, _ = rig.pose(posed, implicit=False)
    fixed, _ = rig.pose(posed)
    assert drift(fixed) < 0.5 * drift(raw) and drift(fixed) < 0.01
    edges = np.asarray(mesh.edges_unique)
    rest = np.linalg.norm(np.diff(mesh.vertices[edges], axis=1)[:, 0], axis=1)
    posed_length = np.linalg.norm(np.diff(np.asarray(fixed)[edges], axis=1)[:, 0], axis=1)
    ratio = posed_length / rest
    assert 0.5 < ratio.min() and ratio.max() < 2.0


def test_float32_poses_stay_float32(capsule):
    mesh, medial, rig = capsule
    posed = bent(medial, np.pi / 2)
    single = MedialPose(medial, posed.centers.astype(jnp.float32),
                        posed.rotations.astype(jnp.float32))
    x32, valid = rig.pose(single)
    x64, _ = rig.pose(posed)
    assert x32.dtype == jnp.float32 and valid.dtype == jnp.bool_
    assert np.abs(np.asarray(x32) - np.asarray(x64)).max() < 1e-4
    x, _ = rig.pose(MedialPose.rest(MedialMesh(np.asarray(medial.centers, np.float32),
                                               np.asarray(medial.radii, np.float32),
                                               medial.edges)))
    assert x.dtype == jnp.float32
    assert np.abs(np.asarray(x) - mesh.vertices).max() <= 1e-6 * diagonal(mesh.vertices)


def test_jit_and_gradients(capsule):
    mesh, medial, rig = capsule
    posed = bent(medial, 1.0)
    x, _ = rig.pose(posed)
    xj, _ = jax.jit(rig.pose)(posed)
    assert np.allclose(np.asarray(xj), np.asarray(x), atol=1e-12)
    weights = jnp.asarray(np.random.default_rng(2).normal(size=x.shape))

    def loss(centers):
        return jnp.sum(weights * rig.pose(MedialPose(medial, centers, posed.rotations))[0])

    grad = jax.grad(loss)(posed.centers)
    assert np.isfinite(np.asarray(grad)).all()
    check_grads(loss, (posed.centers,), order=1, modes=["rev"])
    # At the rest pose too (identity rotations: the quaternion blend's degenerate branch).
    rest = MedialPose.rest(medial)
    g = jax.grad(lambda c: jnp.sum(rig.pose(MedialPose(medial, c, rest.rotations))[0] ** 2))
    assert np.isfinite(np.asarray(g(rest.centers))).all()


def test_rotation_blend_across_primitives_closes_cracks():
    # A capsule whose medial mesh is two chains with no edge between them: the vertices on
    # either side of the gap bind to different chains, which share no sphere. Turning the
    # two chains apart tears the surface there unless the rotation weights are smoothed.
    mesh = capsule_mesh()
    n = SPHERES
    medial = chain(n)
    keep = np.ones(n - 1, bool)
    keep[n // 2 - 1] = False
    split = MedialMesh(medial.centers, medial.radii, np.asarray(medial.edges)[keep])
    centers = np.asarray(medial.centers)
    theta = np.where(np.arange(n) >= n // 2, 0.4, 0.0)  # the upper chain turns about a hinge
    hinge = centers[n // 2 - 1] * 0.5 + centers[n // 2] * 0.5
    rotations = np.stack([rot_y(t) for t in theta])
    posed_centers = hinge + np.einsum("nij,nj->ni", rotations, centers - hinge)
    posed = MedialPose(split, jnp.asarray(posed_centers), jnp.asarray(rotations))
    edges = np.asarray(mesh.edges_unique)
    rest = np.linalg.norm(np.diff(mesh.vertices[edges], axis=1)[:, 0], axis=1)

    def worst(rig, pose=posed):
        x = np.asarray(rig.pose(pose, implicit=False)[0])
        ratio = np.linalg.norm(np.diff(x[edges], axis=1)[:, 0], axis=1) / rest
        return np.abs(np.log(ratio)).max()

    sharp = worst(MedialRig(mesh.vertices, split, faces=mesh.faces, smoothing=0))
    smooth = worst(MedialRig(mesh.vertices, split, faces=mesh.faces))
    # The reference: the same hinge on the connected chain, rotations blended over each
    # cone only (the hinge's own kink stretches the outer side there too).
    connected = worst(MedialRig(mesh.vertices, medial, faces=mesh.faces, smoothing=0),
                      MedialPose(medial, posed.centers, posed.rotations))
    assert smooth < 0.3 * sharp and smooth <= connected


# --- bad input and invalid vertices ---------------------------------------------------


def test_invalid_vertices_are_flagged_not_nan(capsule):
    mesh, medial, _ = capsule
    v = np.array(mesh.vertices)
    v[3] = np.nan
    v[7] = [100.0, 0, 0]  # far from every primitive
    rig = MedialRig(v, medial, faces=mesh.faces)
    x, valid = rig.pose(bent(medial, 1.0))
    assert not valid[3] and not valid[7] and int(valid.sum()) == len(v) - 2
    assert np.isfinite(np.asarray(x)).all()
    assert np.allclose(np.asarray(x)[7], v[7])


def test_bad_input(capsule):
    mesh, medial, rig = capsule
    with pytest.raises(ValueError, match="vertices"):
        MedialRig(np.zeros((4, 2)), medial)
    with pytest.raises(TypeError, match="vertices"):
        MedialRig(np.array(["a", "b", "c"])[None], medial)
    with pytest.raises(ValueError, match="medial.*sphere"):
        MedialRig(mesh.vertices, MedialMesh(np.zeros((0, 3)), np.zeros(0)))
    with pytest.raises(TypeError, match="medial"):
        MedialRig(mesh.vertices, "not a medial mesh")
    with pytest.raises(ValueError, match="faces"):
        MedialRig(mesh.vertices, medial, faces=np.array([[0, 1, len(mesh.vertices)]]))
    with pytest.raises(ValueError, match="faces"):
        MedialRig(mesh.vertices, medial, faces=np.zeros((3, 2), int))
    with pytest.raises(ValueError, match="smoothing"):
        MedialRig(mesh.vertices, medial, smoothing=-1)
    with pytest.raises(ValueError, match="posed.*9 spheres"):
        rig.pose(MedialPose.rest(chain(5)))
    with pytest.raises(TypeError, match="posed"):
        rig.pose(np.zeros((SPHERES, 3)))
    with pytest.raises(ValueError, match="method.*'medial', 'lbs', 'dqs'.*'spline'"):
        rig.pose(MedialPose.rest(medial), "spline")


def test_lone_spheres_bind_and_follow():
    # A medial mesh of two spheres and no edge: each vertex follows its own sphere rigidly.
    a = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    b = a.copy()
    b.apply_translation([2.0, 0, 0])
    mesh = trimesh.util.concatenate([a, b])
    medial = MedialMesh(np.array([[0.0, 0, 0], [2.0, 0, 0]]), np.array([0.5, 0.5]))
    rig = MedialRig(mesh.vertices, medial, faces=mesh.faces)
    spheres = np.asarray(rig.spheres)[np.asarray(rig.welded), 0]
    assert np.array_equal(spheres, (mesh.vertices[:, 0] > 1).astype(int))
    turn = rot_z(0.5)
    posed = MedialPose(medial, jnp.asarray([[0.0, 0, 0], [2.0, 1.0, 0]]),
                       jnp.asarray(np.stack([np.eye(3), turn])))
    x, valid = rig.pose(posed)
    v = mesh.vertices
    right = v[:, 0] > 1
    expected = np.where(right[:, None], (v - [2, 0, 0]) @ turn.T + [2, 1, 0], v)
    assert bool(valid.all()) and np.abs(np.asarray(x) - expected).max() < 1e-6

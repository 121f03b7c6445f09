"""MedialRig: footprint binding, medial / LBS / DQS skinning and the implicit correction.

Poses are built by hand: rigid motions, a capsule's chain of spheres bent onto an arc (the
arc's rotation at each sphere) or twisted about its axis. Meshes are small (a few hundred
vertices, a chain of 9 spheres) and the pose programs few (one per method and implicit flag,
shared across tests), so that the file runs in well under a minute.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from jax.test_util import check_grads

import fleshing_jax as fj
from fleshing_jax._medial.footprint import segment_footprint, slab_footprint
from fleshing_jax._medial.implicit import cone_field, cone_table, slab_field, slab_table
from fleshing_jax._medial.medial_mesh import MedialMesh
from fleshing_jax._medial.pose import MedialPose
from fleshing_jax._medial.primitives import union_distance
from fleshing_jax._medial.rig import METHODS, MedialRig

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
    cones = cone_table(jnp.asarray(centers), jnp.asarray(radii), jnp.asarray(edges))
    slabs = slab_table(jnp.asarray(centers), jnp.asarray(radii), jnp.asarray(faces))
    cv, cg = jax.vmap(jax.vmap(cone_field, (None, 0)), (0, None))(jnp.asarray(points), cones)
    sv, sg = jax.vmap(jax.vmap(slab_field, (None, 0)), (0, None))(jnp.asarray(points), slabs)
    ours = np.minimum(np.asarray(cv).min(1), np.asarray(sv).min(1))
    assert np.allclose(ours, expected, atol=1e-9)
    # The gradients are the distance's: unit vectors, equal to finite differences.
    value = jax.vmap(lambda q: jnp.min(jax.vmap(cone_field, (None, 0))(q, cones)[0]))
    h = np.array([1e-6, 0, 0])
    fd = value(jnp.asarray(points + h)) - value(jnp.asarray(points - h))
    nearest = np.argmin(np.asarray(cv), axis=1)
    grad = np.asarray(cg)[np.arange(300), nearest]
    assert np.allclose(np.linalg.norm(grad, axis=1), 1)
    assert np.allclose(grad[:, 0], np.asarray(fd) / 2e-6, atol=1e-5)


def test_binding_of_the_capsule(capsule):
    mesh, medial, rig = capsule
    assert bool(rig.valid.all())
    beta = np.asarray(rig.beta)
    assert np.all(beta >= 0) and np.allclose(beta.sum(1), 1)
    # On a chain of equal spheres the footprint is the projection onto the axis: offsets
    # are radial on the cylinder, of length 0.5 everywhere.
    offset = np.asarray(rig.offset)
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

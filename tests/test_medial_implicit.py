"""The implicit correction's field on a medial mesh with slabs: each distinct cone evaluated
once per vertex (the slabs read their edges' fields by slot) gives the same field as
evaluating every candidate's own primitives in place; the blocked evaluation and the
NumPy rest iso-values agree with it; rest and rigid poses are kept.

A small sheet of three slabs with a cone hanging off it, 300 points around it (a point
cloud: no faces, so no relaxation) bound with two slab candidates each (more shared edges
than the default one), so that the file runs in a few seconds.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from fleshing_jax._medial_axis.medial_mesh import MedialMesh
from fleshing_jax._medial_deform import implicit
from fleshing_jax._medial_deform.implicit import (
    cone_field,
    cone_table,
    correct,
    field,
    slab_field,
    slab_table,
    smooth_union,
)
from fleshing_jax._medial_deform.pose import MedialPose
from fleshing_jax._medial_deform.rig import MedialRig

CENTERS = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2], [2, 0.5, 0], [3, 0.5, 0.3]])
RADII = np.array([0.3, 0.4, 0.35, 0.45, 0.3, 0.25])
FACES = np.array([[0, 1, 2], [1, 3, 2], [1, 4, 3]])
# Every face edge, in both orientations among them, and a cone off the sheet.
EDGES = np.array([[0, 1], [2, 1], [0, 2], [1, 3], [3, 2], [4, 1], [3, 4], [4, 5]])


@pytest.fixture(scope="module")
def sheet():
    medial = MedialMesh(CENTERS, RADII, EDGES, FACES)
    rng = np.random.default_rng(0)
    points = rng.uniform([-0.5, -0.5, -0.6], [3.4, 1.6, 0.8], size=(300, 3))
    return points, medial, MedialRig(points, medial, field_slabs=2)


@jax.jit
def reference_field(points, centers, radii, cones, data):
    """The field of `implicit.field` evaluated in place: every cone candidate, and every slab
    candidate with its own three edge cones (in the face's orientation), folded in order."""
    cone_tab = cone_table(centers, radii, cones)
    slab_tab = slab_table(centers, radii, jnp.asarray(FACES))
    edge_tab = cone_table(centers, radii, jnp.asarray(FACES)[:, jnp.array(
        [[0, 1], [1, 2], [0, 2]])].reshape(-1, 2))

    def one(p, width, ic, js):
        def at(table, i):
            return cone_field(p, jax.tree.map(lambda a: a[i], table))

        out = [at(cone_tab, i) for i in ic]
        for j in js:
            edges = [at(edge_tab, 3 * j + a) for a in range(3)]
            out.append(slab_field(p, jax.tree.map(lambda a: a[j], slab_tab),
                                  jnp.stack([v for v, _ in edges]),
                                  jnp.stack([g for _, g in edges])))
        value, grad = out[0]
        for v, g in out[1:]:
            value, grad = smooth_union(value, grad, v, g, width)
        return value, grad

    return jax.vmap(one)(points, data.width, data.field_cones, data.field_slabs)


@jax.jit
def shared_field(points, centers, radii, cones, data):
    """`implicit.field` as `correct` calls it: distinct cones once, slab edges by slot."""
    cone_tab = cone_table(centers, radii, cones)
    slab_tab = slab_table(centers, radii, jnp.asarray(FACES))

    def one(p, width, ic, ie, js, slots):
        def rows(table, i):
            return jax.tree.map(lambda a: a[i], table)

        return field(p, width, rows(cone_tab, ic), rows(cone_tab, ie), rows(slab_tab, js),
                     slots)

    d = data
    return jax.vmap(one)(points, d.width, d.field_cones, d.edge_cones, d.field_slabs,
                         d.edge_slots)


def test_slab_edges_are_shared_with_the_cone_candidates(sheet):
    _, _, rig = sheet
    d = rig.correction
    e, ks = d.edge_cones.shape[1], d.field_slabs.shape[1]
    assert ks == 2 and e < 3 * ks  # fewer cone evaluations than kc + 3 ks per vertex
    # Every slot names a cone on the same two spheres as the slab's edge.
    needed = np.concatenate([np.asarray(d.field_cones), np.asarray(d.edge_cones)], 1)
    cones = np.sort(np.asarray(rig.cones), axis=1)
    at = np.take_along_axis(needed, np.asarray(d.edge_slots).reshape(len(needed), -1), 1)
    edges = np.sort(FACES[:, [[0, 1], [1, 2], [0, 2]]], axis=2)[np.asarray(d.field_slabs)]
    np.testing.assert_array_equal(cones[at], edges.reshape(len(needed), -1, 2))


def test_shared_edges_give_the_field_evaluated_in_place(sheet):
    _, medial, rig = sheet
    points = np.asarray(rig.points)  # in the order of the binding's arrays
    rng = np.random.default_rng(1)
    args = (jnp.asarray(points + rng.normal(scale=0.05, size=points.shape)),
            jnp.asarray(CENTERS + rng.normal(scale=0.1, size=CENTERS.shape)),
            rig.radii, rig.cones, rig.correction)
    value, grad = shared_field(*args)
    ref_value, ref_grad = reference_field(*args)
    np.testing.assert_allclose(value, ref_value, rtol=0, atol=1e-12)
    np.testing.assert_allclose(grad, ref_grad, rtol=0, atol=1e-12)
    # At rest, the NumPy iso-values of the binding are this field.
    rest, _ = shared_field(jnp.asarray(points), rig.rest_centers, rig.radii, rig.cones,
                           rig.correction)
    np.testing.assert_allclose(rig.correction.iso, rest, rtol=0, atol=1e-12)


def test_blocks_do_not_mix_vertices(sheet, monkeypatch):
    # 300 vertices in blocks of 128 (three, the last padded) or in one block.
    points, _, rig = sheet
    rng = np.random.default_rng(2)
    centers = jnp.asarray(CENTERS + rng.normal(scale=0.1, size=CENTERS.shape))
    skinned = jnp.asarray(points + rng.normal(scale=0.05, size=points.shape))

    def run():  # traced anew at each call (a new function), so with the current BLOCK
        return jax.jit(lambda: correct(
            skinned, jnp.broadcast_to(jnp.eye(3), (len(points), 3, 3)), centers, rig.radii,
            rig.cones, rig.medial_faces, rig.correction, newton_steps=2, relax_iterations=0,
            relax_step=0.5, contact_angle=55.0))()

    monkeypatch.setattr(implicit, "BLOCK", 128)
    blocked, contact = run()
    monkeypatch.setattr(implicit, "BLOCK", 1024)
    whole, whole_contact = run()
    np.testing.assert_allclose(blocked, whole, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(contact, whole_contact)
    assert float(jnp.abs(whole - skinned).max()) > 1e-3  # the correction did move them


def test_rest_and_rigid_poses_of_a_sheet(sheet):
    points, medial, rig = sheet
    x, valid = rig.pose(MedialPose.rest(medial))
    assert bool(valid.all())
    assert float(jnp.abs(x - points).max()) <= 1e-6 * float(np.ptp(points, axis=0).max())
    c, s = np.cos(0.7), np.sin(0.7)
    rotation = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    shift = np.array([0.3, -1.0, 0.5])
    posed = MedialPose(medial, jnp.asarray(CENTERS @ rotation.T + shift),
                       jnp.asarray(np.broadcast_to(rotation, (len(CENTERS), 3, 3))))
    x, _ = rig.pose(posed)
    assert float(jnp.abs(x - (points @ rotation.T + shift)).max()) <= 1e-4


def test_gradients_through_slabs_match_finite_differences(sheet):
    points, medial, rig = sheet
    weights = jnp.asarray(np.random.default_rng(3).normal(size=points.shape))
    rotations = jnp.broadcast_to(jnp.eye(3), (len(CENTERS), 3, 3))

    def loss(centers):
        return jnp.sum(weights * rig.pose(MedialPose(medial, centers, rotations))[0])

    centers = jnp.asarray(CENTERS + np.random.default_rng(4).normal(scale=0.05,
                                                                      size=CENTERS.shape))
    assert np.isfinite(np.asarray(jax.grad(loss)(centers))).all()
    check_grads(loss, (centers,), order=1, modes=["rev"])


@pytest.mark.parametrize("newton_steps, relax_iterations", [(2, 2), (0, 1)])
def test_correction_loop_is_its_steps_in_turn(newton_steps, relax_iterations):
    # `correct` runs its Newton steps and relaxation rounds as one loop; the same steps
    # written out one after the other: Newton steps (the angle test from the second on),
    # then each round a tangential move to the turned rest Laplacian and one projection.
    # A grid above the sheet with faces, so that the relaxation runs.
    u, v = np.meshgrid(np.linspace(-0.3, 3.2, 12), np.linspace(-0.3, 1.4, 8), indexing="ij")
    points = np.c_[u.ravel(), v.ravel(), np.full(u.size, 0.45)]
    quads = (np.arange(11)[:, None] * 8 + np.arange(7)[None]).ravel()
    faces = np.r_[np.c_[quads, quads + 8, quads + 1], np.c_[quads + 1, quads + 8, quads + 9]]
    medial = MedialMesh(CENTERS, RADII, EDGES, FACES)
    rig = MedialRig(points, medial, faces=faces, field_slabs=2)
    rng = np.random.default_rng(5)
    centers = jnp.asarray(CENTERS + rng.normal(scale=0.1, size=CENTERS.shape))
    skinned = jnp.asarray(points + rng.normal(scale=0.05, size=points.shape))
    turn = np.linalg.qr(rng.normal(size=(len(points), 3, 3)))[0]
    turn = jnp.asarray(turn * np.sign(np.linalg.det(turn))[:, None, None])  # rotations
    d, cos_max = rig.correction, np.cos(np.radians(55.0))

    @jax.jit
    def steps_in_turn(x):
        active, g_prev = jnp.ones(len(x), bool), None

        def project(x, active, g_prev):
            f, g = shared_field(x, centers, rig.radii, rig.cones, d)
            if g_prev is not None:
                cos = jnp.sum(g * g_prev, 1) / (jnp.linalg.norm(g, axis=1)
                                                * jnp.linalg.norm(g_prev, axis=1))
                active = active & (cos >= cos_max)
            moved = x - ((f - d.iso) / jnp.maximum(jnp.sum(g * g, 1), 0.25))[:, None] * g
            return jnp.where(active[:, None], moved, x), active, g

        for _ in range(newton_steps):
            x, active, g_prev = project(x, active, g_prev)
        if g_prev is None:
            g_prev = shared_field(x, centers, rig.radii, rig.cones, d)[1]
        for _ in range(relax_iterations):
            mean = jnp.einsum("nk,nkd->nd", d.ring_weights, x[d.ring])
            move = mean + jnp.einsum("nab,nb->na", turn, d.laplacian) - x
            move = move - jnp.sum(move * g_prev, 1)[:, None] * g_prev
            x = jnp.where(active[:, None], x + 0.5 * move, x)
            x, active, g_prev = project(x, active, g_prev)
        return x, ~active

    def loop(x):
        return correct(x, turn, centers, rig.radii, rig.cones, rig.medial_faces, d,
                       newton_steps=newton_steps, relax_iterations=relax_iterations,
                       relax_step=0.5, contact_angle=55.0)

    expected, contact = steps_in_turn(skinned)
    x, loop_contact = jax.jit(loop)(skinned)
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(loop_contact, contact)
    assert float(jnp.abs(x - skinned).max()) > 1e-3  # the correction did move them

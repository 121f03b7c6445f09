"""The skeleton in any units and at any place (issue 47, item 6), and on any size of mesh
(item 8): tiny meshes, memory in blocks."""

import tracemalloc
import warnings

import jax
import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._medial_axis import surface
from fleshing_jax._medial_axis.characters import jointed_quadruped, jointed_quadruped_medial
from fleshing_jax._medial_axis.unit import UnitFrame
from fleshing_jax._skeleton import build

FEW = dict(spheres=60, samples=5000, refine=0, progress=False)
# Spot on the grid (`spot_case`) sampled less: its largest region (the head's) 531 vertices, not
# 1,205 at 5,000 samples, so its registrations pad to 768 as the skeleton tests' spot rig's and
# the far spot's (`test_far_from_the_origin_in_any_units`) do, not to 1,536 (programs no other
# test compiled); the same limbs (a head with four children, four legs), cheaper medial meshes.
GRIDDED = dict(FEW, samples=3000)


def _on_grid(x):
    """`x` rounded to 2⁻²⁰: moved by up to 2³² it stays exact, scaled by powers of two too."""
    return np.round(np.asarray(x, np.float64) * 2.0**20) / 2.0**20


@pytest.fixture(scope="module")
def spot_case():
    mesh = fj.data.spot()
    vertices, faces = _on_grid(mesh.vertices), np.asarray(mesh.faces)
    medial = fj.medial_mesh((vertices, faces), **GRIDDED)
    return vertices, faces, medial, fj.skeleton((vertices, faces), medial=medial)


@pytest.fixture(scope="module")
def character_case():
    """The jointed quadruped on its own (hand-made) medial mesh: no medial mesh to compute.
    At resolution 36 (3,742 vertices) its largest region, 322 vertices, pads its rest
    registrations to 384, as the skeleton tests' quadruped rigs (at 24, to 128: programs of
    its own)."""
    mesh = jointed_quadruped(36)
    vertices, faces = _on_grid(mesh.vertices), np.asarray(mesh.faces)
    medial = jointed_quadruped_medial()
    medial = fj.MedialMesh(_on_grid(medial.centers), _on_grid(medial.radii), medial.edges,
                           medial.faces)  # fmt: skip
    return vertices, faces, medial, fj.skeleton((vertices, faces), medial=medial)


def _rest_is_valid(vertices, faces, skeleton):
    registration = fj.register_skeleton((vertices, faces), skeleton)
    return bool(np.all(np.asarray(fj.pose_skeleton(registration, skeleton, {}).valid)))


def _same_up_to(found, skeleton, factor, shift):
    """`found` is `skeleton` scaled by `factor` and moved by `shift`: regions and parents
    equal, spines and joints mapped."""
    assert np.array_equal(np.asarray(found.region), np.asarray(skeleton.region))
    assert [limb.parent for limb in found.limbs] == [limb.parent for limb in skeleton.limbs]
    # The medial mesh, given in the moved frame, rounds to its offset's precision (1e-10 at
    # 1e6): the spines are fitted to that.
    tolerance = 1e-9 * factor + 1e-14 * abs(shift)
    for a, b in zip(found.limbs, skeleton.limbs, strict=True):
        assert np.allclose(np.asarray(a.spine.control_points),
                           np.asarray(b.spine.control_points) * factor + shift,
                           rtol=0, atol=tolerance)  # fmt: skip
        assert np.isclose(float(a.joint), float(b.joint) * factor, rtol=0, atol=tolerance)


# Scales 1e-6 and 1e6 and moves of 1e6 diagonals (spot's diagonal 2.6), each exact on the
# gridded vertices: a power of two, a multiple of the unit frame's scale.
SIMILARITIES = [(2.0**-20, 2.0**-2), (2.0**20, -(2.0**40)), (1.0, 2.0**22)]


@pytest.mark.parametrize("factor, shift", SIMILARITIES)
def test_medial_mesh_and_skeleton_are_the_same_moved_and_scaled(spot_case, factor, shift):
    vertices, faces, medial, skeleton = spot_case
    moved = vertices * factor + shift
    other = fj.medial_mesh((moved, faces), **GRIDDED)
    centers, radii, edges, tris = medial.numpy()
    assert np.array_equal(other.numpy()[2], edges) and np.array_equal(other.numpy()[3], tris)
    assert np.array_equal(other.numpy()[0], centers * factor + shift)
    assert np.array_equal(other.numpy()[1], radii * factor)
    found = fj.skeleton((moved, faces), medial=other)
    _same_up_to(found, skeleton, factor, shift)
    assert _rest_is_valid(moved, faces, found)


@pytest.mark.parametrize("factor, shift", SIMILARITIES[:2])
def test_a_characters_skeleton_is_the_same_moved_and_scaled(character_case, factor, shift):
    vertices, faces, medial, skeleton = character_case
    assert len(skeleton.limbs) >= 8  # legs jointed, neck, tail
    centers, radii, edges, tris = medial.numpy()
    moved = vertices * factor + shift
    with warnings.catch_warnings():
        # Its 26-vertex second shell (a marching artefact) was flipped 1e6 diagonals away.
        warnings.simplefilter("error")
        other = fj.MedialMesh(centers * factor + shift, radii * factor, edges, tris)
        found = fj.skeleton((moved, faces), medial=other)
    _same_up_to(found, skeleton, factor, shift)
    assert _rest_is_valid(moved, faces, found)


def test_far_from_the_origin_in_any_units(spot_case):
    """Moved 1e6 from the origin and scaled by 10 (neither exact: the coordinates round), the
    skeleton is found (it used to fail: repeated control points 1e4 away, a medial mesh
    outside its mesh 1e6 away) and rests valid. Its limbs may differ: a rounding of the input
    reorders the medial mesh's nearly tied collapses (see `_medial_axis.unit`)."""
    vertices, faces, _, _ = spot_case
    moved = fj.data.spot().vertices * 10.0 + np.array([1e6, -1e6, 3.3e5])
    medial = fj.medial_mesh((moved, faces), **FEW)
    low, high = moved.min(axis=0), moved.max(axis=0)
    assert np.all((medial.numpy()[0] > low) & (medial.numpy()[0] < high))
    skeleton = fj.skeleton((moved, faces), medial=medial)
    assert len(skeleton.limbs) >= 4  # at least the legs
    assert _rest_is_valid(moved, faces, skeleton)


def test_rest_spine_far_from_the_origin(spot_case):
    vertices, faces, medial, _ = spot_case
    spine = fj.rest_spine(medial, surface=(vertices, faces))
    shift = np.array([1e4, 2e4, -1e4])
    far = fj.rest_spine(fj.MedialMesh(medial.centers + shift, medial.radii, medial.edges,
                                      medial.faces), surface=(vertices + shift, faces))  # fmt: skip
    assert np.allclose(np.asarray(far.control_points) - shift,
                       np.asarray(spine.control_points), atol=1e-9)  # fmt: skip


def test_unit_frame_is_exact():
    rng = np.random.default_rng(0)
    points = rng.uniform(-3.0, 3.0, size=(100, 3)) + 1e6
    frame = UnitFrame.of(points)
    unit = frame.to_unit(points)
    diagonal = np.linalg.norm(np.ptp(points, axis=0))
    assert frame.scale / 2 < diagonal <= frame.scale and np.all(frame.center == 1e6)
    assert 0.5 < np.linalg.norm(np.ptp(unit, axis=0)) <= 1.0
    assert np.array_equal(frame.from_unit(unit), points)
    with pytest.raises(ValueError, match="span no box"):
        UnitFrame.of(np.ones((4, 3)))


def test_a_tiny_mesh_is_a_body():
    """A box of 8 vertices (any mesh under 16 crashed: an empty block of vertices): a limb
    moves at least `FEWEST` vertices, so it is a body, as a finer box is."""
    box = trimesh.creation.box()
    skeleton = fj.skeleton(box)
    assert len(skeleton.limbs) == 0 and np.all(np.asarray(skeleton.region) == -1)
    assert _rest_is_valid(np.asarray(box.vertices), np.asarray(box.faces), skeleton)
    with pytest.raises(TypeError, match="`medial`"):
        fj.skeleton(box, medial="spheres")


def test_the_belonging_check_works_in_blocks():
    """Every vertex's gap to the nearest sphere, in blocks of `BLOCK` pairs: at once (a
    sixteenth of the vertices at a time) it took 10 GB on a 302k-vertex mesh."""
    rng = np.random.default_rng(1)
    vertices = rng.normal(size=(16_000, 3))
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)  # a unit sphere's surface
    centers = rng.uniform(-0.02, 0.02, size=(2000, 3))
    tracemalloc.start()
    try:
        build._check_belongs(centers, np.full(2000, 0.9), vertices)  # it belongs
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # A sixteenth at once: 1,000 × 2,000 × 3 doubles, 48 MB and as much for their squares;
    # a block of 2¹⁸ pairs: 6 MB.
    assert peak < 30e6


def test_long_slivers_split_into_few_pieces(monkeypatch):
    """A capsule's side faces, 4.0 long among cap faces 1e-2 long, were bisected without end
    (a 302k-vertex capsule: 10 GB). At most `PIECES` pieces a face; the closest points stay
    exact (the same as with the pieces unbounded)."""
    mesh = trimesh.creation.capsule(height=4.0, radius=0.5, count=[48, 48])
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    bounded = surface.SurfaceQuery(vertices, faces)
    assert len(bounded.piece_face) <= surface.PIECES * len(faces)
    monkeypatch.setattr(surface, "PIECES", 10**6)
    unbounded = surface.SurfaceQuery(vertices, faces)
    assert len(unbounded.piece_face) > 2 * len(bounded.piece_face)
    points = np.random.default_rng(2).uniform(-1.0, 1.0, size=(300, 3)) * [1, 1, 3]
    for a, b in zip(bounded.query(points), unbounded.query(points), strict=True):
        assert np.allclose(a, b, rtol=0, atol=1e-12)


def test_a_path_far_shorter_than_its_radii_is_fitted_straight():
    """A limb's path 0.023 long among medial radii of 0.15-0.22 (a hand's, in its unit
    frame): no smoothing meets the curvature bound, and the smoothest fit with straight ends
    shrank towards a point (0.023 -> 4e-6 long; in float32 its control points coincided and
    `fj.skeleton` raised). It is the straight segment between the path's ends; a limb's fit
    (`strict`) has none."""
    from fleshing_jax._skeleton.fit import fit_bspline

    points = np.array([[-0.0374859, -0.0228842, 0.2812773], [-0.0344045, -0.0248035, 0.2843151],
                       [-0.0311177, -0.0117843, 0.2973408], [-0.0306066, -0.0097597, 0.2993664]])
    radii = np.array([0.2161913, 0.2069146, 0.1580697, 0.1521033])
    spine = fit_bspline(points, radii, 8, bounded=True, straight_ends=True)
    t = np.linspace(0.0, 1.0, 9)
    length = float(spine.length)
    assert length == pytest.approx(np.linalg.norm(points[-1] - points[0]), rel=1e-9)
    on = np.asarray(jax.vmap(spine)(t * length))
    assert np.allclose(on, points[0] + t[:, None] * (points[-1] - points[0]), atol=1e-10)
    bend = np.linalg.norm(np.asarray(jax.vmap(spine.curvature_vector)(t * length)), axis=1)
    assert np.all(bend < 1e-6)
    assert fit_bspline(points, radii, 8, bounded=True, straight_ends=True, strict=True) is None


def test_a_route_with_no_length_has_no_spine():
    """A route whose one sphere's centre, start and tip are one point (a knuckle's, far thinner
    than the palm it leaves) gets no spine and so no limb: its fit raised before."""
    from fleshing_jax._skeleton.limb_fit import limb_spine
    from fleshing_jax._skeleton.limbs import LimbPath

    centers = np.array([[0.0, 0.0, 0.0], [1e-7, 0.0, 0.0]])
    radii = np.array([1.0, 1e-6])
    route = LimbPath(np.array([1]), 0, np.array([0]), np.array([1]), -1)
    # (No vertex on the route's ray, which would take its tip out to the surface.)
    turn = trimesh.transformations.euler_matrix(0.3, 0.5, 0.7)[:3, :3]
    vertices = trimesh.creation.icosphere(2).vertices @ turn.T
    assert limb_spine(route, centers, radii, vertices, margin=1e-3) is None


def test_the_librarys_own_medial_mesh_is_not_refused(monkeypatch):
    """Where a character's skin overlaps itself (Blender's skin modifier where legs branch:
    a kangaroo's, a spider's), vertices lie inside the volume, nearer an unfitted sphere's
    centre than a fifth of its radius, and `fj.skeleton` refused the medial mesh it had just
    computed. The belonging check is for a medial mesh the user gives."""
    from fleshing_jax._medial_axis import construct

    mesh = trimesh.creation.capsule(height=2.0, radius=0.5, count=[8, 8])
    frame = UnitFrame.of(np.asarray(mesh.vertices))  # (where `fj.skeleton` finds limbs)
    unit = (frame.to_unit(np.asarray(mesh.vertices)), np.asarray(mesh.faces))
    medial = construct.medial_mesh(unit, 10, refine=0, progress=False)
    radii = np.asarray(medial.radii).copy()
    radii[np.argmax(radii)] *= 6.0  # past `REACHES` times its distance to a vertex
    medial = fj.MedialMesh(medial.centers, radii, medial.edges, medial.faces)
    monkeypatch.setattr(construct, "medial_mesh", lambda *args, **kwargs: medial)
    assert len(fj.skeleton(mesh).limbs) <= 1  # (refused before)
    given = fj.MedialMesh(frame.from_unit(np.asarray(medial.centers)), radii * frame.scale,
                          medial.edges, medial.faces)
    with pytest.raises(ValueError, match="does not belong"):
        fj.skeleton(mesh, medial=given)

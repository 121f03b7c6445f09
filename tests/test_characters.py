"""The procedural test characters (`_medial_axis.characters`): closed, manifold, one shell,
and their jointed limbs where the medial meshes put them, measured on the surface."""

import inspect

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from fleshing_jax._medial_axis import characters as ch


def _cell(mesh, resolution):
    """The envelope's grid cell: the bounding box's longest side over `resolution` (the
    spheres' box, which the surface's matches to within round-off)."""
    return float(np.ptp(np.asarray(mesh.vertices), axis=0).max()) / resolution


def _build(name):
    """The character at its default resolution, and that resolution's grid cell."""
    build = getattr(ch, name)
    mesh = build()
    return mesh, _cell(mesh, inspect.signature(build).parameters["resolution"].default)


@pytest.fixture(scope="module")
def quadruped():
    return _build("jointed_quadruped")


@pytest.fixture(scope="module")
def biped():
    return _build("biped")


@pytest.fixture(scope="module")
def insect():
    return _build("insect")


def _mirror(points, side):
    return [(x, y * side, z, r) for x, y, z, r in points]


def _section(mesh, a, b, t=0.5, reach=0.1, band=0.012):
    """The surface's cross-section radius at `a + t (b − a)` across the axis from `a` to `b`
    (points or spheres `(x, y, z, r)`): the median distance to the axis of the vertices in a
    slab `band` thick there, within `reach` of the point (not the rest of the body)."""
    a, b = np.asarray(a, float)[:3], np.asarray(b, float)[:3]
    axis = (b - a) / np.linalg.norm(b - a)
    d = np.asarray(mesh.vertices) - (a + t * (b - a))
    along = d @ axis
    across = np.linalg.norm(d - along[:, None] * axis, axis=1)
    near = (np.abs(along) < band) & (across < reach)
    assert near.sum() >= 6
    return float(np.median(across[near]))


def _radius(mesh, point, reach=0.1):
    """The surface's radius around `point` on a limb's axis (a point or a sphere
    `(x, y, z, r)`): its distance to the nearest triangle, the radius of the largest ball
    there inside the surface (a tube's cross-section radius; at a joint, where the next
    segment leaves, unlike a cross-section, not widened by it)."""
    point = np.asarray(point, float)[:3]
    triangles = np.asarray(mesh.triangles)
    near = np.linalg.norm(triangles.mean(axis=1) - point, axis=1) < reach
    assert near.any()
    closest = trimesh.triangles.closest_point(triangles[near], np.tile(point, (near.sum(), 1)))
    return float(np.linalg.norm(closest - point, axis=1).min())


def _tip(a, b):
    """The surface point beyond sphere `b` on the axis from sphere `a`: a limb's tip."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = (b[:3] - a[:3]) / np.linalg.norm(b[:3] - a[:3])
    return b[:3] + b[3] * axis


def _apart(values):
    """The widest gap between sorted `values`."""
    return float(np.diff(np.sort(values)).max())


def _turn(a, b, c):
    """The angle (degrees) by which the axis a → b → c turns at b."""
    u, v = (np.subtract(q[:3], p[:3]) for p, q in ((a, b), (b, c)))
    return float(np.degrees(np.arccos(u @ v / np.linalg.norm(u) / np.linalg.norm(v))))


@pytest.mark.parametrize("name", ["quadruped", "biped", "insect"])
def test_one_closed_manifold_shell_in_range(name, request):
    """At its default resolution: 3k–9k vertices, one shell (no loose blob of a thin
    part), watertight, consistently wound, outward."""
    mesh, _ = request.getfixturevalue(name)
    assert 3000 <= len(mesh.vertices) <= 9000
    assert len(mesh.split(only_watertight=False)) == 1
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0


def test_quadruped_legs_are_jointed_and_apart(quadruped):
    """Four hooves on the ground at their corners; each leg narrower at the knee than at
    the thigh and at the ankle than at the shin, its knee bent 15–25°; the legs of a pair
    more than two grid cells apart; a neck narrower than the head; a tail behind."""
    mesh, h = quadruped
    vertices = np.asarray(mesh.vertices)
    tree = cKDTree(vertices)
    for side in (-1, 1):
        for leg in (ch.QUADRUPED_HIND_LEG, ch.QUADRUPED_FRONT_LEG):
            thigh, knee, shin, ankle, hoof = _mirror(leg, side)
            assert tree.query(_tip(ankle, hoof))[0] < h  # the hoof's sole
            assert 15 < _turn(thigh, knee, shin) < 25
            # Across the leg: the thigh's section below the body wider than the knee's.
            assert _section(mesh, thigh, knee, 0.4) > 0.05 > _section(mesh, thigh, knee, 1)
            assert _radius(mesh, knee) < min(_radius(mesh, shin), 0.043)  # 0.04 < 0.045
            assert _radius(mesh, ankle) < min(_radius(mesh, hoof), _radius(mesh, shin))
    assert vertices[:, 2].min() < 0.01
    for x in (0.27, 0.73):  # below the body: left legs and right ones, apart
        legs = (np.abs(vertices[:, 0] - x) < 0.1) & (vertices[:, 2] < 0.44)
        assert _apart(vertices[legs, 1]) > 2 * h
    neck = _section(mesh, (0.8, 0, 0.61), (0.98, 0, 0.82), 0.7)  # medial radius 0.05
    assert neck < 0.06 < tree.query((1.07, 0, 0.87))[0]  # the head's: 0.075
    assert neck < 0.1 < tree.query((0.5, 0, 0.61))[0]  # the body's: 0.13
    assert vertices[:, 0].min() < -0.18  # the tail's tip
    assert vertices[:, 0].max() > 1.2  # the snout's


def test_biped_limbs_are_jointed_and_apart(biped):
    """Hands at the ends of arms held out from the torso (more than two grid cells from
    it at the elbows), narrower at the elbow and the wrist; feet towards +x on the ground,
    legs narrower at the knee and the ankle, apart; a neck narrower than the head."""
    mesh, h = biped
    vertices = np.asarray(mesh.vertices)
    tree = cKDTree(vertices)
    assert np.isclose(np.ptp(vertices[:, 2]), 1, atol=0.01)
    for side in (-1, 1):
        shoulder, upper, elbow, fore, wrist, hand = _mirror(ch.BIPED_ARM, side)
        assert tree.query(_tip(wrist, hand))[0] < h
        out = np.degrees(np.arctan2(abs(elbow[1] - shoulder[1]), shoulder[2] - elbow[2]))
        assert 40 < out < 50 and 10 < _turn(shoulder, elbow, wrist) < 25  # held out, bent
        assert _radius(mesh, upper) > _radius(mesh, elbow) < _radius(mesh, fore)
        assert _radius(mesh, fore) > _radius(mesh, wrist) < _radius(mesh, hand)
        hip, thigh, knee, calf, ankle, foot = _mirror(ch.BIPED_LEG, side)
        assert tree.query(_tip(ankle, foot))[0] < h
        assert _section(mesh, thigh, knee, 0) > 0.045 > _section(mesh, thigh, knee, 1)
        assert _radius(mesh, thigh) > _radius(mesh, knee) < _radius(mesh, calf)
        assert _radius(mesh, calf) > _radius(mesh, ankle)
        foot = (vertices[:, 2] < 0.03) & (np.abs(vertices[:, 1] - side * 0.1) < 0.04)
        assert vertices[foot, 0].max() > 0.1 and vertices[foot, 0].min() > -0.05  # forwards
    elbows = np.abs(vertices[:, 2] - 0.66) < 0.03
    assert _apart(np.abs(vertices[elbows, 1])) > 2 * h  # the arms from the torso
    legs = (vertices[:, 2] > 0.1) & (vertices[:, 2] < 0.35)
    assert _apart(vertices[legs, 1]) > 2 * h
    assert _section(mesh, (0, 0, 0.8), (0, 0, 0.9), 0.4) < 0.045  # neck: 0.035
    assert tree.query((0.01, 0, 0.935))[0] > 0.06  # head: 0.065
    assert vertices[:, 2].max() > 0.99 and vertices[:, 2].min() < 0.01


def test_insect_has_six_jointed_legs_on_its_thorax_and_two_antennae(insect):
    """Six tarsi on the ground, each leg narrower at its knee than along its femur and at
    its ankle than along its tibia, its knee above the thorax's middle; the thorax the
    thickest part; antennae at least 1.5 grid cells thick at resolution 48."""
    mesh, h = insect
    vertices = np.asarray(mesh.vertices)
    tree = cKDTree(vertices)
    for side in (-1, 1):
        for leg in ch.INSECT_LEGS:
            coxa, femur, knee, tibia, ankle, tarsus = _mirror(ch.insect_leg(*leg), side)
            assert tree.query(_tip(ankle, tarsus))[0] < h
            assert tarsus[2] - tarsus[3] < 0.005  # on the ground
            assert np.linalg.norm(np.subtract(coxa[:3], (0.6, 0, 0.3))) < 0.11  # in the thorax
            assert knee[2] > 0.4
            assert _radius(mesh, femur) > _radius(mesh, knee) < _radius(mesh, tibia)
            assert _radius(mesh, tibia) > _radius(mesh, ankle)
        antenna = _mirror(ch.INSECT_ANTENNA, side)
        assert tree.query(_tip(antenna[-2], antenna[-1]))[0] < h
        assert 2 * min(r for *_, r in antenna) > 1.5 * _cell(mesh, 48)

    def thickness(x):  # the body's height at x, on its axis (y = 0)
        column = (np.abs(vertices[:, 0] - x) < h) & (np.abs(vertices[:, 1]) < h)
        return np.ptp(vertices[column, 2])

    thorax = thickness(0.6)
    assert thorax > max(thickness(0.3), thickness(0.8), thickness(0.45)) + 0.02

"""Invalid points counted by cause, and the largest valid bend, against the closed-form limits."""

import jax
import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._fleshing.diagnose import diagnose, largest_valid_bend, planar_bend

# The bending limit of each method along the target's normal: κ₁ x* < limit (README, Validity).
LIMITS = {"radial": 1 / np.sqrt(3), "normal": 0.5, "binormal": 1.0}


def _box(n=400, seed=0):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-0.5, 0.5, (n, 3))
    points[:, 0] = 0.2 + 3.6 * (points[:, 0] + 0.5)  # inside [0, 4]: all registered on the line
    return points


@pytest.mark.parametrize("method", sorted(LIMITS))
def test_causes_match_the_bending_limit(method):
    source, points = fj.Line(4.0), _box()
    registration = fj.register(points, source)
    target = planar_bend(source, 4.0 / 0.6)  # radius 0.6: tighter than the box allows
    normal = np.asarray(fj.rotation_minimizing_frame(source, 0.0))[1]
    towards_centre = points @ normal  # the offset x* along the arc's normal (line source)
    causes = diagnose(registration, target, method=method)
    _, valid = fj.pose(registration, target, method=method)
    assert causes.points == len(points) and causes.outside_source == 0
    assert causes.beyond_limit == np.sum(towards_centre / 0.6 >= LIMITS[method])
    assert causes.invalid == np.sum(~np.asarray(valid))


def test_points_outside_the_source_are_counted_first():
    source, points = fj.Line(4.0), _box()
    points[:7, 0] = 50.0  # far past the end: beyond the search range of the line
    points[:7, 1:] = 3.0  # and far off the line: beyond the bending limit too, counted once
    points[7, 0] = np.nan
    causes = diagnose(fj.register(points, source), planar_bend(source, 1.0))
    assert causes.outside_source == 8 and causes.invalid == 8


def test_largest_valid_bend_is_the_radial_limit():
    source, points = fj.Line(4.0), _box()
    registration = fj.register(points, source)
    normal = np.asarray(fj.rotation_minimizing_frame(source, 0.0))[1]
    for sign in (1.0, -1.0):
        # Radial: every point valid iff L/θ > √3 max x*, the offsets towards the centre.
        x_max = np.max(sign * points @ normal)
        expected = 4.0 / (np.sqrt(3) * x_max)
        angle = largest_valid_bend(registration, source, sign=sign, steps=30)
        assert angle == pytest.approx(expected, rel=1e-6)


def test_planar_bend_starts_as_the_spine():
    spine = fj.BSpline(np.array([[0, 0, 0], [1, 0.2, 0], [2, 0, 0.3], [3, 0.1, 0], [4, 0, 0],
                                 [5, 0.3, 0.1]]))  # fmt: skip
    arc = planar_bend(spine, 1.2)
    frame = np.asarray(fj.rotation_minimizing_frame(spine, 0.0))
    np.testing.assert_allclose(arc(0.0), spine(0.0), atol=1e-12)
    np.testing.assert_allclose(arc.tangent(0.0), frame[0], atol=1e-12)
    np.testing.assert_allclose(arc.curvature_vector(0.0), 1.2 / float(spine.length) * frame[1],
                               atol=1e-12)  # fmt: skip
    assert float(arc.length) == pytest.approx(float(spine.length))
    back = planar_bend(spine, -1.2)
    np.testing.assert_allclose(back.curvature_vector(0.0), -arc.curvature_vector(0.0), atol=1e-12)
    assert isinstance(planar_bend(spine, 0.0), fj.Line)
    assert jax.numpy.isfinite(arc(1.0)).all()


def test_local_volume_change_of_the_demo_figure():
    from fleshing_jax._demo import local_volume_change

    source, target, points = fj.Line(4.0), fj.Arc(3.0, 4.0), _box(64)
    towards_centre = points @ np.asarray(target.curvature_vector(0.0)) * 3.0  # unit normal
    # Skinning carries offsets rigidly: the arc-length element at x* is (1 − κ x*) ds.
    skinning = local_volume_change(points, source, target, "skinning")
    np.testing.assert_allclose(skinning, -towards_centre / 3.0, atol=1e-6)
    np.testing.assert_allclose(local_volume_change(points, source, target, "radial"), 0, atol=1e-6)

"""The fleshing pipeline: det J = 1, inverse, arc-length transfer, twist, identity, API."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import PAIRS, central_difference, cloud

import fleshing_jax as fj
from fleshing_jax._fleshing.pipeline import pose_point
from fleshing_jax._fleshing.projection import register_point

MAPS = ("radial", "normal", "binormal")


@jax.jit
def _determinants(source, target, points):
    """det J of the three maps (`fj.jacobian_determinant` of each `Fleshing(source, target,
    method=m, twist=0.7)`: NaN where not valid), in one program: each point is registered on
    the source once for the three (as each map's `apply_point` registers it, then poses it),
    which a `Fleshing` each traced and differentiated three times (the five pairs: 23 → 18 s
    of CPU, helix-helix 10.9 → 8.0 s; the same determinants, bit for bit). In one program
    they compile in 20 % less CPU time than in a program each (helix-helix)."""
    twist = jnp.asarray(0.7)

    def images(x):
        registration = register_point(source, x)
        posed = [pose_point(registration, target, method, twist) for method in MAPS]
        return [image for image, _ in posed], [valid for _, valid in posed]

    jacobians, valid = jax.vmap(jax.jacfwd(images, has_aux=True))(points)
    return [jnp.where(v, jnp.linalg.det(j), jnp.nan) for j, v in zip(jacobians, valid)]


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_det_jacobian_is_one(name):
    source, target = PAIRS[name]
    points = cloud(source, overshoot=0.1)  # includes points past the ends
    for method, det in zip(MAPS, _determinants(source, target, points), strict=True):
        det = np.asarray(det)
        assert np.isfinite(det).all(), f"{method}: every point of this tube is in the valid space"
        assert np.max(np.abs(det - 1)) < 1e-10, method


# The arc-helix pair with `-m slow`: one pair shows the property, and each compiled its own
# det J program (4 s of CPU, cold).
@pytest.mark.parametrize("name", ["line-arc", pytest.param("arc-helix", marks=pytest.mark.slow)])
def test_skinning_is_not_volume_preserving(name):
    source, target = PAIRS[name]
    fleshing = fj.Fleshing(source, target, method="skinning", twist=0.7)
    det = np.asarray(fj.jacobian_determinant(fleshing, cloud(source)))
    assert np.max(np.abs(det - 1)) > 0.05


_CASES = [(name, "radial") for name in sorted(PAIRS)]
_CASES += [(name, method) for name in ("arc-helix", "unequal") for method in fj.METHODS[1:]]


@pytest.mark.parametrize("name, method", _CASES)
def test_inverse_round_trip_and_arc_length_transfer(name, method):
    source, target = PAIRS[name]
    stretch = float(target.length / source.length)
    points = cloud(source, overshoot=0.1)
    points[:6] = np.asarray(jax.vmap(source)(np.linspace(0.05, 0.95, 6) * float(source.length)))
    image, valid = fj.flesh(points, source, target, method=method, twist=-0.4)
    assert bool(valid.all())

    # The inverse is the fleshing back, with the opposite twist.
    inverse = fj.Fleshing(source, target, method=method, twist=-0.4).inverse
    assert inverse.source is target and inverse.target is source
    back, back_valid = fj.flesh(
        image, inverse.source, inverse.target, method=method, twist=inverse.twist
    )
    assert bool(back_valid.all())
    np.testing.assert_allclose(back, points, atol=1e-9)

    # M(C0(s)) = C1(λs), and the image projects on C1 at the scaled arc length (property 4).
    s0 = fj.register(points, source).arc_length
    s1 = fj.register(image, target).arc_length
    np.testing.assert_allclose(s1, stretch * s0, atol=1e-9)
    np.testing.assert_allclose(image[:6], jax.vmap(target)(stretch * s0[:6]), atol=1e-12)


def test_inverse_of_one_point():
    source, target = PAIRS["arc-helix"]
    fleshing = fj.Fleshing(source, target, method="normal", twist=1.1)
    x = jnp.asarray(cloud(source)[0])
    np.testing.assert_allclose(fleshing.inverse(fleshing(x)), x, atol=1e-12)


@pytest.mark.parametrize("method", fj.METHODS)
def test_identity_when_target_is_source(method):
    spine = fj.Helix(1.5, 2.0, 7.0)
    points = cloud(spine, overshoot=0.1)
    image, valid = fj.flesh(points, spine, spine, method=method)
    assert bool(valid.all())
    np.testing.assert_allclose(image, points, atol=1e-12)


def test_twist_rotates_about_tangent_right_hand():
    line = fj.Line(3.0)  # along +x
    w = 0.6
    x = jnp.array([1.0, 0.3, 0.0])  # offset along +y
    image = fj.Fleshing(line, line, twist=w)(x)
    # Right-hand rotation about +x takes +y towards +z.
    np.testing.assert_allclose(image, [1.0, 0.3 * np.cos(w), 0.3 * np.sin(w)], atol=1e-14)


def test_unequal_lengths_stretch_with_volume_compensation():
    source, target = fj.Line(2.0), fj.Line(5.0, tangent=(0, 1, 0))
    stretch = 2.5
    x = jnp.array([0.8, 0.2, -0.1])
    image = fj.Fleshing(source, target)(x)
    # Arc length scales by λ, the cross-section by 1/√λ.
    np.testing.assert_allclose(image[1], 0.8 * stretch, atol=1e-14)
    frame0 = fj.rotation_minimizing_frame(source, 0.8)
    # The target's first normal is the source's carried by the smallest rotation taking x to
    # y (a quarter turn about z), not the target's own rule's (+x): I₁ = R I₀, J₁ = T₁ × I₁.
    quarter = jnp.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    normal = quarter @ frame0[1]
    frame1 = jnp.stack([normal, jnp.cross(jnp.array([0.0, 1, 0]), normal)])
    offset0 = frame0[1:] @ (x - source(0.8))
    offset1 = frame1 @ (image - target(2.0))
    np.testing.assert_allclose(offset1, offset0 / np.sqrt(stretch), atol=1e-14)


def test_points_beyond_the_ends_are_continuous():
    source, target = PAIRS["line-arc"]
    fleshing = fj.Fleshing(source, target, method="radial")
    for end in (0.0, 4.0):
        inside = jnp.array([end - 1e-7 if end else 1e-7, 0.2, 0.1])
        outside = jnp.array([end + 1e-7 if end else -1e-7, 0.2, 0.1])
        np.testing.assert_allclose(fleshing(inside), fleshing(outside), atol=1e-6)
        assert bool(fleshing.is_valid(outside))


def _limit_points(limit, curvature, margin):
    """Points on a line, offset along +y (towards the arc's centre) at κx = limit·(1 ± margin)."""
    x = limit / curvature * np.array([1 - margin, 1 + margin])
    return np.stack([np.full(2, 1.0), x, np.zeros(2)], axis=1)


@pytest.mark.parametrize(
    "method, limit",
    [("radial", 1 / np.sqrt(3)), ("normal", 0.5), ("binormal", 1.0), ("skinning", 1.0)],
)
def test_validity_at_bending_limit(method, limit):
    # Bending a line into a unit circle: each method's limit of κ₁x (eqs. 9, 13, 17; reach).
    source, target = fj.Line(2.0), fj.Arc(1.0, 2.0)
    image, valid = fj.flesh(_limit_points(limit, 1.0, 1e-3), source, target, method=method)
    np.testing.assert_array_equal(valid, [True, False])
    assert np.isfinite(image).all()


@pytest.mark.parametrize("method", fj.METHODS)
def test_validity_at_reach_of_source(method):
    # Unbending a unit arc: the reach of C0 (κ₀x < 1, the centre) bounds every method.
    source, target = fj.Arc(1.0, 2.0), fj.Line(2.0)
    centre, on_arc = np.array([0.0, 1.0, 0.0]), np.asarray(source(1.0))
    points = np.stack([on_arc + (centre - on_arc) * f for f in (1 - 1e-3, 1 + 1e-3)])
    _, valid = fj.flesh(points, source, target, method=method)
    np.testing.assert_array_equal(valid, [True, False])


def test_invalid_points_do_not_disturb_others():
    source, target = PAIRS["line-arc"]
    good = cloud(source, n=8)
    bad = np.array([[np.nan, 0.0, 0.0], [1.0, np.inf, 0.0], [1.0, 2.9, 0.0], [30.0, 0.0, 0.0]])
    image, valid = fj.flesh(np.concatenate([good, bad]), source, target)
    alone, _ = fj.flesh(good, source, target)
    np.testing.assert_array_equal(valid, [True] * 8 + [False] * 4)
    np.testing.assert_allclose(image[:8], alone, atol=1e-15)
    np.testing.assert_array_equal(image[-2:], bad[-2:])  # invalid points come back unchanged

    def loss(radius):
        moved, ok = fj.flesh(np.concatenate([good, bad]), source, fj.Arc(radius, 4.0))
        return jnp.sum(jnp.where(ok[:, None], moved, 0.0))

    assert np.isfinite(jax.jit(jax.grad(loss))(3.0))  # (eagerly: about 40 programs)


@pytest.mark.parametrize("method", ["normal", "binormal", "radial"])
def test_finite_gradients_on_straight_spines(method):
    line = fj.Line(3.0)
    fleshing = fj.Fleshing(line, fj.Line(3.0, tangent=(0, 1, 1)), method=method, twist=0.2)

    # (One compiled program for the three derivatives: evaluated eagerly, they were hundreds
    # of one-operation programs, 10 s for the first method.)
    @jax.jit
    def derivatives(x):
        jac = jax.jacfwd(fleshing)(x)
        grad_twist = jax.grad(lambda w: fj.Fleshing(line, line, method=method, twist=w)(x)[2])
        # Straightening an arc (κ₁ = 0): finite gradients with respect to the source radius.
        arc = jax.grad(lambda r: fj.Fleshing(fj.Arc(r, 2.0), line, method=method)(x)[1])
        return jac, grad_twist(0.2), arc(2.0)

    for x in (jnp.array([1.0, 0.2, 0.3]), jnp.array([1.0, 0.0, 0.0])):
        jac, grad_twist, g = derivatives(x)
        assert np.isfinite(jac).all()
        np.testing.assert_allclose(np.linalg.det(jac), 1.0, atol=1e-12)
        assert np.isfinite(grad_twist)
    assert np.isfinite(g)  # (on the axis: the last point)


def _with_slope(mapped):
    """`r ↦ (mapped(r), dmapped/dr)` (forward mode, as `jacfwd` of a scalar): compiled, the
    values for the central differences come from the same program as the derivative."""
    return lambda r: jax.jvp(mapped, (r,), (jnp.ones_like(r),))


@pytest.mark.parametrize("method", MAPS)
def test_gradient_wrt_spine_parameter(method):
    x = jnp.array([1.2, 0.25, -0.3])

    def mapped(radius):
        return fj.Fleshing(fj.Line(3.0), fj.Helix(radius, 1.0, 3.0), method=method, twist=0.5)(x)

    # Forward and reverse mode, each with its values for the differences (one program each:
    # the differences of the eager map compiled a third).
    image_and_slope = jax.jit(_with_slope(mapped))
    slope = image_and_slope(2.0)[1]
    fd = central_difference(lambda r: image_and_slope(r)[0], 2.0)
    np.testing.assert_allclose(slope, fd, rtol=1e-6, atol=1e-8)
    loss_and_grad = jax.jit(jax.value_and_grad(lambda r: jnp.sum(mapped(r) ** 2)))
    grad = loss_and_grad(2.0)[1]
    fd = central_difference(lambda r: loss_and_grad(r)[0], 2.0)
    np.testing.assert_allclose(grad, fd, rtol=1e-6)


@pytest.mark.parametrize("method", ["radial", "normal", "binormal"])
def test_gradient_wrt_source_spine_parameter(method):
    # Through the registration on the source: the closest projection's implicit derivative.
    x = jnp.array([1.2, 0.25, -0.3])

    def mapped(radius):
        source = fj.Arc(radius, 3.0, normal=(0, 1, 0))
        return fj.Fleshing(source, fj.Helix(2.0, 1.0, 3.0), method=method, twist=0.5)(x)

    image_and_slope = jax.jit(_with_slope(mapped))
    fd = central_difference(lambda r: image_and_slope(r)[0], 2.5)
    np.testing.assert_allclose(image_and_slope(2.5)[1], fd, rtol=1e-6, atol=1e-8)


def test_gradient_wrt_twist():
    x = jnp.array([1.2, 0.25, -0.3])

    def mapped(w):
        return fj.Fleshing(fj.Line(3.0), fj.Arc(2.0, 3.0), twist=w)(x)

    image_and_slope = jax.jit(_with_slope(mapped))  # (eagerly: about 160 programs)
    fd = central_difference(lambda w: image_and_slope(w)[0], 0.4)
    np.testing.assert_allclose(image_and_slope(0.4)[1], fd, atol=1e-8)


def test_register_then_pose_equals_flesh():
    source = fj.Arc(2.5, 5.0)
    points = cloud(source, overshoot=0.1)
    registration = fj.register(points, source)
    for target in (fj.Helix(2.0, 1.5, 5.0), fj.Helix(2.5, 0.5, 5.5)):
        posed = fj.pose(registration, target, method="normal", twist=0.1)
        direct = fj.flesh(points, source, target, method="normal", twist=0.1)
        np.testing.assert_array_equal(posed[1], direct[1])
        np.testing.assert_allclose(posed[0], direct[0], atol=1e-15)


def test_fleshing_under_jit_vmap_and_pytree():
    source, target = PAIRS["arc-helix"]
    fleshing = fj.Fleshing(source, target, method="binormal")
    points = cloud(source)
    batched = jax.jit(jax.vmap(fleshing))(points)
    np.testing.assert_allclose(batched, fj.flesh(points, source, target, method="binormal")[0])
    # A Fleshing is a pytree: it can be passed through jit as an argument.
    out = jax.jit(lambda m, x: m(x))(fleshing, points[0])
    np.testing.assert_allclose(out, batched[0], atol=1e-15)


def test_float32_keeps_dtype():
    source = fj.Line(4.0)
    target = fj.Arc(3.0, 4.0)
    points = cloud(source).astype(np.float32)
    image, valid = fj.flesh(points, source, target, twist=0.2)
    assert image.dtype == jnp.float32
    assert bool(valid.all())
    reference, _ = fj.flesh(points.astype(np.float64), source, target, twist=0.2)
    np.testing.assert_allclose(image, reference, atol=1e-5)
    fleshing = fj.Fleshing(source, target, twist=0.2)
    assert fleshing(points[0]).dtype == jnp.float32
    det = fj.jacobian_determinant(fleshing, points)
    assert det.dtype == jnp.float32
    assert np.max(np.abs(np.asarray(det) - 1)) < 1e-4


def test_jacobian_determinant_marks_invalid_points():
    fleshing = fj.Fleshing(fj.Line(2.0), fj.Arc(1.0, 2.0), method="normal")
    det = np.asarray(fj.jacobian_determinant(fleshing, np.array([[1, 0.2, 0], [1, 0.9, 0.0]])))
    assert abs(det[0] - 1) < 1e-12 and np.isnan(det[1])


def test_bad_arguments():
    line = fj.Line(1.0)
    with pytest.raises(ValueError, match="points"):
        fj.flesh(np.zeros((4, 2)), line, line)
    with pytest.raises(ValueError, match="method"):
        fj.flesh(np.zeros((4, 3)), line, line, method="bulge")
    with pytest.raises(ValueError, match="method"):
        fj.Fleshing(line, line, method="Radial")
    with pytest.raises(ValueError, match="twist"):
        fj.Fleshing(line, line, twist=[0.1, 0.2])
    with pytest.raises(TypeError, match="target"):
        fj.flesh(np.zeros((4, 3)), line, "arc")
    with pytest.raises(ValueError, match="x"):
        fj.Fleshing(line, line)(np.zeros(2))

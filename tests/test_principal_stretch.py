"""`fj.principal_stretch` and `fj.pose_stretch`: how far a fleshing squeezes the shape."""

import jax
import jax.numpy as jnp
import jax.test_util
import numpy as np
import pytest

import fleshing_jax as fj

BASE = fj.Line(3.0)
BENT = fj.BentSpine(BASE, joint=0.5, bend=1.4, direction=0.3, twist=0.2)
POINTS = np.random.default_rng(1).uniform([0.2, -0.3, -0.3], [2.8, 0.3, 0.3], (24, 3))


def _finite_difference_stretch(fleshing, x, h=1e-6):
    columns = [(np.asarray(fleshing(x + h * e)) - np.asarray(fleshing(x - h * e))) / (2 * h)
               for e in np.eye(3)]
    sigma = np.linalg.svd(np.stack(columns, axis=1), compute_uv=False)
    return max(sigma[0], 1 / sigma[-1])


def test_the_singular_values_of_the_map_s_jacobian():
    fleshing = fj.Fleshing(BASE, BENT)
    stretch = np.asarray(fj.principal_stretch(fleshing, POINTS))
    assert np.all(np.isfinite(stretch)) and stretch.max() > 1.15  # a real bend squeezes
    # The differences of the same map without its projection check, which only flags points
    # (these are valid): a one-point program of half the size (compiled in 2.7 s, not 5.6).
    unchecked = fj.Fleshing(BASE, BENT, check_projection=False)
    for i in range(0, 24, 6):
        assert stretch[i] == pytest.approx(_finite_difference_stretch(unchecked, POINTS[i]),
                                           rel=1e-6)
    # The map's own squeezing grows with the bend; a spine onto itself does not squeeze.
    sharper = fj.BentSpine(BASE, joint=0.5, bend=2.0, direction=0.3, twist=0.2)
    assert np.all(np.asarray(fj.principal_stretch(fj.Fleshing(BASE, sharper), POINTS)) >=
                  stretch - 1e-12)
    same = np.asarray(fj.principal_stretch(fj.Fleshing(BASE, BASE), POINTS))
    np.testing.assert_allclose(same, 1.0, atol=1e-12)


def test_invalid_points_are_nan_and_float32_keeps_its_dtype():
    far = np.array([[1.0, 5.0, 0.0], [1.0, 0.1, 0.0]])  # beyond the bend's focal set; inside
    stretch = np.asarray(fj.principal_stretch(fj.Fleshing(BASE, BENT), far))
    assert np.isnan(stretch[0]) and np.isfinite(stretch[1])
    # (Without its projection check, which only flags points (these are valid): a float32
    # program half the size of the checked map's, which the float64 calls compile.)
    single = fj.Fleshing(fj.Line(np.float32(3.0)), BENT, check_projection=False)
    value = fj.principal_stretch(single, POINTS.astype(np.float32))
    assert value.dtype == jnp.float32
    np.testing.assert_allclose(value, fj.principal_stretch(fj.Fleshing(BASE, BENT), POINTS),
                               rtol=2e-4)
    with pytest.raises(TypeError, match="`fleshing`"):
        fj.principal_stretch(BASE, POINTS)
    with pytest.raises(ValueError, match="`points`"):
        fj.principal_stretch(fj.Fleshing(BASE, BENT), POINTS[:, :2])


def test_its_gradient_is_finite_where_singular_values_coincide():
    from fleshing_jax._fleshing.verify import stretch_of

    # A rigid motion (all equal), and a squeeze with two equal: only the values' derivatives.
    # (Compiled: differentiated eagerly, the SVD's rules ran as about 45 small programs.)
    grad = jax.jit(jax.grad(stretch_of))
    for jacobian in (np.eye(3), np.diag([2.0, 0.5, 0.5]), np.diag([1.5, 1.5, 0.4])):
        gradient = np.asarray(grad(jnp.asarray(jacobian)))
        assert np.all(np.isfinite(gradient))
    skewed = jnp.asarray([[2.5, 0.1, 0.0], [0.0, 0.5, 0.2], [0.1, 0.0, 0.8]])
    jax.test_util.check_grads(jax.jit(stretch_of), (skewed,), order=2)
    assert float(stretch_of(jnp.diag(jnp.asarray([1.2, 1.0, 0.25])))) == pytest.approx(4.0)


def test_at_registered_points_it_is_the_map_s():
    # The per-frame path's map (registered feet, a prepared target), differentiated at the
    # registered feet: the same as the one-point map's, on both sides of the spine's end.
    from fleshing_jax._fleshing.pipeline import prepare_target
    from fleshing_jax._fleshing.verify import registered_stretch

    points = np.concatenate([POINTS, [[3.3, 0.1, -0.1], [-0.2, 0.05, 0.1]]])
    for beyond in ("continue", "rigid"):
        registration = fj.register(points, BASE)
        poser = prepare_target(BENT, points.dtype, check_projection=False,
                               start=registration.ends, beyond=beyond)
        registered = registered_stretch(BASE, registration, poser)
        # (The poser checks no projection, which only flags points (these are valid): nor
        # does the rigid map, a program half the size; the continued one is the first test's.)
        fleshing = fj.Fleshing(BASE, BENT, beyond=beyond, check_projection=beyond == "continue")
        exact = fj.principal_stretch(fleshing, points)
        np.testing.assert_allclose(registered, exact, rtol=1e-10)

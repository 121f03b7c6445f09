"""The closed-form maps' building blocks: the radial cubic and its safe branches."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_difference
from jax.test_util import check_grads

import fleshing_jax as fj
from fleshing_jax._fleshing.maps import _halley_root

A = 2 / (3 * np.sqrt(3))  # the branch point of μ³ − μ = α
# Roots of a batch, compiled: run eagerly, each test was about 85 one-operation programs.
roots = jax.jit(jax.vmap(fj.cubic_root))


def test_cubic_root_solves_the_cubic_on_both_branches():
    alpha = jnp.concatenate([jnp.linspace(-A, A, 2001), jnp.linspace(A, 50.0, 2001)])
    mu = roots(alpha)
    np.testing.assert_allclose(mu**3 - mu, alpha, atol=1e-13, rtol=1e-13)
    assert float(fj.cubic_root(0.0)) == 1.0
    # The branch through μ(0) = 1: increasing, from 1/√3 at α = −a, through 2/√3 at α = a.
    assert np.all(np.diff(np.asarray(mu)) >= 0)
    np.testing.assert_allclose(float(fj.cubic_root(-A)), 1 / np.sqrt(3), atol=1e-7)
    np.testing.assert_allclose(float(fj.cubic_root(A)), 2 / np.sqrt(3), atol=1e-14)
    # Far on the convex side (large α), where the starting guess comes from the exponent bits.
    large = jnp.asarray([1.0, 1.0 + 1e-12, 7.5, 1e3, 1e6, 1e12, 1e30])
    mu = roots(large)
    np.testing.assert_allclose(mu**3 - mu, large, rtol=1e-15)


def test_cubic_root_in_float32_matches_the_closed_form():
    # float32 takes Halley steps (`_halley_root`), float64 the closed form: the same root over
    # the whole valid range but the ill-conditioned neighbourhood of the double root, and the
    # iteration itself to float64 round-off.
    alpha = np.concatenate([np.linspace(-A + 1e-3, 3.0, 4001), np.geomspace(3.0, 1e30, 200)])
    mu32 = roots(jnp.asarray(alpha, jnp.float32))
    assert mu32.dtype == jnp.float32
    mu64 = roots(jnp.asarray(alpha))
    np.testing.assert_allclose(mu32, mu64, rtol=1e-6)
    np.testing.assert_allclose(jax.jit(_halley_root)(jnp.asarray(alpha)), mu64, rtol=2e-15)
    assert float(_halley_root(jnp.asarray(-A))) == pytest.approx(1 / np.sqrt(3), abs=1e-7)


def test_cubic_root_gradients_are_finite_at_the_branch_points():
    grad = jax.jit(jax.vmap(jax.grad(fj.cubic_root)))
    # Where arccos hands over to arccosh (α = a), on both sides and exactly there.
    near_a = jnp.asarray([A - 1e-9, A, A + 1e-9])
    slopes = grad(near_a)
    mu = roots(near_a)
    np.testing.assert_allclose(slopes, 1 / (3 * mu**2 - 1), rtol=1e-12)
    np.testing.assert_allclose(slopes, 1 / 3, rtol=1e-6)  # μ = 2/√3: 1/(3·4/3 − 1)
    # Towards the double root (α → −a) the slope grows like 1/√(α + a), but stays finite;
    # exactly at −a (the edge of the valid space) it is reported as 0, never NaN.
    edge = grad(jnp.asarray([-A + 1e-6, -A + 1e-12, -A]))
    assert np.all(np.isfinite(np.asarray(edge)))
    assert float(edge[0]) > 100
    # And the slope is the derivative of the values away from the branch points.
    for alpha in (-0.3, 0.0, 0.2, 1.0, 10.0):
        np.testing.assert_allclose(
            grad(jnp.asarray([alpha]))[0], central_difference(fj.cubic_root, alpha), rtol=1e-7
        )


def test_radial_map_gradient_through_the_branch_switch():
    # A point whose bend parameter α crosses the arccos/arccosh switch as the target bends.
    source, x = fj.Line(3.0), jnp.asarray([1.5, -0.5, 0.0])

    def mapped(radius):
        return fj.Fleshing(source, fj.Arc(radius, 3.0, normal=(0, 1, 0)), twist=0.0)(x)

    # The image and its derivative in one compiled program, also for the differences:
    # differentiated eagerly, the map ran as about 200 one-operation programs.
    @jax.jit
    def image_and_slope(radius):
        return jax.jvp(mapped, (radius,), (jnp.ones_like(radius),))

    for radius in (0.6, 0.8659, 1.5):
        jac = image_and_slope(radius)[1]
        assert np.all(np.isfinite(np.asarray(jac)))
        fd = central_difference(lambda r: image_and_slope(r)[0], radius)
        np.testing.assert_allclose(jac, fd, rtol=1e-5, atol=1e-7)


def test_whole_radial_bend_is_exact_then_compresses_without_crossing_the_centre():
    # Past k·d* = WHOLE_FROM a pose that keeps every point (a limb past its joint's range)
    # compresses the concave side towards the centre of curvature: monotone, never across it
    # (the exact map's continuation sent points past the centre: a fold), C¹ at the switch.
    from fleshing_jax._fleshing.maps import WHOLE_FROM, radial_bend, radial_bend_whole

    k = jnp.asarray([2.0, 0.0])
    p = np.linspace(-1.0, 1.5, 1001)
    d = jnp.stack([jnp.asarray(p) / 2.0, jnp.full(p.shape, 0.1)], axis=1)
    # (Compiled, here and below: run eagerly, the test was about 270 one-operation programs.)
    whole, ok = jax.jit(jax.vmap(radial_bend_whole, in_axes=(0, None)))(d, k)
    exact, exact_ok = jax.jit(jax.vmap(radial_bend, in_axes=(0, None)))(d, k)
    below = p <= WHOLE_FROM
    np.testing.assert_array_equal(whole[below], exact[below])
    np.testing.assert_array_equal(ok, exact_ok & below)  # flagged past the switch
    p1 = np.asarray(whole @ k)
    assert np.all(np.diff(p1) > 0) and np.all(p1 < 1)  # monotone, short of the centre
    assert np.asarray(exact @ k)[-1] > 1  # (where the continued exact map had crossed it)

    def p1_of(q):
        return radial_bend_whole(jnp.stack([q / 2.0, 0.1]), k)[0] @ k

    slope = jax.jit(jax.grad(p1_of))
    for q in (WHOLE_FROM - 1e-7, WHOLE_FROM + 1e-7, 3.0):
        assert np.isfinite(float(slope(q)))
    np.testing.assert_allclose(slope(WHOLE_FROM - 1e-7), slope(WHOLE_FROM + 1e-7), rtol=1e-5)
    bent = jax.jit(lambda x: radial_bend_whole(x, k)[0])
    check_grads(bent, (d[900],), order=2)
    check_grads(bent, (d[100],), order=2)
    # Single precision stays single.
    assert radial_bend_whole(d[0].astype(jnp.float32), k.astype(jnp.float32))[0].dtype == (
        jnp.float32)

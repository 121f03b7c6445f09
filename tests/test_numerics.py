"""`_numerics`: the single-precision `sincos` and the per-component vector operations."""

import jax
import jax.numpy as jnp
import numpy as np
from jax.test_util import check_grads

from fleshing_jax._numerics import held_trig, per_component, sincos


def test_sincos_matches_sine_and_cosine_in_single_precision():
    # Every quadrant, both signs, the multiples of π/2 themselves and large arguments.
    x = np.concatenate(
        [np.linspace(-100, 100, 400_001), np.pi / 2 * np.arange(-64, 65), [0.0, -0.0, 1e-30]]
    ).astype(np.float32)
    sin, cos = jax.jit(sincos)(x)
    assert sin.dtype == cos.dtype == jnp.float32
    exact = x.astype(np.float64)  # the float32 argument, evaluated exactly
    np.testing.assert_allclose(np.asarray(sin), np.sin(exact), rtol=0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(cos), np.cos(exact), rtol=0, atol=1e-7)
    # Beyond, the reduction's error grows with |x|, as the argument's own resolution does.
    big = np.linspace(-1e4, 1e4, 20_001).astype(np.float32)
    sin, cos = sincos(big)
    tolerance = 1e-7 + 1e-9 * np.abs(big)
    assert np.all(np.abs(np.asarray(sin) - np.sin(big.astype(np.float64))) <= tolerance)
    assert np.all(np.abs(np.asarray(cos) - np.cos(big.astype(np.float64))) <= tolerance)


def test_sincos_is_jnp_sin_and_cos_in_double_precision():
    x = np.linspace(-50, 50, 1001)
    sin, cos = sincos(jnp.asarray(x))
    assert sin.dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(sin), np.asarray(jnp.sin(x)))
    np.testing.assert_array_equal(np.asarray(cos), np.asarray(jnp.cos(x)))


def test_sincos_derivatives():
    # The rule to second order (float64), and the single-precision derivatives against cos
    # and −sin (the polynomial's own derivative would be less accurate).
    check_grads(lambda x: sincos(x)[0] * sincos(2 * x)[1], (0.7,), order=2)
    check_grads(lambda x: sincos(x)[1], (np.asarray([-3.0, 0.0, 1.0, 40.0]),), order=2)
    x = np.linspace(-10, 10, 2001).astype(np.float32)
    first = jax.vmap(jax.grad(lambda x: sincos(x)[0] + 2 * sincos(x)[1]))(x)
    second = jax.vmap(jax.grad(jax.grad(lambda x: sincos(x)[0])))(x)
    exact = x.astype(np.float64)
    np.testing.assert_allclose(np.asarray(first), np.cos(exact) - 2 * np.sin(exact), atol=5e-7)
    np.testing.assert_allclose(np.asarray(second), -np.sin(exact), atol=2e-7)


def test_per_component_is_the_vector_operation():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(2, 5, 3))
    t = rng.normal(size=(5,))
    # One point, and batched by vmap (its use in the batched paths).
    np.testing.assert_allclose(per_component(lambda a, b: a + 2.0 * b, x[0], y[0]), x[0] + 2 * y[0])
    batched = jax.vmap(lambda x, y, t: per_component(lambda a, b: a * t - b, x, y))(x, y, t)
    np.testing.assert_allclose(np.asarray(batched), x * t[:, None] - y)


def test_held_trig_is_the_sine_and_cosine():
    # Held in memory by a product with the identity (`held_trig`): the same values, batched
    # too, and a NaN angle's own values NaN, not its neighbours' nor the other angle's.
    x = jnp.asarray(np.linspace(-7, 7, 303).reshape(3, 101))
    y = x.at[1, 5].set(jnp.nan)
    (cos, sin), (cos2, sin2) = jax.jit(held_trig)(x, y)
    np.testing.assert_array_equal(np.asarray(cos), np.cos(np.asarray(x)))
    np.testing.assert_array_equal(np.asarray(sin), np.sin(np.asarray(x)))
    assert np.isnan(np.asarray(cos2)).sum() == np.isnan(np.asarray(sin2)).sum() == 1
    np.testing.assert_array_equal(np.asarray(sin2), np.sin(np.asarray(y)))
    batched = jax.jit(jax.vmap(lambda a: held_trig(a)[0]))(x)
    np.testing.assert_array_equal(np.asarray(batched[0]), np.asarray(cos))


def test_bounded_held_trig_is_sincos():
    # Bounded angles (a bend or twist times a ramp): in float32 `sincos`'s polynomials, within
    # 1e-7 of the exact values; in float64 XLA's own, bit for bit.
    x = np.linspace(-2 * np.pi, 2 * np.pi, 4001)
    ((cos, sin),) = jax.jit(lambda a: held_trig(a, bounded=True))(x.astype(np.float32))
    fast_sin, fast_cos = jax.jit(sincos)(x.astype(np.float32))
    exact = x.astype(np.float32).astype(np.float64)
    for held, fast, value in ((cos, fast_cos, np.cos(exact)), (sin, fast_sin, np.sin(exact))):
        # (Compiled apart, XLA may contract a multiply-add of one and not the other: an ulp.)
        np.testing.assert_allclose(np.asarray(held), np.asarray(fast), rtol=0, atol=6e-8)
        np.testing.assert_allclose(np.asarray(held), value, rtol=0, atol=1e-7)
    ((cos, sin),) = held_trig(jnp.asarray(x), bounded=True)
    np.testing.assert_array_equal(np.asarray(cos), np.cos(x))
    np.testing.assert_array_equal(np.asarray(sin), np.sin(x))


"""`_fit.jacobian.materialised`: residuals whose derivative is their materialised Jacobian."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from fleshing_jax._fit.jacobian import for_solver, materialised


def _residuals(y):  # (2, 3) -> (4,), nonlinear in every parameter
    return jnp.stack([jnp.sin(y[0, 0]) * y[1, 2], jnp.exp(y[0, 1] - y[1, 0]),
                      y[0, 2] ** 3 + y[1, 1], jnp.cos(jnp.sum(y))])


Y = jnp.asarray([[0.3, -0.2, 0.7], [1.1, 0.4, -0.5]])


def test_value_and_derivatives_are_the_function_s():
    function = materialised(_residuals)
    np.testing.assert_array_equal(function(Y), _residuals(Y))
    np.testing.assert_allclose(jax.jacfwd(function)(Y), jax.jacfwd(_residuals)(Y), rtol=1e-14)
    # Reverse mode (a minimiser's gradient) transposes the matrix product.
    def loss(f):
        return lambda y: jnp.sum(f(y) ** 2)
    np.testing.assert_allclose(jax.grad(loss(function))(Y), jax.grad(loss(_residuals))(Y),
                               rtol=1e-14)
    value, linear = jax.linearize(function, Y)
    direction = jnp.arange(6.0).reshape(2, 3)
    np.testing.assert_allclose(linear(direction), jax.jvp(_residuals, (Y,), (direction,))[1],
                               rtol=1e-14)


def test_levenberg_marquardt_solves_through_it():
    target = _residuals(Y)

    def residuals(y):
        return _residuals(y) - target

    start = Y + 0.05
    solution = optx.least_squares(materialised(residuals), optx.LevenbergMarquardt(1e-12, 1e-12),
                                  start, throw=False)
    assert solution.result == optx.RESULTS.successful
    np.testing.assert_allclose(residuals(solution.value), 0, atol=1e-10)


def test_pytrees_of_parameters_and_residuals():
    # As `fit_spine`'s: `y = (free values, twist or None)`, residuals a tuple of arrays.
    def residuals(y):
        (a, b), twist = y
        return (jnp.sin(a) * b[0], jnp.stack([jnp.exp(b[1]) * a[1], jnp.sum(a**2)]))

    y = ((jnp.asarray([0.4, -1.2]), jnp.asarray([0.3, 0.8])), None)
    function = materialised(residuals)
    direction = ((jnp.asarray([1.0, -2.0]), jnp.asarray([0.5, 3.0])), None)
    value, tangent = jax.jvp(function, (y,), (direction,))
    expected_value, expected = jax.jvp(residuals, (y,), (direction,))
    for got, want in zip(value + tangent, expected_value + expected):
        np.testing.assert_allclose(got, want, rtol=1e-14)


def test_a_minimiser_keeps_the_residuals_as_they_are():
    # Its gradient is one reverse pass; a least-squares solver gets the materialised Jacobian.
    assert for_solver(_residuals, optx.BFGS(1e-8, 1e-8)) is _residuals
    function = for_solver(_residuals, optx.LevenbergMarquardt(1e-8, 1e-8))
    assert function is not _residuals
    np.testing.assert_array_equal(function(Y), _residuals(Y))


def test_compressed_passes_give_the_function_s_derivatives():
    # Rows moved by disjoint parameters (as a skeleton's limbs of one depth move their own
    # vertices): parameters 0 and 1 share a pass, so do 2 and 3; row 2 depends on none.
    from jax.test_util import check_grads

    from fleshing_jax._fit.jacobian import compressed

    def inner(y):  # (4,) -> (3, 2)
        return jnp.stack([jnp.stack([jnp.sin(y[0]) * y[2], y[2] ** 2]),
                          jnp.stack([jnp.exp(y[1]), y[1] * y[3]]), jnp.ones(2)])

    def outer(x):
        return (jnp.cos(x[:, 0]) + x[:, 1] ** 3, jnp.sum(x**2))

    seeds = jnp.asarray([[1, 1, 0, 0], [0, 0, 1, 1]])
    moves = jnp.asarray([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 0, 0]], bool)
    function = compressed(inner, outer, seeds, moves)
    y = jnp.asarray([0.3, -0.7, 1.2, 0.4])
    for got, want in zip(jax.jacfwd(function)(y), jax.jacfwd(lambda y: outer(inner(y)))(y)):
        np.testing.assert_allclose(got, want, rtol=1e-14)
    check_grads(function, (y,), order=2, modes=("fwd",))
    check_grads(function, (y,), order=1, modes=("rev",))
    # Kept (a solver's auxiliary output): the inner value beside the residuals, both with the
    # function's derivatives (the inner's from the same passes).
    kept = compressed(inner, outer, seeds, moves, keep_inner=True)
    value, x = kept(y)
    np.testing.assert_array_equal(x, inner(y))
    for got, want in zip(jax.tree.leaves(value), jax.tree.leaves(function(y))):
        np.testing.assert_array_equal(got, want)
    jacobians = jax.jacfwd(kept)(y)
    np.testing.assert_allclose(jacobians[1], jax.jacfwd(inner)(y), rtol=1e-14)
    for got, want in zip(jacobians[0], jax.jacfwd(lambda y: outer(inner(y)))(y)):
        np.testing.assert_allclose(got, want, rtol=1e-14)

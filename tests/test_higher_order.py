"""Derivatives of every order: spines in `s` and in their parameters, and the whole fleshing.

The custom derivative rules (arc-length inverse, closest projection, the radial cubic) are
written in differentiable operations, so that nested `jacfwd`/`jacrev`, `jax.hessian` and
Newton-type solvers see the derivatives of the exact functions, not of a first-order
linearisation. Compile time dominates: each test builds one or two programs.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import fleshing_jax as fj
from fleshing_jax._fleshing.maps import cubic_root
from fleshing_jax._numerics import polish_root

CONTROL = np.array(
    [[0, 0, 0], [1, 0.4, 0.1], [2, 1.2, 0.6], [3, 0.5, 1.4], [4, -0.6, 1.2], [5, 0, 0.4],
     [6.5, 0.8, 0.0], [7.5, 1.0, 0.8]]
)  # fmt: skip
POLYNOMIAL = np.array([[0, 0, 0], [1, 1, 0.2], [2, 0.5, 1], [3, -0.5, 0.8], [4, 0, 0.1]])

SPINES = {
    "bspline5": lambda: fj.BSpline(CONTROL),
    "bspline3": lambda: fj.BSpline(CONTROL, degree=3),
    "polynomial": lambda: fj.InterpolatingPolynomial(POLYNOMIAL),
    "polyline": lambda: fj.Polyline(CONTROL),
    "line": lambda: fj.Line(3.0, origin=(1, 2, 3), tangent=(0, 0.6, 0.8)),
    "arc": lambda: fj.Arc(2.5, 5.0, origin=(1.0, -1.0, 0.5), tangent=(0, 1, 0), normal=(1, 0, 1)),
    "helix": lambda: fj.Helix(2.0, 1.5, 5.0),
}
# Inside (away from knots and polyline vertices) and past both ends (the continuations).
FRACTIONS = np.array([0.13, 0.37, 0.61, 0.83, -0.05, 1.05])
H = 1e-4  # finite-difference step in s (central: error ~ h² |k'''| ~ 1e-8)


def _taylor(f, s, order):
    """`[f(s), f'(s), …, f⁽ᵒʳᵈᵉʳ⁾(s)]` by nested forward mode (one trace for all orders)."""
    for _ in range(order):
        f = (lambda g: lambda s: jax.jvp(g, (s,), (jnp.ones_like(s),)))(f)
    out = f(s)
    terms = []
    for n in range(order + 1):  # the n-th derivative: n tangent parts, then primal parts
        term = out
        for m in range(order):
            term = term[1 if m >= order - n else 0]
        terms.append(term)
    return terms


@eqx.filter_jit
def _s_derivatives(spine, s, polyline):
    """Autodiff derivatives of `C` (or of `T`, on polylines) in `s`, forward to third order and
    forward over reverse to second, the closed forms at `s`, and central differences of `T`
    and `k`."""
    _, tangent, k = spine.jet(s)
    derivatives = dict(
        tangent=tangent, k=k, torsion=spine.torsion(s),
        fd_c2=(spine.tangent(s + H) - spine.tangent(s - H)) / (2 * H),
        fd_k=(spine.curvature_vector(s + H) - spine.curvature_vector(s - H)) / (2 * H),
    )  # fmt: skip
    if polyline:  # its C' is the edge direction, its T the blended vertex tangents
        _, derivatives["t1"], derivatives["t2"] = _taylor(spine.tangent, s, 2)
        derivatives["c2"] = jax.jacfwd(jax.jacfwd(spine))(s)
        return derivatives
    _, derivatives["c1"], derivatives["c2"], derivatives["c3"] = _taylor(spine, s, 3)
    derivatives["c2_rev"] = jax.jacfwd(jax.jacrev(spine))(s)
    return derivatives


# The quintic B-spline with `-m slow`: the cubic runs the same code (5 s a spine).
@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=pytest.mark.slow) if n == "bspline5" else n for n in sorted(SPINES)],
)
def test_derivatives_in_s(name):
    spine = SPINES[name]()
    length = float(spine.length)
    polyline = name == "polyline"
    derivatives = jax.vmap(_s_derivatives, in_axes=(None, 0, None))
    s = jnp.asarray(FRACTIONS * length)
    d = {key: np.asarray(v) for key, v in derivatives(spine, s, polyline).items()}
    k, tangent = d["k"], d["tangent"]
    if polyline:  # T' = k, T'' against differences of k; C'' = 0 on the edges
        np.testing.assert_allclose(d["t1"], k, atol=1e-9)
        np.testing.assert_allclose(d["t2"], d["fd_k"], atol=1e-6)
        np.testing.assert_allclose(d["c2"][:4], 0, atol=1e-12)
        return
    np.testing.assert_allclose(d["c1"], tangent, atol=1e-12)
    np.testing.assert_allclose(d["c2"], k, atol=1e-10)
    np.testing.assert_allclose(d["c2"], d["fd_c2"], atol=1e-7)
    np.testing.assert_allclose(d["c2_rev"], k, atol=1e-10)
    np.testing.assert_allclose(d["c3"], d["fd_k"], atol=1e-6)
    # Frenet closed forms: T·C‴ = −κ², and (T × k)·C‴ = κ² τ (τ = 0 on the continuations).
    kk = np.sum(k**2, axis=-1)
    np.testing.assert_allclose(np.sum(tangent * d["c3"], axis=-1), -kk, atol=1e-10)
    binormal_part = np.sum(np.cross(tangent, k) * d["c3"], axis=-1)
    np.testing.assert_allclose(binormal_part, kk * d["torsion"], atol=1e-9)
    assert np.all(kk[:4] > 1e-3) or name == "line"  # the checks above are not vacuous


# A source with torsion (on a circle, `∂²f/∂s² = 0` at the foot would hide a first-order-only
# projection rule) and a free-form target built from its control points in the traced function.
SOURCE = fj.Helix(2.0, 3.0, 5.0)
TARGET = np.array([[0, 0, 0], [1.5, 0.8, 0.0], [3, 1.6, 0.8], [4, 2.8, 1.2], [4.2, 4.0, 1.5]])


def _points():
    rng = np.random.default_rng(3)
    s = np.array([0.2, 0.5, 0.8]) * float(SOURCE.length)
    offsets = rng.uniform(-0.25, 0.25, (3, 3))
    return np.asarray(jax.vmap(SOURCE)(jnp.asarray(s))) + offsets


@jax.jit
def _fleshed(points, control_points, twist):
    target = fj.BSpline(control_points, degree=3)
    return fj.flesh(points, SOURCE, target, method="radial", twist=twist, check_projection=False)


def _images(points, control_points, twist):
    return _fleshed(points, control_points, twist)[0]


def test_polish_root_to_third_order():
    """`polish_root`'s implicit-function rule (the projection's and the arc-length inverse's)
    composes: the real root of `s³ + p s − q` (one root for `p > 0`) in `(p, q)`, forward and
    reverse, to third order against finite differences."""

    def residual(s, params):
        p, q = params
        return s**3 + p * s - q, 3 * s**2 + p

    def root(p, q):
        s = jax.lax.fori_loop(0, 30, lambda _, s: s - jnp.divide(*residual(s, (p, q))), q / p)
        return polish_root(residual, jax.lax.stop_gradient(s), (p, q))

    args = (jnp.asarray(1.3), jnp.asarray(0.7))
    s = root(*args)
    np.testing.assert_allclose(s**3 + 1.3 * s, 0.7, atol=1e-14)
    check_grads(jax.jit(root), args, order=3, modes=("fwd", "rev"), eps=1e-3)


def test_projection_and_arc_length_to_second_order():
    """The closest projection on a source with torsion in the point (on a circle the second
    derivative at the foot vanishes and would hide a first-order-only rule), and a free-form
    spine's arc-length inverse in its control points: second order, reverse over reverse."""
    x = jnp.asarray(_points()[1])
    foot = jax.jit(lambda x: fj.closest_arc_length(SOURCE, x)[0])
    check_grads(foot, (x,), order=2, modes=("rev",), eps=1e-4, atol=1e-6, rtol=1e-6)
    s = jnp.asarray(2.1)

    def point(control_points, s):
        return fj.BSpline(control_points, degree=3)(s)

    check_grads(jax.jit(point), (jnp.asarray(TARGET), s), order=2, modes=("rev",), eps=1e-4,
                atol=1e-6, rtol=1e-6)


@pytest.mark.slow  # (the custom rules stay checked to second order above, in smaller programs)
def test_check_grads_of_flesh_to_second_order():
    """`check_grads` order 2 (reverse over reverse, the mode of Newton-type solvers and
    `jax.hessian`'s inner pass) with respect to points, the target's control points and the
    twist at once: the projection on the source, the target's arc-length inverse and
    frames, the radial cubic."""
    points = jnp.asarray(_points())
    assert np.all(_fleshed(points, jnp.asarray(TARGET), 0.3)[1])
    args = (points, jnp.asarray(TARGET), jnp.asarray(0.3))
    check_grads(_images, args, order=2, modes=("rev",), eps=1e-4, atol=1e-6, rtol=1e-6)


@pytest.mark.slow  # (`python -m pytest -m slow`; second order stays checked above)
def test_hessian_of_a_fitting_loss():
    """`jax.hessian` (forward over reverse) of a least-squares fitting loss in the target's
    control points against central differences of its gradient."""
    points = jnp.asarray(_points())
    wanted = _images(points, jnp.asarray(TARGET) * 1.05, 0.3)

    def loss(control_points):
        return jnp.sum((_images(points, control_points, 0.3) - wanted) ** 2)

    theta = jnp.asarray(TARGET)
    hessian = np.asarray(jax.hessian(loss)(theta)).reshape(theta.size, theta.size)
    gradient = jax.grad(loss)
    fd = [
        np.asarray(gradient(theta + H * e) - gradient(theta - H * e)) / (2 * H)
        for e in np.eye(theta.size).reshape(-1, *theta.shape)
    ]
    fd = np.stack(fd).reshape(theta.size, theta.size)
    scale = np.max(np.abs(hessian))
    assert scale > 1e-2
    np.testing.assert_allclose(hessian, hessian.T, atol=1e-9 * scale)
    np.testing.assert_allclose(hessian, fd, atol=1e-6 * scale)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_cubic_root_to_third_order(dtype):
    """The radial cubic's custom rule composes: μ', μ'', μ‴ from implicit differentiation of
    `μ³ − μ = α` (`μ' = 1/(3μ² − 1)`, `μ'' = −6μ μ'³`, `μ‴ = −6μ'⁴ + 108 μ² μ'⁵`), on both
    branches (float32: the Halley path)."""
    alpha = jnp.asarray([-0.3, -0.1, 0.0, 0.2, 0.38, 0.5, 3.0], dtype)

    @jax.jit
    def derivatives(alpha):
        first = jax.grad(cubic_root)
        second = jax.grad(first)
        third = jax.jacfwd(second)
        return [jax.vmap(f)(alpha) for f in (cubic_root, first, second, third)]

    mu, first, second, third = (np.asarray(v, np.float64) for v in derivatives(alpha))
    d1 = 1 / (3 * mu**2 - 1)
    tol = 1e-12 if dtype == jnp.float64 else 2e-4
    np.testing.assert_allclose(first, d1, rtol=tol)
    np.testing.assert_allclose(second, -6 * mu * d1**3, rtol=tol)
    np.testing.assert_allclose(third, -6 * d1**4 + 108 * mu**2 * d1**5, rtol=tol)

"""Free-form spines: B-spline and interpolating polynomial (exact arc length, errors, gradients)."""

import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._numerics import dot, safe_sqrt
from fleshing_jax._spines import arclength
from fleshing_jax._spines.bspline import _de_boor

CONTROL = np.array(
    [[0, 0, 0], [1, 0.4, 0.1], [2, 1.2, 0.6], [3, 0.5, 1.4], [4, -0.6, 1.2], [5, 0, 0.4],
     [6.5, 0.8, 0.0], [7.5, 1.0, 0.8]]
)  # fmt: skip
KNOTS = np.array([0, 0, 0, 0, 0, 0, 0.2, 0.55, 1, 1, 1, 1, 1, 1.0]) * 3.0  # non-uniform


def _reference(points, knots, degree, panels=3000):
    """Dense Gauss–Legendre arc length of the B-spline, from its derivative B-spline (NumPy).

    Returns `(length, inverse)` where `inverse(s)` is the parameter of arc length `s`.
    """
    q = (
        degree
        * np.diff(points, axis=0)
        / (knots[degree + 1 : -1] - knots[1 : -degree - 1])[:, None]
    )
    x, w = np.polynomial.legendre.leggauss(16)
    edges = np.linspace(knots[degree], knots[-degree - 1], panels + 1)
    a, b = edges[:-1, None], edges[1:, None]
    t = (a + (b - a) * (x + 1) / 2).ravel()
    speed = np.linalg.norm(_de_boor(q, knots[1:-1], degree - 1, t), axis=-1).reshape(panels, -1)
    pieces = (b - a)[:, 0] * (speed @ (w / 2))
    cumulative = np.concatenate([[0.0], np.cumsum(pieces)])

    def inverse(s):
        lo, hi = knots[degree], knots[-degree - 1]
        for _ in range(60):  # bisection on the reference length (slow but independent)
            mid = (lo + hi) / 2
            k = np.searchsorted(edges, mid, side="right") - 1
            k = min(k, panels - 1)
            tt = edges[k] + (mid - edges[k]) * (x + 1) / 2
            sp = np.linalg.norm(_de_boor(q, knots[1:-1], degree - 1, tt), axis=-1)
            value = cumulative[k] + (mid - edges[k]) * (sp @ (w / 2))
            lo, hi = (mid, hi) if value < s else (lo, mid)
        return (lo + hi) / 2

    return cumulative[-1], inverse


@pytest.fixture(scope="module")
def spline():
    return fj.BSpline(CONTROL, knots=KNOTS)


@pytest.fixture(scope="module")
def jet_fn():
    return jax.jit(jax.vmap(lambda spine, s: spine.jet(s), in_axes=(None, 0)))


def test_collinear_is_a_straight_line(jet_fn):
    spine = fj.BSpline([[0, 0, 0], [1, 1, 1], [3, 3, 3], [3.5, 3.5, 3.5], [5, 5, 5], [6, 6, 6]])
    length = 6 * np.sqrt(3)
    assert abs(float(spine.length) - length) < 1e-12 * length
    s = jnp.linspace(0, length, 9)
    c, t, k = jet_fn(spine, s)
    direction = np.ones(3) / np.sqrt(3)
    np.testing.assert_allclose(c, np.asarray(s)[:, None] * direction, atol=1e-12)
    np.testing.assert_allclose(t, np.broadcast_to(direction, (9, 3)), atol=1e-12)
    np.testing.assert_allclose(k, 0, atol=1e-12)


def test_length_and_arc_length_parameterisation(spline, jet_fn):
    length, inverse = _reference(CONTROL, KNOTS, 5)
    assert abs(float(spline.length) - length) < 1e-12 * length
    s = np.linspace(0, length, 7)
    c, _, _ = jet_fn(spline, jnp.asarray(s))
    expected = _de_boor(CONTROL, KNOTS, 5, np.array([inverse(v) for v in s]))
    np.testing.assert_allclose(c, expected, atol=1e-10)


def test_speed_curvature_and_torsion(spline, jet_fn):
    s = jnp.linspace(0, spline.length, 41)
    c, t, k = jet_fn(spline, s)
    derivatives = jax.jit(jax.vmap(jax.jacfwd(lambda s: spline.jet(s)[:2])))(s)
    speed = np.linalg.norm(derivatives[0], axis=-1)
    assert np.max(np.abs(speed - 1)) < 1e-10
    np.testing.assert_allclose(derivatives[1], k, atol=1e-10)  # k = dT/ds
    assert np.max(np.abs(np.sum(np.asarray(t) * np.asarray(k), axis=-1))) < 1e-12

    # Torsion against the Frenet formula τ = (C' × C'')·C''' / |C' × C''|² in arc length.
    @jax.jit
    def torsions(s0):
        d3 = jax.jacfwd(lambda s: spline.curvature_vector(s))(s0)
        _, t0, k0 = spline.jet(s0)
        return spline.torsion(s0), jnp.dot(jnp.cross(t0, k0), d3) / jnp.dot(k0, k0)

    torsion, expected = torsions(spline.length / 3)
    assert abs(float(torsion) - float(expected)) < 1e-8


def test_interpolating_polynomial(jet_fn):
    points = np.array([[0, 0, 0], [1, 1, 0.2], [2, 0.5, 1], [3, -0.5, 0.8], [4, 0, 0.1]])
    spine = fj.InterpolatingPolynomial(points)
    # Reference: the same polynomial by NumPy (exact interpolation, degree N − 1).
    nodes = np.arange(5.0)
    coefficients = [np.polyfit(nodes, points[:, i], 4) for i in range(3)]
    x, w = np.polynomial.legendre.leggauss(20)
    edges = np.linspace(0, 4, 401)
    a, b = edges[:-1, None], edges[1:, None]
    t = a + (b - a) * (x + 1) / 2
    speed = np.sqrt(sum(np.polyval(np.polyder(c), t) ** 2 for c in coefficients))
    length = np.sum((b - a)[:, 0] * (speed @ (w / 2)))
    assert abs(float(spine.length) - length) < 1e-12 * length
    # It passes through every point: each projects on it at distance 0.
    s, ok = jax.jit(jax.vmap(lambda x: fj.closest_arc_length(spine, x)))(jnp.asarray(points))
    assert np.all(ok)
    c, _, _ = jet_fn(spine, s)
    np.testing.assert_allclose(c, points, atol=1e-10)
    speed = jax.jit(jax.vmap(jax.jacfwd(spine)))(jnp.linspace(0, spine.length, 9))
    assert np.max(np.abs(np.linalg.norm(speed, axis=-1) - 1)) < 1e-10
    line = fj.InterpolatingPolynomial([[0, 0, 0], [1, 2, 2], [2, 4, 4]])
    assert abs(float(line.length) - 6) < 1e-12


def test_gradient_wrt_control_points():
    def loss(points):
        spine = fj.BSpline(points, knots=KNOTS)
        (c, t, k), (i, _) = spine.jet_and_normals(spine.length * 0.4)
        return spine.length + jnp.dot(c, c) + jnp.sum(k * t) + jnp.sum(k**2) + jnp.sum(i)

    # The loss and its gradient in one compiled program, also for the differences (the
    # gradient of the jitted loss, run eagerly, compiled its pieces apart: 9 programs).
    loss_and_grad = jax.jit(jax.value_and_grad(loss))
    points = jnp.asarray(CONTROL)
    gradient = np.asarray(loss_and_grad(points)[1])
    assert np.all(np.isfinite(gradient))
    rng = np.random.default_rng(0)
    for _ in range(3):
        direction = rng.normal(size=CONTROL.shape)
        h = 1e-5
        plus, minus = (loss_and_grad(points + sign * h * direction)[0] for sign in (1, -1))
        fd = (plus - minus) / (2 * h)
        assert abs(float(fd) - np.sum(gradient * direction)) < 1e-6 * (1 + abs(float(fd)))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(control_points=CONTROL[:4]), "at least degree + 1 = 6 rows, got 4"),
        (dict(control_points=np.where(np.arange(8)[:, None] == 2, np.nan, CONTROL)), "finite"),
        (dict(control_points=np.insert(CONTROL, 3, CONTROL[3], axis=0)), "rows 3 and 4"),
        (dict(control_points=CONTROL, knots=KNOTS[::-1]), "non-decreasing"),
        (dict(control_points=CONTROL, knots=KNOTS[:-1]), "`knots` must have shape"),
        (dict(control_points=CONTROL, degree=0), "`degree`"),
        (dict(control_points=CONTROL[:, :2]), "shape (N, 3)"),
        (dict(control_points=[[0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 0, 0]], degree=2), "cusp"),
    ],
)
def test_bad_input(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        fj.BSpline(**kwargs)


def test_bad_input_polynomial_and_traced():
    with pytest.raises(ValueError, match="at least 2"):
        fj.InterpolatingPolynomial([[0, 0, 0]])
    with pytest.raises(ValueError, match="rows 1 and 2"):
        fj.InterpolatingPolynomial([[0, 0, 0], [1, 0, 0], [1, 0, 0]])
    bad = CONTROL.copy()
    bad[1, 1] = np.nan
    with pytest.raises(Exception, match="must be finite"):
        jax.block_until_ready(jax.jit(lambda p: fj.BSpline(p).length)(bad))
    # Traced control points work (static sizes fall back to shape-derived defaults).
    traced = jax.jit(lambda p: fj.BSpline(p).length)(jnp.asarray(CONTROL))
    assert abs(float(traced) - float(fj.BSpline(CONTROL).length)) < 1e-12
    assert isinstance(eqx.filter_jit(lambda s: s)(fj.BSpline(CONTROL)), fj.BSpline)


def test_float32():
    spine = fj.BSpline(CONTROL.astype(np.float32))
    assert spine.length.dtype == jnp.float32
    s = jnp.linspace(0, spine.length, 5)
    c, t, k = jax.jit(jax.vmap(spine.jet))(s)
    assert c.dtype == jnp.float32 and np.all(np.isfinite(c))
    reference = fj.BSpline(CONTROL)
    assert abs(float(spine.length) - float(reference.length)) < 1e-5 * float(reference.length)
    speed = jax.jit(jax.vmap(jax.jacfwd(spine)))(s)
    assert np.max(np.abs(np.linalg.norm(speed, axis=-1) - 1)) < 1e-5


def test_extension_reaches_as_each_end_alone():
    # Both ends are evaluated in one batched call (one arc-length inverse compiled, not two):
    # each end's reach is what its own evaluation gives, bit for bit.
    @eqx.filter_jit
    def reaches(spine):
        prepared = spine._prepare()
        alone = []
        for s in (jnp.zeros_like(prepared.length), prepared.length):
            k = prepared._jet(s)[2]
            kappa = safe_sqrt(dot(k, k))
            alone.append(jnp.minimum(prepared.length, 0.5 * jnp.pi / jnp.maximum(kappa, 1e-30)))
        return prepared.extension(), alone

    both, alone = reaches(fj.BSpline(CONTROL.astype(np.float32)))
    assert both[0].dtype == jnp.float32 and float(both[0]) != float(both[1])
    np.testing.assert_array_equal(np.array(both), np.array(alone))


def test_arc_length_inverse_runs_newton_until_converged():
    # Control points spaced geometrically: the speed changes by much of itself within a
    # sub-interval, where two Newton steps and the polish leave s(u(s)) off by 4e-8 of the
    # length; the inverse stops on the step's size, not after a fixed count.
    points = [[0, 0, 0], [5e-4, 2e-4, 0], [4e-3, 2e-3, 0], [0.03, 0.02, 0], [0.3, 0.1, 0],
              [3, 1, 0.5]]  # fmt: skip
    tables = fj.BSpline(np.array(points), degree=5, subdivisions=8)._prepare().tables
    length = tables.cumulative[tables.end]

    def residual(s):
        i, u, j = arclength.inverse(tables.coefficients, tables.cumulative, tables.parts, s,
                                    tables.end)  # fmt: skip
        start = -1 + 2 * (j % tables.parts).astype(s.dtype) / tables.parts
        return tables.cumulative[j] + arclength._partial(tables.coefficients[i], start, u) - s

    s = jnp.linspace(0, length, 2001)
    assert float(jnp.max(jnp.abs(jax.jit(jax.vmap(residual))(s)))) < 1e-14 * float(length)

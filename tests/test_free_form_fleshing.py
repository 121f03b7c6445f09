"""Free-form spines in the core: det J on B-spline pairs, inflections, projection, polylines."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._fleshing.pipeline import pose_point
from fleshing_jax._fleshing.projection import register_point

TORSION = np.array([[0, 0, 0], [1, 0.2, 0.1], [2, 0.5, 0.4], [3, 0.3, 0.9], [4, -0.2, 1.0],
                    [5, 0, 0.8], [6, 0.3, 0.5]])  # fmt: skip
# Point-symmetric about its middle control point: an inflection (κ = 0) at s = L/2.
INFLECTION = np.array([[0, 0, 0], [1, 0.8, 0.1], [2, 1.0, 0.3], [3, 0, 0.5], [4, -1.0, 0.7],
                       [5, -0.8, 0.9], [6, 0, 1.0]])  # fmt: skip


def _points_around(spine, count, seed, radius=(0.05, 0.3)):
    rng = np.random.default_rng(seed)
    s = jnp.asarray(rng.uniform(0.3, float(spine.length) - 0.3, count))
    (c, _, _), (i, j) = _jets_and_normals(spine, s)
    angle = rng.uniform(0, 2 * np.pi, (count, 1))
    r = rng.uniform(*radius, (count, 1))
    return np.asarray(c + r * (np.cos(angle) * i + np.sin(angle) * j))


@eqx.filter_jit  # (the spine an argument: one program for spines alike, as the B-splines here)
def _jets_and_normals(spine, s):
    return jax.vmap(spine.jet_and_normals)(s)


@pytest.mark.parametrize(
    "kind,methods",
    [("bspline", ("binormal",)), ("polynomial", ("radial",)),
     pytest.param("bspline", ("radial", "normal"), marks=pytest.mark.slow)],
)
def test_det_j_on_free_form_pairs(kind, methods):
    # A spine with torsion (a quintic B-spline, or the cubic through 4 of its points) → one
    # with an inflection.
    if kind == "bspline":
        source = fj.BSpline(TORSION)
    else:
        source = fj.InterpolatingPolynomial(TORSION[::2])
    target = fj.BSpline(INFLECTION)
    mid = float(target.length) / 2
    assert float(jnp.linalg.norm(target.curvature_vector(mid))) < 1e-10  # the inflection
    points = _points_around(source, 8, 0)

    # The polynomial's own code is the projection, which one method exercises; the B-spline
    # source's other methods run with `-m slow` (each method is a compiled program: 10 s).
    @jax.jit
    def determinants(points):
        out = []
        for method in methods:
            fleshing = fj.Fleshing(source, target, method=method, twist=0.7, check_projection=False)

            def one(x, fleshing=fleshing):
                jacobian, valid = jax.jacfwd(fleshing.apply, has_aux=True)(x)
                return jnp.linalg.det(jacobian), valid

            out.append(jax.vmap(one)(points))
        return out

    for det, valid in determinants(points):
        assert np.sum(valid) >= 6
        assert np.max(np.abs(np.asarray(det)[np.asarray(valid)] - 1)) < 1e-8


def test_inflection_values_and_gradients_are_finite():
    source = fj.Helix(1.0, 2.0, 7.0)
    target = fj.BSpline(INFLECTION)
    # Points whose projection is the inflection of the *source*: flesh from the S-curve.
    mid = target.length / 2
    (c, _, _), (i, j) = target.jet_and_normals(mid)
    points = jnp.stack([c + 0.2 * i, c - 0.1 * j, c + 0.05 * (i + j)])
    twist = jnp.asarray(0.3)

    def loss(control_points, points):
        # Each map's `Fleshing(spine, source, method=m, twist=0.3, check_projection=False)`
        # (its `apply_point`: register on the source, pose on the target), the registration on
        # the traced B-spline shared by the three maps (in a `Fleshing` each, it was traced and
        # differentiated three times).
        spine = fj.BSpline(control_points)

        def images(x):
            registration = register_point(spine, x)
            return [pose_point(registration, source, method, twist, False)[0]
                    for method in ("radial", "normal", "binormal")]

        return sum(jnp.sum(image**2) for image in jax.vmap(images)(points))

    # (The value and gradient jitted as one program: `value_and_grad` of a jitted `loss`
    # compiled its linearisation and its transpose as two.)
    value, (g_control, g_points) = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))(
        jnp.asarray(INFLECTION), points
    )
    assert np.isfinite(float(value))
    assert np.all(np.isfinite(g_control)) and np.all(np.isfinite(g_points))
    assert float(jnp.max(jnp.abs(g_control))) > 0


def _brute_force(spine, points, count=20001):
    s = jnp.linspace(0, spine.length, count)
    c = jax.jit(jax.vmap(spine))(s)
    d = jnp.sum((points[:, None] - c[None]) ** 2, axis=-1)
    return np.asarray(s[jnp.argmin(d, axis=1)]), np.sqrt(np.asarray(jnp.min(d, axis=1)))


@pytest.mark.parametrize("shape", ["u_turn", pytest.param("coil", marks=pytest.mark.slow)])
def test_projection_is_global(shape):
    if shape == "u_turn":  # two parallel branches 1 apart, joined by a tight turn
        spine = fj.BSpline([[0, 0, 0], [4, 0, 0], [5, 0, 0], [5.5, 0.5, 0], [5, 1, 0],
                            [4, 1, 0], [0, 1, 0]], degree=3)  # fmt: skip
    else:  # a coil: 3 turns of radius 1 with pitch 0.6, as a B-spline
        angle = np.linspace(0, 6 * np.pi, 40)
        spine = fj.BSpline(np.stack([np.cos(angle), np.sin(angle), 0.1 * angle], -1), degree=5)
    rng = np.random.default_rng(1)
    lo, hi = np.min(spine.control_points, 0) - 0.3, np.max(spine.control_points, 0) + 0.3
    # The last two points (U-turn): equidistant from both branches, and slightly closer to one.
    extra = jnp.array([[2.0, 0.5, 0.3], [2.0, 0.52, 0.3]])
    points = jnp.concatenate([jnp.asarray(rng.uniform(lo, hi, (60, 3))), extra])
    s, ok = jax.jit(jax.vmap(lambda x: fj.closest_arc_length(spine, x)))(points)
    s_ref, d_ref = _brute_force(spine, points)
    inside = (s_ref > 1e-3) & (s_ref < float(spine.length) - 1e-3)
    distance = np.linalg.norm(np.asarray(points - jax.jit(jax.vmap(spine))(s)), axis=-1)
    ok = np.asarray(ok)
    # Every converged projection is the global one (never a farther local minimum).
    assert np.all(distance[ok] <= d_ref[ok] + 1e-6)
    assert np.mean(ok[inside]) > 0.8
    if shape == "u_turn":  # equidistant from both branches: no unique projection, flagged
        assert not ok[-2]
        assert ok[-1] and float(s[-1]) > float(spine.length) / 2


@pytest.mark.slow  # two jacobian_determinant programs (two polyline buckets): 40 s
def test_polyline_converges_to_second_order():
    # A polyline sampled from an arc, fleshed to another: volume error shrinks with the step.
    arc0, arc1 = fj.Arc(3.0, 4.0), fj.Arc(2.0, 4.0, normal=(0, 0, 1))
    points = _points_around(arc0, 6, 2, radius=(0.1, 0.3))
    errors = []
    for edges in (8, 32):
        t = np.linspace(0, 4.0, edges + 1)
        line0 = fj.Polyline(jax.vmap(arc0)(jnp.asarray(t)))
        line1 = fj.Polyline(jax.vmap(arc1)(jnp.asarray(t)))
        fleshing = fj.Fleshing(line0, line1, method="radial", check_projection=False)
        det = fj.jacobian_determinant(fleshing, points)
        assert np.all(np.isfinite(det))
        errors.append(float(jnp.max(jnp.abs(det - 1))))
    assert errors[1] < errors[0] / 4  # second order in the step
    assert errors[0] > 1e-6  # not exact: the polyline is an approximation


def test_polyline_works_in_the_core():
    arc0, arc1 = fj.Arc(3.0, 4.0), fj.Arc(2.0, 4.0, normal=(0, 0, 1))
    points = _points_around(arc0, 6, 2, radius=(0.1, 0.3))
    t = jnp.linspace(0, 4.0, 17)
    line0, line1 = fj.Polyline(jax.vmap(arc0)(t)), fj.Polyline(jax.vmap(arc1)(t))
    out, valid = fj.flesh(points, line0, line1, method="normal", twist=0.2)
    assert np.all(valid) and np.all(np.isfinite(out))
    # Near the arc's image: the polyline's error is second order in its step (0.25).
    exact, _ = fj.flesh(points, arc0, arc1, method="normal", twist=0.2)
    assert 1e-6 < float(jnp.max(jnp.abs(out - exact))) < 0.05
    with pytest.raises(ValueError, match="turn back"):
        fj.Polyline([[0, 0, 0], [1, 0, 0], [0, 0, 0.0]])
    with pytest.raises(ValueError, match="`step`"):
        fj.Polyline([[0, 0, 0], [1, 0, 0]], step=-1.0)
    resampled = fj.Polyline([[0, 0, 0], [1, 0, 0], [1, 3, 0]], step=0.5)
    assert resampled.vertices().shape == (9, 3)
    assert abs(float(resampled.length) - 4.0) < 0.3


def test_register_pose_float32():
    source = fj.BSpline(TORSION.astype(np.float32))
    # (Eight points drawn: those of the det J test's program.)
    points = _points_around(fj.BSpline(TORSION), 8, 3)[:5].astype(np.float32)
    registration = fj.register(points, source)
    # Posing on the source itself is the identity.
    out, valid = fj.pose(registration, source, method="radial")
    assert out.dtype == jnp.float32 and np.all(np.isfinite(out))
    assert np.sum(valid) >= 4
    assert np.max(np.abs(np.asarray(out - points))) < 1e-4

"""Analytic spines: arc-length parameterisation, derivatives, frames, continuation."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fleshing_jax as fj

SPINES = {
    "line": fj.Line(2.0, origin=(1.0, 2.0, 3.0), tangent=(1.0, 1.0, 0.0)),
    "arc": fj.Arc(1.5, 4.0, origin=(0.0, 1.0, 0.0), tangent=(0, 0, 1), normal=(1, 1, 0)),
    "helix": fj.Helix(1.2, 2.0, 9.0),
    "left-helix": fj.Helix(0.8, -3.0, 5.0),
}


@pytest.fixture(params=sorted(SPINES))
def spine(request):
    return SPINES[request.param]


def _samples(spine, n=9, overshoot=0.3):
    length = float(spine.length)
    return jnp.linspace(-overshoot * length, (1 + overshoot) * length, n)


# The samples' derivatives and frames, each one compiled program for a spine type (the spine
# an argument: both helices share it): evaluated eagerly, sample by sample, the two tests were
# about 300 one-operation programs.
@eqx.filter_jit
def _derivatives(spine, s):
    def one(s):
        return (jax.jacfwd(spine)(s), jax.jacfwd(jax.jacfwd(spine))(s), spine.tangent(s),
                spine.curvature_vector(s))  # fmt: skip

    return jax.vmap(one)(s)


@eqx.filter_jit
def _frames(spine, s):
    def normal(s):
        return fj.rotation_minimizing_frame(spine, s, twist=0.4)[1]

    return jax.vmap(lambda s: (fj.rotation_minimizing_frame(spine, s, twist=0.4),
                               jax.jacfwd(normal)(s), spine.tangent(s)))(s)  # fmt: skip


def test_unit_speed_and_curvature_vector(spine):
    # Derivatives by autodiff of the position, including on the continuations past the ends.
    for tangent, k, closed_tangent, closed_k in zip(*_derivatives(spine, _samples(spine))):
        np.testing.assert_allclose(np.linalg.norm(tangent), 1.0, atol=1e-12)
        np.testing.assert_allclose(closed_tangent, tangent, atol=1e-12)
        np.testing.assert_allclose(closed_k, k, atol=1e-10)
        assert abs(np.dot(closed_k, closed_tangent)) < 1e-12


def test_closed_forms():
    arc = fj.Arc(2.0, 3.0)
    np.testing.assert_allclose(np.linalg.norm(arc.curvature_vector(1.0)), 0.5, rtol=1e-14)
    np.testing.assert_allclose(arc(np.pi), [2.0, 2.0, 0.0], atol=1e-14)  # quarter turn
    helix = fj.Helix(2.0, 3.0, 10.0)
    h = 3.0 / (2 * np.pi)
    c2 = 4.0 + h**2
    np.testing.assert_allclose(np.linalg.norm(helix.curvature_vector(2.0)), 2.0 / c2, rtol=1e-14)
    np.testing.assert_allclose(helix.torsion(2.0), h / c2, rtol=1e-14)
    u = 1.0 / np.sqrt(c2)
    np.testing.assert_allclose(helix(1.0), [2 * np.cos(u), 2 * np.sin(u), h * u], rtol=1e-14)
    assert float(fj.Line(3.0).torsion(1.0)) == 0.0


def test_torsion_matches_frenet_derivative():
    helix = SPINES["left-helix"]
    s = 1.3

    @jax.jit  # (one program: eagerly, about 100 one-operation ones)
    def frame_and_binormal_rate(s):
        return fj.frenet_frame(helix, s), jax.jacfwd(lambda s: fj.frenet_frame(helix, s)[0][2])(s)

    ((t, n, b), defined), db = frame_and_binormal_rate(s)
    assert bool(defined)
    np.testing.assert_allclose(db, -helix.torsion(s) * n, atol=1e-12)  # B' = −τN


def test_rotation_minimizing_frame(spine):
    for frame, di, tangent in zip(*_frames(spine, _samples(spine))):
        frame = np.asarray(frame)
        np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-13)
        np.testing.assert_allclose(np.linalg.det(frame), 1.0, atol=1e-13)
        np.testing.assert_allclose(frame[0], tangent, atol=1e-14)
        # Rotation minimising: I' has no component along J (no spin about the tangent).
        assert abs(np.dot(di, frame[2])) < 1e-11


def test_initial_frame_rule_and_twist():
    # The same start tangent gives the same start frame, whatever the rest of the spine.
    a = fj.rotation_minimizing_frame(fj.Line(1.0, tangent=(0, 0, 1)), 0.0)
    b = fj.rotation_minimizing_frame(fj.Arc(1.0, 2.0, tangent=(0, 0, 1), normal=(1, 2, 0)), 0.0)
    np.testing.assert_allclose(a, b, atol=1e-15)
    twisted = fj.rotation_minimizing_frame(fj.Line(1.0, tangent=(0, 0, 1)), 0.0, twist=0.3)
    # Right-hand rule about T: I → cos w I + sin w J.
    np.testing.assert_allclose(twisted[1], np.cos(0.3) * a[1] + np.sin(0.3) * a[2], atol=1e-15)


def test_frenet_undefined_on_line_without_nan():
    frame, defined = fj.frenet_frame(fj.Line(1.0), 0.5)
    assert not bool(defined)
    assert np.all(np.isfinite(frame))
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-15)


def test_continuation_is_c2_at_ends(spine):
    for end in (0.0, float(spine.length)):
        for f in (spine, spine.tangent, spine.curvature_vector):
            np.testing.assert_allclose(f(end - 1e-9), f(end + 1e-9), atol=1e-8)
    # Past the end, the continuation is the osculating circle: constant curvature magnitude.
    past = float(spine.length) + 0.5
    k_end = np.linalg.norm(spine.curvature_vector(spine.length))
    np.testing.assert_allclose(np.linalg.norm(spine.curvature_vector(past)), k_end, atol=1e-12)
    assert float(spine.torsion(past)) == 0.0


def test_arc_continues_as_itself():
    arc = fj.Arc(2.0, 1.0)
    # Continuation along the osculating circle of an arc is the same circle.
    np.testing.assert_allclose(arc(1.5), arc._jet(jnp.asarray(1.5))[0], atol=1e-14)
    np.testing.assert_allclose(arc(-0.5), arc._jet(jnp.asarray(-0.5))[0], atol=1e-14)


def test_spines_are_pytrees_under_jit_and_grad():
    @jax.jit
    def end_point(radius):
        return fj.Arc(radius, 3.0)(3.0)

    g = jax.jacfwd(end_point)(2.0)
    eps = 1e-6
    fd = (end_point(2.0 + eps) - end_point(2.0 - eps)) / (2 * eps)
    np.testing.assert_allclose(g, fd, atol=1e-8)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: fj.Line(-1.0), "length"),
        (lambda: fj.Line(1.0, tangent=(0, 0, 0)), "tangent"),
        (lambda: fj.Line(1.0, origin=(0, 0)), "origin"),
        (lambda: fj.Arc(0.0, 1.0), "radius"),
        (lambda: fj.Arc(1.0, 1.0, tangent=(1, 0, 0), normal=(2, 0, 0)), "normal"),
        (lambda: fj.Helix(1.0, np.nan, 1.0), "pitch"),
        (lambda: fj.Helix(1.0, 1.0, np.inf), "length"),
    ],
)
def test_bad_spine_arguments(make, match):
    with pytest.raises(ValueError, match=match):
        make()

"""Rotation-minimising frames: double reflection (4th order) against the helix closed form."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._spines.parametric import RMF_NODES_PER_RADIAN

HELIX = fj.Helix(1.0, 1.0, 12.0)


# The node density free-form spines use by default, on this helix (its curvature 1 / (1 + (1 /
# 2π)²) over 12 units of arc length).
DEFAULT_STEPS = int(np.ceil(RMF_NODES_PER_RADIAN * (1.0 / (1.0 + (1.0 / (2 * np.pi)) ** 2)) * 12.0))
# The propagations compared with the closed form, `(steps, method)`.
PROPAGATIONS = ((DEFAULT_STEPS, "double_reflection"), (64, "double_reflection"),
                (128, "double_reflection"), (128, "projection"), (256, "projection"),
                (None, "projection"))  # fmt: skip


def _helix_error(steps, method):
    return _helix_errors()[steps, method]


@functools.cache
def _helix_errors():
    """Each propagation's largest difference from the closed form at the helix's end:
    `{(steps, method): error}`, all from one compiled program (run eagerly, the propagations
    were about 300 one-operation programs; in a program each, 3.5 s of CPU against 2.4 s, the
    errors the same to the last bit)."""

    @jax.jit
    def differences():
        exact = fj.rotation_minimizing_frame(HELIX, 12.0)  # closed form
        frames = [fj.rotation_minimizing_frame(HELIX, 12.0, method=method, steps=steps)
                  for steps, method in PROPAGATIONS]  # fmt: skip
        return [jnp.max(jnp.abs(frame - exact)) for frame in frames]

    return dict(zip(PROPAGATIONS, map(float, differences()), strict=True))


def test_double_reflection_matches_helix_closed_form():
    # The general algorithm, with the node density free-form spines use by default.
    assert _helix_error(DEFAULT_STEPS, "double_reflection") < 1e-9
    # Fourth order for double reflection, first order for the paper's projection.
    ratio = _helix_error(64, "double_reflection") / _helix_error(128, "double_reflection")
    assert 12 < ratio < 20
    ratio = _helix_error(128, "projection") / _helix_error(256, "projection")
    assert 1.5 < ratio < 2.5


@pytest.mark.parametrize("kind", ["bspline", "polynomial", "polyline"])
def test_frames_orthonormal_and_tangent(kind):
    points = np.array([[0, 0, 0], [1, 0.5, 0.2], [2, 0.2, 1], [3, -0.6, 0.8], [4, 0, 0.1],
                       [5, 0.7, 0.4]])  # fmt: skip
    spine = {
        "bspline": lambda: fj.BSpline(points, degree=3),
        "polynomial": lambda: fj.InterpolatingPolynomial(points),
        "polyline": lambda: fj.Polyline(points, step=0.25),
    }[kind]()

    @jax.jit
    def frames(s):
        return jax.vmap(lambda s: (fj.rotation_minimizing_frame(spine, s, twist=0.3),
                                   spine.tangent(s)))(s)  # fmt: skip

    s = jnp.linspace(-0.5, spine.length + 0.5, 23)
    frame, tangent = frames(s)
    gram = jnp.einsum("nij,nkj->nik", frame, frame)
    assert float(jnp.max(jnp.abs(gram - jnp.eye(3)))) < 1e-12
    assert float(jnp.max(jnp.abs(frame[:, 0] - tangent))) < 1e-14
    assert float(jnp.max(jnp.abs(jnp.linalg.det(frame) - 1))) < 1e-12


def test_bspline_frame_is_rotation_minimising():
    # Along an RMF, dI/ds has no component along J (no rotation about the tangent).
    spine = fj.BSpline([[0, 0, 0], [1, 0.5, 0.2], [2, 0.2, 1], [3, -0.6, 0.8], [4, 0, 0.1],
                        [5, 0.7, 0.4], [6, 0, 0]])  # fmt: skip

    @jax.jit
    def twist_rate(s):
        def normals(s):
            return spine.jet_and_normals(s)[1]

        (i, j), (di, _) = jax.jvp(normals, (s,), (jnp.ones_like(s),))
        return jnp.dot(di, j)

    rates = jax.vmap(twist_rate)(jnp.linspace(0.01, spine.length - 0.01, 17))
    assert float(jnp.max(jnp.abs(rates))) < 1e-6


@pytest.mark.parametrize("kind", ["bspline", "polynomial"])
def test_free_form_default_frame_against_a_fine_propagation(kind):
    # The frame the fleshing uses on free-form spines (double reflection from nodes placed by
    # the turning), at the end of the spine, against a 4096-step fourth-order propagation
    # (error ~1e-14): the default settings' own error.
    points = [[0, 0, 0], [1, 0.5, 0.2], [2, 0.2, 1], [3, -0.6, 0.8], [4, 0, 0.1], [5, 0.7, 0.4]]
    spine = fj.BSpline(points) if kind == "bspline" else fj.InterpolatingPolynomial(points[:4])
    default, fine = _default_and_fine(spine)
    assert float(jnp.max(jnp.abs(default - fine))) < 1e-9


@eqx.filter_jit
def _default_and_fine(spine):
    """The default frame and the 4096-step propagation's at the spine's end, as one compiled
    program (eagerly, the propagation's jets ran, and compiled, operation by operation: 85
    programs for the B-spline)."""
    return (fj.rotation_minimizing_frame(spine, spine.length),
            fj.rotation_minimizing_frame(spine, spine.length, steps=4096))  # fmt: skip


def test_method_argument():
    with pytest.raises(ValueError, match="method"):
        fj.rotation_minimizing_frame(HELIX, 1.0, method="frenet")
    with pytest.raises(ValueError, match="steps"):
        fj.rotation_minimizing_frame(HELIX, 1.0, steps=0)
    # The default projection (1024 steps) is only first-order accurate.
    assert 1e-4 < _helix_error(None, "projection") < 1e-1

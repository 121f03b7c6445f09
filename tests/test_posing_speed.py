"""Posing frame after frame (issue 46 item 5): a new angle never compiles a program again, on
the eager path nor in a jitted frame. (The speed itself is measured in benchmarks/posing.py.)"""

import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fleshing_jax as fj


@pytest.fixture
def compiles(caplog):
    """A function that runs `f()` and returns the number of programs JAX traced or compiled for
    it (`jax.log_compiles`' records), with `f`'s result."""

    def count(f):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="jax"), jax.log_compiles():
            out = jax.block_until_ready(f())
        records = [r.getMessage() for r in caplog.records]
        return sum(m.startswith(("Compiling", "Finished tracing")) for m in records), out

    return count


def test_an_eager_pose_at_a_new_angle_compiles_nothing(skeleton, registration, compiles):
    # 90° leaves the tube's limb points that the reach bound does not certify, 60° none: the
    # two-phase eager pose compiled the sampled check at 90° (30 s on its own). Past about
    # 82°, limb 0's free child carries the bend on (`spill`), and past about 136° both are
    # inexact: the first call, at 150°, poses both (and may compile).
    def pose(angle):
        return fj.pose_skeleton(registration, skeleton, {0: fj.LimbPose(angle, 20.0, 5.0)})

    first = pose(150.0)
    assert int(np.sum(~np.asarray(first.valid))) > 0
    assert compiles(lambda: pose(150.0))[0] == 0
    for angle in (60.0, 90.0, 37.5, 120.0):
        count, posed = compiles(lambda angle=angle: pose(angle))
        assert count == 0, f"a pose at {angle}° compiled {count} programs"
        # A real new pose: the limb moved.
        assert not np.array_equal(np.asarray(posed.vertices), np.asarray(first.vertices))


def test_a_jitted_frame_is_traced_once_for_every_angle(skeleton, registration, compiles):
    frame = jax.jit(lambda poses: fj.pose_skeleton(registration, skeleton, poses).vertices)
    # Lowered only (compiling the frame takes a minute): a new program needs a new trace.
    first, _ = compiles(lambda: frame.lower({2: fj.LimbPose(60.0, 10.0, 5.0)}))
    assert first > 0
    # New values of every kind a user may give: a jnp scalar is weakly typed (it had its own
    # program), an int, a NumPy float.
    for bend in (90.0, jnp.asarray(30.0), 45, np.float64(10.0)):
        pose = fj.LimbPose(bend, jnp.asarray(170.0), 0)
        count, _ = compiles(lambda pose=pose: frame.lower({2: pose}))
        assert count == 0, f"a frame at {bend!r}° was traced again"


def test_a_frame_without_the_projection_check_places_the_same_vertices(skeleton, registration):
    """`check_projection=False` (a live preview's frame) skips only the global check: the
    vertices are placed bit for bit alike, every vertex the checked pose calls valid is still
    valid, and past the range (150° on the tube's limb) both flag every vertex past the
    joint (inexact: the sections' blend)."""
    for angle in (60.0, 150.0):
        poses = {0: fj.LimbPose(angle, 20.0, 5.0)}
        checked = fj.pose_skeleton(registration, skeleton, poses)
        quick = fj.pose_skeleton(registration, skeleton, poses, check_projection=False)
        assert np.array_equal(np.asarray(quick.vertices), np.asarray(checked.vertices))
        ok, fast = np.asarray(checked.valid), np.asarray(quick.valid)
        assert np.all(fast[ok])
    assert np.sum(~fast) == np.sum(~ok) > 0
    with pytest.raises(TypeError, match="check_projection"):
        fj.pose_skeleton(registration, skeleton, poses, check_projection="no")


def test_a_pose_of_python_numbers_is_kept_as_the_general_path_keeps_it():
    """Python numbers take `LimbPose`'s quick path (a frame's poses, built every frame): its
    angles must be what the general path makes of the same values as NumPy scalars (the same
    types, dtypes and values: the same compiled frame), and values it does not take (past a
    turn, not finite, bools) still refused by name."""
    for angles in ((60.0, 10.0, 5.0), (45, -170, 0), (-360.0, 359.5, 360)):
        quick = fj.LimbPose(*angles)
        general = fj.LimbPose(*(np.asarray(a) for a in angles))
        for name in ("bend", "direction", "twist"):
            a, b = getattr(quick, name), getattr(general, name)
            assert type(a) is type(b) and a.dtype == b.dtype and a == b, name
        assert quick.towards is None
        assert jax.tree.structure(quick) == jax.tree.structure(general)
    for bad, match in (((361.0,), "full turn"), ((0.0, 0.0, -400),
                                                  "full turn"), ((np.inf,), "finite"),
                       ((0.0, float("nan")), "finite"), ((True,), "an angle")):
        with pytest.raises((ValueError, TypeError), match=match):
            fj.LimbPose(*bad)
    # A direction past a turn takes the general path: kept as given.
    assert float(fj.LimbPose(10.0, 720.0).direction) == 720.0

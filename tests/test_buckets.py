"""Eager calls compile once per bucket of batch sizes (`_batching.buckets`), not once per size.

A long session that fleshes batches of many sizes used to compile new programs for each one
until XLA ran out of memory maps; the tests count the traces JAX reports while many sizes run.
"""

import collections

import jax
import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._batching.buckets import PAD_LIMIT, bucket, pad_batch, unpad_batch

TRACE_EVENT = "/jax/core/compile/jaxpr_trace_duration"


@pytest.fixture
def traces():
    """A counter of the functions JAX traces for `jit` while the test runs, by name."""
    counter = collections.Counter()
    active = [True]

    def listener(event, duration, **kwargs):
        if active[0] and event == TRACE_EVENT:
            counter[kwargs.get("fun_name")] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)
    yield counter
    active[0] = False  # JAX has no public way to remove a listener


def test_buckets_are_few_and_tight():
    sizes = np.arange(1, PAD_LIMIT + 1)
    buckets = np.array([bucket(int(n)) for n in sizes[::97]] + [bucket(PAD_LIMIT)])
    assert (buckets >= sizes[::97].tolist() + [PAD_LIMIT]).all()
    assert np.all(np.diff(buckets) >= 0)
    big = sizes[::97] >= 64
    assert (buckets[:-1][big] <= 1.5 * sizes[::97][big]).all()  # at most a third is padding
    assert len(set(buckets)) <= 2 * np.log2(PAD_LIMIT / 64) + 1  # two per doubling
    assert bucket(0) == 0 and bucket(PAD_LIMIT + 1) == PAD_LIMIT + 1


def test_pad_and_unpad_keep_the_points():
    points = np.arange(15.0).reshape(5, 3)
    padded = pad_batch({"p": points, "scalar": np.float64(2.0)}, 8)
    assert padded["p"].shape == (8, 3) and padded["scalar"] == 2.0
    np.testing.assert_array_equal(padded["p"][5:], np.broadcast_to(points[-1], (3, 3)))
    np.testing.assert_array_equal(unpad_batch(padded, 5)["p"], points)


def _points(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0.1, 1.9, n), rng.uniform(-0.3, 0.3, (n, 2))])


def _run_all(points, source, target):
    images, valid = fj.flesh(points, source, target)
    posed, posed_valid = fj.pose(fj.register(points, source), target)
    determinants = fj.jacobian_determinant(fj.Fleshing(source, target), points)
    return images, valid, posed, posed_valid, determinants


def test_many_sizes_reuse_the_programs_of_their_bucket(traces):
    source, target = fj.Line(2.0), fj.Arc(1.5, 2.0)
    points = _points(256)
    _run_all(points[:100], source, target)  # compiles the programs of the 97–128 bucket
    traces.clear()
    for n in range(97, 129, 4):
        outputs = _run_all(points[:n], source, target)
        assert all(len(o) == n for o in outputs)
    assert sum(traces.values()) == 0, f"sizes of one bucket traced again: {dict(traces)}"
    _run_all(points[:150], source, target)  # a new bucket: new programs (the counter works)
    assert traces["_register_certified"] == 1 and traces["_determinants"] == 1


def test_padding_does_not_change_the_results():
    source, target = fj.Line(2.0), fj.Arc(1.5, 2.0)
    points = _points(200, seed=1)

    def run(p):  # (det J's padding is that of the other calls: not compiled again here)
        return (*fj.flesh(p, source, target), *fj.pose(fj.register(p, source), target))

    small = run(points[:97])  # bucket 128
    large = run(points)  # bucket 256
    for a, b in zip(small, large):  # flags equal; floats to round-off (programs of other sizes
        a, b = np.asarray(a), np.asarray(b)[:97]  # vectorise differently)
        if a.dtype == bool:
            np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13)


def test_float32_and_traced_calls_keep_their_shapes():
    source, target = fj.Line(2.0), fj.Arc(1.5, 2.0)
    points = _points(70).astype(np.float32)
    images, valid = fj.flesh(points, source, target)
    assert images.shape == (70, 3) and images.dtype == np.float32 and valid.shape == (70,)
    jitted, _ = jax.jit(lambda p: fj.flesh(p, source, target))(points)  # traced: not padded
    np.testing.assert_allclose(jitted, images, atol=1e-5)

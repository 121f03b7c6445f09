"""Eager calls compile once per bucket of batch sizes (`_batching.buckets`), not once per size.

A long session that fleshes batches of many sizes used to compile new programs for each one
until XLA ran out of memory maps; the tests count the traces JAX reports while many sizes run.
"""

import collections

import equinox as eqx
import jax
import jax.numpy as jnp
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
    assert traces["_register_start"] == 1 and traces["_jacobians"] == 1


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


# Spines: their control-point counts and turning-dependent sizes are static, so every new
# spine used to compile new programs; `AbstractSpine._bucketed` pads them to a few sizes.


def _bspline(count, bend=0.3, **options):
    t = np.linspace(0.0, 1.0, count)
    points = np.column_stack([2 * t, bend * np.sin(np.pi * t), 0.1 * bend * t])
    return fj.BSpline(points, **options)


def _polyline(count, **options):
    t = np.linspace(0.0, 1.0, count)
    return fj.Polyline(np.column_stack([2 * t, 0.3 * np.sin(np.pi * t), 0.03 * t]), **options)


def _signature(spine):
    """What `eqx.filter_jit` compiles a spine argument for: its structure (static fields
    included), its leaves' shapes and dtypes, and its search samples (an argument of
    `register`'s program)."""
    leaves, treedef = jax.tree.flatten(spine)
    return treedef, tuple((a.shape, a.dtype) for a in leaves), spine.default_samples()


SPINES = {
    "bspline": lambda: _bspline(7),  # 8 control points padded, 3 pieces (1 padding)
    "bspline-cubic-knots": lambda: _bspline(
        9, degree=3, knots=[0, 0, 0, 0, 0.1, 0.3, 0.3, 0.6, 0.8, 1, 1, 1, 1]
    ),  # (a double knot: an empty span, left out of the pieces)
    "polyline": lambda: _polyline(10),
    "polyline-step": lambda: _polyline(10, step=0.05),  # 42 edges padded to 48
}


# The cubic B-spline with a double knot and the resampled polyline with `-m slow` (8-10 s each).
@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=pytest.mark.slow) if n in ("bspline-cubic-knots", "polyline-step")
     else n for n in SPINES],
)
def test_padded_spines_evaluate_and_differentiate_as_the_spines(name):
    spine = SPINES[name]()
    assert type(spine._bucketed()) is not type(spine)  # (the bucket's own type: shared)
    field = "control_points" if hasattr(spine, "control_points") else "points"
    s = np.linspace(-0.3, float(spine.length) + 0.3, 9)  # beyond both ends too

    def loss(parameters, pad):  # (torsion: a polyline's is round-off amplified, not compared)
        rebuilt = eqx.tree_at(lambda c: getattr(c, field), spine, parameters)
        rebuilt = rebuilt._bucketed() if pad else rebuilt
        values = rebuilt.length, jax.vmap(rebuilt.jet_and_normals)(s)
        (c, t, k), (i, _) = values[1]
        return rebuilt.length + jnp.sum(c[1:-1] * t[1:-1]) + jnp.sum(k[1:-1] * i[1:-1]), values

    parameters = getattr(spine, field)
    gradient = jax.jit(jax.grad(loss, has_aux=True), static_argnums=1)
    (exact, values), (padded, padded_values) = (gradient(parameters, p) for p in (False, True))
    for a, b in zip(jax.tree.leaves(values), jax.tree.leaves(padded_values)):
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-13)
    # Gradients reach the spine's own parameters, as without padding.
    assert np.all(np.isfinite(padded)) and np.any(padded != 0)
    np.testing.assert_allclose(padded, exact, rtol=0, atol=1e-11)


def test_padded_spines_keep_float32():
    for spine in (_bspline(7), _polyline(10)):
        padded = jax.tree.map(
            lambda a: a.astype(np.float32) if jnp.issubdtype(a.dtype, jnp.floating) else a,
            spine._bucketed(),
        )
        c, t, k = padded.jet(np.float32(0.5))
        assert c.dtype == t.dtype == k.dtype == padded.length.dtype == np.float32


def test_twenty_spines_share_a_few_programs(traces):
    # B-splines of 6 … 25 control points bent more and more; polylines of 10 … 200 points.
    families = {
        "bspline": [_bspline(6 + i, bend=0.2 + 0.02 * i) for i in range(20)],
        "polyline": [_polyline(10 * (i + 1)) for i in range(20)],
    }
    padded = {name: [s._bucketed() for s in spines] for name, spines in families.items()}
    assert sum(traces.values()) == 0, dict(traces)  # (built without compiling anything)
    families["arc"] = [fj.Arc(0.2 + 0.1 * i, 2.0) for i in range(20)]  # turning 10 … 1 rad
    padded["arc"] = [s._bucketed() for s in families["arc"]]
    for name, spines in families.items():
        signatures = {_signature(s) for s in padded[name]}
        if name != "arc":  # (an arc's size is fixed: only its samples vary)
            assert len({_signature(s) for s in spines}) == 20
        # At most two buckets per doubling of the count or the turning (20 before).
        assert len(signatures) <= {"bspline": 9, "polyline": 9, "arc": 4}[name], name


def test_spines_of_one_bucket_reuse_the_programs(traces, monkeypatch):
    points = _points(100)
    registration = fj.register(points, fj.Line(2.0))
    # 9 … 12 control points: one bucket (12). The turning-dependent sizes are those of the
    # bucket too (given for the counts, by default for the turnings: asserted).
    spines = [_bspline(n, subdivisions=16) for n in (9, 10, 11, 12)]
    spines += [_bspline(11), _bspline(12, bend=0.35)]
    assert {(s.subdivisions, s.samples) for s in spines} == {(16, 128)}
    # Polylines of 10 … 12 points (9 … 11 edges): one bucket (12 points, 12 edges).
    polylines = [_polyline(n) for n in (10, 11, 12)]
    posed = [fj.pose(registration, s) for s in (spines[0], polylines[0])]  # compiles
    traces.clear()
    posed += [fj.pose(registration, s) for s in spines[1:] + polylines[1:]]
    assert sum(traces.values()) == 0, f"spines of one bucket traced again: {dict(traces)}"
    # Results: those of the spine itself (programs of its own size, compiled without padding).
    monkeypatch.setattr(fj.BSpline, "_bucketed", lambda self: self)
    images, valid = fj.pose(registration, spines[0])
    assert traces["_pose_certified"] == 1  # (compiled for the unpadded spline)
    np.testing.assert_array_equal(posed[0][1], valid)
    assert np.mean(valid) > 0.9
    np.testing.assert_allclose(posed[0][0], images, rtol=0, atol=1e-13)


def test_fits_of_one_bucket_share_their_solve(traces):
    # `fit_spine` pads the clouds with weightless copies: clouds of 70 … 96 points (one
    # bucket) compile one solve; each fit recovers the bend, with (n,) flags.
    source, truth, guess = fj.Line(2.0), fj.Arc(1.5, 2.0), fj.Arc(4.0, 2.0)
    points = _points(96)
    target, _ = fj.flesh(points, source, truth)
    fits = {}
    for n in (70, 83, 96):
        fits[n] = fj.fit_spine(source, guess, points[:n], target[:n])
        if n == 70:
            traces.clear()
    assert traces["solve"] == 0, f"fits of one bucket traced the solve again: {dict(traces)}"
    for n, fit in fits.items():
        assert fit.converged and fit.valid.shape == (n,) and fit.num_invalid == 0
        assert float(fit.rms) < 1e-8
        np.testing.assert_allclose(fit.spine.radius, 1.5, atol=1e-8)
    # Weightless padding: the same fit as weighting the copies out by hand at the bucket size.
    weights = np.r_[np.ones(70), np.zeros(26)]
    padded = fj.fit_spine(source, guess, points, target, weights=weights)
    np.testing.assert_allclose(padded.spine.radius, fits[70].spine.radius, rtol=0, atol=1e-12)


def test_quick_programs_compile_with_cheap_options_at_top_level_only():
    """`Program` compiles with XLA's cheap options when called on its own, and nested in a
    caller's program (where JAX refuses compiler options) compiles with it: same values."""
    from fleshing_jax._batching.quick import QUICK_COMPILE, Program, top_level

    seen = []

    def double(x):
        seen.append(top_level())
        return 2 * x

    program = Program(double)
    x = jnp.arange(3.0)
    np.testing.assert_array_equal(program(x), 2 * x)
    assert seen == [False]  # traced once, by the quick program at the top level
    assert program.quick._cached._cache_size() == 1
    assert program.optimised._cached._cache_size() == 0
    np.testing.assert_array_equal(jax.jit(lambda y: program(y) + 1)(x), 2 * x + 1)
    assert program.optimised._cached._cache_size() == 0  # nested: traced into the caller
    np.testing.assert_array_equal(program(x, quick=False), 2 * x)
    assert program.optimised._cached._cache_size() == 1
    # The options are XLA's own: a compile with them succeeds.
    jax.jit(double).lower(x).compile(compiler_options=QUICK_COMPILE)


def test_fleshing_under_eager_transformations_runs_its_compiled_program(monkeypatch):
    """`jax.vmap(M)` and `jax.jacfwd(M)` called eagerly transform `M`'s compiled program
    whole (one program); under a caller's `jit` the one-point map is traced inline. Never is
    it run operation by operation (each compiled on its own: hundreds of programs)."""
    from fleshing_jax._batching.quick import compiling
    from fleshing_jax._fleshing import pipeline

    assert not compiling()
    seen = {}

    def probe(name):
        def f(x):
            seen[name] = compiling()
            return x

        return f

    jax.vmap(probe("vmap"))(jnp.ones(2))
    jax.jacfwd(probe("jacfwd"))(jnp.ones(2))
    jax.grad(lambda x: probe("grad")(x).sum())(jnp.ones(2))
    jax.jit(probe("jit"))(jnp.ones(2))
    jax.jit(jax.vmap(probe("vmap in jit")))(jnp.ones(2))
    jax.vmap(jax.jit(probe("jit in vmap")))(jnp.ones(2))
    assert seen == {"vmap": False, "jacfwd": False, "grad": False, "jit": True,
                    "vmap in jit": True, "jit in vmap": True}  # fmt: skip

    inline = []
    apply_point = pipeline.apply_point

    def recording(fleshing, x):
        inline.append(compiling())
        return apply_point(fleshing, x)

    monkeypatch.setattr(pipeline, "apply_point", recording)
    source, target = fj.Line(2.0), fj.Arc(1.5, 2.0)
    fleshing = fj.Fleshing(source, target)
    points = _points(100)  # (`flesh`: the programs of the 97–128 bucket, as above)
    images, valid = jax.vmap(fleshing.apply)(points)
    jacobian = jax.jacfwd(fleshing)(points[0])
    assert all(inline), "the one-point map ran operation by operation"
    expected, expected_valid = fj.flesh(points, source, target)
    np.testing.assert_array_equal(valid, expected_valid)
    np.testing.assert_allclose(images, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(jacobian), 1.0, atol=1e-10)

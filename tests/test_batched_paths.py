"""The batched paths (`register`, `pose`, `flesh`) against the one-point global ones.

The batched paths certify most projections with a lower bound of the spine's reach, run the
global search only on the other points, and work in chunks of points; results must be those of
the one-point path.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import cloud

import fleshing_jax as fj
from fleshing_jax._batching import chunks
from fleshing_jax._batching.chunks import map_chunks
from fleshing_jax._batching.compact import update_where
from fleshing_jax._fleshing.projection import closest_arc_lengths
from fleshing_jax._fleshing.reach import REACH_SAMPLES, LocalReach, reach_lower_bound
from fleshing_jax._numerics import cast_floats

U_TURN = [[0, 0, 0], [4, 0, 0], [5, 0, 0], [5.5, 0.5, 0], [5, 1, 0], [4, 1, 0], [0, 1, 0]]


def _coil():
    angle = np.linspace(0, 6 * np.pi, 40)
    return fj.BSpline(np.stack([np.cos(angle), np.sin(angle), 0.1 * angle], -1), degree=5)


def test_reach_lower_bound():
    # (Each spine's bounds built in one compiled program: built eagerly, they were hundreds of
    # one-operation programs.)
    lower = eqx.filter_jit(reach_lower_bound)
    assert np.isinf(float(lower(fj.Line(3.0))))
    arc = float(lower(fj.Arc(3.0, 4.0)))
    assert 0.5 < arc <= 3.0  # the reach of an arc is its radius
    helix = fj.Helix(1.0, 1.0, 12.0)
    assert 0.1 < float(lower(helix)) <= 1 / float(jnp.linalg.norm(helix.curvature_vector(0.0)))
    # The U-turn's tightest bend has curvature 4: the reach is at most 1/4 there. Its bounds
    # stay below that around the bend and exceed it along the straight branches (1 apart).
    s, kappa, reach = _curvatures_and_reach(fj.BSpline(U_TURN, degree=3))
    bend = float(s[np.argmax(kappa)])
    assert float(reach(bend)) <= 1 / float(np.max(kappa)) < float(reach(1.0))
    assert 0.25 < float(reach(1.0)) <= 0.5  # the branches are 1 apart


@eqx.filter_jit
def _curvatures_and_reach(spine):
    """The curvature at 4001 arc lengths along `spine`, and its `LocalReach`."""
    s = jnp.linspace(0.0, spine.length, 4001)
    kappa = jnp.linalg.norm(jax.vmap(spine.curvature_vector)(s), axis=-1)
    return s, kappa, LocalReach(spine)


def _local_reach_by_definition(spine, samples=96):
    """The bounds of `_fleshing.reach.LocalReach` computed as written, in NumPy float64: for
    each sample `i` and window `w = m h`, the curvature bound within `m + 1` samples and the
    smallest `q_ij` over all samples `j` at least `w − h` away."""
    lo, hi, jets = _reach_bounds(spine, samples)[2]
    lo, hi = float(lo), float(hi)
    h = (hi - lo) / (samples - 1)
    positions, tangents, k = (np.asarray(a, np.float64) for a in jets)
    kappa = np.linalg.norm(k, axis=-1)
    jumps = np.abs(np.diff(kappa, append=kappa[-1]))

    def kappa_hat(i, m):
        around = slice(max(i - m - 1, 0), i + m + 2)
        return kappa[around].max() + jumps[around].max()

    bounds = []
    for i in range(samples):
        # q_ij for every sample j at once.
        delta = positions - positions[i]
        length = np.linalg.norm(delta, axis=-1)
        across = np.linalg.norm(delta - (delta @ tangents[i])[:, None] * tangents[i], axis=-1)
        a = length - h
        c = across + length * kappa_hat(i, 1) * h + h
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(a > 0, np.maximum(a * a / (2 * c), a / 2), 0.0)
        best = 0.0
        m = 2
        while True:
            far = np.abs(np.arange(samples) - i) >= m - 1
            far = q[far].min() if far.any() else np.inf
            with np.errstate(divide="ignore"):
                near = 1 / kappa_hat(i, m) - m * h
            best = max(best, min(near, far))
            if m >= samples + 1:
                break
            m *= 2
        bounds.append(best)
    return np.array(bounds)


@eqx.filter_jit
def _reach_bounds(spine, samples=REACH_SAMPLES):
    """`LocalReach(spine, samples)`'s bounds, `reach_lower_bound(spine, samples)`, and the
    spine's search range `(lo, hi)` and jets at `samples` points over it, in one program
    (built eagerly: hundreds of one-operation programs)."""
    prepared = spine._prepare()
    e0, e1 = prepared.extension()
    lo, hi = -e0, prepared.length + e1
    grid = jnp.linspace(lo, hi, samples).astype(prepared.length.dtype)
    sampled = lo, hi, jax.vmap(prepared.jet)(grid)
    return LocalReach(spine, samples).bounds, reach_lower_bound(spine, samples), sampled


# float64 with `-m slow`: the running minima are the same code in both; float32 is posing's.
@pytest.mark.parametrize("dtype", [pytest.param(np.float64, marks=pytest.mark.slow), np.float32])
def test_local_reach_equals_its_definition(dtype):
    shapes = [fj.Line(3.0), fj.Arc(3.0, 4.0), fj.Helix(1.0, 1.0, 12.0), _coil()]
    shapes.append(fj.BSpline(U_TURN, degree=3))
    for spine in shapes:
        spine = jax.tree.map(lambda a: a.astype(dtype) if eqx.is_inexact_array(a) else a, spine)
        bounds, lowest, _ = _reach_bounds(spine, 96)
        bounds = np.asarray(bounds, np.float64)
        expected = _local_reach_by_definition(spine)
        # (float32: `√(|δ|² − along²)` cancels, a bound is good to about 1e-4 relative, and a
        # bound clamped at 0 can come out at a few ulps.)
        rtol, atol = (1e-10, 0) if dtype == np.float64 else (2e-4, 1e-6)
        np.testing.assert_allclose(bounds, expected, rtol=rtol, atol=atol, err_msg=str(spine))
        # The global bound is the smallest local one.
        assert float(lowest) == float(bounds.min())
    # Local: along the U-turn's straight branches (the last spine's bounds, checked above)
    # the bounds exceed the bend's radius of curvature (1/4), which the bend's own bounds
    # stay below.
    assert bounds.min() < 0.25 < np.median(bounds)


def _smallest_squared_distances(points, dense, dense_squared):
    """Each point's smallest squared distance to the `dense` samples (`dense_squared`: their
    squared norms), through one product (round-off ~1e-14 here, far below the test's
    tolerance), summed in place: `|p|²` added after the minimum (one (n, m) array, not four:
    the distances about twice as fast)."""
    squared = points @ (-2 * dense.T)
    squared += dense_squared
    return np.maximum(squared.min(axis=1) + np.sum(points**2, 1), 0)


@eqx.filter_jit  # (one program a spine: evaluated eagerly, hundreds of small ones)
def _points_inside_the_bounds(spine, fraction, angle, depth):
    """Points at `depth` (a fraction) of the `LocalReach` bound from the continued `spine`,
    at arc lengths `fraction` of the first 383 sample spacings and at `angle` about the
    tangent; the spine densely sampled (40001 points) over the same range; its reach."""
    spine = spine._prepare()
    reach = LocalReach(spine)
    s = reach.lo + fraction * 383 * reach.h
    (c, t, _), (i, j) = jax.vmap(spine.jet_and_normals)(s)
    r = jax.vmap(reach)(s) * depth
    angle = angle[:, None]
    x = c + r[:, None] * (jnp.cos(angle) * i + jnp.sin(angle) * j)
    dense = jax.vmap(spine)(jnp.linspace(reach.lo, reach.lo + 383 * reach.h, 40001))
    return x, r, dense, reach


@pytest.mark.parametrize("shape", ["arc", "helix", "u_turn", "coil"])
def test_local_reach_bounds_are_sound(shape):
    # Points at a distance below the local bound from their foot, in any normal direction:
    # no point of the continued spine (densely sampled) is closer than the foot.
    spine = {
        "arc": fj.Arc(3.0, 4.0),
        "helix": fj.Helix(1.0, 1.0, 12.0),
        "u_turn": fj.BSpline(U_TURN, degree=3),
        "coil": _coil(),
    }[shape]
    rng = np.random.default_rng(5)
    fraction, angle, depth = (rng.uniform(*bounds, 2000) for bounds in
                              ((0, 1), (0, 2 * np.pi), (0.9, 0.999)))  # fmt: skip
    x, r, dense, reach = _points_inside_the_bounds(spine, fraction, angle, depth)
    dense = np.asarray(dense)
    dense_squared = np.sum(dense**2, 1)
    nearest = np.sqrt(np.concatenate([_smallest_squared_distances(block, dense, dense_squared)
                                      for block in np.split(np.asarray(x), 8)]))  # fmt: skip
    assert np.all(nearest >= np.asarray(r) * (1 - 1e-9) - 1e-12)
    # And the bounds are not vacuous: the tube they certify has a useful radius.
    assert np.median(np.asarray(reach.bounds)) > 0.2


@pytest.mark.parametrize("shape", ["u_turn", pytest.param("coil", marks=pytest.mark.slow)])
def test_batched_projection_equals_global_search(shape):
    spine = fj.BSpline(U_TURN, degree=3) if shape == "u_turn" else _coil()
    rng = np.random.default_rng(2)
    lo, hi = np.min(spine.control_points, 0) - 0.4, np.max(spine.control_points, 0) + 0.4
    box = rng.uniform(lo, hi, (300, 3))
    # And points very near the spine, most of them inside the certified reach bound.
    # (Arc lengths padded to the 400 points' count: one program with the call below.)
    s = np.pad(rng.uniform(0, float(spine.length), 100), (0, 300))
    near = _positions_and_reach(spine, s)[0][:100]
    points = jnp.concatenate([jnp.asarray(box), near + rng.normal(0, 0.01, (100, 3))])
    single = jax.jit(jax.vmap(lambda x: fj.closest_arc_length(spine, x)))(points)
    batched = eqx.filter_jit(closest_arc_lengths)(spine, points)
    ok = np.asarray(single[1])
    np.testing.assert_array_equal(np.asarray(batched[1]), ok)
    np.testing.assert_allclose(np.asarray(batched[0])[ok], np.asarray(single[0])[ok], atol=1e-9)
    # Both paths ran: some points certified by the reach bound, others searched globally.
    feet, reach = map(np.asarray, _positions_and_reach(spine, single[0]))
    distance = np.linalg.norm(np.asarray(points) - feet, axis=-1)
    assert np.any(ok & (distance < reach)) and np.any(ok & (distance > reach))


@eqx.filter_jit  # (one program: evaluated eagerly, hundreds of one-operation programs)
def _positions_and_reach(spine, s):
    """`spine` at the arc lengths `s` (n,), and its `LocalReach` bounds there."""
    return jax.vmap(spine)(s), jax.vmap(LocalReach(spine))(s)


@pytest.fixture(scope="module")
def global_feet():
    """Points around lines and arcs, and the global search's feet and flags on each spine
    (float64): the reference of both dtypes' closed-form feet, searched once."""
    rng = np.random.default_rng(5)
    points = rng.uniform(-4.5, 4.5, (200, 3))
    axis = np.array([[0.0, 1.0, 0.5], [0.0, 1.0, 2.0]])  # on the wrapped arc's axis
    points = np.concatenate([points, axis])
    line = fj.Line(4.0, origin=(-1, 0.5, 0), tangent=(1, 1, 0))
    wrapped = fj.Arc(1.0, 5.0, origin=(0, 0, 0.5))
    feet = [(spine, *jax.jit(jax.vmap(lambda x, spine=spine: fj.closest_arc_length(spine, x)))(
        points)) for spine in (line, fj.Arc(3.0, 4.0), wrapped)]  # fmt: skip
    return points, feet


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_closed_form_feet_of_lines_and_arcs_equal_the_global_search(dtype, global_feet):
    # Lines and arcs register through their closed-form foot (`_closest_start`): the same arc
    # lengths and convergence as the global search, past the ends too, and no unique foot
    # (an arc whose search range wraps more than a full turn: the same point of the circle at
    # two arc lengths; points on its axis) reported as not converged.
    points, feet = global_feet
    tol = 1e-9 if dtype == jnp.float64 else 2e-4
    for spine, s, ok in feet:
        batched, converged = eqx.filter_jit(closest_arc_lengths)(spine, points.astype(dtype))
        converged = np.asarray(converged)
        # The same verdicts, but within round-off of a tie in float32.
        assert np.mean(converged != np.asarray(ok)) <= (0 if dtype == jnp.float64 else 0.02)
        both = converged & np.asarray(ok)
        np.testing.assert_allclose(np.asarray(batched)[both], np.asarray(s)[both], atol=tol)
    assert not converged[-2:].any()
    assert 0.2 < converged.mean() < 0.8  # the wrapped arc: many points have two feet


@pytest.mark.parametrize("method", ["radial", pytest.param("binormal", marks=pytest.mark.slow)])
def test_flesh_onto_u_turn_flags_images_near_the_other_branch(method):
    target = fj.BSpline(U_TURN, degree=3)
    source = fj.Line(float(target.length))
    rng = np.random.default_rng(3)
    n = 400
    s = rng.uniform(0.0, float(target.length), n)
    radius, angle = rng.uniform(0.0, 0.8, n), rng.uniform(0, 2 * np.pi, n)
    points = jnp.asarray(np.stack([s, radius * np.cos(angle), radius * np.sin(angle)], -1))
    out, valid = fj.flesh(points, source, target, method=method, twist=0.4)
    fleshing = fj.Fleshing(source, target, method=method, twist=0.4)
    out_one, valid_one = jax.jit(jax.vmap(fleshing.apply))(points)
    np.testing.assert_array_equal(np.asarray(valid), np.asarray(valid_one))
    np.testing.assert_allclose(np.asarray(out), np.asarray(out_one), atol=1e-10)
    # Images that would land closer to the other branch are flagged; the rest map.
    assert 0.2 < float(jnp.mean(valid)) < 0.95
    registration = fj.register(points, source)
    unchecked = fj.pose(registration, target, method=method, twist=0.4, check_projection=False)
    assert np.any(np.asarray(unchecked[1]) & ~np.asarray(valid))


@pytest.mark.parametrize("n", [0, 1, 7, 1000])
def test_update_where(n):
    rng = np.random.default_rng(n)
    needed = jnp.asarray(rng.uniform(size=n) < 0.3)
    inputs = (jnp.asarray(rng.normal(size=(n, 2))), jnp.arange(n))
    values = jnp.zeros(n)

    def function(args):
        x, i = args
        return jnp.sum(x) + i

    out = jax.jit(lambda v, w, i: update_where(w, function, v, i, chunk=64))(values, needed, inputs)
    expected = np.where(np.asarray(needed), np.sum(np.asarray(inputs[0]), -1) + np.arange(n), 0)
    np.testing.assert_allclose(np.asarray(out), expected)


def test_map_chunks_equals_one_batch_with_gradients():
    rng = np.random.default_rng(4)
    inputs = {"x": jnp.asarray(rng.normal(size=(37, 3))), "w": jnp.asarray(rng.normal(size=37))}

    def function(batch):  # per-point work, batched
        return jnp.sin(batch["x"]).sum(-1) * batch["w"], batch["x"] ** 2

    for chunk in (5, 37, 64):  # padded chunks, one exact chunk, one call
        out = jax.jit(lambda i, c=chunk: map_chunks(function, i, chunk=c))(inputs)
        jax.tree.map(np.testing.assert_allclose, out, function(inputs))
    grad = jax.grad(lambda i: map_chunks(function, i, chunk=8)[0].sum())(inputs)
    jax.tree.map(np.testing.assert_allclose, grad, jax.grad(lambda i: function(i)[0].sum())(inputs))


_LAX_MAP = jax.lax.map


def _chunked(monkeypatch, size: int, call):
    """`call()` with `chunks.CHUNK_POINTS = size`, asserting that `map_chunks` looped over
    chunks of `size` points. The chunk size is read when tracing: where a program of the same
    inputs was traced before with another (no loop of `size` seen), the caches are cleared and
    it is traced again. (Not cleared otherwise, nor after: clearing them made every later
    test of the worker trace its programs again, ~9 s a tube pose; the programs traced here
    serve only calls on these inputs, and return their values, as this test checks.)"""
    monkeypatch.setattr(chunks, "CHUNK_POINTS", size)
    seen = []

    def recording(f, xs, *args, **kwargs):
        seen.append(jax.tree.leaves(xs)[0].shape[1])
        return _LAX_MAP(f, xs, *args, **kwargs)

    monkeypatch.setattr(jax.lax, "map", recording)
    out = call()
    if size not in seen:  # (a test on new inputs never comes here)
        jax.clear_caches()
        out = call()
    assert size in seen
    return out


def test_flesh_in_chunks_equals_one_point_path(monkeypatch):
    # Chunks of 64 points: 600 points, padded to 768 (`_batching.buckets`), make 12 chunks.
    # (Not the U-turn test's 400: its programs, traced with the default chunk, would be
    # found in the caches, which `_chunked` would then clear for every later test.)
    target = fj.BSpline(U_TURN, degree=3)
    source = fj.Line(float(target.length))
    rng = np.random.default_rng(5)
    n = 600
    points = np.column_stack(
        [rng.uniform(-0.3, float(target.length) + 0.3, n), rng.uniform(-0.6, 0.6, (n, 2))]
    )
    points[::50] = np.nan  # invalid points stay invalid, without disturbing the others
    points = jnp.asarray(points)
    fleshing = fj.Fleshing(source, target, method="radial", twist=0.4)
    expected = jax.jit(jax.vmap(fleshing.apply))(points)
    for out, valid in (
        _chunked(monkeypatch, 64, lambda: fj.flesh(points, source, target, twist=0.4)),
        _chunked(monkeypatch, 64, lambda: fj.pose(fj.register(points, source), target, twist=0.4)),
    ):
        np.testing.assert_array_equal(np.asarray(valid), np.asarray(expected[1]))
        np.testing.assert_allclose(np.asarray(out), np.asarray(expected[0]), atol=1e-10)
    assert 0.3 < float(jnp.mean(expected[1])) < 0.99


def test_a_small_batch_runs_its_pending_points_at_its_own_size():
    # Eagerly, the pending points run in a second program, gathered to a padded size: a batch
    # of up to `WHOLE_BATCH` points at its own size whatever the count (a skeleton's limbs,
    # padded alike, share one program), a larger one at a power of two >= `MINIMUM_BATCH`.
    from fleshing_jax._fleshing.eager import MINIMUM_BATCH, WHOLE_BATCH, pending_index

    rng = np.random.default_rng(0)
    for n, count, size in ((512, 1, 512), (512, 300, 512), (WHOLE_BATCH, WHOLE_BATCH, WHOLE_BATCH),
                           (4 * WHOLE_BATCH, 1, MINIMUM_BATCH), (4 * WHOLE_BATCH, 70, 128)):
        pending = np.zeros(n, bool)
        pending[rng.choice(n, count, replace=False)] = True
        index = pending_index(pending)
        assert index.shape == (size,) and index.dtype == np.int32
        # Every pending point once, in order, then copies of the last one.
        np.testing.assert_array_equal(index[:count], np.flatnonzero(pending))
        assert np.all(index[count:] == index[count - 1])


# In the slow set (25 s a dtype): the eager paths' results are checked point for point against
# the one-point map by `test_flesh_in_chunks_equals_one_point_path`, and in float32 against
# exact float64 by `test_table.py::test_float32_batched_paths_agree_with_exact_float64`.
@pytest.mark.slow
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_eager_two_phase_paths_equal_the_one_program_paths(dtype, monkeypatch):
    # Called eagerly, `register` and `pose` run the global searches in a second program, on
    # the pending points only; under `jit`, in one program. Same results, point for point, on
    # a target that comes back near itself (many pending points), over more than one chunk
    # (float64 spines are exact: in chunks; 1024 points a chunk keeps the batch small).
    from fleshing_jax._fleshing import eager, pipeline

    monkeypatch.setattr(chunks, "CHUNK_POINTS", 1024)
    jax.clear_caches()  # the chunk size is read when tracing

    turn = fj.BSpline(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [2.3, 0.6, 0], [1, 0.8, 0],
                                [0, 0.8, 0]], dtype))  # fmt: skip
    source = fj.BSpline(np.array([[0, 0, 0], [0.6, 0.1, 0], [1.2, 0, 0.1], [1.8, 0, 0],
                                  [2.5, 0.1, 0]], dtype), degree=3)  # fmt: skip
    rng = np.random.default_rng(1)
    n = 3000 if dtype == "float32" else chunks.CHUNK_POINTS + 100
    points = jnp.asarray(rng.uniform(-0.3, 0.3, (n, 3)) + [1.0, 0.2, 0], dtype)
    far = jnp.asarray(rng.uniform(-3, 3, (40, 3)), dtype)  # beyond the reach bounds: searched
    points = points.at[:40].set(far)
    # (The eager calls pad the spines to their bucket, `AbstractSpine._bucketed`: so do the
    # one-program references, or float32 round-off would differ on invalid points.)
    registrar = pipeline._registrar(source._bucketed(), source.default_samples())
    assert eager._register_certified(registrar, points)[1].sum() > 0  # both phases run
    one_program = fj.Registration(points, *pipeline._register(registrar, points))
    registration = fj.register(points, source)
    # (The programs are fused differently: floats agree to their last bits, flags exactly.)
    atol = 1e-5 if dtype == "float32" else 1e-12
    for a, b in zip(jax.tree.leaves(registration), jax.tree.leaves(one_program)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=atol)
    zero = jnp.asarray(0.0, dtype)
    poser = pipeline._poser(turn._bucketed(), "radial", zero, True, zero, registration.ends)
    assert eager._pose_certified(poser, registration)[2].sum() > 0
    images, valid = fj.pose(registration, turn)
    images_one, valid_one = pipeline._pose(poser, registration)
    np.testing.assert_array_equal(np.asarray(valid), np.asarray(valid_one))
    np.testing.assert_allclose(np.asarray(images), np.asarray(images_one), rtol=0, atol=atol)
    # The U-turn makes the projection check reject points: returned unchanged.
    rejected = np.asarray(fj.pose(registration, turn, check_projection=False)[1]) & ~valid
    assert rejected.sum() > n // 100
    np.testing.assert_array_equal(np.asarray(images)[rejected], np.asarray(points)[rejected])
    monkeypatch.undo()
    jax.clear_caches()


def test_large_batches_flesh_in_blocks(monkeypatch, capsys):
    # Above `BLOCK_POINTS`, eager `flesh` works a block at a time into the output (bounded
    # memory), the last block overlapping the one before; same result as one batch.
    from fleshing_jax._fleshing import pipeline

    source, target = fj.Line(4.0), fj.Arc(3.0, 4.0)
    points = jnp.asarray(cloud(source, n=1000, overshoot=0.1), jnp.float32)
    points = points.at[3].set(jnp.nan)
    whole, whole_valid = fj.pose(fj.register(points, source), target, twist=0.2)
    monkeypatch.setattr(pipeline, "BLOCK_POINTS", 256)  # 4 blocks, the last one overlapping
    images, valid = fj.flesh(points, source, target, twist=0.2, progress=True)
    np.testing.assert_array_equal(np.asarray(valid), np.asarray(whole_valid))
    np.testing.assert_array_equal(np.asarray(images)[3], np.asarray(points)[3])
    np.testing.assert_allclose(np.asarray(images), np.asarray(whole), rtol=0, atol=1e-6)
    assert images.dtype == jnp.float32 and not valid[3]
    assert "flesh" in capsys.readouterr().err  # the progress bar


def test_closed_form_feet_need_no_reach_bounds():
    # Lines and arcs are registered by their closed-form feet: their preparation builds no
    # reach bounds (which only certify the searched feet of the other spines).
    from fleshing_jax._fleshing.projection import Registrar

    # (What is built is known from tracing it: `filter_eval_shape` runs and compiles nothing.)
    def prepared(spine):
        return eqx.filter_eval_shape(Registrar, spine)

    for spine in (fj.Line(2.0), fj.Arc(1.5, 3.0)):
        assert prepared(spine).reach is None
    curve = fj.BSpline(np.array([[0, 0, 0], [1, 0.3, 0], [2, 0, 0.2], [3, 0, 0.0]]), degree=3)
    assert isinstance(prepared(curve).reach, LocalReach)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_projection_check_on_lines_and_arcs_equals_the_global_check(dtype):
    # Onto lines and arcs, the projection check is a closed form of `s₁` (no reach bounds, no
    # search, no foot read back): the same flags as the global search (`closest_arc_length`)
    # would give, on the batched path and on the one-point path. The arcs bend a thick
    # tube past their centres and wrap more than a turn (two candidate feet).
    from fleshing_jax._numerics import relative_tolerance

    rng = np.random.default_rng(11)
    n = 300
    points = jnp.asarray(
        np.column_stack([rng.uniform(-0.5, 4.5, n), rng.uniform(-1.2, 1.2, (n, 2))]), dtype
    )
    source = fj.Line(4.0)
    registration = fj.register(points, source)
    arcs = (fj.Arc(0.9, 4.0), fj.Arc(0.5, 4.0, origin=(0, 0, 0.3)))
    for target in (*arcs, fj.Line(4.0, tangent=(0, 1, 1))):
        target = cast_floats(target, dtype)
        images, bent = fj.pose(registration, target, method="skinning", check_projection=False)
        s1 = registration.arc_length  # (equal lengths)
        back, converged = jax.jit(jax.vmap(lambda x: fj.closest_arc_length(target, x)))(images)
        distance = jnp.linalg.norm(images - jax.vmap(target)(s1), axis=1)
        tol = relative_tolerance(dtype) * (4.0 + distance)
        expected = bent & converged & (jnp.abs(back - s1) <= tol)
        one_point = jax.vmap(fj.Fleshing(source, target, method="skinning").is_valid)(points)
        eager = fj.pose(registration, target, method="skinning")[1]
        for valid in (eager, one_point):
            # (float32: within round-off of a tie or of the tolerance, a flag may differ.)
            mismatch = np.mean(np.asarray(valid) != np.asarray(expected))
            assert mismatch <= (0 if dtype == jnp.float64 else 0.01), target
        if isinstance(target, fj.Arc):  # both verdicts are tested
            assert 0.1 < float(jnp.mean(expected)) < 0.95, target

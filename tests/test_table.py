"""The tabulated spines of the single-precision batched paths (`_spines.table`).

The table replaces the exact spine in `register`, `pose` and `flesh` for float32 points only: its
interpolation error must sit far below float32's resolution, so that those paths give what the
exact spines give, to float32 round-off (and float64 keeps the exact spines).
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import cloud, mapped

import fleshing_jax as fj
from fleshing_jax._fleshing.projection import Registrar, _nearest
from fleshing_jax._fleshing.target import TargetFrames
from fleshing_jax._spines.spine import AbstractSpine
from fleshing_jax._spines.table import SpineTable, fast_evaluator

TORSION = [[0, 0, 0], [1, 0.4, 0.1], [2, 0.1, 0.6], [3, -0.5, 0.4], [4, 0, 0.2], [5, 0.3, 0.8]]
INFLECTION = [[0, 0, 0], [1, 1, 0], [2, 0, 0.5], [3, -1, 0], [4, 0, 0.3], [5, 1, 1.0]]
ZOO = {
    "arc": fj.Arc(3.0, 4.0),
    "tight-arc": fj.Arc(0.5, 3.0),
    "helix": fj.Helix(2.0, 3.0, 8.0),
    "bspline-torsion": fj.BSpline(TORSION),
    "bspline-inflection": fj.BSpline(INFLECTION),
    "polynomial": fj.InterpolatingPolynomial(
        [[0, 0, 0], [1, 0.5, 0.2], [2, 0.2, 0.5], [3, -0.3, 0.4]]
    ),
}


def _values(spine, s):
    (c, t, k), (i, j) = spine.jet_and_normals(s)
    return jnp.concatenate([c, t, k, i, j])


@pytest.mark.parametrize("name", sorted(ZOO))
def test_table_matches_the_spine_over_its_search_range(name):
    # Built in float64, so that what is measured is the interpolation error alone.
    spine = ZOO[name]._prepare()
    table = SpineTable(spine, max(128, spine.default_samples()))
    assert float(table.lo) < 0 and float(table.hi) > float(spine.length)
    s = jnp.linspace(table.lo, table.hi, 5001)
    exact, tabulated = (mapped(eqx.Partial(_values, f), s) for f in (spine, table))
    error = np.abs(np.asarray(exact - tabulated))
    # Position, tangent and normals to 1e-7, curvature to 1e-6: below float32's resolution
    # once multiplied by the offsets (≲ the reach, ≲ 1/κ).
    assert error[:, :6].max() < 1e-7 and error[:, 9:].max() < 1e-7, error.max(axis=0)
    assert error[:, 6:9].max() < 1e-6, error[:, 6:9].max()


@pytest.mark.parametrize("name", sorted(ZOO))
def test_tabulated_target_frames_match_the_exact_ones(name):
    # What `pose` looks up in single precision: C₁, the twisted normals and the curvature in
    # them, tabulated (as `Poser` does) from the spine's table. Built in float64 to measure the
    # interpolation error alone.
    spine = ZOO[name]._prepare()
    exact = TargetFrames(spine, jnp.asarray(0.4))
    tabulated = TargetFrames(SpineTable(spine), jnp.asarray(0.4), tabulate=True)
    assert tabulated.table is not None and exact.table is None
    assert float(tabulated.lo) == float(exact.lo) and float(tabulated.hi) == float(exact.hi)
    s = jnp.linspace(exact.lo, exact.hi, 5001)
    error = np.abs(
        np.concatenate(mapped(exact, s), axis=-1) - np.concatenate(mapped(tabulated, s), -1)
    )
    assert error[:, :9].max() < 1e-7, error.max(axis=0)
    assert error[:, 9:].max() < 1e-6, error[:, 9:].max()
    # The twist is folded into the table: the normals turn by it about the tangent.
    (_, t, _), (i, _) = spine.jet_and_normals(1.0)
    _, i1, j1, _ = tabulated(1.0)
    np.testing.assert_allclose(float(jnp.dot(i, i1)), np.cos(0.4), atol=1e-7)
    np.testing.assert_allclose(np.asarray(jnp.cross(i1, j1)), np.asarray(t), atol=1e-7)


@pytest.mark.parametrize("radius, length", [(3.0, 4.0), (0.5, 3.0), (0.4, 9.0)])
def test_arc_target_frames_are_a_sinusoid(radius, length):
    # An arc's frames (point, twisted normals, curvature in them) are `a + b sin φ + c (1 −
    # cos φ)`: three coefficient rows give them exactly, everywhere (the last arc wraps more
    # than three turns; its search range reaches a quarter turn past each end). Built in
    # float64 to see the representation's error alone: round-off.
    from fleshing_jax._spines.sinusoid import Sinusoid

    arc = fj.Arc(radius, length, origin=(0.5, -1, 2), tangent=(1, 2, 0.5), normal=(0, 0, 1))
    exact = TargetFrames(arc, jnp.asarray(0.4))
    looked_up = TargetFrames(arc, jnp.asarray(0.4), tabulate=True)
    assert isinstance(looked_up.table, Sinusoid) and looked_up.table.coefficients.shape == (3, 11)
    s = jnp.linspace(exact.lo - 2 * length, exact.hi + 2 * length, 4001)
    error = np.abs(
        np.concatenate(mapped(exact, s), axis=-1) - np.concatenate(mapped(looked_up, s), -1)
    )
    assert error.max() < 1e-13 * (1 + length), error.max(axis=0)
    # So are the values and products its registration reads (`SpineTable`): no cubic pieces.
    table = SpineTable(arc)
    assert isinstance(table.cubics, Sinusoid)
    assert float(table.lo) == float(exact.lo) and float(table.hi) == float(exact.hi)
    for name in ("_foot_terms", "_local_terms"):
        x = jnp.asarray([0.3, -0.2, 1.1])
        terms = [mapped(eqx.Partial(getattr(spine, name), x), s) for spine in (arc, table)]
        for a, b in zip(*terms):
            np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=0, atol=1e-12 * length)
    # A spine that is not an arc keeps its table of cubic pieces.
    assert not isinstance(TargetFrames(fj.Helix(2.0, 3.0, 8.0), 0.0, True).table, Sinusoid)
    assert not isinstance(SpineTable(fj.Helix(2.0, 3.0, 8.0)).cubics, Sinusoid)


def test_pose_onto_an_arc_in_two_programs_equals_one_program():
    # Called eagerly on looked-up frames, `pose` bends the points in one program and places
    # them in another (`eager.pose_eagerly`); under `jit`, one program. Same images and flags,
    # in single precision, onto an arc (its frames a `Sinusoid`, its check in closed form),
    # with points beyond its reach and its search range flagged and returned unchanged.
    from fleshing_jax._fleshing import pipeline
    from fleshing_jax._spines.sinusoid import Sinusoid

    source, target = fj.Line(np.float32(4.0)), fj.Arc(np.float32(0.8), np.float32(4.0))
    points = cloud(source, n=3000, radius=0.6, seed=5, overshoot=0.3).astype(np.float32)
    registration = fj.register(points, source)
    twist, zero = jnp.asarray(0.3, jnp.float32), jnp.asarray(0.0, jnp.float32)
    poser = pipeline._poser(target, "radial", twist, True, zero, registration.ends)
    assert isinstance(poser.frames.table, Sinusoid) and poser.fused
    images, valid = fj.pose(registration, target, twist=0.3)
    images_one, valid_one = pipeline._pose(poser, registration)
    assert images.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(valid), np.asarray(valid_one))
    assert 0.2 < np.mean(valid) < 0.95  # both kinds of points
    np.testing.assert_allclose(np.asarray(images), np.asarray(images_one), rtol=0, atol=2e-6)
    np.testing.assert_array_equal(np.asarray(images)[~valid], points[~np.asarray(valid)])
    # And the exact float64 pose, to float32's round-off.
    exact, valid64 = fj.pose(fj.register(points.astype(np.float64), fj.Line(4.0)),
                             fj.Arc(0.8, 4.0), twist=0.3)
    np.testing.assert_array_equal(np.asarray(valid), np.asarray(valid64))
    np.testing.assert_allclose(np.asarray(images), np.asarray(exact), rtol=0, atol=4e-6)


@pytest.mark.parametrize("name", sorted(ZOO))
def test_tabulated_search_terms_match_the_spine(name):
    # The closest-point search's terms, formed per point from tabulated products (`C·T`,
    # `k·C`, `C·I`, ...): the same as from the exact jet and frame, to the interpolation error
    # (built in float64 to measure it alone), at points around the spine and past its ends.
    spine = ZOO[name]._prepare()
    table = SpineTable(spine)
    rng = np.random.default_rng(3)
    s = jnp.asarray(rng.uniform(float(table.lo), float(table.hi), 400))
    x = mapped(spine, s) + jnp.asarray(rng.normal(0, 0.3, (400, 3)))
    for terms in ("_foot_terms", "_local_terms"):
        exact = mapped(getattr(spine, terms), x, s)
        tabulated = mapped(getattr(table, terms), x, s)
        for e, t in zip(exact, tabulated):
            np.testing.assert_allclose(np.asarray(t), np.asarray(e), rtol=0, atol=2e-6)
    # What the terms are: f = (C − x)·T, f' = 1 − k·(x − C), |x − C|.
    (c, t, k) = mapped(spine.jet, s)
    f, slope, distance = mapped(table._foot_terms, x, s)
    np.testing.assert_allclose(f, jnp.sum((c - x) * t, -1), atol=2e-6)
    np.testing.assert_allclose(slope, 1 - jnp.sum(k * (x - c), -1), atol=2e-6)
    np.testing.assert_allclose(distance, jnp.linalg.norm(x - c, axis=-1), atol=2e-6)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_nearest_sample_by_packed_keys(dtype):
    # `_nearest` takes the minimum of the squared distances with the candidate's position
    # packed in their low bits: the nearest candidate, up to distances equal in all but those
    # bits, and the first of exact ties.
    rng = np.random.default_rng(4)
    samples = jnp.asarray(rng.normal(size=(17, 3)), dtype)
    points = jnp.asarray(rng.normal(size=(500, 3)), dtype)
    picked = jax.jit(jax.vmap(lambda x: _nearest(list(samples.T), x)))(points)
    squared = np.sum((np.asarray(points)[:, None] - np.asarray(samples)[None]) ** 2, -1)
    best = squared[np.arange(500), np.asarray(picked)]
    np.testing.assert_array_less(best, squared.min(1) * (1 + 2.0**-17) + 1e-30)
    assert np.mean(np.asarray(picked) == squared.argmin(1)) > 0.99
    # Exact ties: the first one wins.
    twice = jnp.concatenate([samples, samples])
    picked = jax.jit(jax.vmap(lambda x: _nearest(list(twice.T), x)))(points)
    assert np.all(np.asarray(picked) < 17)


def test_table_values_are_looked_up_where_first_read():
    # `fields` returns a table's values as `Lookups`: each computed when first read, once (a
    # caller's unread values are never traced), indexed and sliced as a list.
    from fleshing_jax._spines.lookups import Lookups

    computed = []
    values = Lookups(5, lambda f: computed.append(f) or 10 * f)
    assert len(values) == 5 and computed == []
    assert values[3] == 30 and values[1:3] == [10, 20] and values[-1] == 40 and values[3] == 30
    assert computed == [3, 1, 2, 4] and list(values) == [0, 10, 20, 30, 40]
    with pytest.raises(IndexError):
        values[5]


def test_a_grid_mapped_once_is_mapped_as_by_nested_maps():
    # `grid_vmap` (one `vmap` over a table's flattened pieces × nodes, for its tracing time)
    # computes what nested `vmap`s compute, element by element, for pytrees of any point shape.
    from fleshing_jax._batching.grid import grid_vmap

    def point(s, x):
        return {"a": jnp.where(s > 0, jnp.sin(s) * x, x / 3), "b": s * s + 1}

    s = jnp.linspace(-1, 1, 12, dtype=jnp.float32).reshape(3, 4)
    x = jnp.arange(24, dtype=jnp.float32).reshape(3, 4, 2)
    once, nested = grid_vmap(point, s, x), jax.vmap(jax.vmap(point))(s, x)
    assert once["a"].shape == (3, 4, 2) and once["b"].shape == (3, 4)
    for a, b in zip(jax.tree.leaves(once), jax.tree.leaves(nested), strict=True):
        np.testing.assert_array_equal(a, b)


def test_fast_evaluator_is_exact_in_float64_and_for_polylines():
    assert not isinstance(fast_evaluator(fj.Arc(3.0, 4.0)), SpineTable)  # float64 (conftest)
    arc32 = fj.Arc(np.float32(3.0), np.float32(4.0))
    assert isinstance(fast_evaluator(arc32), SpineTable)
    polyline = fj.Polyline(np.asarray(INFLECTION, np.float32))
    assert not isinstance(fast_evaluator(polyline), SpineTable)


def _same_values_and_derivatives(f, g, *args):
    # (One compiled program for both and their derivatives: evaluated eagerly, they were
    # hundreds of one-operation programs, 11 s.)
    def values_and_derivatives(f):
        derivatives = jax.jacfwd(f, argnums=tuple(range(len(args))))
        return lambda *args: (jax.vmap(f)(*args), jax.vmap(derivatives)(*args))

    want, got = jax.jit(lambda *args: (values_and_derivatives(f)(*args),
                                       values_and_derivatives(g)(*args)))(*args)
    for w, v in zip(jax.tree.leaves(want), jax.tree.leaves(got), strict=True):
        np.testing.assert_allclose(np.asarray(v), np.asarray(w), rtol=0, atol=1e-13)


class _GenericLine(fj.Line):
    def _continues_as_itself(self):
        return False


class _GenericArc(fj.Arc):
    def _continues_as_itself(self):
        return False


def test_lines_and_arcs_are_evaluated_in_closed_form_past_their_ends():
    # Both continue past their ends as themselves (an arc along its osculating circle): their
    # closed forms at any `s` equal the generic continuation from the end, values and
    # derivatives. A line is cheaper exactly than through a table: float32 searches it as it
    # is, on whole batches, with its search and registration terms in closed form.
    line32 = fj.Line(np.float32(4.0))
    assert fast_evaluator(line32) is line32
    # (What is built is known from tracing it: `filter_eval_shape` runs and compiles nothing.)
    registrars = [eqx.filter_eval_shape(Registrar, s) for s in (line32, fj.Helix(2.0, 3.0, 8.0))]
    assert registrars[0].fused and not registrars[1].fused
    options = dict(origin=(1.0, 2.0, 3.0), tangent=(0.0, 0.6, 0.8))
    line, generic_line = fj.Line(4.0, **options), _GenericLine(4.0, **options)
    arc, generic_arc = (kind(2.0, 5.0, normal=(1.0, 0.0, 1.0), **options)
                        for kind in (fj.Arc, _GenericArc))
    rng = np.random.default_rng(5)
    s = jnp.asarray(rng.uniform(-3.0, 8.0, 60))  # about a third of them past an end
    for spine, generic in ((line, generic_line), (arc, generic_arc)):
        _same_values_and_derivatives(generic.jet_and_normals, spine.jet_and_normals, s)
    x = jax.vmap(line)(s) + jnp.asarray(rng.normal(0, 0.5, (60, 3)))
    for terms in ("_foot_terms", "_local_terms"):
        generic = functools.partial(getattr(AbstractSpine, terms), generic_line)
        _same_values_and_derivatives(generic, getattr(line, terms), x, s)


PAIRS = {
    "line-arc": (fj.Line(4.0), fj.Arc(3.0, 4.0)),
    "arc-line": (fj.Arc(1.5, 4.0), fj.Line(4.5)),
    "helix-helix": (fj.Helix(2.0, 3.0, 8.0), fj.Helix(1.5, -2.5, 8.0)),
    "bspline-bspline": (fj.BSpline(TORSION), fj.BSpline(INFLECTION)),
}


@pytest.mark.parametrize(
    "pair, method",
    [
        ("line-arc", "radial"),
        ("arc-line", "radial"),
        # (The free-form cases with `python -m pytest -m slow`: the longest compiles.)
        pytest.param("helix-helix", "normal", marks=pytest.mark.slow),
        pytest.param("bspline-bspline", "binormal", marks=pytest.mark.slow),
    ],
)
def test_float32_batched_paths_agree_with_exact_float64(pair, method):
    # (Gradients through the table: the float32 fit in tests/test_fit.py.)
    source, target = PAIRS[pair]
    points = cloud(source, n=512, radius=0.25, seed=3, overshoot=0.05)
    exact, valid = fj.flesh(points, source, target, method=method, twist=0.4)
    fast, valid32 = fj.flesh(points.astype(np.float32), source, target, method=method, twist=0.4)
    assert fast.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(valid32), np.asarray(valid))
    assert np.mean(valid) > 0.9
    scale = float(np.max(np.abs(exact)))
    # float32 round-off through projection, frames and maps: a few ulps of the coordinates.
    np.testing.assert_allclose(np.asarray(fast), np.asarray(exact), atol=2e-6 * scale)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_images_beyond_the_target_search_range_are_invalid(dtype):
    # A straight source is searched one length past its ends; a tight arc only a quarter turn
    # (π/4 here). A point 2 past the source's end maps 2 past the arc's: outside its range.
    source, target = fj.Line(4.0), fj.Arc(0.5, 4.0)
    points = np.asarray([[6.0, 0.1, 0.0], [2.0, 0.1, 0.0]], dtype)
    for check in (True, False):
        _, valid = fj.flesh(points, source, target, check_projection=check)
        np.testing.assert_array_equal(np.asarray(valid), [False, True])
        M = fj.Fleshing(source, target, check_projection=check)
        assert not bool(M.is_valid(points[0])) and bool(M.is_valid(points[1]))

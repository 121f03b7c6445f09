"""The valid region (`_fleshing.region`): a map that tears is never reported valid.

An edge whose two ends are valid, with a margin of half its length, never crosses the spines'
cut locus or focal set, so its image is never torn: its length is at most the largest stretch
of the map along it times its rest length. Tears show as image edges as long as the distance
between the stretches of the spine the two ends were projected on.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._fleshing.diagnose import diagnose
from fleshing_jax._fleshing.region import ValidRegion, clear_where

STEP = 0.1  # lattice spacing: edges of this length, margin half of it


def lattice(lo, hi, step=STEP):
    """Points on a regular grid over the box `[lo, hi]` and its edges: `(points (n, 3),
    edges (m, 2))`."""
    axes = [np.arange(a, b + 1e-9, step) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"))
    index = np.arange(grid[0].size).reshape(grid.shape[1:])
    edges = [
        np.stack([np.take(index, range(0, n - 1), axis=a).ravel(),
                  np.take(index, range(1, n), axis=a).ravel()], 1)
        for a, n in enumerate(index.shape)
    ]  # fmt: skip
    return grid.reshape(3, -1).T, np.concatenate(edges)


def stretches(images, valid, edges, step=STEP):
    """The image lengths of the edges with two valid ends, over their rest length."""
    images, valid = np.asarray(images, np.float64), np.asarray(valid)
    both = valid[edges[:, 0]] & valid[edges[:, 1]]
    a, b = images[edges[both, 0]], images[edges[both, 1]]
    return np.linalg.norm(a - b, axis=1) / step


# A hairpin: two straight stretches 0.8 apart joined by a U-turn. Its cut locus between the
# stretches is the plane y = 0.4; the lattice's y = 0.35 and 0.45 straddle it.
HAIRPIN = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [3.5, 0.1, 0], [3.6, 0.4, 0],
                    [3.5, 0.7, 0], [3, 0.8, 0], [2, 0.8, 0], [1, 0.8, 0],
                    [0, 0.8, 0.0]])  # fmt: skip


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_bottleneck_tears_without_margin_and_never_with_it(dtype):
    source = fj.BSpline(HAIRPIN.astype(dtype), degree=3)
    target = fj.Line(source.length)  # straightened: the two stretches go far apart
    points, edges = lattice((0.0, -0.25, -0.2), (3.2, 1.05, 0.2))
    points = points.astype(dtype)
    # Without a margin each point is valid on its own, and edges across y = 0.4 tear.
    images, valid = fj.flesh(points, source, target)
    assert stretches(images, valid, edges).max() > 30
    images, valid = fj.flesh(points, source, target, margin=STEP / 2)
    assert images.dtype == jnp.dtype(dtype)
    assert stretches(images, valid, edges).max() < 1.5
    # The points flagged are those within the margin of the cut locus, counted apart.
    registration = fj.register(points, source, margin=STEP / 2)
    flagged = np.asarray(registration.discontinuous)
    y = points[:, 1]
    assert flagged[np.abs(y - 0.4) < 0.06].all()
    assert not flagged[(np.abs(y - 0.4) > 0.3) & (points[:, 0] < 2.5)].any()
    causes = diagnose(registration, target, margin=STEP / 2)
    assert causes.beyond_reach == flagged.sum() > 0
    assert causes.outside_source == np.sum(~np.asarray(registration.valid) & ~flagged)


def _wavy(rng, dtype, amplitude=0.8, n=8):
    x = np.linspace(0, 4, n)
    yz = rng.uniform(-amplitude, amplitude, (n, 2))
    yz[0] = 0
    return fj.BSpline(np.column_stack([x, yz]).astype(dtype), degree=3)


def continuity(points, valid, edges, map_points, pieces=8):
    """For each edge with two valid ends, its largest piece's image length over the mean of
    its `pieces` pieces' (1 where the map is smooth along it, about `pieces` where it jumps,
    or where a point of it is invalid, so left in place); `map_points`: (n, 3) → (images,
    valid), with margin 0."""
    valid = np.asarray(valid)
    both = edges[valid[edges[:, 0]] & valid[edges[:, 1]]]
    t = np.linspace(0, 1, pieces + 1)[None, :, None]
    path = points[both[:, :1]] * (1 - t) + points[both[:, 1:]] * t  # (e, pieces + 1, 3)
    images, _ = map_points(path.reshape(-1, 3).astype(points.dtype))
    images = np.asarray(images, np.float64).reshape(path.shape)
    piece = np.linalg.norm(np.diff(images, axis=1), axis=2)
    return piece.max(axis=1) / piece.mean(axis=1)


@pytest.mark.slow  # (`python -m pytest -m slow`; the hairpin test above keeps the guarantee)
@pytest.mark.parametrize(
    "seed, method", [(1, "radial"), (2, "radial"), (2, "normal"), (1, "binormal")]
)
def test_valid_edges_are_never_torn_on_random_wavy_spines(seed, method):
    # Property: random wavy spines (their bends come close to each other), random targets,
    # every point of a lattice around them. Along each edge with two valid ends the map is
    # continuous: mapped in 8 pieces, no piece's image is much longer than the others' (a tear
    # puts the whole jump in one piece: ratio near 8). Without the margin, edges tear.
    rng = np.random.default_rng(seed)
    dtype = "float32"  # (tabulated spines, fast; float64 is the hairpin's and spot's)
    source, target = _wavy(rng, dtype), _wavy(rng, dtype)
    points, edges = lattice((-0.3, -0.75, -0.75), (4.3, 0.75, 0.75), step=0.15)
    points = points.astype(dtype)

    def raw(p):  # the map itself, every point off the cut locus
        return fj.flesh(p, source, target, method=method, check_projection=False)

    images, valid = fj.flesh(points, source, target, method=method, margin=0.075)
    assert np.mean(valid) > 0.3
    assert continuity(points, valid, edges, raw).max() < 3
    if method == "radial":  # the test bites: without the margin, some edges tear
        _, valid = fj.flesh(points, source, target, method=method)
        assert continuity(points, valid, edges, raw).max() > 4.5


@pytest.mark.slow  # (`python -m pytest -m slow`: kept out of the 10-minute suite)
def test_one_point_batched_and_jit_paths_agree_on_the_region():
    source = fj.BSpline(HAIRPIN, degree=3)
    target = fj.Arc(2.0, float(source.length))
    points, _ = lattice((0.0, -0.25, 0.0), (3.2, 1.05, 0.0), step=0.3)
    fleshing = fj.Fleshing(source, target, margin=0.05)
    one = jax.vmap(fleshing.apply)(jnp.asarray(points))
    batched = fj.flesh(points, source, target, margin=0.05)
    jitted = jax.jit(lambda p: fj.flesh(p, source, target, margin=0.05))(jnp.asarray(points))
    for images, valid in (batched, jitted):
        np.testing.assert_array_equal(np.asarray(valid), np.asarray(one[1]))
        np.testing.assert_allclose(np.asarray(images), np.asarray(one[0]), atol=1e-9)
    # The hairpin's middle (y = 0.35 … 0.45 is not on this lattice: y = 0.35) is flagged.
    assert not np.asarray(one[1])[np.abs(points[:, 1] - 0.35) < 1e-9].any()


# float64 with `-m slow`: the pruned and sampled tests are the same code in both dtypes, and
# float32 (posing's per-frame dtype) is the one whose round-off could let a pruned pass slip
# past a sampled failure; each dtype compiled its own program (7 s of CPU each, cold).
@pytest.mark.parametrize("dtype", [pytest.param("float64", marks=pytest.mark.slow), "float32"])
def test_pruned_region_test_agrees_with_the_sampled_test(dtype):
    # Random points around the hairpin (its cut locus and focal sets among them), each with a
    # foot near its own: the pruned test (`surely_clear`, O(runs) a point) passes only points
    # that the sampled test passes, and most of them; the batched two passes (`clear_where`)
    # give the sampled test's flags, bit for bit, with and without a margin.
    rng = np.random.default_rng(3)
    spine = fj.BSpline(HAIRPIN.astype(dtype), degree=3)
    n = 4096
    s = rng.uniform(-0.3, float(spine.length) + 0.3, n).astype(dtype)
    points = np.asarray(jax.vmap(spine)(jnp.asarray(s))) + rng.normal(0, 0.3, (n, 3))
    points, s = points.astype(dtype), (s + rng.normal(0, 0.02, n)).astype(dtype)

    @jax.jit
    def tests(margin):
        region = ValidRegion(spine, margin)
        every = jnp.ones(n, bool)
        batched = clear_where(every, region, ~every, (points, s))
        return (jax.vmap(region.clear)(points, s), jax.vmap(region.surely_clear)(points, s),
                batched)

    for margin in (0.0, STEP / 2):
        sampled, sure, batched = map(np.asarray, tests(jnp.asarray(margin, dtype)))
        assert 0.3 < sampled.mean() < 0.9  # both answers, many of each
        assert not np.any(sure & ~sampled)
        assert sure[sampled].mean() > 0.5
        np.testing.assert_array_equal(batched, sampled)


def test_margin_and_beyond_are_checked():
    line = fj.Line(2.0)
    points = np.zeros((4, 3))
    with pytest.raises(ValueError, match="margin"):
        fj.flesh(points, line, line, margin=-1.0)
    with pytest.raises(ValueError, match="margin"):
        fj.register(points, line, margin=float("nan"))
    with pytest.raises(TypeError, match="margin"):
        fj.flesh(points, line, line, margin="a")
    with pytest.raises(ValueError, match="beyond"):
        fj.flesh(points, line, line, beyond="clamp")


def _tail_case(dtype):
    """A body (a box) behind the start of a tail spine (a line out of it), and the tail bent
    by an arc that starts with the line's frame."""
    rng = np.random.default_rng(0)
    body = rng.uniform([-3, -1, -1], [0, 1, 1], (400, 3))
    tail = np.column_stack([rng.uniform(0.05, 2, 200), rng.uniform(-0.2, 0.2, (200, 2))])
    points = np.concatenate([body, tail]).astype(dtype)
    source = fj.Line(np.asarray(2.0, dtype))
    frame = np.asarray(fj.rotation_minimizing_frame(source, 0.0))
    target = fj.Arc(
        np.asarray(1.5, dtype), np.asarray(2.0, dtype), tangent=frame[0], normal=frame[1]
    )
    return points, source, target, len(body)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_rigid_beyond_keeps_the_body_still_bit_for_bit(dtype):
    points, source, target, n_body = _tail_case(dtype)
    images, valid = fj.flesh(points, source, target, beyond="rigid")
    assert np.asarray(valid).all()
    np.testing.assert_array_equal(np.asarray(images)[:n_body], points[:n_body])
    assert np.abs(np.asarray(images)[n_body:] - points[n_body:]).max() > 0.3  # the tail bent
    # Continued instead, the arc's continuation carries the body round with it.
    moved, _ = fj.flesh(points, source, target)
    assert np.abs(np.asarray(moved)[:n_body] - points[:n_body]).max() > 0.1
    # Per frame (`pose`) and one point at a time, the same.
    posed, _ = fj.pose(fj.register(points, source), target, beyond="rigid")
    np.testing.assert_array_equal(np.asarray(posed)[:n_body], points[:n_body])
    one = jax.vmap(fj.Fleshing(source, target, beyond="rigid"))(jnp.asarray(points[:50]))
    np.testing.assert_array_equal(np.asarray(one), points[:50])


def test_rigid_beyond_moves_with_the_end_frames_and_keeps_volume():
    # Past the end, points follow the end frame rigidly: distances between them are kept,
    # and the map there is a rotation (det J = 1).
    points, source, target, _ = _tail_case("float64")
    beyond = np.array([[2.3, 0.1, 0.0], [2.8, -0.2, 0.3], [2.5, 0.0, -0.4]])
    images, valid = fj.flesh(beyond, source, target, beyond="rigid")
    assert np.asarray(valid).all()
    images = np.asarray(images)
    for i, j in ((0, 1), (1, 2), (0, 2)):
        np.testing.assert_allclose(np.linalg.norm(images[i] - images[j]),
                                   np.linalg.norm(beyond[i] - beyond[j]), rtol=1e-12)  # fmt: skip
    end = np.asarray(target(target.length))
    np.testing.assert_allclose(np.linalg.norm(images[0] - end),
                               np.linalg.norm(beyond[0] - [2.0, 0, 0]), rtol=1e-12)  # fmt: skip
    fleshing = fj.Fleshing(source, target, beyond="rigid")
    det = fj.jacobian_determinant(fleshing, jnp.asarray(beyond))
    np.testing.assert_allclose(np.asarray(det), 1.0, atol=1e-12)
    # (Both measured on the map with its `beyond`: the determinant alone cannot tell.)
    stretch = fj.principal_stretch(fleshing, jnp.asarray(beyond))
    np.testing.assert_allclose(np.asarray(stretch), 1.0, atol=1e-12)


def _tangent(z):
    t = np.array([1.0, 0.3, z])
    return t / np.linalg.norm(t)


# Where `initial_normal` switches from the z axis to the y axis for tangents (1, 0.3, z):
# |t_y| + 1e-4 = |t_z| + 2e-4 (its tie-breaking margins), to 1e-9.
SWITCH = 0.3 - 1e-4 * np.linalg.norm([1.0, 0.3, 0.3])


def test_no_roll_from_the_frame_rule():
    # `initial_normal` picks the coordinate axis least aligned with the tangent: for these two
    # nearly equal tangents, y and then z, normals 90° apart. Posing one line onto the other
    # must not roll the shape about its axis: the target's first normal is the source's,
    # carried by the smallest rotation between the tangents.
    source = fj.Line(3.0, tangent=_tangent(SWITCH - 1e-6))
    points = np.asarray(source(1.5)) + np.array([[0, 0.3, 0], [0, 0, 0.3], [0, -0.2, 0.1]])
    rule = [np.asarray(fj.rotation_minimizing_frame(s, 0.0))[1] for s in (source, fj.Line(
        3.0, tangent=_tangent(SWITCH + 1e-6)))]  # fmt: skip
    assert abs(np.dot(*rule)) < 0.1  # the rule's jump, between the two tangents
    for z in (SWITCH - 1e-6, SWITCH + 1e-6):
        target = fj.Line(3.0, tangent=_tangent(z))
        images, valid = fj.flesh(points, source, target)
        assert np.asarray(valid).all()
        assert np.abs(np.asarray(images) - points).max() < 1e-5  # a turn of 1e-6, no roll


def _spot():
    """Spot (Keenan Crane, CC0), welded: the package's copy, else `../shared/data`."""
    import pathlib

    import trimesh

    loader = getattr(getattr(fj, "data", None), "spot", None)
    if loader is not None:
        return loader()
    path = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data" / "spot.obj"
    if not path.exists():
        pytest.skip(f"spot.obj not found at {path}")
    mesh = trimesh.load(path, process=False)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


@pytest.mark.slow  # (`python -m pytest -m slow`: kept out of the 10-minute suite)
def test_spot_on_wavy_spines_is_never_torn_and_keeps_its_volume():
    # Wavy rest spines through spot's body (head to rump, along −z), bent onto others: the
    # mesh's edges with two valid ends stay continuous; with a straight rest spine every
    # vertex is valid and the volume changes by the flat-face error only.
    mesh = _spot()
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    vertices32, edges = vertices.astype(np.float32), np.asarray(mesh.edges_unique)
    volume = fj.volume(vertices, faces)
    z = np.linspace(1.1, -0.75, 8)
    rng = np.random.default_rng(3)
    lift = np.array([[0.0, 0]] * 4 + [[0.1 * i, 0] for i in range(4)])  # the head turns
    for amplitude in (0.0, 0.15):
        wiggle = rng.uniform(-amplitude, amplitude, (2, 8, 2))
        source, target = (
            fj.BSpline(np.column_stack([w[:, 0], 0.1 + w[:, 1], z]).astype(np.float32), degree=3)
            for w in (wiggle[0], wiggle[1] + lift)
        )
        # (In single precision: tabulated spines, a few seconds.)
        bent, _, valid = fj.deform_mesh((vertices32, faces), source, target)

        def raw(p, source=source, target=target):
            return fj.flesh(p, source, target, check_projection=False)

        assert continuity(vertices32, valid, edges, raw, pieces=4).max() < 2.5
        if amplitude == 0:
            assert valid.all()
            change = fj.volume(np.asarray(bent, np.float64), faces) / volume - 1
            assert abs(change) < 1e-3


@pytest.mark.parametrize("method", ["radial", "binormal"])
def test_rigid_beyond_joins_the_fleshed_part_continuously_where_end_curvatures_differ(method):
    # A line bent onto an arc: the arc's curvature at both ends is not the line's. Points just
    # before and just past each end plane land together (the fleshed points near it give up
    # the cross-section's departure from the rigid one); before the fix they were 0.03 apart.
    source = fj.Line(3.0, origin=(1.0, 0.0, 0.0))
    target = fj.Arc(1.2, 3.0, origin=(1.0, 0.0, 0.0))
    offsets = np.array([[0.0, 0.3, 0.0], [0.0, -0.25, 0.1], [0.0, 0.05, -0.3]])
    eps = 1e-7
    for plane in (1.0, 4.0):
        before = offsets + [plane - eps, 0, 0]
        after = offsets + [plane + eps, 0, 0]
        images, valid = fj.flesh(np.concatenate([before, after]), source, target,
                                 beyond="rigid", method=method)
        images = np.asarray(images)
        assert np.asarray(valid).all()
        np.testing.assert_allclose(images[:3], images[3:], atol=1e-5)
    # Far from the ends the map is the exact one: det J = 1 in the middle. (Radial: the
    # program of `test_rigid_beyond_moves_with_the_end_frames_and_keeps_volume`'s det J.)
    fleshing = fj.Fleshing(source, target, beyond="rigid", method=method)
    det = fj.jacobian_determinant(fleshing, jnp.asarray([[2.5, 0.2, 0.1]]))
    np.testing.assert_allclose(np.asarray(det), 1.0, atol=1e-9)

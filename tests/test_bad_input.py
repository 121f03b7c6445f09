"""Bad input, tried systematically on every public entry point.

Each case must end in a `ValueError`/`TypeError` whose message names the argument, in a
per-point validity flag with the point returned unchanged, or in a correct result: never an
unflagged NaN, a traceback from inside JAX, a hang or a half-written file. Small inputs, and
one point shape (4, 3) wherever a compiled program runs, so that programs are shared.
"""

import json
import os
import signal
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._cli import main
from fleshing_jax._spines.files import MAX_FILE_BYTES, MAX_ROWS

C0, C1 = fj.Line(4.0), fj.Arc(3.0, 4.0)
POINTS = np.array([[0.5, 0.1, 0.0], [1.5, 0.0, 0.2], [2.5, -0.2, 0.1], [3.5, 0.1, -0.1]])
CONTROL = np.array([[0, 0, 0], [1, 0.4, 0.1], [2, 1.2, 0.6], [3, 0.5, 1.4], [4, -0.6, 1.2]])


def _fit(source, **options):
    return fj.fit_spine(C0, fj.Arc(4.0, 4.0), source, source, max_steps=2, **options)


def _fit_cloud(source, **options):
    return fj.fit_spine_to_points(C0, fj.Arc(4.0, 4.0), source, source, max_steps=2, **options)


# Every entry point taking points, as `f(points)`, and the name its errors must give.
POINT_ENTRIES = {
    "flesh": (lambda p: fj.flesh(p, C0, C1), "points"),
    "register": (lambda p: fj.register(p, C0), "points"),
    "jacobian_determinant": (lambda p: fj.jacobian_determinant(fj.Fleshing(C0, C1), p), "points"),
    "deform_mesh": (lambda p: fj.deform_mesh((p, np.zeros((0, 3), int)), C0, C1), "points"),
    "flesh_chunked": (lambda p: fj.flesh_chunked(p, C0, C1), "points"),
    "fit_spine": (_fit, "source"),
    "fit_spine_to_points": (_fit_cloud, "source"),
    "volume": (lambda p: fj.volume(p, [[0, 1, 2]]), "vertices"),
}
BAD_POINTS = {
    "vector": (np.zeros(3), ValueError),
    "two columns": (np.zeros((4, 2)), ValueError),
    "four columns": (np.zeros((4, 4)), ValueError),
    "string": ("abc", TypeError),
    "none": (None, TypeError),
    "complex": (POINTS + 1j, TypeError),
    "ragged": ([[0, 0, 0], [1, 0]], TypeError),
}


@pytest.mark.parametrize("bad", sorted(BAD_POINTS))
@pytest.mark.parametrize("entry", sorted(POINT_ENTRIES))
def test_bad_points_raise_naming_the_argument(entry, bad):
    function, name = POINT_ENTRIES[entry]
    value, error = BAD_POINTS[bad]
    if entry == "volume" and bad == "vector":
        error = ValueError
    with pytest.raises(error, match=f"`{name}`"):
        function(value)


@pytest.mark.parametrize("entry", ["flesh", "register", "deform_mesh", "fit_spine", "volume"])
def test_half_precision_is_refused(entry):
    function, name = POINT_ENTRIES[entry]
    if entry == "volume":  # a volume is a sum: half precision is allowed there
        assert np.isfinite(float(function(POINTS.astype(np.float16))))
        return
    with pytest.raises(TypeError, match=f"`{name}` must be float32 or float64"):
        function(POINTS.astype(np.float16))


@pytest.mark.parametrize("shape", [(2,), (4,), (1, 3)])
def test_fleshing_one_point_shapes(shape):
    with pytest.raises(ValueError, match="`x` must have shape"):
        fj.Fleshing(C0, C1)(np.zeros(shape))


@pytest.fixture(scope="module")
def registration():
    return fj.register(POINTS, C0)


TWIST_ENTRIES = {
    "flesh": lambda t, r: fj.flesh(POINTS, C0, C1, twist=t),
    "pose": lambda t, r: fj.pose(r, C1, twist=t),
    "Fleshing": lambda t, r: fj.Fleshing(C0, C1, twist=t),
    "deform_mesh": lambda t, r: fj.deform_mesh(POINTS, C0, C1, twist=t),
    "fit_spine": lambda t, r: _fit(POINTS, twist=t),
    "fit_spine_to_points": lambda t, r: _fit_cloud(POINTS, twist=t),
}
BAD_TWISTS = {
    "nan": (np.nan, ValueError),
    "inf": (-np.inf, ValueError),
    "vector": (np.zeros(2), ValueError),
    "per point": (np.zeros(4), ValueError),
    "string": ("0.3", TypeError),
    "none": (None, TypeError),
    "complex": (1j, TypeError),
}


@pytest.mark.parametrize("bad", sorted(BAD_TWISTS))
@pytest.mark.parametrize("entry", sorted(TWIST_ENTRIES))
def test_bad_twist_raises(entry, bad, registration):
    value, error = BAD_TWISTS[bad]
    with pytest.raises(error, match="`twist`"):
        TWIST_ENTRIES[entry](value, registration)


METHOD_ENTRIES = {
    "flesh": lambda r: fj.flesh(POINTS, C0, C1, method="radiall"),
    "pose": lambda r: fj.pose(r, C1, method="Radial"),
    "Fleshing": lambda r: fj.Fleshing(C0, C1, method="norm"),
    "deform_mesh": lambda r: fj.deform_mesh(POINTS, C0, C1, method="skinnning"),
    "fit_spine": lambda r: _fit(POINTS, method="binormals"),
    "fit_spine_to_points": lambda r: _fit_cloud(POINTS, method=""),
}


@pytest.mark.parametrize("entry", sorted(METHOD_ENTRIES))
def test_misspelt_method(entry, registration):
    with pytest.raises(ValueError, match="`method` must be one of"):
        METHOD_ENTRIES[entry](registration)


def _odd_points():
    """POINTS with a NaN row, an inf row, a row far outside the reach of the bent target and
    a row on the spine itself: (4, 3), the shape of POINTS."""
    points = POINTS.copy()
    points[0] = [np.nan, 0, 0]
    points[1, 2] = np.inf
    points[2] = [2.0, 5.0, 0.0]  # the arc's centre is at y = 3: beyond it, outside the reach
    points[3] = [3.0, 0.0, 0.0]  # on the spine: goes exactly onto the target
    return points


def _check_flags(points, images, valid):
    images, valid = np.asarray(images), np.asarray(valid)
    np.testing.assert_array_equal(valid, [False, False, False, True])
    np.testing.assert_array_equal(images[:3], points[:3])  # unchanged, NaN and inf included
    np.testing.assert_allclose(images[3], np.asarray(C1(3.0)), atol=1e-12)


@pytest.mark.parametrize(
    "entry", ["flesh", "register+pose", "Fleshing", "deform_mesh", "list", "float32"]
)
def test_non_finite_far_and_on_spine_points(entry):
    points = _odd_points()
    if entry == "flesh":
        _check_flags(points, *fj.flesh(points, C0, C1))
    elif entry == "register+pose":
        _check_flags(points, *fj.pose(fj.register(points, C0), C1))
    elif entry == "Fleshing":
        _check_flags(points, *jax.vmap(fj.Fleshing(C0, C1).apply)(jnp.asarray(points)))
    elif entry == "deform_mesh":
        cloud = fj.deform_mesh(points, C0, C1)
        _check_flags(points, cloud.vertices, cloud.metadata["valid"])
    elif entry == "list":
        _check_flags(points, *fj.flesh(points.tolist(), C0, C1))
    else:
        images, valid = fj.flesh(points.astype(np.float32), C0, C1)
        assert images.dtype == jnp.float32
        np.testing.assert_array_equal(np.asarray(valid), [False, False, False, True])
        np.testing.assert_array_equal(np.asarray(images)[:3], points[:3].astype(np.float32))


def test_jacobian_determinant_flags_invalid_points_with_nan():
    det = np.asarray(fj.jacobian_determinant(fj.Fleshing(C0, C1), _odd_points()))
    assert np.all(np.isnan(det[:3]))
    assert abs(det[3] - 1) < 1e-12


def test_integer_points_are_floats():
    integers = np.array([[1, 0, 0], [2, 0, 0], [3, 0, 0], [1, 0, 1]])
    images, valid = fj.flesh(integers, C0, C1)
    expected, _ = fj.flesh(integers.astype(float), C0, C1)
    assert jnp.issubdtype(images.dtype, jnp.floating) and np.all(valid)
    np.testing.assert_array_equal(np.asarray(images), np.asarray(expected))


@pytest.mark.parametrize("entry", ["flesh", "register+pose", "deform_mesh", "det"])
def test_empty_inputs(entry):
    empty = np.zeros((0, 3))
    if entry == "flesh":
        images, valid = fj.flesh(empty, C0, C1)
    elif entry == "register+pose":
        images, valid = fj.pose(fj.register(empty, C0), C1)
    elif entry == "deform_mesh":
        cloud = fj.deform_mesh(empty, C0, C1)
        images, valid = cloud.vertices, cloud.metadata["valid"]
    else:
        images = valid = fj.jacobian_determinant(fj.Fleshing(C0, C1), empty)
    assert np.shape(images)[0] == 0 and np.shape(valid) == (0,)


@pytest.mark.parametrize(
    "make, name",
    [
        (lambda: fj.Line(0.0), "length"),
        (lambda: fj.Line(-1.0), "length"),
        (lambda: fj.Line(np.nan), "length"),
        (lambda: fj.Line(1.0, tangent=(0, 0, 0)), "tangent"),
        (lambda: fj.Line("1"), "length"),
        (lambda: fj.Arc(0.0, 1.0), "radius"),
        (lambda: fj.Arc(-2.0, 1.0), "radius"),
        (lambda: fj.Arc(2.0, 0.0), "length"),
        (lambda: fj.Arc(2.0, np.inf), "length"),
        (lambda: fj.Arc(2.0, 1.0, normal=(2, 0, 0)), "normal"),
        (lambda: fj.Arc(None, 1.0), "radius"),
        (lambda: fj.Helix(0.0, 1.0, 1.0), "radius"),
        (lambda: fj.Helix(1.0, np.nan, 1.0), "pitch"),
        (lambda: fj.Helix(1.0, 1.0, -1.0), "length"),
        (lambda: fj.BSpline(np.ones((6, 3))), "control_points"),
        (lambda: fj.BSpline(CONTROL.tolist() + [[5, 0, np.nan]]), "control_points"),
        (lambda: fj.BSpline(CONTROL), "control_points"),  # 5 points: too few for degree 5
        (lambda: fj.BSpline(CONTROL, degree=0), "degree"),
        (lambda: fj.BSpline(CONTROL, degree=True), "degree"),
        (lambda: fj.BSpline(np.arange(300.0).reshape(100, 3), degree=99), "degree"),
        (lambda: fj.BSpline(CONTROL, degree=3, subdivisions=0), "subdivisions"),
        (lambda: fj.BSpline(CONTROL, degree=3, subdivisions=10**8), "subdivisions"),
        (lambda: fj.BSpline(CONTROL + 1j, degree=3), "control_points"),
        (lambda: fj.InterpolatingPolynomial(CONTROL[:1]), "points"),
        (lambda: fj.InterpolatingPolynomial(CONTROL[[0, 1, 1, 2]]), "points"),
        (lambda: fj.InterpolatingPolynomial(np.arange(90.0).reshape(30, 3)), "points"),
        (lambda: fj.Polyline(CONTROL[:1]), "points"),
        (lambda: fj.Polyline(CONTROL[[0, 1, 1, 2]]), "points"),
        (lambda: fj.Polyline(CONTROL, step=0.0), "step"),
        (lambda: fj.Polyline(CONTROL, step=np.nan), "step"),
        (lambda: fj.Polyline(CONTROL, step=1e-9), "step"),
        (lambda: fj.Polyline(CONTROL[[0, 1, 0]]), "points"),  # turns back on itself
    ],
)
def test_degenerate_spines_raise(make, name):
    with pytest.raises((ValueError, TypeError), match=f"`{name}"):
        make()


def test_float32_high_degree_polynomial_is_refused():
    """20 points: the float32 pieces missed the polynomial by percents (length 2× wrong)."""
    s = np.linspace(0, 1, 20)
    points = np.stack([4.5 * s, 0.6 * np.sin(3 * s), 0.4 * s**2], axis=1)
    with pytest.raises(ValueError, match="`points`.*float32"):
        fj.InterpolatingPolynomial(points.astype(np.float32))
    exact = fj.InterpolatingPolynomial(points)  # float64: accurate, accepted
    chords = np.sum(np.linalg.norm(np.diff(points, axis=0), axis=-1))
    assert chords < float(exact.length) < 1.01 * chords
    low = fj.InterpolatingPolynomial(points[::4].astype(np.float32))  # degree 4: fine
    assert abs(float(low.length) - float(fj.InterpolatingPolynomial(points[::4]).length)) < 1e-5


def test_degenerate_but_valid_spines_give_correct_results():
    # Collinear control points: a straight line; a helix of zero pitch: a circle.
    line = fj.BSpline([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0], [5, 0, 0]])
    assert abs(float(line.length) - 5) < 1e-12
    circle = fj.Helix(3.0, 0.0, 4.0)  # starts at (3, 0, 0) along +y, turning about the z axis
    images, valid = fj.flesh(POINTS, C0, circle)
    arc = fj.Arc(3.0, 4.0, origin=(3, 0, 0), tangent=(0, 1, 0), normal=(-1, 0, 0))
    expected, ok = fj.flesh(POINTS, C0, arc)
    assert np.all(valid) and np.all(ok)
    np.testing.assert_allclose(np.asarray(images), np.asarray(expected), atol=1e-10)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_tiny_and_multi_turn_arcs_flag_points_unchanged(dtype):
    """`Arc(1e-30, 4)` (1e29 turns) and an arc of 1.5 turns, as source and as target: the
    points that have no unique projection or image are flagged and returned unchanged."""
    points = POINTS.astype(dtype)
    for source, target in [
        (fj.Arc(1e-30, 4.0), C1),
        (C0, fj.Arc(1e-30, 4.0)),
        (fj.Arc(0.4, 4.0), C1),  # 1.6 turns: the points around it are ambiguous
    ]:
        images, valid = (np.asarray(v) for v in fj.flesh(points, source, target))
        assert np.all(np.isfinite(images))
        np.testing.assert_array_equal(images[~valid], points[~valid])
        assert not np.all(valid)
    image, ok = fj.Fleshing(fj.Arc(1e-30, 4.0), C1).apply(POINTS[0])
    assert not bool(ok) and np.array_equal(np.asarray(image), POINTS[0])


def test_spine_lengths_100_times_apart():
    small, large = fj.Line(0.04), fj.Arc(300.0, 4.0)
    points = POINTS * np.array([0.01, 0.01, 0.01])
    images, valid = fj.flesh(points, small, large)
    assert np.all(valid) and np.all(np.isfinite(np.asarray(images)))
    back, ok = fj.flesh(images, large, small)
    assert np.all(ok)
    np.testing.assert_allclose(np.asarray(back), points, atol=1e-12)
    det = fj.jacobian_determinant(fj.Fleshing(small, large), points)
    np.testing.assert_allclose(np.asarray(det), 1, atol=1e-10)


def test_volume_face_indices_are_checked():
    vertices = np.eye(4)[:, :3]
    for faces, index in [([[0, 1, 4]], "4"), ([[0, 1, -1]], "-1")]:
        with pytest.raises(ValueError, match=rf"`faces` must index the 4 vertices.*= {index}"):
            fj.volume(vertices, faces)
    with pytest.raises(TypeError, match="`faces`"):
        fj.volume(vertices, [[0.0, 1.0, 2.0]])
    with pytest.raises(Exception, match="`faces` must index the vertices"):
        jax.jit(fj.volume)(vertices, jnp.asarray([[0, 1, 7]]))
    assert np.isfinite(float(jax.jit(fj.volume)(vertices, jnp.asarray([[0, 1, 2]]))))


@pytest.mark.parametrize("chunk_size, error", [(0, ValueError), (-3, ValueError),
                                               (2.5, TypeError), (True, TypeError)])  # fmt: skip
def test_deform_mesh_chunk_size(chunk_size, error):
    with pytest.raises(error, match="`chunk_size`"):
        fj.deform_mesh(POINTS, C0, C1, chunk_size=chunk_size)


def test_deform_mesh_bad_faces_and_types():
    with pytest.raises(ValueError, match="`mesh` faces must index"):
        fj.deform_mesh((POINTS, [[0, 1, 9]]), C0, C1)
    with pytest.raises(TypeError, match="`mesh`"):
        fj.deform_mesh("abc", C0, C1)
    with pytest.raises(TypeError, match="`source`"):
        fj.flesh(POINTS, "line", C1)


# Spine files: each bad file gives one ValueError naming the file and the field, quickly.
BAD_FILES = {
    "not json": ("{'type': 'line'", "not valid JSON"),
    "not an object": ("[1, 2, 3]", "JSON object"),
    "unknown type": ('{"type": "spiral", "length": 1}', "'type'"),
    "missing field": ('{"type": "arc", "radius": 1.0}', "'length'"),
    "mistyped field": ('{"type": "arc", "radius": "1", "length": 1.0}', "'radius'"),
    "bool degree": ('{"type": "bspline", "control_points": [[0,0,0],[1,0,0]], "degree": true}',
                    "'degree'"),
    "unknown field": ('{"type": "line", "length": 1.0, "colour": 3}', "'colour'"),
    "nan": ('{"type": "line", "length": NaN}', "'length'"),
    "rejected value": ('{"type": "line", "length": -1.0}', "`length`"),
    "huge subdivisions": ('{"type": "bspline", "control_points": [[0,0,0],[1,0,0],[2,1,0]], '
                          '"degree": 2, "subdivisions": 100000000}', "`subdivisions`"),
    "tiny step": ('{"type": "polyline", "points": [[0,0,0],[1,0,0]], "step": 1e-9}', "`step`"),
    "too many rows": (json.dumps({"type": "polyline", "points": [[i, 0, 0] for i in
                                                                 range(MAX_ROWS + 1)]}),
                      "'points' must have at most"),
    "deep nesting": ("[" * 100_000 + "]" * 100_000, "not valid JSON"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_spine_files(case, tmp_path):
    content, words = BAD_FILES[case]
    path = tmp_path / "spine.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=words) as info:
        fj.load_spine(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_oversized_and_missing_spine_files(tmp_path):
    path = tmp_path / "big.json"
    with open(path, "wb") as file:
        file.truncate(MAX_FILE_BYTES + 1)  # sparse: refused by its size, never read
    with pytest.raises(ValueError, match="more than a spine file may hold"):
        fj.load_spine(path)
    with pytest.raises(FileNotFoundError, match="no such spine file"):
        fj.load_spine(tmp_path / "missing.json")
    with pytest.raises(TypeError, match="`spine`"):
        fj.save_spine("line", tmp_path / "x.json")


_KILLED_SAVE = textwrap.dedent(
    """
    import os, signal, sys
    import fleshing_jax as fj
    os.fsync = lambda fd: os.kill(os.getpid(), signal.SIGKILL)  # killed mid-save
    fj.save_spine(fj.BSpline([[0, 0, 0], [1, 1, 0], [2, 0, 1], [3, 1, 1]], degree=3), sys.argv[1])
    """
)


def test_save_spine_is_atomic_and_cleans_stale_temporaries(tmp_path, monkeypatch):
    path = tmp_path / "spine.json"
    fj.save_spine(C1, path)
    before = path.read_text()
    # A process killed while saving leaves the previous file intact (and a temporary file).
    run = subprocess.run([sys.executable, "-c", _KILLED_SAVE, str(path)], capture_output=True)
    assert run.returncode == -signal.SIGKILL
    assert path.read_text() == before
    stale = [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    assert len(stale) == 1 and stale[0].name.startswith(".spine.json.")

    # An interrupted save in this process cleans up after itself.
    def interrupt(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupt)
    with pytest.raises(KeyboardInterrupt):
        fj.save_spine(C0, path)
    monkeypatch.undo()
    assert path.read_text() == before
    assert sorted(tmp_path.iterdir()) == sorted([path, stale[0]])
    # The next save removes the stale temporary file (older than a save can take).
    os.utime(stale[0], (0, 0))
    fj.save_spine(C0, path)
    assert sorted(tmp_path.iterdir()) == [path]
    assert isinstance(fj.load_spine(path), fj.Line)


# The command line: one-line errors, exit status 2, no output file.
@pytest.fixture(scope="module")
def cli_files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli")
    fj.save_spine(fj.Line(4.0), tmp / "a.json")
    fj.save_spine(fj.Arc(2.0, 4.0, normal=(0.0, 0.0, -1.0)), tmp / "b.json")
    box = trimesh.creation.box((4.0, 0.6, 0.6))
    box.apply_translation((2.0, 0.0, 0.0))
    box.export(str(tmp / "in.obj"))
    (tmp / "empty.obj").write_text("")
    (tmp / "garbage.obj").write_bytes(np.random.default_rng(0).bytes(2000))
    nan = box.copy()
    nan.vertices[0] = np.nan
    (tmp / "nan.obj").write_text(
        "".join(f"v {x} {y} {z}\n" for x, y, z in nan.vertices)
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in nan.faces)
    )
    (tmp / "huge.json").write_text(
        '{"type": "polyline", "points": [[0,0,0],[4,0,0]], "step": 1e-9}'
    )
    (tmp / "folder.obj").mkdir()
    return tmp


def _deform_argv(tmp, input="in.obj", output="out.ply", *extra):
    return ["deform", str(tmp / input), str(tmp / output), "--from", str(tmp / "a.json"),
            "--to", str(tmp / "b.json"), *extra]  # fmt: skip


CLI_CASES = {
    "missing input": (dict(input="nope.obj"), ["nope.obj"]),
    "empty input": (dict(input="empty.obj"), ["empty.obj"]),
    "garbage input": (dict(input="garbage.obj"), ["garbage.obj", "mesh"]),
    "input is a folder": (dict(input="folder.obj"), ["folder.obj"]),
    "non-finite vertices": (dict(input="nan.obj"), ["nan.obj", "non-finite"]),
    "no output folder": (dict(output="no/such/out.ply"), ["does not exist"]),
    "unknown format": (dict(output="out.xyz123"), ["extension", ".xyz123"]),
    "output is a folder": (dict(output="folder.obj"), ["folder"]),
    "nan twist": (dict(extra=("--twist", "nan")), ["`twist`", "finite"]),
    "huge spine": (dict(spine="huge.json"), ["huge.json", "`step`"]),
}


@pytest.mark.parametrize("case", sorted(CLI_CASES))
def test_cli_errors(case, cli_files, capsys):
    options, words = CLI_CASES[case]
    tmp = cli_files
    argv = _deform_argv(tmp, options.get("input", "in.obj"), options.get("output", "out.ply"),
                        *options.get("extra", ()))  # fmt: skip
    if "spine" in options:
        argv[argv.index(str(tmp / "b.json"))] = str(tmp / options["spine"])
    code = main(argv)
    _, err = capsys.readouterr()
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fleshing-jax: error: "), err
    assert "Traceback" not in err and ".tmp" not in err
    for word in words:
        assert word in lines[0], lines[0]
    assert not (tmp / "out.ply").exists() and not (tmp / "out.xyz123").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads and writes regardless of modes")
def test_cli_unreadable_input_and_unwritable_folder(cli_files, capsys, tmp_path):
    tmp = cli_files
    unreadable = tmp_path / "unreadable.obj"
    unreadable.write_bytes((tmp / "in.obj").read_bytes())
    unreadable.chmod(0)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        assert main(_deform_argv(tmp, str(unreadable))) == 2
        assert "unreadable.obj" in capsys.readouterr().err
        assert main(_deform_argv(tmp, output=str(locked / "out.ply"))) == 2
        assert "not writable" in capsys.readouterr().err
    finally:
        locked.chmod(0o700)
        unreadable.chmod(0o600)


_KILLED_WRITE = textwrap.dedent(
    """
    import os, signal, sys
    import trimesh
    from fleshing_jax._cli import main
    export = trimesh.Trimesh.export
    def killed(self, *args, **kwargs):
        data = export(self, *args, **kwargs)
        os.write(sys.stdout.fileno(), b"exported\\n")
        os.kill(os.getpid(), signal.SIGKILL)  # killed while writing the file
    trimesh.Trimesh.export = killed
    sys.exit(main(sys.argv[1:]))
    """
)


def test_cli_killed_while_writing_leaves_no_partial_file(cli_files):
    tmp = cli_files
    out = tmp / "killed.ply"
    run = subprocess.run(
        [sys.executable, "-c", _KILLED_WRITE, *_deform_argv(tmp, output="killed.ply")],
        capture_output=True,
        timeout=300,
    )
    assert run.returncode == -signal.SIGKILL and b"exported" in run.stdout, run.stderr[-2000:]
    assert not out.exists()

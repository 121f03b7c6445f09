import json
import os
import stat
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import fleshing_jax as fj
from fleshing_jax._cli import main


@pytest.fixture
def files(tmp_path):
    fj.save_spine(fj.Line(4.0), tmp_path / "a.json")
    fj.save_spine(fj.Arc(1.6, 4.0, normal=(0.0, 0.0, -1.0)), tmp_path / "b.json")
    mesh = fj.creature(segments=12, around=8)
    mesh.export(str(tmp_path / "in.obj"))
    return tmp_path, mesh


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _assert_one_line_error(code, err, *words):
    assert code != 0
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fleshing-jax: error: ")
    for word in words:
        assert word in lines[0]


def test_deform(files, capsys):
    tmp, mesh = files
    out_path = tmp / "out.ply"
    code, out, err = _run(
        capsys,
        "deform",
        tmp / "in.obj",
        out_path,
        "--from",
        tmp / "a.json",
        "--to",
        tmp / "b.json",
        "--method",
        "radial",
    )
    assert code == 0, err
    assert "volume before" in out and "volume after" in out
    assert "invalid vertices: 0 of" in out
    back = trimesh.load(str(out_path), process=False)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    expected = fj.deform_mesh(mesh, fj.Line(4.0), fj.Arc(1.6, 4.0, normal=(0, 0, -1.0)))
    np.testing.assert_allclose(back.vertices, expected.vertices, atol=1e-5)
    assert sorted(p.name for p in tmp.iterdir()) == ["a.json", "b.json", "in.obj", "out.ply"]


def test_deform_measures_and_refuses_stretch_as_pose_does(files, capsys):
    # One rule for every entry point (issue 47 item 4): the largest change of an edge between
    # valid vertices and the map's principal stretch are printed, and a bend beyond
    # --max-stretch is not written (status 3).
    tmp, mesh = files
    out_path = tmp / "out.ply"
    args = ["deform", tmp / "in.obj", out_path, "--from", tmp / "a.json", "--to",
            tmp / "b.json"]
    code, out, err = _run(capsys, *args)
    assert code == 0, err
    line = next(x for x in out.splitlines() if x.startswith("largest edge stretch"))
    edge = float(line.split(": ")[1].split("×")[0])
    principal = float(line.split("principal stretch of the map: ")[1].split("×")[0])
    bent = np.asarray(trimesh.load(str(out_path), process=False).vertices)
    np.testing.assert_allclose(edge, float(np.max(fj.edge_stretch(mesh, bent))), rtol=2e-3)
    assert 1 < edge < principal * 1.5 and principal > 1
    out_path.unlink()
    code, _, err = _run(capsys, *args, "--max-stretch", 0.5 * (1 + min(edge, principal)))
    assert code == 3 and "--max-stretch" in err and not out_path.exists()


def test_missing_input(files, capsys):
    tmp, _ = files
    out_path = tmp / "out.obj"
    code, _, err = _run(
        capsys,
        "deform",
        tmp / "nope.obj",
        out_path,
        "--from",
        tmp / "a.json",
        "--to",
        tmp / "b.json",
    )
    _assert_one_line_error(code, err, "nope.obj")
    assert not out_path.exists()


@pytest.mark.parametrize(
    "content,words",
    [
        ("{not json", ["bad.json", "JSON"]),
        (json.dumps({"type": "arc", "radius": 1.0}), ["bad.json", "'length'"]),
        (json.dumps({"type": "arc", "radius": -1.0, "length": 2.0}), ["bad.json", "radius"]),
        (json.dumps({"type": "spiral", "length": 2.0}), ["bad.json", "'type'"]),
        (json.dumps({"type": "line", "length": 2.0, "origin": [0, 0]}), ["bad.json", "'origin'"]),
        (json.dumps({"type": "line", "length": "2"}), ["bad.json", "'length'"]),
    ],
)
def test_malformed_spine(files, capsys, content, words):
    tmp, _ = files
    (tmp / "bad.json").write_text(content)
    out_path = tmp / "out.obj"
    out_path.write_text("previous")
    code, _, err = _run(
        capsys,
        "deform",
        tmp / "in.obj",
        out_path,
        "--from",
        tmp / "a.json",
        "--to",
        tmp / "bad.json",
    )
    _assert_one_line_error(code, err, *words)
    assert out_path.read_text() == "previous"


def test_non_mesh_input(files, capsys):
    tmp, _ = files
    for name, content in (("notes.obj", "hello world\n"), ("notes.txt", "hello world\n")):
        (tmp / name).write_text(content)
        code, _, err = _run(
            capsys,
            "deform",
            tmp / name,
            tmp / "out.obj",
            "--from",
            tmp / "a.json",
            "--to",
            tmp / "b.json",
        )
        _assert_one_line_error(code, err, name)
        assert not (tmp / "out.obj").exists()


def test_bad_method_is_a_usage_error(files, capsys):
    tmp, _ = files
    code, _, err = _run(
        capsys,
        "deform",
        tmp / "in.obj",
        tmp / "o.obj",
        "--from",
        tmp / "a.json",
        "--to",
        tmp / "b.json",
        "--method",
        "magic",
    )
    assert code == 2 and "invalid choice" in err and "Traceback" not in err


def test_spine_json_round_trip(tmp_path):
    spines = [
        fj.Line(2.0, origin=(1.0, 2.0, 3.0), tangent=(0.0, 0.0, 1.0)),
        fj.Arc(2.0, 3.0, origin=(0.0, 1.0, 0.0), tangent=(1.0, 0.0, 0.0), normal=(0, 0, 1.0)),
        fj.Helix(1.0, 0.5, 6.0),
    ]
    for spine in spines:
        path = tmp_path / "s.json"
        fj.save_spine(spine, path)
        data = json.loads(path.read_text())
        assert data["type"] == type(spine).__name__.lower()
        back = fj.load_spine(path)
        assert type(back) is type(spine)
        for s in (0.0, 0.7, 1.9):
            np.testing.assert_allclose(np.asarray(back(s)), np.asarray(spine(s)), atol=1e-14)
    example = {
        "type": "arc",
        "radius": 2.0,
        "length": 3.0,
        "origin": [0, 0, 0],
        "tangent": [1, 0, 0],
        "normal": [0, 1, 0],
    }
    (tmp_path / "e.json").write_text(json.dumps(example))
    arc = fj.load_spine(tmp_path / "e.json")
    assert float(arc.radius) == 2.0 and float(arc.length) == 3.0


def test_demo(tmp_path, capsys):
    out_dir = tmp_path / "demo"
    code, out, err = _run(capsys, "demo", "--out", out_dir)
    assert code == 0, err
    for method in fj.METHODS:
        assert (out_dir / f"creature-{method}.obj").is_file()
        line = next(ln for ln in out.splitlines() if ln.startswith(method))
        change = float(line.split()[2].rstrip("%")) / 100
        if method == "skinning":
            assert abs(change) > 0.03
        else:
            assert abs(change) < 1e-3
    png = (out_dir / "demo.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_help_and_version_do_not_import_jax():
    # `--help` must answer at once: no JAX import before a command runs (fresh process).
    script = (
        "import sys\n"
        "from fleshing_jax._cli import main\n"
        "assert main(['--version']) == 0\n"
        "assert main(['deform', '--help']) == 0\n"
        "assert 'jax' not in sys.modules, 'jax imported'\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert f"fleshing-jax {fj.__version__}" in done.stdout
    assert '"type": "line"' in done.stdout  # the spine format, with a line example


def test_bend_angle_reports_the_largest_valid_bend(files, capsys):
    tmp, mesh = files
    out_path = tmp / "out.obj"
    args = ("deform", tmp / "in.obj", out_path, "--from", tmp / "a.json", "--bend-angle", 300)
    code, out, err = _run(capsys, *args)
    # 300° of a 4-unit line is far too tight for the creature: invalid vertices, by cause,
    # and the torn mesh is not written unless asked for.
    assert code == 3 and "--allow-invalid" in err and not out_path.exists()
    # Allowed, it is still refused past --max-stretch (one rule with `pose`), then written.
    code, out, err = _run(capsys, *args, "--allow-invalid", "--max-stretch", 1.5)
    assert code == 3 and "--max-stretch" in err and not out_path.exists()
    code, out, err = _run(capsys, *args, "--allow-invalid", "--max-stretch", 1e3)
    assert code == 0, err
    invalid = int(out.split("invalid vertices: ")[1].split()[0])
    causes = [int(ln.rsplit(":", 1)[1]) for ln in out.splitlines() if ln.startswith("  ")]
    assert invalid > 0 and len(causes) == 4 and sum(causes) == invalid
    angle = float(out.split("keeping every vertex valid (radial): ")[1].split()[0])
    # At that angle, every vertex is valid (but those outside the rest spine's reach, which no
    # bend can make valid); 2 % more and some are not.
    registered = np.asarray(fj.register(np.asarray(mesh.vertices), fj.Line(4.0)).valid)
    normal = fj.initial_normal(jnp.array([1.0, 0, 0]))
    for factor, all_valid in ((1.0, True), (1.02, False)):
        target = fj.Arc(4.0 / np.radians(angle * factor), 4.0, normal=normal)
        ok = fj.deform_mesh(mesh, fj.Line(4.0), target).vertex_attributes["valid"]
        assert ok[registered].all() == all_valid
    assert "mtllib" not in out_path.read_text()


def test_bend_angle_beyond_a_turn_refused_before_work(files, capsys):
    tmp, _ = files
    out_path = tmp / "out.obj"
    for angle in (400, -360):
        code, out, err = _run(capsys, "deform", tmp / "in.obj", out_path, "--from",
                              tmp / "a.json", "--bend-angle", angle)  # fmt: skip
        assert code == 2 and "--bend-angle" in err and "360" in err and not out_path.exists()
        assert "volume" not in out  # refused before the mesh was read


def test_output_checked_before_any_work(files, capsys):
    tmp, _ = files
    for output, words in (
        (tmp / "out.xyz123", ["out.xyz123", "extension", ".ply"]),
        (tmp / "no-extension", ["no-extension", "no extension"]),
        (tmp / "missing" / "out.obj", ["missing", "does not exist"]),
    ):
        code, out, err = _run(
            capsys, "deform", tmp / "in.obj", output, "--from", tmp / "a.json", "--to",
            tmp / "b.json",
        )  # fmt: skip
        _assert_one_line_error(code, err, *words)
        assert out == ""  # nothing was bent
        assert ".tmp" not in err


def test_output_permissions_follow_the_umask(files, capsys):
    tmp, _ = files
    previous = os.umask(0o022)
    try:
        code, _, err = _run(
            capsys, "deform", tmp / "in.obj", tmp / "o.ply", "--from", tmp / "a.json", "--to",
            tmp / "b.json",
        )  # fmt: skip
    finally:
        os.umask(previous)
    assert code == 0, err
    assert stat.S_IMODE((tmp / "o.ply").stat().st_mode) == 0o644


def test_open_mesh_advice_and_cap_holes(tmp_path, capsys):
    fj.save_spine(fj.Line(4.0), tmp_path / "a.json")
    fj.save_spine(fj.Arc(3.0, 4.0), tmp_path / "b.json")
    closed = fj.creature(segments=12, around=8)
    keep = np.ones(len(closed.faces), bool)
    keep[:3] = False  # a hole
    trimesh.Trimesh(closed.vertices, closed.faces[keep], process=False).export(
        str(tmp_path / "open.obj")
    )
    args = ["deform", tmp_path / "open.obj", tmp_path / "o.obj", "--from", tmp_path / "a.json"]
    code, out, err = _run(capsys, *args, "--to", tmp_path / "b.json")
    assert code == 0, err
    assert "not closed" in out and "--cap-holes" in out
    code, out, err = _run(capsys, *args, "--to", tmp_path / "b.json", "--cap-holes")
    assert code == 0, err
    assert "not closed" not in out and "--cap-holes" not in out
    # Without a rest spine, an open mesh is refused with the way out.
    code, out, err = _run(capsys, *args[:3], "--bend-angle", 30)
    _assert_one_line_error(code, err, "closed mesh", "--cap-holes", "--from")


def test_compilation_cache_folder(monkeypatch, tmp_path):
    from fleshing_jax import _cache

    monkeypatch.setenv(_cache.ENVIRONMENT_VARIABLE, "off")
    assert _cache.cache_folder() is None
    monkeypatch.setenv(_cache.ENVIRONMENT_VARIABLE, str(tmp_path / "c"))
    assert _cache.cache_folder() == tmp_path / "c"
    monkeypatch.delenv(_cache.ENVIRONMENT_VARIABLE)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    if sys.platform.startswith("linux"):
        assert _cache.cache_folder() == tmp_path / "xdg" / "fleshing-jax" / "jax-compilation-cache"


def test_compilation_cache_through_jax_environment_variables(monkeypatch, tmp_path):
    # The commands ask for the cache through JAX's variables, read when JAX is imported by the
    # command's process; `jax.config` is never changed, and a user's own setting wins.
    import jax

    from fleshing_jax import _cache

    before = jax.config.jax_compilation_cache_dir
    for name in ("DIR", "MIN_COMPILE_TIME_SECS", "MIN_ENTRY_SIZE_BYTES"):
        prefix = "JAX_COMPILATION_CACHE_" if name == "DIR" else "JAX_PERSISTENT_CACHE_"
        monkeypatch.delenv(prefix + name, raising=False)  # restored after the test
    monkeypatch.setenv(_cache.ENVIRONMENT_VARIABLE, str(tmp_path / "c"))
    assert _cache.enable_compilation_cache() == tmp_path / "c"
    assert os.environ["JAX_COMPILATION_CACHE_DIR"] == str(tmp_path / "c")
    assert (tmp_path / "c").is_dir() and jax.config.jax_compilation_cache_dir == before
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "mine"))
    _cache.enable_compilation_cache()
    assert os.environ["JAX_COMPILATION_CACHE_DIR"] == str(tmp_path / "mine")
    monkeypatch.setenv(_cache.ENVIRONMENT_VARIABLE, "off")
    assert _cache.enable_compilation_cache() is None


def test_beyond_rigid_keeps_the_body_still(tmp_path, capsys):
    # A body (a box) and a tail (a cylinder along +x from the box's face); the rest spine runs
    # along the tail only and the bent one curls it. Rigid beyond the start, the body's
    # vertices are written where they were; continued, they are carried round.
    import trimesh

    body = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    body.apply_translation((-1.0, 0, 0))
    tail = trimesh.creation.cylinder(radius=0.15, height=2.0, sections=12)
    tail.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    tail.apply_translation((1.0, 0, 0))
    mesh = trimesh.util.concatenate([body, tail])
    mesh.export(str(tmp_path / "in.obj"))
    fj.save_spine(fj.Line(2.0), tmp_path / "a.json")
    normal = np.asarray(fj.rotation_minimizing_frame(fj.Line(2.0), 0.0))[1]
    fj.save_spine(fj.Arc(1.2, 2.0, normal=tuple(normal)), tmp_path / "b.json")
    moved = {}
    for beyond in ("rigid", "continue"):
        out = tmp_path / f"{beyond}.obj"
        code, _, err = _run(capsys, "deform", tmp_path / "in.obj", out, "--from",
                            tmp_path / "a.json", "--to", tmp_path / "b.json", "--beyond",
                            beyond, "--allow-invalid")  # fmt: skip
        assert code == 0, err
        result = trimesh.load(str(out), process=False)
        moved[beyond] = np.abs(np.asarray(result.vertices) - mesh.vertices)[: len(body.vertices)]
    assert moved["rigid"].max() < 1e-6 and moved["continue"].max() > 0.1

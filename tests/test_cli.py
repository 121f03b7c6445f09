import json

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

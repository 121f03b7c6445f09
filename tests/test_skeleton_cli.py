"""`fleshing-jax skeleton IN OUT.json`: the limbs' table and the skeleton file."""

import numpy as np
import pytest

import fleshing_jax as fj
from fleshing_jax._cli import main


def test_skeleton_command_prints_the_limbs_and_writes_the_file(table_file, tmp_path, capsys):
    out = tmp_path / "table.json"
    assert main(["skeleton", str(table_file), str(out), "--spheres", "30", "--seed", "1"]) == 0
    printed = capsys.readouterr().out
    skeleton = fj.load_skeleton(out)
    assert len(skeleton.children(-1)) == 4  # the legs (each a chain from the top)
    count = len(skeleton.limbs)
    rows = [line.split() for line in printed.splitlines()[1 : 1 + count]]
    assert len(rows) == count
    region = np.asarray(skeleton.region)
    for i, row in enumerate(rows):
        limb = skeleton.limbs[i]
        assert int(row[0]) == i and int(row[1]) == limb.parent
        assert float(row[2]) == pytest.approx(float(limb.spine.length), rel=1e-4)
        assert float(row[3]) == pytest.approx(float(limb.joint), rel=1e-4)
        assert int(row[4]) == np.sum(region == i)
        end = np.array([float(v) for v in row[5].split(",")])
        assert end[2] < 0.05  # the leg's foot
    assert f"body: {np.sum(region == -1)} vertices" in printed
    assert len(region) == len(fj.load_mesh(table_file).vertices)
    assert not list(tmp_path.glob(".*.tmp"))


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--spheres", "1"], "--spheres"),
        (["--seed", "-1"], "--seed"),
    ],
)
def test_skeleton_command_refuses_bad_options(table_file, tmp_path, capsys, arguments, message):
    out = tmp_path / "out.json"
    assert main(["skeleton", str(table_file), str(out), *arguments]) == 2
    assert message in capsys.readouterr().err and not out.exists()


def test_skeleton_command_refuses_bad_files(table_file, tmp_path, capsys):
    assert main(["skeleton", str(tmp_path / "missing.obj"), str(tmp_path / "a.json")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["skeleton", str(table_file), str(tmp_path / "a.obj")]) == 2
    assert ".json" in capsys.readouterr().err
    assert main(["skeleton", str(table_file), str(tmp_path / "no" / "a.json")]) == 2
    assert "does not exist" in capsys.readouterr().err

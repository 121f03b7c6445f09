"""`fj.plot_skeleton` and `fleshing-jax skeleton --png`: the picture an animator checks a
skeleton on (regions coloured, spines, joints, limb numbers, the model upright)."""

import json

import matplotlib
import numpy as np
import pytest
from _skeleton_rigs import quadruped_rig

import fleshing_jax as fj
from fleshing_jax._cli import main
from fleshing_jax._skeleton import build
from fleshing_jax._skeleton.plot import guess_up, up_rotation

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Path3DCollection, Poly3DCollection  # noqa: E402

PNG = b"\x89PNG\r\n\x1a\n"


# The skeleton tests' rigs: spot (y up; conftest) and quadruped(32) (z up; `_skeleton_rigs`).
@pytest.fixture(scope="module")
def spot(spot_rig):
    return spot_rig[0], spot_rig[2]


@pytest.fixture(scope="module")
def animal():
    mesh, _, skeleton = quadruped_rig()
    return mesh, skeleton


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def _parts(figure):
    (ax,) = figure.axes
    (mesh,) = [c for c in ax.collections if isinstance(c, Poly3DCollection)]
    dots = [c for c in ax.collections if isinstance(c, Path3DCollection)]
    return ax, mesh, dots


def _spine(limb, s):
    return np.asarray(limb.spine(s), np.float64)


def test_each_face_is_coloured_by_its_region(spot):
    mesh, skeleton = spot
    ax, drawn, _ = _parts(fj.plot_skeleton(mesh, skeleton))
    faces, region = np.asarray(mesh.faces), np.asarray(skeleton.region)
    assert len(drawn.get_facecolor()) == len(faces)  # one coloured face per mesh face
    colours = np.asarray(drawn._facecolor3d)  # in the faces' order (matplotlib sorts the 2D ones)
    assert colours.shape == (len(faces), 4) and np.ptp(colours[:, 3]) == 0
    assert 0 < colours[0, 3] < 1  # translucent: the spines show through
    # Lit faces: each a shade of its region's colour, the same colour scaled.
    base = colours[:, :3] / colours[:, :3].max(axis=1, keepdims=True)
    pure = region[faces[:, 0]] == region[faces[:, 1]]
    pure &= region[faces[:, 1]] == region[faces[:, 2]]
    owners = region[faces[pure, 0]]
    shown = {}
    for r in np.unique(region):
        mine = base[pure][owners == r]
        assert len(mine) and np.ptp(mine, axis=0).max() < 1e-9, f"region {r} has many colours"
        shown[int(r)] = mine[0]
    np.testing.assert_allclose(shown[-1], [1, 1, 1])  # the body grey
    limbs = np.array([shown[i] for i in range(len(skeleton.limbs))])
    gaps = np.linalg.norm(limbs[:, None] - limbs[None], axis=2) + np.eye(len(limbs))
    assert gaps.min() > 0.1  # distinct limbs, distinct colours
    assert np.ptp(limbs, axis=1).min() > 0.1  # none of them grey


def test_spines_joints_and_numbers_are_drawn_on_the_upright_model(spot):
    mesh, skeleton = spot
    ax, _, dots = _parts(fj.plot_skeleton(mesh, skeleton, up="y"))
    turn = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # y up: (x, y, z) → (x, −z, y)
    lines, texts = ax.get_lines(), ax.texts
    assert len(lines) == len(dots) == len(texts) == len(skeleton.limbs)
    assert [t.get_text() for t in texts] == [str(i) for i in range(len(skeleton.limbs))]
    for limb, line, dot, text in zip(skeleton.limbs, lines, dots, texts):
        drawn = np.column_stack(line.get_data_3d())
        np.testing.assert_allclose(drawn[0], turn @ _spine(limb, 0.0), atol=1e-9)
        tip = turn @ _spine(limb, limb.spine.length)
        np.testing.assert_allclose(drawn[-1], tip, atol=1e-9)
        np.testing.assert_allclose(text.get_position_3d(), tip, atol=1e-9)  # at the tip
        joint = np.column_stack([np.ravel(v) for v in dot._offsets3d])[0]
        np.testing.assert_allclose(joint, turn @ _spine(limb, limb.joint), atol=1e-5)
    # The vertical is spot's y: its hooves at the bottom, its horns at the top.
    y = np.asarray(mesh.vertices)[:, 1]
    bottom, top = ax.get_zlim()
    assert bottom == pytest.approx(y.min(), abs=0.02) and top == pytest.approx(y.max(), abs=0.02)
    assert "up y" in ax.get_title()
    flipped = _parts(fj.plot_skeleton(mesh, skeleton, up="-y"))[0].get_lines()
    np.testing.assert_allclose(flipped[0].get_data_3d()[2], -lines[0].get_data_3d()[2])


def test_the_up_axis_is_guessed_from_the_legs(spot, animal):
    for (mesh, skeleton), up in ((spot, "+y"), (animal, "+z")):
        assert guess_up(mesh, skeleton) == up
        ax = _parts(fj.plot_skeleton((mesh.vertices, mesh.faces), skeleton))[0]
        assert f"up {up} (guessed)" in ax.get_title()
        axis = "xyz".index(up[1])
        low, high = np.asarray(mesh.vertices)[:, axis].min(), np.asarray(mesh.vertices).max(0)
        assert ax.get_zlim()[0] == pytest.approx(low, abs=0.02)  # the feet at the bottom
        assert ax.get_zlim()[1] == pytest.approx(high[axis], abs=0.02)


def test_the_up_axis_is_the_one_the_feet_stand_on():
    """A toy built as cheburashka is (y up): a head up, two arms down and out, two short feet
    forwards (+z) on the floor. The limbs' directions, summed, point along the feet (the old
    guess, `-z`); the two limb ends on the bounding box's bottom face say `+y`."""
    def line(start, end):
        start, end = np.asarray(start, float), np.asarray(end, float)
        return fj.Limb(fj.Line(np.linalg.norm(end - start), origin=start, tangent=end - start),
                       0.01)
    limbs = (line([0.5, 0.6, 0.5], [0.5, 1.0, 0.5]), line([0.5, 0.5, 0.5], [0.1, 0.3, 0.5]),
             line([0.5, 0.5, 0.5], [0.9, 0.3, 0.5]), line([0.4, 0.05, 0.5], [0.4, 0.02, 0.9]),
             line([0.6, 0.05, 0.5], [0.6, 0.02, 0.9]))
    box = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    skeleton = fj.Skeleton(limbs, np.arange(8) % 6 - 1, box)
    assert guess_up(box, skeleton) == "+y"


def test_up_rotations_are_proper_and_turn_up_to_vertical():
    for up in ("x", "y", "z", "-x", "+y", "-z", [0.3, -1.0, 2.0], (0, -2, 0), [0, 0, -1]):
        turn = up_rotation(up)
        vector = np.eye(3)["xyz".index(up.strip("+-"))] * (-1 if up[0] == "-" else 1) if (
            isinstance(up, str)) else np.asarray(up, float)  # fmt: skip
        np.testing.assert_allclose(turn @ turn.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(turn) == pytest.approx(1.0)  # not mirrored
        np.testing.assert_allclose(turn @ vector / np.linalg.norm(vector), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(up_rotation([0, 5, 0]), up_rotation("y"))


def test_it_draws_into_a_given_axis(animal):
    mesh, skeleton = animal
    figure = plt.figure()
    ax = figure.add_subplot(projection="3d")
    assert fj.plot_skeleton(mesh, skeleton, ax=ax, elev=30, azim=10) is figure
    assert len(ax.get_lines()) == len(skeleton.limbs) and ax.azim == 10


def test_bad_arguments_are_named(spot, animal):
    mesh, skeleton = spot
    with pytest.raises(TypeError, match="`skeleton`"):
        fj.plot_skeleton(mesh, "skeleton.json")
    with pytest.raises(ValueError, match="`skeleton` was built on a mesh of 2930 vertices"):
        fj.plot_skeleton(animal[0], skeleton)
    with pytest.raises(TypeError, match="`mesh`"):
        fj.plot_skeleton(3, skeleton)
    for up in ("w", "up", "--y", [1.0, 0.0], [0, 0, 0], [np.nan, 0, 1]):
        with pytest.raises(ValueError, match="`up`"):
            fj.plot_skeleton(mesh, skeleton, up=up)
    with pytest.raises(TypeError, match="`up`"):
        fj.plot_skeleton(mesh, skeleton, up={"y": 1})
    with pytest.raises(TypeError, match="`ax`"):
        fj.plot_skeleton(mesh, skeleton, ax=plt.figure().add_subplot())  # a 2D axis
    for alpha in (0, 1.5, True):
        with pytest.raises(ValueError, match="`alpha`"):
            fj.plot_skeleton(mesh, skeleton, alpha=alpha)
    with pytest.raises(ValueError, match="`azim`"):
        fj.plot_skeleton(mesh, skeleton, azim=float("inf"))


def test_skeleton_command_draws_the_png(table_file, tmp_path, capsys):
    out, picture = tmp_path / "table.json", tmp_path / "table.png"
    arguments = [str(table_file), str(out), "--spheres", "30", "--seed", "1"]
    assert main(["skeleton", *arguments, "--png", str(picture)]) == 0
    assert f"wrote {picture}" in capsys.readouterr().out
    assert picture.read_bytes()[:8] == PNG and picture.stat().st_size > 10_000
    assert json.loads(out.read_text())["type"] == "skeleton"
    assert len(fj.load_skeleton(out).region) == len(fj.load_mesh(table_file).vertices)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.json", "table.png"]


def test_skeleton_command_refuses_a_picture_not_png_before_the_work(
    table_file, tmp_path, capsys, monkeypatch
):
    def no_work(*args, **kwargs):
        raise AssertionError("the skeleton was computed")

    monkeypatch.setattr(build, "skeleton", no_work)
    out = tmp_path / "table.json"
    for name in ("table.jpg", "table", "table.png.txt"):
        assert main(["skeleton", str(table_file), str(out), "--png", str(tmp_path / name)]) == 2
        error = capsys.readouterr().err
        assert "error: --png" in error and "PNG" in error
    assert main(["skeleton", str(table_file), str(out), "--png",
                 str(tmp_path / "no" / "a.png")]) == 2  # fmt: skip
    assert "does not exist" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())

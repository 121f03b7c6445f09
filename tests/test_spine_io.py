"""Spine files: JSON round trips for every spine type, and errors naming file and field."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fleshing_jax as fj

POINTS = [[0, 0, 0], [1, 0.5, 0.2], [2, 0.2, 1], [3, -0.6, 0.8], [4, 0, 0.1], [5, 0.7, 0.4]]
SPINES = {
    "line": lambda: fj.Line(2.5, origin=(1, 2, 3), tangent=(0, 1, 1)),
    "arc": lambda: fj.Arc(2.0, 3.0, origin=(0, 1, 0), tangent=(1, 0, 0), normal=(0, 0, 1)),
    "helix": lambda: fj.Helix(1.5, -0.7, 9.0),
    "bspline": lambda: fj.BSpline(
        POINTS, degree=3, knots=[0, 0, 0, 0, 0.3, 0.5, 1, 1, 1, 1], subdivisions=40
    ),
    "interpolatingpolynomial": lambda: fj.InterpolatingPolynomial(POINTS[:4], subdivisions=24),
    "polyline": lambda: fj.Polyline(POINTS, step=0.4),
}


@pytest.mark.parametrize("kind", sorted(SPINES))
def test_round_trip(kind, tmp_path):
    spine = SPINES[kind]()
    path = tmp_path / "spine.json"
    fj.save_spine(spine, path)
    data = json.loads(path.read_text())
    assert data["type"] == kind
    loaded = fj.load_spine(path)
    assert type(loaded) is type(spine)
    # Static settings too (the frame nodes of free-form spines), not only the geometry.
    assert jax.tree.structure(loaded) == jax.tree.structure(spine)
    s = jnp.linspace(0, spine.length, 5)
    for a, b in zip(jax.vmap(spine.jet)(s), jax.vmap(loaded.jet)(s)):
        np.testing.assert_allclose(a, b, atol=1e-14)


def test_documented_examples(tmp_path):
    path = tmp_path / "arc.json"
    arc = {"type": "arc", "radius": 2.0, "length": 3.0, "origin": [0, 0, 0]}
    path.write_text(json.dumps({**arc, "tangent": [1, 0, 0], "normal": [0, 1, 0]}))
    assert float(fj.load_spine(path).length) == 3.0
    path.write_text(json.dumps({"type": "bspline", "control_points": POINTS, "degree": 5}))
    assert fj.load_spine(path).degree == 5


@pytest.mark.parametrize(
    "content, field",
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "JSON object"),
        ('{"type": "nurbs"}', "field 'type'"),
        ('{"radius": 1.0}', "field 'type'"),
        ('{"type": "arc", "radius": 1.0}', "field 'length'"),
        ('{"type": "arc", "radius": "big", "length": 1.0}', "field 'radius'"),
        ('{"type": "arc", "radius": 1.0, "length": 1.0, "origin": [0, 0]}', "field 'origin'"),
        ('{"type": "arc", "radius": -1.0, "length": 1.0}', "`radius`"),
        ('{"type": "helix", "radius": 1, "pitch": 1, "length": 1, "colour": 3}', "'colour'"),
        ('{"type": "bspline", "control_points": [[0, 0, 0], [1, 0, 0]]}', "`control_points`"),
        ('{"type": "bspline", "control_points": [[0, 0], [1, 0]]}', "field 'control_points'"),
        (
            '{"type": "bspline", "control_points": [[0,0,0],[1,0,0],[2,1,0]], "degree": 1.5}',
            "field 'degree'",
        ),
        ('{"type": "polyline", "points": [[0, 0, 0], [1, 0, 0]], "step": "x"}', "field 'step'"),
    ],
)
def test_malformed_files(content, field, tmp_path):
    path = tmp_path / "bad_spine.json"
    path.write_text(content)
    with pytest.raises(ValueError) as info:
        fj.load_spine(path)
    assert "bad_spine.json" in str(info.value) and field in str(info.value)

"""`flesh` and `pose` on points sharded across devices (`jax.sharding`), GitHub issue 6.

The check runs in a subprocess: the number of host devices is fixed when JAX starts
(`XLA_FLAGS=--xla_force_host_platform_device_count=4`), and the test session has started JAX
with one device already.
"""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

SCRIPT = textwrap.dedent(
    """
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    import fleshing_jax as fj
    from fleshing_jax._batching import chunks

    devices = jax.devices()
    assert len(devices) == 4, devices
    sharding = NamedSharding(Mesh(np.array(devices), ("p",)), PartitionSpec("p"))

    rng = np.random.default_rng(0)
    n = 64
    points = np.column_stack(
        [rng.uniform(-0.4, 4.4, n), rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n)]
    )
    points[::13, 0] += 20.0  # a few points beyond the search range: invalid
    local = jax.device_put(points, devices[0])
    sharded = jax.device_put(points, sharding)
    assert len(sharded.sharding.device_set) == 4

    control = np.array([[0, 0, 0], [1, 0.2, 0], [2, 0.5, 0.3], [3, 0.2, 0.6], [4, -0.3, 0.4],
                        [5, -0.2, 0.0], [6, 0.1, -0.2]], dtype=float)
    bent = control + np.array([[0, 0, 0], [0, 0.5, 0], [-0.3, 1.2, 0], [-0.9, 1.8, 0.2],
                               [-1.5, 2.2, 0.5], [-2.4, 2.3, 0.4], [-3.4, 2.0, 0.2]])
    pairs = {
        "line-arc": (fj.Line(4.0), fj.Arc(3.0, 4.0)),
        "bspline-bspline": (fj.BSpline(control), fj.BSpline(bent)),
    }
    configurations = [
        ("line-arc", "radial", True),
        ("bspline-bspline", "binormal", False),
    ]
    # The second in chunks of 16 points, fewer than the 64 points (the large-input path).
    runs = [(chunks.CHUNK_POINTS, configurations[0]), (16, configurations[1])]
    for chunk_size, (name, method, check) in runs:
        chunks.CHUNK_POINTS = chunk_size
        jax.clear_caches()  # the chunk size is read when tracing
        source, target = pairs[name]
        kwargs = dict(method=method, twist=0.3, check_projection=check)
        expected = fj.flesh(local, source, target, **kwargs)
        flat = fj.flesh(sharded, source, target, **kwargs)
        posed = fj.pose(fj.register(sharded, source), target, **kwargs)
        for out, valid in (flat, posed):
            np.testing.assert_allclose(out, expected[0], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(valid, expected[1])
            assert out.shape == (n, 3) and valid.shape == (n,)
            # The result stays distributed: each device holds its quarter.
            assert len(out.sharding.device_set) == 4, (name, out.sharding)
            assert out.sharding.is_equivalent_to(sharded.sharding, 2), out.sharding
            shards = out.addressable_shards
            assert sorted(s.data.shape[0] for s in shards) == [16] * 4
        assert 0 < int(np.sum(expected[1])) < n, (name, int(np.sum(expected[1])))
    print("sharding ok")
    """
)


@pytest.mark.slow  # (`python -m pytest -m slow`): four devices' programs, 100 s of compiling
def test_flesh_and_pose_on_sharded_points():
    env = dict(os.environ)
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4"
    ).strip()
    env["JAX_PLATFORMS"] = "cpu"
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")]))
    result = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "sharding ok" in result.stdout

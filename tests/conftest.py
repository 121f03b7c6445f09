"""Shared test configuration and helpers.

float64 is enabled here (never in the library); float32 behaviour is tested explicitly.

The suite's time is almost all XLA compilation, so the tests ask XLA for cheap compiles (the
tests check values, not speed): no backend optimisation, XLA CPU's older loop emitters, which
compile the suite's programs 1.7× faster than the MLIR fusion emitters (measured on the det J
program: 3.3 s → 1.9 s), and each program's machine code generated in one piece rather than
split for parallel threads (the two test workers keep both cores busy already; 10–15 % less
compile time per program, measured on the second-order program of `test_higher_order`), and
XLA CPU's fast-compile preset, which runs fewer HLO passes (the det J programs of three spine
pairs: 10.7–11.9 → 6.9 s of compile CPU; their determinants move by at most 7e-16).
Compiled programs are shared between the pytest-xdist workers (and between a worker's tests
that trace the same program anew) through JAX's persistent compilation cache: every program,
however quickly it compiled: the small ones are most of the programs and the ones that repeat
(eager operations on the tests' common shapes). The notebooks' kernels inherit these flags.

Python's cyclic garbage collector runs rarely (and never over the modules loaded before the
tests): tracing allocates millions of short-lived objects and a worker's heap of cached programs
grows, so that at the default thresholds a process running four test files spent 8.4 s of its
130 s of CPU in 7,639 collections (1.9 s in 69 here; its peak memory 2.56 → 2.70 GB).
"""

import functools
import gc
import os
from pathlib import Path

os.environ.setdefault(
    "XLA_FLAGS",
    "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
    " --xla_cpu_use_fusion_emitters=false --xla_cpu_parallel_codegen_split_count=1"
    " --xla_cpu_opt_preset=CPU_OPT_PRESET_FAST_COMPILE",
)

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# FLESHING_JAX_TEST_CACHE points a run at another cache (an empty folder times a cold run).
_CACHE = Path(
    os.environ.get("FLESHING_JAX_TEST_CACHE")
    or Path(__file__).resolve().parents[1] / ".pytest_cache" / "jax-compilation-cache"
)
jax.config.update("jax_compilation_cache_dir", str(_CACHE))
os.environ["FLESHING_JAX_CACHE"] = str(_CACHE)  # the command line in tests: the same cache
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

from _posing_shapes import tube_mesh, tube_registration, tube_skeleton  # noqa: E402

import fleshing_jax as fj  # noqa: E402

gc.freeze()
gc.set_threshold(50_000, 20, 100)


@eqx.filter_jit
def _frames_and_centres(spine, s):
    """The spine's rotation-minimising frames and points at arc lengths `s`: `(n, 3, 3)`,
    `(n, 3)`. One compiled program for spines of one kind (their values are its arguments):
    batched eagerly, the frames ran operation by operation, half the CPU of a file's clouds."""
    return jax.vmap(lambda t: (fj.rotation_minimizing_frame(spine, t), spine(t)))(s)


@eqx.filter_jit
def mapped(f, *args):
    """`jax.vmap(f)(*args)` as one compiled program, `f` a module whose values are its arguments
    (a spine, its bound method, `eqx.Partial(function, spine)`): one program per kind of spine
    and shape. Called eagerly, each operation of `f` ran, and compiled, on its own."""
    return jax.vmap(f)(*args)


def cloud(spine, n=32, radius=0.5, seed=0, overshoot=0.0):
    """Random points in a tube of `radius` around `spine`, optionally past its ends.

    Built from the spine's own frame so the tube follows the spine: (n, 3) numpy array. Tests
    keep `n` at its default where they can, so that compiled functions are reused.
    """
    rng = np.random.default_rng(seed)
    length = float(spine.length)
    s = rng.uniform(-overshoot * length, (1 + overshoot) * length, n)
    frames, centre = map(np.asarray, _frames_and_centres(spine, s))
    angle = rng.uniform(0, 2 * np.pi, n)
    r = radius * np.sqrt(rng.uniform(0, 1, n))
    return (
        centre
        + (r * np.cos(angle))[:, None] * frames[:, 1]
        + (r * np.sin(angle))[:, None] * frames[:, 2]
    )


def central_difference(f, x, eps=1e-6):
    """Central finite-difference derivative of `f` at scalar `x`."""
    return (np.asarray(f(x + eps)) - np.asarray(f(x - eps))) / (2 * eps)


# Pairs of spines used across the tests: (name, C0, C1). Each C1 is bent well inside the
# valid space of a 0.5-radius tube.
def _pairs():
    return {
        "line-arc": (fj.Line(4.0), fj.Arc(3.0, 4.0)),
        "arc-helix": (
            fj.Arc(2.5, 5.0, origin=(1.0, -1.0, 0.5), tangent=(0, 1, 0), normal=(1, 0, 1)),
            fj.Helix(2.0, 1.5, 5.0),
        ),
        "helix-helix": (fj.Helix(2.0, 3.0, 8.0), fj.Helix(1.5, -2.5, 8.0)),
        "arc-line": (fj.Arc(2.0, 3.0), fj.Line(3.0, origin=(1, 2, 3), tangent=(0, 0, 1))),
        "unequal": (fj.Arc(3.0, 4.0), fj.Helix(2.0, 2.0, 6.0)),
    }


PAIRS = _pairs()


@pytest.fixture(params=sorted(PAIRS))
def pair(request):
    return PAIRS[request.param]


# The posing tests' tube, its hand-cut skeleton and their registration (`_posing_shapes`).
@pytest.fixture(scope="session")
def table_file(tmp_path_factory):
    """The procedural table (four legs under a top) as an OBJ file, for the CLI's tests."""
    from fleshing_jax._medial_axis.table import table

    path = tmp_path_factory.mktemp("table") / "table.obj"
    table().export(path)
    return path


@functools.cache
def spot_skeleton(seed):
    """`fj.skeleton` of spot (the default medial mesh) at `seed`, built once per worker: the
    skeleton tests and the characters' tests check seed 1 each (a skeleton is immutable)."""
    return fj.skeleton(fj.data.spot(), seed=seed)


# Spot rigged on 60 spheres of a quick medial mesh, shared by the skeleton tests and the
# skeleton figures' tests (built once per worker, not once per file): `(mesh, medial,
# skeleton)`. Trimesh objects are mutable: tests copy before editing. (The quadruped's rig:
# `_skeleton_rigs.py`.)
_FEW = dict(refine=0, progress=False)


@pytest.fixture(scope="session")
def spot_rig():
    mesh = fj.data.spot()  # y up
    medial = fj.medial_mesh(mesh, 60, samples=5000, **_FEW)
    return mesh, medial, fj.skeleton(mesh, medial=medial)


@pytest.fixture(scope="module")
def tube():
    return tube_mesh()


@pytest.fixture(scope="module")
def skeleton(tube):
    return tube_skeleton(tube)


@pytest.fixture(scope="module")
def registration(tube, skeleton):
    return tube_registration(tube, skeleton)


# Tests that each run for tens of seconds in a process of their own (notebook kernels, the
# multi-device subprocess) start first, so that the two workers do not end the session with
# one of them alone on a long test.
_FIRST = ("test_notebooks.py", "test_sharding.py")
# Then the files that pose the tube (`tube`, `skeleton`, `registration`), one after another:
# worksteal hands each worker a contiguous half of this order and steals from a queue's tail,
# so they all run on one worker, which traces and lowers their shared programs (the tube's
# registration, its eager poses and their checks) once. On two workers each traced them again
# only to find them in the persistent cache.
_TUBE = (
    "test_posing.py",
    "test_posing_speed.py",
    "test_fit_pose.py",
    "test_joint_zone.py",
    "test_skeleton_bad_input.py",
)


def pytest_collection_modifyitems(items):
    items.sort(key=lambda item: (item.path.name not in _FIRST, item.path.name not in _TUBE))

"""Time to first result of the command line and of the library's slowest first calls: cold
(fresh process, empty compilation cache) and warm (fresh process, cache filled by the previous
call). Issues 19 (command line) and 31 (library).

    python benchmarks/startup.py [--repeats 3] [--skip-demo] [--library-only] [--only WORD]

The library's first calls run in a fresh Python process that asks for the cache with
`fj.compilation_cache_settings()` (as the notebooks do) and times the call itself (not the
imports): the first `flesh` of a point cloud on a B-spline (line → B-spline), the first
`fit_spine` of a free B-spline to a shape bent onto an arc (issue 31's case), and the first
`deform_medial` of spot (its head turned; the medial mesh read from a `.ma` file written
before, so that its construction is not counted), and the first `register_skeleton` of spot
in float32 (its skeleton read from a file written before). `--only WORD` runs the library
calls whose name holds WORD.

Each figure is the wall time of a whole `fleshing-jax` process (median of `--repeats`), so it
includes Python's start, the imports, reading and writing the mesh, tracing and compiling (or
loading compiled programs from the cache). The bunny (`../shared/data/stanford-bunny.obj`,
capped) is bent from a line to an arc with the radial method.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BUNNY = DATA / "stanford-bunny.obj"
LINE = {"type": "line", "length": 0.17, "origin": [-0.1, 0.1, 0.0], "tangent": [1, 0, 0]}
ARC = {**LINE, "type": "arc", "radius": 0.3, "normal": [0, 1, 0]}


def timed(command: list[str], cache: Path | str, cwd: Path) -> float:
    environment = {**os.environ, "FLESHING_JAX_CACHE": str(cache)}
    started = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True, env=environment, cwd=cwd)
    return time.perf_counter() - started


def cold_and_warm(command: list[str], folder: Path, repeats: int) -> tuple[list, list]:
    cold, warm = [], []
    for i in range(repeats):
        cache = folder / f"cache-{i}"  # empty: a cold start
        cold.append(timed(command, cache, folder))
        warm.append(timed(command, cache, folder))
    return cold, warm


# Each prints the seconds of its first call (after the imports and the set-up).
_LIBRARY_SETUP = """
import sys, time
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import fleshing_jax as fj
for name, value in fj.compilation_cache_settings().items():
    jax.config.update(name, value)
rng = np.random.default_rng(0)
points = np.c_[rng.uniform(0, 4, 256), rng.normal(0, 0.2, (256, 2))]
straight = np.c_[np.linspace(0, 4, 6), np.zeros(6), np.zeros(6)]
"""
LIBRARY = {
    "first `flesh`, line → B-spline (256 points)": """
bent = straight.copy(); bent[2:, 1] = [0.3, 0.9, 1.6, 2.4]
started = time.perf_counter()
jax.block_until_ready(fj.flesh(points, fj.Line(4.0), fj.BSpline(bent)))
print(time.perf_counter() - started)
""",
    "first `fit_spine`, free B-spline onto an arc (256 points)": """
rest = fj.BSpline(straight)
target, _ = fj.flesh(points, fj.Line(4.0), fj.Arc(3.0, 4.0))
started = time.perf_counter()
fit = fj.fit_spine(rest, rest, points, target)
jax.block_until_ready(fit.rms)
print(time.perf_counter() - started)
""",
    "first `deform_medial` of spot (head turned 30°, 200 spheres)": """
spot = fj.data.spot()
medial = fj.load_medial(sys.argv[1])
c = np.asarray(medial.centers)
head = np.flatnonzero((c[:, 2] < -0.35) & (c[:, 1] > 0.0))
core = np.setdiff1d(np.flatnonzero((np.abs(c[:, 2] + 0.1) < 0.25) & (c[:, 1] > -0.1)), head)
cos, sin = np.cos(np.radians(30)), np.sin(np.radians(30))
turn = np.array([[cos, 0, sin], [0, 1, 0], [-sin, 0, cos]])
pivot = np.array([0.0, 0.3, -0.3])
targets = np.r_[(c[head] - pivot) @ turn.T + pivot, c[core]]
started = time.perf_counter()
out = fj.deform_medial(spot, medial, np.r_[head, core], targets)
print(time.perf_counter() - started)
""",
    "first `register_skeleton` of spot, float32": """
spot = fj.data.spot()
skeleton = fj.load_skeleton(sys.argv[2])
started = time.perf_counter()
jax.block_until_ready(fj.register_skeleton(spot, skeleton, dtype=np.float32))
print(time.perf_counter() - started)
""",
}


def library(folder: Path, repeats: int, only: str = "") -> list:
    """Rows (name, cold seconds, warm seconds) of the library's first calls (those whose name
    holds `only`)."""
    import fleshing_jax as fj

    spot = fj.data.spot()
    medial, skeleton = folder / "spot.ma", folder / "spot-skeleton.json"
    spheres = fj.medial_mesh(spot, 200, progress=False)
    fj.save_medial(spheres, medial)
    fj.save_skeleton(fj.skeleton(spot, medial=spheres), skeleton)
    rows = []
    for name, body in LIBRARY.items():
        if only not in name:
            continue
        command = [sys.executable, "-c", _LIBRARY_SETUP + body, str(medial), str(skeleton)]
        cold, warm = [], []
        for i in range(repeats):
            cache = folder / f"library-{len(rows)}-{i}"
            for times in (cold, warm):
                environment = {**os.environ, "FLESHING_JAX_CACHE": str(cache)}
                done = subprocess.run(command, check=True, capture_output=True, text=True,
                                      env=environment, cwd=folder)  # fmt: skip
                times.append(float(done.stdout.split()[-1]))
        print(f"{name}: cold {cold}, warm {warm}", file=sys.stderr, flush=True)
        rows.append((name, cold, warm))
    return rows


def command_line(folder: Path, args) -> list:
    """Rows (name, cold seconds, warm seconds) of whole `fleshing-jax` processes."""
    cli = [sys.executable, "-m", "fleshing_jax._cli"]
    (folder / "rest.json").write_text(json.dumps(LINE))
    (folder / "bent.json").write_text(json.dumps(ARC))
    help_times = [timed([*cli, "--help"], "off", folder) for _ in range(args.repeats)]
    rows = [("`fleshing-jax --help`", help_times, help_times)]
    if BUNNY.is_file():
        deform = [*cli, "deform", str(BUNNY), "out.ply", "--from", "rest.json", "--to",
                  "bent.json", "--cap-holes"]  # fmt: skip
        rows.append(("`deform` bunny (36k vertices)", *cold_and_warm(deform, folder, args.repeats)))
    else:
        print(f"skipping the bunny: {BUNNY} not found", file=sys.stderr)
    if not args.skip_demo:
        demo = [*cli, "demo", "--out", "demo"]
        rows.append(("`demo`", *cold_and_warm(demo, folder, max(1, args.repeats // 2))))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-demo", action="store_true")
    parser.add_argument("--library-only", action="store_true", help="only the library's calls")
    parser.add_argument("--only", default="", metavar="WORD",
                        help="only the library calls whose name holds WORD")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rows = library(folder, args.repeats, args.only)
        if not args.library_only:
            rows += command_line(folder, args)
    print("| call | cold (s) | warm (s) |")
    print("|---|---:|---:|")
    for name, cold, warm in rows:
        print(f"| {name} | {statistics.median(cold):.2f} | {statistics.median(warm):.2f} |")


if __name__ == "__main__":
    main()

"""Time to first result of the command line: cold (fresh process, empty compilation cache) and
warm (fresh process, cache filled by the previous call). Issue 19, part 1.

    python benchmarks/startup.py [--repeats 3] [--skip-demo]

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-demo", action="store_true")
    args = parser.parse_args()
    cli = [sys.executable, "-m", "fleshing_jax._cli"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "rest.json").write_text(json.dumps(LINE))
        (folder / "bent.json").write_text(json.dumps(ARC))
        help_times = [timed([*cli, "--help"], "off", folder) for _ in range(args.repeats)]
        rows.append(("`fleshing-jax --help`", help_times, help_times))
        if BUNNY.is_file():
            deform = [*cli, "deform", str(BUNNY), "out.ply", "--from", "rest.json", "--to",
                      "bent.json", "--cap-holes"]  # fmt: skip
            times = cold_and_warm(deform, folder, args.repeats)
            rows.append(("`deform` bunny (36k vertices)", *times))
        else:
            print(f"skipping the bunny: {BUNNY} not found", file=sys.stderr)
        if not args.skip_demo:
            demo = [*cli, "demo", "--out", "demo"]
            rows.append(("`demo`", *cold_and_warm(demo, folder, max(1, args.repeats // 2))))
    print("| command | cold (s) | warm (s) |")
    print("|---|---:|---:|")
    for name, cold, warm in rows:
        print(f"| {name} | {statistics.median(cold):.2f} | {statistics.median(warm):.2f} |")


if __name__ == "__main__":
    main()

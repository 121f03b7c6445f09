"""Q-MAT (Li et al. 2015) built from its public source and timed beside our `medial_mesh`
(issue 49).

    python benchmarks/qmat_build.py --qmat-src PATH/TO/QMAT [--meshes spot,quadruped,bunny]
                                    [--spheres 200] [--axis-samples 20000] [--work DIR]

`--qmat-src` is a checkout of Q-MAT's public source (github.com/ningnawang/QMAT: `CMakeLists.txt`,
`main.cpp`, `src/`, and `include/` holding the CGAL, Eigen and Boost headers it ships). The
script copies it into a scratch folder (`--work`, default a new temporary folder; an existing
build there is reused) and builds it there in Release mode. It needs `cmake`, a C++14 compiler
and GMP's headers (Debian: `apt-get install cmake g++ libgmp-dev`) and says which is missing.
Two stand-ins let the Windows/macOS source build on Linux, both in the scratch folder, the
source untouched: a `corecrt_math_defines.h` (Windows' math constants, which `<cmath>` has) and
a header for each `#include "name"` whose file differs from `name` only in case.

That Q-MAT simplifies a given initial medial axis (`QMAT MESH.off AXIS.ma N`; computing the
initial axis is on its to-do list). Each mesh's initial axis is ours: the inner Voronoi complex
of `--axis-samples` surface samples (seed 0; 20,000 as `medial_mesh` takes by default), as
`medial_mesh` computes it first; Q-MAT collapses it to `N` spheres. Q-MAT's time grows with
that axis (spot: about 79k spheres from 20,000 samples). Per mesh, in one run, one process each:

- ours: `medial_mesh(mesh, N)` in a fresh process, wall time of the call (its Voronoi stage
  included);
- Q-MAT: the wall time of its process on that axis (reading, quadrics, collapses, writing),
  and beside it the time of the initial axis it was given (ours, measured apart);
- both medial meshes measured with `medial.py`'s ruler (`medial.compare`: `medial_distance`
  on samples of seed 1, volume error, spheres in no edge, components).

Prints Markdown tables.
"""

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
import medial as ruler  # noqa: E402  (benchmarks/medial.py: the same shapes and ruler)

SAMPLES = 20_000


def missing_tools() -> list[str]:
    """What the build needs and this machine lacks, each with what to install."""
    missing = []
    if shutil.which("cmake") is None:
        missing.append("cmake (Debian: apt-get install cmake)")
    compiler = shutil.which("c++") or shutil.which("g++")
    if compiler is None:
        missing.append("a C++14 compiler (Debian: apt-get install g++)")
    else:
        probe = subprocess.run([compiler, "-E", "-x", "c++", "-"], input="#include <gmp.h>\n",
                               capture_output=True, text=True)
        if probe.returncode != 0:
            missing.append("GMP's headers, which CGAL needs (Debian: apt-get install libgmp-dev)")
    return missing


def check_source(source: Path) -> None:
    needed = ["CMakeLists.txt", "main.cpp", "src/SlabMesh.h", "include/CGAL"]
    absent = [name for name in needed if not (source / name).exists()]
    if absent:
        raise SystemExit(f"--qmat-src {source} is not a Q-MAT checkout: no {', '.join(absent)} "
                         "(clone github.com/ningnawang/QMAT, whose include/ ships CGAL, Eigen "
                         "and Boost)")


def _case_stand_ins(source: Path, shims: Path) -> None:
    # Written on case-insensitive file systems: `#include "nonmanifoldmesh.h"` for the file
    # NonManifoldMesh.h. A header of the included name that includes the real file.
    headers = {path.name.lower(): path for path in source.rglob("*.h") if "include" not in
               path.relative_to(source).parts}
    for path in [*source.glob("*.cpp"), *source.glob("src/*.cpp"), *source.glob("src/*.h")]:
        for name in re.findall(r'#include\s+"([^"]+)"', path.read_text(errors="replace")):
            real = headers.get(Path(name).name.lower())
            if real is not None and real.name != Path(name).name:
                (shims / Path(name).name).write_text(f'#include "{real}"\n')


def build(source: Path, work: Path) -> Path:
    """Q-MAT's executable, built from a copy of `source` under `work` (reused if there)."""
    binary = work / "build" / "QMAT"
    if binary.is_file():
        return binary
    missing = missing_tools()
    if missing:
        raise SystemExit("cannot build Q-MAT here; missing: " + "; ".join(missing))
    copy = work / "qmat-src"
    shutil.copytree(source, copy, ignore=shutil.ignore_patterns(".git", "data", "build"),
                    dirs_exist_ok=True)
    shims = work / "stand-ins"
    shims.mkdir(exist_ok=True)
    (shims / "corecrt_math_defines.h").write_text(
        "// Windows' header of math constants: on Linux <cmath> defines them\n#include <cmath>\n")
    _case_stand_ins(copy, shims)
    start = time.perf_counter()
    for command in (["cmake", "-S", str(copy), "-B", str(work / "build"),
                     "-DCMAKE_BUILD_TYPE=Release", f"-DCMAKE_CXX_FLAGS=-I{shims}"],
                    ["cmake", "--build", str(work / "build"), "-j", str(os.cpu_count() or 1)]):
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"building Q-MAT failed ({' '.join(command[:2])}):\n"
                             + (done.stdout + done.stderr)[-3000:])
    print(f"Q-MAT built in {time.perf_counter() - start:.0f} s ({binary})", file=sys.stderr)
    return binary


def meshes(names: list[str]):
    from fleshing_jax._medial_axis.animal import quadruped

    def shape(label):  # medial.py's own meshes, built only up to the one asked for
        return next((mesh for name, mesh in ruler.shapes(quick=False) if name == label), None)

    made = {"spot": lambda: shape("spot"), "quadruped": lambda: quadruped(32),
            "bunny": lambda: shape("bunny (capped)")}
    for name in names:
        if name not in made:
            raise SystemExit(f"--meshes: unknown mesh {name!r} (known: {', '.join(made)})")
        mesh = made[name]()
        if mesh is None:
            print(f"skipped {name}: {ruler.DATA} is absent", file=sys.stderr)
            continue
        yield name, mesh


def _initial_axis(mesh_path: str, samples: int, out: str) -> None:
    """Writes the inner Voronoi complex `medial_mesh` starts from (seed 0) to `out`; prints
    its time. `construct.medial_mesh`'s first steps (in the mesh's own coordinates)."""
    from fleshing_jax._medial_axis.construct import axis_samples
    from fleshing_jax._medial_axis.files import save_medial
    from fleshing_jax._medial_axis.medial_mesh import MedialMesh
    from fleshing_jax._medial_axis.surface import SurfaceQuery, closed_mesh_arrays
    from fleshing_jax._medial_axis.voronoi import initial_medial_axis

    mesh = trimesh.load(mesh_path, process=False)
    start = time.perf_counter()
    query = SurfaceQuery(*closed_mesh_arrays(mesh))
    points, normals, weights, sample_faces = axis_samples(query, samples,
                                                         np.random.default_rng(0))
    axis = initial_medial_axis(query, points, normals, weights, sample_faces)
    elapsed = time.perf_counter() - start
    save_medial(MedialMesh(axis.centers, axis.radii, axis.edges, axis.faces), out)
    print(json.dumps({"seconds": elapsed, "spheres": len(axis.centers)}))


def _ours(mesh_path: str, spheres: int, out: str) -> None:
    from fleshing_jax._medial_axis.construct import medial_mesh
    from fleshing_jax._medial_axis.files import save_medial

    mesh = trimesh.load(mesh_path, process=False)
    start = time.perf_counter()
    medial = medial_mesh(mesh, spheres, progress=False)
    elapsed = time.perf_counter() - start
    save_medial(medial, out)
    print(json.dumps({"seconds": elapsed}))


def _in_fresh_process(*args: str) -> dict:
    done = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(args[:1])} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def run_qmat(binary: Path, mesh_path: Path, axis_path: Path, spheres: int, folder: Path):
    """Q-MAT's wall time and the `.ma` it wrote (`export_half___v_…` in its folder)."""
    for old in folder.glob("export_half___v_*.ma"):
        old.unlink()
    start = time.perf_counter()
    done = subprocess.run([str(binary), str(mesh_path), str(axis_path), str(spheres)],
                          cwd=folder, capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    written = sorted(folder.glob("export_half___v_*.ma"))
    if done.returncode != 0 or not written:
        raise SystemExit(f"Q-MAT failed on {mesh_path.name} (exit {done.returncode}):\n"
                         + (done.stdout + done.stderr)[-3000:])
    return elapsed, written[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--qmat-src", type=Path, help="a checkout of Q-MAT's public source")
    parser.add_argument("--meshes", default="spot,quadruped,bunny",
                        help="comma-separated: spot, quadruped (quadruped(32)), bunny (capped)")
    parser.add_argument("--spheres", type=int, default=200)
    parser.add_argument("--axis-samples", type=int, default=SAMPLES,
                        help="surface samples of the initial axis given to Q-MAT")
    parser.add_argument("--work", type=Path, help="scratch folder (default: a new temporary one)")
    parser.add_argument("--check", action="store_true",
                        help="only say whether Q-MAT can be built here")
    parser.add_argument("--_initial", nargs=3, help=argparse.SUPPRESS)
    parser.add_argument("--_ours", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args._initial:
        return _initial_axis(args._initial[0], int(args._initial[1]), args._initial[2])
    if args._ours:
        return _ours(args._ours[0], int(args._ours[1]), args._ours[2])
    if args.check:
        missing = missing_tools()
        print("can build Q-MAT here" if not missing else "missing: " + "; ".join(missing))
        return
    if args.qmat_src is None:
        parser.error("--qmat-src is needed: a checkout of github.com/ningnawang/QMAT")
    check_source(args.qmat_src.resolve())
    work = (args.work or Path(tempfile.mkdtemp(prefix="qmat-"))).resolve()
    work.mkdir(parents=True, exist_ok=True)
    binary = build(args.qmat_src.resolve(), work)

    rows = []
    for name, mesh in meshes(args.meshes.split(",")):
        folder = work / name
        folder.mkdir(exist_ok=True)
        mesh_path = folder / f"{name}.off"  # Q-MAT reads OFF; the ruler reads the same file
        mesh.export(mesh_path)
        axis = _in_fresh_process("--_initial", str(mesh_path), str(args.axis_samples),
                                 str(folder / "initial.ma"))
        ours = _in_fresh_process("--_ours", str(mesh_path), str(args.spheres),
                                 str(folder / "ours.ma"))
        qmat_seconds, qmat_path = run_qmat(binary, mesh_path, folder / "initial.ma",
                                           args.spheres, folder)
        rows.append((name, len(mesh.vertices), axis, ours["seconds"], qmat_seconds,
                     mesh_path, folder / "ours.ma", qmat_path))
        print(f"{name}: ours {ours['seconds']:.1f} s, Q-MAT {qmat_seconds:.1f} s",
              file=sys.stderr, flush=True)

    load = os.getloadavg()[0]
    print(f"\n{args.spheres} spheres; ours from {SAMPLES} samples, Q-MAT's initial axis from "
          f"{args.axis_samples}; seed 0; wall times, one process each, load average "
          f"{load:.1f} at the end, {os.cpu_count()} CPUs\n")
    print("| mesh | vertices | initial axis: spheres, time (ours) | ours: `medial_mesh` | "
          "Q-MAT on that axis | Q-MAT + the axis |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, vertices, axis, ours_s, qmat_s, *_ in rows:
        print(f"| {name} | {vertices:,} | {axis['spheres']:,}, {axis['seconds']:.1f} s | "
              f"{ours_s:.1f} s | {qmat_s:.1f} s | {qmat_s + axis['seconds']:.1f} s |")
    for name, _, _, _, _, mesh_path, ours_path, qmat_path in rows:
        print(f"\n{name} (ours: ours.ma; Q-MAT: {qmat_path.name}):\n")
        ruler.compare(str(ours_path), str(mesh_path), seed=1)
        ruler.compare(str(qmat_path), str(mesh_path), seed=1, header=False)


if __name__ == "__main__":
    main()

"""Medial meshes against the targets of issue 17.

    python benchmarks/medial.py               # both tables
    python benchmarks/medial.py --quick       # procedural shapes only, no scaling table
    python benchmarks/medial.py --scaling     # only the scaling table
    python benchmarks/medial.py --compare OTHER.ma --mesh MESH.obj   # any tool's .ma, our ruler
    python benchmarks/medial.py --fresh 5 [--against OLD_CHECKOUT]   # time of a fresh process

Prints Markdown tables:

1. Accuracy per shape and sphere count: time of `medial_mesh` (sampling, Voronoi,
   simplification, fit), the one-sided Hausdorff distances surface → envelope and envelope →
   surface (fractions of the bounding-box diagonal, on samples of seed 1, which the
   construction did not fit), the envelope's volume error, the Euler
   characteristic `V − E + F` of the medial mesh, and the widest slab (smallest altitude of
   a face's triangle of centres, fraction of the diagonal). Shapes: a capsule (radius 0.5,
   axis 4), a torus (2, 0.5), a box 3 × 2 × 1, a flat ellipsoid 2 × 1.2 × 0.3,
   spot (`fleshing_jax.data.spot()`, welded) and, where `../shared/data` is present, the
   Stanford bunny (capped).
2. Time against mesh size (icospheres stretched into ellipsoids, 2.5k → 41k vertices) and
   sphere count.
3. Memory of one `medial_mesh` run alone (`--memory`; the capped bunny and the 41k-vertex
   ellipsoid, 200 spheres): each in a fresh subprocess, the peak resident set (`ru_maxrss`)
   of the call minus the resident set after importing and loading the mesh.
4. Time of a fresh process (`--fresh N`; spot and the capped bunny, 200 spheres): N
   processes each, medians of the whole process's wall and CPU time (user + system) and of
   the call's (its imports of JAX and numba and numba's start included: they happen in the
   first call); with `--against DIR`, another checkout's code (e.g. a `git worktree` of an
   older commit) run in turns with this one, so that both see the same load.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

from fleshing_jax import data
from fleshing_jax._medial_axis.construct import medial_mesh
from fleshing_jax._medial_axis.distance import medial_distance
from fleshing_jax._medial_axis.files import load_medial

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _close(mesh):
    try:
        from fleshing_jax import cap_holes
    except ImportError:  # during the package's reorganisation
        mesh = mesh.copy()
        trimesh.repair.fill_holes(mesh)
        return mesh
    return cap_holes(mesh)


def shapes(quick: bool):
    yield "capsule", trimesh.creation.capsule(height=4.0, radius=0.5, count=[48, 48])
    yield "torus", trimesh.creation.torus(2.0, 0.5, major_sections=96, minor_sections=32)
    yield "box", trimesh.creation.box([3, 2, 1])
    ellipsoid = trimesh.creation.icosphere(4)
    ellipsoid.vertices *= [2, 1.2, 0.3]
    yield "flat ellipsoid", ellipsoid
    if quick:
        return
    yield "spot", data.spot()  # shipped with the package
    if (DATA / "stanford-bunny.obj").is_file():
        yield "bunny (capped)", _close(trimesh.load(str(DATA / "stanford-bunny.obj"),
                                                    process=False))


def _widest_slab(centers, faces, diagonal):
    if len(faces) == 0:
        return 0.0
    a, b, c = (centers[faces[:, k]] for k in range(3))
    longest = np.max([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                      np.linalg.norm(a - c, axis=1)], axis=0)
    return float((np.linalg.norm(np.cross(b - a, c - a), axis=1) / longest).max() / diagonal)


def accuracy(quick: bool):
    print("| shape | vertices | spheres | time (s) | surface → envelope | envelope → surface "
          "| volume error | V − E + F | widest slab |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, mesh in shapes(quick):
        diagonal = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
        for spheres in (200, 50):
            start = time.perf_counter()
            medial = medial_mesh(mesh, spheres, progress=False)
            elapsed = time.perf_counter() - start
            # seed 1: samples that the construction (seed 0) did not fit
            to_envelope, to_surface = medial_distance(medial, mesh, seed=1)
            centers, _, edges, faces = medial.numpy()
            volume = medial.volume() / mesh.volume - 1
            print(f"| {name} | {len(mesh.vertices)} | {spheres} | {elapsed:.1f} | "
                  f"{100 * to_envelope:.2f} % | {100 * to_surface:.2f} % | {100 * volume:+.2f} % "
                  f"| {len(centers) - len(edges) + len(faces)} | "
                  f"{100 * _widest_slab(centers, faces, diagonal):.2f} % |", flush=True)


def scaling():
    print("\n| mesh vertices | spheres | time (s) | peak memory (GiB) |")
    print("| ---: | ---: | ---: | ---: |")
    for level in (4, 5, 6):
        mesh = trimesh.creation.icosphere(level)
        mesh.vertices *= [2, 1.2, 0.6]
        for spheres in (50, 200, 800):
            start = time.perf_counter()
            medial_mesh(mesh, spheres, progress=False)
            elapsed = time.perf_counter() - start
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
            print(f"| {len(mesh.vertices)} | {spheres} | {elapsed:.1f} | {peak:.2f} |",
                  flush=True)


def _resident_gib() -> float:
    with open("/proc/self/status") as status:
        line = next(ln for ln in status if ln.startswith("VmRSS:"))
    return int(line.split()[1]) / 2**20


def _probe(name: str) -> None:
    """One medial_mesh run in this (fresh) process: prints the peak and the baseline."""
    if name == "bunny":
        mesh = _close(trimesh.load(str(DATA / "stanford-bunny.obj"), process=False))
    else:
        mesh = trimesh.creation.icosphere(6)
        mesh.vertices *= [2, 1.2, 0.6]
    base = _resident_gib()
    start = time.perf_counter()
    medial_mesh(mesh, 200, progress=False)
    elapsed = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    print(f"{len(mesh.vertices)} {elapsed:.1f} {peak - base:.2f} {base:.2f}")


def memory():
    print("\n| mesh | vertices | spheres | time (s) | peak memory of the run (GiB) |")
    print("| --- | ---: | ---: | ---: | ---: |")
    names = (["bunny"] if (DATA / "stanford-bunny.obj").is_file() else []) + ["ellipsoid"]
    for name in names:
        done = subprocess.run([sys.executable, __file__, "--_probe", name], capture_output=True,
                              text=True, check=True)
        vertices, elapsed, peak, _ = done.stdout.split()
        print(f"| {name} | {vertices} | 200 | {elapsed} | {peak} |", flush=True)


_FRESH = """import time, warnings
warnings.simplefilter("ignore")
import fleshing_jax as fj, trimesh
mesh = trimesh.load({path!r}, process=False, force="mesh")
mesh = fj.cap_holes(mesh) if {cap} else mesh
cpu, wall = time.process_time(), time.perf_counter()
fj.medial_mesh(mesh, 200, progress=False)
print(time.process_time() - cpu, time.perf_counter() - wall)
"""


def fresh(runs: int, against: str | None) -> None:
    """Table 4: `runs` fresh processes per mesh and code, the codes in turns."""
    import os
    import statistics

    root = str(Path(__file__).resolve().parents[1])
    codes = {"this checkout": root} | ({f"`{against}`": against} if against else {})
    print("\n| mesh | code | process: wall | process: CPU | call: wall | call: CPU |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for name, cap in (("spot", False), ("stanford-bunny", True)):
        script = _FRESH.format(path=str(DATA / f"{name}.obj"), cap=cap)
        times = {code: [] for code in codes}
        for _ in range(runs):
            for code, path in codes.items():
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                start = time.perf_counter()
                done = subprocess.run([sys.executable, "-c", script], capture_output=True,
                                      text=True, check=True, cwd="/",
                                      env={**os.environ, "PYTHONPATH": path})
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
                call_cpu, call_wall = map(float, done.stdout.split())
                times[code].append((time.perf_counter() - start, cpu, call_wall, call_cpu))
        for code, rows in times.items():
            medians = [statistics.median(column) for column in zip(*rows)]
            print(f"| {name} | {code} | " + " | ".join(f"{x:.2f} s" for x in medians) + " |")
    print(f"\n(medians of {runs} runs; load average {os.getloadavg()[0]:.1f} at the end)")


def compare(path: str, mesh_path: str, seed: int, header: bool = True) -> None:
    """One row of the accuracy table for a `.ma` file made by any tool (Q-MAT, Coverage
    Axis, ...) of the mesh at `mesh_path`, measured as ours are: `medial_distance(...,
    seed=1)` both ways, the volume error, `V − E + F`, the widest slab; and the spheres in
    no edge and the graph's connected components (ours: none, and one per volume).
    `header`: print the table's header first (`qmat_build.py` prints rows one after another)."""
    from fleshing_jax._medial_axis.connect import components

    mesh = trimesh.load(mesh_path, process=False)
    if mesh_path.endswith(".obj"):  # seams split vertices in OBJ files: weld them
        mesh.merge_vertices(merge_tex=True, merge_norm=True)
    medial = load_medial(path)
    diagonal = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    to_envelope, to_surface = medial_distance(medial, mesh, seed=seed)
    centers, _, edges, faces = medial.numpy()
    lone = int((np.bincount(edges.reshape(-1), minlength=len(centers)) == 0).sum())
    volume = medial.volume() / mesh.volume - 1
    if header:
        print("| file | spheres | surface → envelope | envelope → surface | volume error "
              "| V − E + F | widest slab | spheres in no edge | components |")
        print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    print(f"| {Path(path).name} | {len(centers)} | {100 * to_envelope:.2f} % | "
          f"{100 * to_surface:.2f} % | {100 * volume:+.2f} % | "
          f"{len(centers) - len(edges) + len(faces)} | "
          f"{100 * _widest_slab(centers, faces, diagonal):.2f} % | {lone} | "
          f"{components(len(centers), edges)[0]} |")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--memory", action="store_true", help="only the memory table")
    parser.add_argument("--scaling", action="store_true", help="only the scaling table")
    parser.add_argument("--compare", metavar="FILE.ma",
                        help="measure a .ma file of --mesh with the same ruler as ours")
    parser.add_argument("--mesh", help="the mesh the --compare file was made from")
    parser.add_argument("--seed", type=int, default=1,
                        help="seed of --compare's surface samples (default 1, as ours)")
    parser.add_argument("--fresh", type=int, metavar="N",
                        help="only table 4: N fresh processes per mesh (and code)")
    parser.add_argument("--against", metavar="DIR",
                        help="with --fresh: another checkout's code, run in turns with this")
    parser.add_argument("--_probe", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.compare:
        if not args.mesh:
            parser.error("--compare needs --mesh (the mesh the .ma file was made from)")
        compare(args.compare, args.mesh, args.seed)
    elif args._probe:
        _probe(args._probe)
    elif args.fresh:
        fresh(args.fresh, args.against)
    elif args.memory:
        memory()
    elif args.scaling:
        scaling()
    else:
        accuracy(args.quick)
        if not args.quick:
            scaling()
            memory()

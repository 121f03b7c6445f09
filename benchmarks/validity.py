"""The valid region (issue 32): what it flags, what it costs a frame, and tears without it.

    python benchmarks/validity.py [--repeats 20]

Prints two Markdown tables:

1. Spot (2,930 vertices, welded) on its rest spine (`fj.rest_spine`, free-form), the margin half
   its longest edge, bent by 15°, 30° and 60° (`planar_bend`): a pose's time per frame with
   every check on (median over `--repeats` frames after the first), the valid vertices, those
   beyond the rest spine's reach, the largest stretch of an edge with two valid ends and of an
   edge with an invalid end, and the volume change.
2. A hairpin spine (two stretches 0.8 apart) straightened, on a lattice of spacing 0.1 whose
   edges straddle its cut locus: the largest image/rest length of an edge with two valid ends,
   without the margin and with half the spacing.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import trimesh

import fleshing_jax as fj
from fleshing_jax._fleshing.diagnose import diagnose, planar_bend
from fleshing_jax._mesh.deform import longest_edge

HAIRPIN = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [3.5, 0.1, 0], [3.6, 0.4, 0],
                    [3.5, 0.7, 0], [3, 0.8, 0], [2, 0.8, 0], [1, 0.8, 0],
                    [0, 0.8, 0.0]])  # fmt: skip


def spot() -> trimesh.Trimesh:
    data = getattr(fj, "data", None)
    if data is not None:
        return data.spot()
    path = Path(__file__).resolve().parents[2] / "shared" / "data" / "spot.obj"
    mesh = trimesh.load(path, process=False)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def edge_stretch(rest, image, edges, valid):
    lengths = np.linalg.norm(image[edges[:, 0]] - image[edges[:, 1]], axis=1)
    ratio = lengths / np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    both = valid[edges[:, 0]] & valid[edges[:, 1]]
    return ratio[both].max(initial=0), ratio[~both].max(initial=0)


def spot_table(repeats: int) -> None:
    mesh = spot()
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    edges = np.asarray(mesh.edges_unique)
    source = fj.rest_spine(mesh)
    margin = 0.5 * longest_edge(vertices, faces)
    registration = fj.register(jnp.asarray(vertices), source, margin=margin)
    volume = fj.volume(vertices, faces)
    print(f"\nspot: {len(vertices)} vertices, margin {margin:.4f}\n")
    print("| bend | first frame (ms) | per frame, median (ms) | valid | beyond reach | "
          "valid-edge stretch | invalid-edge stretch | volume change |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for degrees in (15, 30, 60):
        target = planar_bend(source, np.radians(degrees))
        times = []
        for _ in range(repeats + 1):
            start = time.perf_counter()
            images, valid = fj.pose(registration, target, margin=margin)
            images.block_until_ready()
            times.append(time.perf_counter() - start)
        images, valid = np.asarray(images, np.float64), np.asarray(valid)
        causes = diagnose(registration, target, margin=margin)
        inner, outer = edge_stretch(vertices, images, edges, valid)
        change = fj.volume(images, faces) / volume - 1
        print(f"| {degrees}° | {1e3 * times[0]:.0f} | {1e3 * np.median(times[1:]):.2f} | "
              f"{valid.mean():.1%} | {causes.beyond_reach} | {inner:.2f} | {outer:.1f} | "
              f"{change:+.3%} |")


def hairpin_table() -> None:
    source = fj.BSpline(HAIRPIN, degree=3)
    target = fj.Line(source.length)
    axes = [np.arange(a, b + 1e-9, 0.1) for a, b in ((0, 3.2), (-0.25, 1.05), (-0.2, 0.2))]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"))
    index = np.arange(grid[0].size).reshape(grid.shape[1:])
    edges = np.concatenate([
        np.stack([np.take(index, range(n - 1), axis=a).ravel(),
                  np.take(index, range(1, n), axis=a).ravel()], 1)
        for a, n in enumerate(index.shape)
    ])  # fmt: skip
    points = grid.reshape(3, -1).T
    print(f"\nhairpin straightened: {len(points)} lattice points, spacing 0.1\n")
    print("| margin | valid | largest stretch of an edge with two valid ends |")
    print("|---:|---:|---:|")
    for margin in (0.0, 0.05):
        images, valid = fj.flesh(points, source, target, margin=margin)
        valid = np.asarray(valid)
        inner, _ = edge_stretch(points, np.asarray(images), edges, valid)
        print(f"| {margin} | {valid.mean():.1%} | {inner:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    spot_table(args.repeats)
    hairpin_table()


if __name__ == "__main__":
    import jax

    jax.config.update("jax_enable_x64", True)
    main()

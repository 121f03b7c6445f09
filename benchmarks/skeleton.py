"""The rig `fj.skeleton` finds on characters (issue 45): limbs, chains, times, pictures.

    python benchmarks/skeleton.py [--figures benchmarks/figures]
    python benchmarks/skeleton.py --seeds 12     # spot's rig over its medial meshes' seeds

For each character (spot; the procedural quadruped, jointed quadruped, biped and insects;
cheburashka where `../shared/data` holds it):
its vertices, the skeleton's limbs and how many of them are chains from the body (with their
lengths), the time of `fj.skeleton` (its medial mesh at 200 spheres included) and of the
first `register_skeleton` (float64, its compilation included), and a pose of every chain at
each joint (the top 30°, each joint below 45°, float64): flagged vertices, volume change, the
largest edge stretch, whether every vertex outside the chains stayed bit for bit. Prints one
Markdown table; with `--figures`, writes `skeleton-NAME.png` (`fj.plot_skeleton`) and
`skeleton-NAME-posed.png` (rest and posed side by side) into that folder. With `--seeds N`,
spot's rig from the medial meshes of seeds 0 … N−1 instead: its limbs, whether the snout is in
a limb with ears and horns as its children, and whether each hoof is in a leg of its own. With
`--large`, the time of `fj.skeleton` on spot subdivided twice (46,850 vertices), in this fresh
process (compilation included): wall and CPU (all threads), and its limbs (issue 45: ≤ 15 s).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np
import trimesh

jax.config.update("jax_enable_x64", True)

import fleshing_jax as fj  # noqa: E402
from fleshing_jax._medial_axis import characters  # noqa: E402
from fleshing_jax._medial_axis.animal import quadruped  # noqa: E402

CHARACTERS = {
    "spot": fj.data.spot,
    "quadruped": lambda: quadruped(32),
    "jointed_quadruped": characters.jointed_quadruped,
    "biped": characters.biped,
    "insect": characters.insect,
    # The head thicker than the thorax, as on real insects: the root must stay the thorax.
    "insect_thick_head": lambda: characters.insect_medial(head=0.13, thorax=0.09).envelope(42),
}
# A real biped with a head thicker than its torso and flat ears (tests and benchmarks only:
# its licence is not stated, so it is read from the shared data folder, never shipped).
CHEBURASHKA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cheburashka.obj"
if CHEBURASHKA.is_file():
    CHARACTERS["cheburashka"] = lambda: trimesh.load(str(CHEBURASHKA), process=False,
                                                     force="mesh")


def measure(name, figures):
    mesh = CHARACTERS[name]()
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    start = time.perf_counter()
    skeleton = fj.skeleton(mesh)
    found = time.perf_counter() - start
    start = time.perf_counter()
    registration = fj.register_skeleton(mesh, skeleton)
    registered = time.perf_counter() - start
    tops = skeleton.children(-1)
    lengths = sorted((max(len(skeleton.chain(k)) for k in range(len(skeleton.limbs))
                          if skeleton.chain(k)[0] == top) for top in tops), reverse=True)
    poses = {k: fj.LimbPose(30.0 if skeleton.limbs[k].parent == -1 else 45.0)
             for k in range(len(skeleton.limbs))}
    posed = fj.pose_skeleton(registration, skeleton, poses)
    moved = np.asarray(posed.vertices)
    region = np.asarray(skeleton.region)
    still = np.array_equal(moved[region == -1], vertices[region == -1])
    edges = np.asarray(mesh.edges_unique)
    stretch = np.linalg.norm(moved[edges[:, 0]] - moved[edges[:, 1]], axis=1) / np.linalg.norm(
        vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    change = float(fj.volume(moved, faces) / fj.volume(vertices, faces)) - 1
    if figures is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fj.plot_skeleton(mesh, skeleton).savefig(figures / f"skeleton-{name}.png", dpi=80)
        plt.close("all")
        figure = plt.figure(figsize=(10, 5))
        for i, (points, title) in enumerate([(vertices, "rest"), (moved, "every joint bent")]):
            ax = figure.add_subplot(1, 2, i + 1, projection="3d")
            fj.plot_skeleton((points, faces), _moved(skeleton, points), ax=ax)
            if i:  # the regions only: the spines drawn are the rest ones
                from mpl_toolkits.mplot3d.art3d import Poly3DCollection

                for artist in [*ax.lines, *ax.texts, *ax.collections]:
                    if not isinstance(artist, Poly3DCollection):
                        artist.remove()
            ax.set_title(title)
        figure.savefig(figures / f"skeleton-{name}-posed.png", dpi=80)
        plt.close("all")
    return (f"| {name} | {len(vertices):,} | {len(skeleton.limbs)} | {len(tops)} | "
            f"{'/'.join(map(str, lengths))} | {found:.1f} | {registered:.1f} | "
            f"{int(np.sum(~np.asarray(posed.valid)))} | {100 * change:+.4f} | "
            f"{stretch.max():.2f} | {'yes' if still else 'no'} |")


def _moved(skeleton, points):
    """The skeleton on posed `points`: the regions as they are."""
    return fj.Skeleton(skeleton.limbs, skeleton.region, points)


def large():
    """`fj.skeleton` of spot subdivided twice (trimesh's `subdivide`: 46,850 vertices), cold:
    one Markdown row."""
    vertices, faces = np.asarray(fj.data.spot().vertices), np.asarray(fj.data.spot().faces)
    for _ in range(2):
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
    start, cpu = time.perf_counter(), time.process_time()
    skeleton = fj.skeleton(trimesh.Trimesh(vertices, faces, process=False))
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    print("| mesh | vertices | limbs | skeleton, wall (s) | CPU, all threads (s) |")
    print("|---|---:|---:|---:|---:|")
    print(f"| spot subdivided twice | {len(vertices):,} | {len(skeleton.limbs)} | {wall:.1f} | "
          f"{cpu:.1f} |")


def seeds_table(count):
    """Spot's rig from the medial meshes of seeds 0 … count−1: one Markdown row each."""
    mesh = fj.data.spot()
    vertices = np.asarray(mesh.vertices)
    snout = vertices[np.argmin(vertices[:, 2])]  # towards −z; y up: the hooves at the bottom
    hooves = [vertices[(vertices[:, 1] < -0.6) & ((vertices[:, 0] > 0) == right)
                       & ((vertices[:, 2] > 0.4) == back)].mean(axis=0)
              for right in (False, True) for back in (False, True)]
    print("| seed | limbs | head (children) | legs (of 4) | skeleton (s) |")
    print("|---:|---:|---|---:|---:|")
    for seed in range(count):
        start = time.perf_counter()
        skeleton = fj.skeleton(mesh, seed=seed)
        elapsed = time.perf_counter() - start
        head = skeleton.limb_at(snout)
        legs = {skeleton.limb_at(h) for h in hooves} - {-1}
        children = len(skeleton.children(head)) if head >= 0 else 0
        print(f"| {seed} | {len(skeleton.limbs)} | {'yes' if head >= 0 else 'no'} ({children}) "
              f"| {len(legs)} | {elapsed:.1f} |", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figures", type=Path, default=None)
    parser.add_argument("--only", nargs="*", default=list(CHARACTERS))
    parser.add_argument("--seeds", type=int, default=None)
    parser.add_argument("--large", action="store_true")
    args = parser.parse_args()
    if args.large:
        large()
        return
    if args.seeds is not None:
        seeds_table(args.seeds)
        return
    if args.figures is not None:
        args.figures.mkdir(parents=True, exist_ok=True)
    print("| character | vertices | limbs | chains from the body | limbs per chain | "
          "skeleton (s) | first register (s) | flagged (all joints bent) | dV/V (%) | "
          "edge stretch | body still |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.only:
        print(measure(name, args.figures), flush=True)


if __name__ == "__main__":
    main()

"""Figs. 8–10 (paper §5.3): volume error against mesh resolution and against element size.

Fig. 8: a box, off-centre around a straight spine, is bent into a circular arc; its surface is
cut into `d × d` grids per face (subdivision levels d = 1, 2, 4, …). Fleshing is exactly
volume preserving in the continuum: the error left comes only from the flat faces, and shrinks
as the mesh is refined. Skinning's error does not.

Figs. 9–10: a cloud of equal cubes (8 vertices each) is bent by the same spines; the mean
absolute relative volume error per cube is plotted against the cube size.

    python benchmarks/paper/fig8_10_resolution.py
"""

from __future__ import annotations

import numpy as np
from _common import ALL_METHODS, figure_path, flesh_many, markdown_table, pyplot

import fleshing_jax as fj

LENGTH = 3.0
BOX = np.array([[0.0, -0.05, -0.25], [LENGTH, 0.45, 0.25]])  # centroid 0.2 off the spine
CLOUD = np.array([[0.0, -0.4, -0.4], [LENGTH, 0.4, 0.4]])
LEVELS = (1, 2, 4, 8, 16, 32, 64)
CUBE_SIZES = (0.2, 0.1, 0.05, 0.025)


def spines():
    """A straight spine along x and an arc of radius 1.25 bending towards +y (137°)."""
    return fj.Line(LENGTH), fj.Arc(1.25, LENGTH, normal=(0.0, 1.0, 0.0))


def resolution(levels=LEVELS, methods=ALL_METHODS):
    """`{method: [relative volume error per level]}` and the vertex counts (Fig. 8)."""
    meshes = [fj.box_grid(BOX, d) for d in levels]
    out = flesh_many([v for v, _ in meshes], *spines(), methods=methods)
    errors = {}
    for method in methods:
        errors[method] = []
        for (v0, faces), (v1, valid) in zip(meshes, out[method]):
            assert valid.all(), f"{method}: invalid vertices"
            errors[method].append(float(fj.volume_change(v0, v1, faces)))
    return errors, [len(v) for v, _ in meshes]


def cube_errors(sizes=CUBE_SIZES, methods=ALL_METHODS):
    """`{method: [mean |relative volume error| over the cubes, per size]}` (Figs. 9–10)."""
    clouds = [fj.cube_cloud(CLOUD, size) for size in sizes]
    out = flesh_many([v.reshape(-1, 3) for v, _ in clouds], *spines(), methods=methods)
    errors = {}
    for method in methods:
        errors[method] = []
        for (v0, faces), (v1, valid) in zip(clouds, out[method]):
            assert valid.all(), f"{method}: invalid vertices"
            change = np.asarray(fj.volume_change(v0, v1.reshape(v0.shape), faces))
            errors[method].append(float(np.mean(np.abs(change))))
    return errors, [len(v) for v, _ in clouds]


def plot(levels, counts, errors, sizes, cubes, cube_counts, path):
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for method, values in errors.items():
        a.loglog(counts, np.abs(values), "o-", label=method)
    a.set_xlabel("vertices")
    a.set_ylabel("|relative volume error|")
    a.set_title("Fig. 8: bent box, error vs resolution")
    for method, values in cubes.items():
        b.loglog(sizes, 100 * np.asarray(values), "o-", label=method)
    b.set_xlabel("cube size")
    b.set_ylabel("mean |relative error| per cube (%)")
    b.set_title("Fig. 10: cloud of cubes, error vs cube size")
    for ax in (a, b):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_meshes(level, path):
    """Fig. 8-style picture: the box at one level bent by each method."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    plt = pyplot()
    v0, faces = fj.box_grid(BOX, level)
    out = flesh_many([v0], *spines())
    fig = plt.figure(figsize=(13, 3.6))
    for i, method in enumerate(ALL_METHODS):
        ax = fig.add_subplot(1, 4, i + 1, projection="3d")
        v1 = out[method][0][0]
        change = float(fj.volume_change(v0, v1, faces))
        ax.add_collection3d(
            Poly3DCollection(v1[faces], facecolor="lightsteelblue", edgecolor="k", linewidths=0.2)
        )
        ax.set_xlim(-0.2, 1.6), ax.set_ylim(0.0, 2.6), ax.set_zlim(-0.9, 0.9)
        ax.view_init(elev=60, azim=-90)
        ax.set_axis_off()
        ax.set_title(f"{method}: {100 * change:+.3f}%")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    errors, counts = resolution()
    rows = [
        (d, n, *(f"{100 * errors[m][i]:+.5f}%" for m in ALL_METHODS))
        for i, (d, n) in enumerate(zip(LEVELS, counts))
    ]
    print("Fig. 8: relative volume error of the bent box against resolution")
    print(markdown_table(("d", "vertices", *ALL_METHODS), rows))
    cubes, cube_counts = cube_errors()
    rows = [
        (s, n, *(f"{100 * cubes[m][i]:.5f}%" for m in ALL_METHODS))
        for i, (s, n) in enumerate(zip(CUBE_SIZES, cube_counts))
    ]
    print("\nFigs. 9–10: mean absolute relative volume error per cube against cube size")
    print(markdown_table(("cube size", "cubes", *ALL_METHODS), rows))
    plot(LEVELS, counts, errors, CUBE_SIZES, cubes, cube_counts, figure_path("fig8_10_errors.png"))
    plot_meshes(4, figure_path("fig8_box_level4.png"))


if __name__ == "__main__":
    main()

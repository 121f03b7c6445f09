"""Fig. 7: a shape sliding along a curve, frame by frame, with its volume deviation.

The paper slides a dolphin along a 3D curve by moving the origin of the arc length of C1. Here the
embedded creature (`fj.creature`, no data needed) slides along a conical spiral (a B-spline whose
curvature and torsion change along it): frame i bends the creature's straight spine onto the
spiral's piece `[σ_i, σ_i + L]`. Skinning's volume changes from frame to frame; fleshing's does
not.

    python benchmarks/paper/fig7_sliding.py
"""

from __future__ import annotations

import jax
import numpy as np
from _common import ALL_METHODS, figure_path, markdown_table, pyplot, render
from _spiral import Piece, conical_spiral

import fleshing_jax as fj

LENGTH = 4.0


def run(frames: int = 12, segments: int = 64, around: int = 32, methods=ALL_METHODS):
    """`starts (frames,)`, `{method: (frames,) relative volume deviations}`, the last poses."""
    mesh = fj.creature(LENGTH, segments, around)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    registration = fj.register(vertices, fj.Line(LENGTH))
    spiral = conical_spiral()
    starts = np.linspace(1.0, float(spiral.length) - LENGTH - 1.0, frames)
    deviations = {m: [] for m in methods}
    poses = {m: [] for m in methods}
    for start in starts:
        target = Piece(spiral, start, LENGTH)
        twist = target.base_twist()  # the spiral's own frame: no roll between frames
        for method in methods:
            bent, valid = fj.pose(registration, target, method=method, twist=twist)
            assert bool(np.all(valid)), f"{method}: invalid vertices at σ = {start}"
            deviations[method].append(float(fj.volume_change(vertices, bent, faces)))
            poses[method].append(np.asarray(bent))
    return starts, {m: np.asarray(d) for m, d in deviations.items()}, poses, faces


def main():
    starts, deviations, poses, faces = run()
    rows = [
        (f"{s:.1f}", *(f"{100 * deviations[m][i]:+.4f}%" for m in ALL_METHODS))
        for i, s in enumerate(starts)
    ]
    print("Volume deviation of the sliding creature, per frame (σ = start of C1 on the spiral)")
    print(markdown_table(("σ", *ALL_METHODS), rows))
    print(
        "max |deviation|: "
        + ", ".join(f"{m} {100 * np.max(np.abs(deviations[m])):.4f}%" for m in ALL_METHODS)
    )
    plt = pyplot()
    fig = plt.figure(figsize=(13, 4.2))
    ax = fig.add_subplot(1, 2, 1)
    for method in ALL_METHODS:
        ax.semilogy(starts, 100 * np.abs(deviations[method]), "o-", label=method)
    ax.set_xlabel("σ (start of the creature on the spiral)")
    ax.set_ylabel("|volume deviation| (%)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title("Fig. 7: volume deviation per frame")
    ax = fig.add_subplot(1, 2, 2, projection="3d")
    spiral = conical_spiral()
    curve = np.asarray(jax.vmap(spiral)(np.linspace(0.0, float(spiral.length), 400)))
    ax.plot(*curve.T, color="0.5", lw=0.8)
    for i in range(0, len(starts), 3):
        render(ax, poses["radial"][i], faces, view=(35, -60))
    everything = np.concatenate(poses["radial"][::3])
    lo, hi = everything.min(0), everything.max(0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_title("radial fleshing, every third frame")
    fig.tight_layout()
    fig.savefig(figure_path("fig7_sliding.png"), dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()

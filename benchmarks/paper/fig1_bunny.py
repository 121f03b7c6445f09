"""Fig. 1: the Stanford bunny bent by a spine — volume change of skinning and of fleshing.

The bunny of ../shared/data is open at the bottom: its holes are capped first (a fan of
triangles around each boundary loop's centroid) and volumes are measured on the closed mesh.
The spine is a straight line low in the body (y = 0.06), from tail to head, bent into an arc.

    python benchmarks/paper/fig1_bunny.py
"""

from __future__ import annotations

import sys

import numpy as np
import trimesh
from _common import ALL_METHODS, DATA, figure_path, flesh_many, markdown_table, pyplot, render

import fleshing_jax as fj

BUNNY = DATA / "stanford-bunny.obj"


def spines():
    """A line along x low in the body; an arc of radius 0.25 bending it downwards."""
    origin = (-0.1, 0.06, 0.01)
    source = fj.Line(0.17, origin=origin)
    target = fj.Arc(0.25, 0.17, origin=origin, tangent=(1.0, 0.0, 0.0), normal=(0.0, -1.0, 0.0))
    return source, target


def closed_bunny(path=BUNNY) -> trimesh.Trimesh:
    return fj.cap_holes(trimesh.load(str(path), process=False))


def run(mesh: trimesh.Trimesh, methods=ALL_METHODS):
    """`{method: (bent vertices, relative volume change, invalid count)}`."""
    out = flesh_many([mesh.vertices], *spines(), methods=methods)
    results = {}
    for method in methods:
        bent, valid = out[method][0]
        change = float(fj.volume_change(mesh.vertices, bent, mesh.faces))
        results[method] = (bent, change, int(np.sum(~valid)))
    return results


def main():
    if not BUNNY.is_file():
        sys.exit(f"skipped: {BUNNY} not found (the shared data folder is absent)")
    mesh = closed_bunny()
    print(f"bunny: {len(mesh.vertices)} vertices after capping, watertight={mesh.is_watertight}")
    results = run(mesh)
    rows = [(m, f"{100 * c:+.4f}%", n) for m, (_, c, n) in results.items()]
    print(markdown_table(("method", "volume change", "invalid vertices"), rows))
    plt = pyplot()
    fig = plt.figure(figsize=(16, 3.6))
    panels = [("input", mesh.vertices, None), *((m, r[0], r[1]) for m, r in results.items())]
    for i, (name, vertices, change) in enumerate(panels):
        ax = fig.add_subplot(1, 5, i + 1, projection="3d")
        colour = (0.85, 0.45, 0.3) if name == "skinning" else (0.3, 0.55, 0.85)
        render(ax, vertices, mesh.faces, colour=colour, view=(10, -90), y_up=True)
        ax.set_title(name if change is None else f"{name}: {100 * change:+.3f}%")
    fig.tight_layout()
    fig.savefig(figure_path("fig1_bunny.png"), dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()

"""The `fleshing-jax demo`: a procedural creature bent by the four methods, compared.

Needs no download and no data folder: the shape is built by `creature()`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._fleshing.methods import METHODS
from ._mesh.deform import deform_mesh
from ._mesh.files import write_mesh_atomic
from ._mesh.shapes import creature
from ._mesh.volume import volume
from ._spines.analytic import Arc, Line

DEFAULT_OUT = "fleshing-demo"


def demo_spines(length: float = 4.0, radius: float = 1.6):
    """The demo's source `Line` along x and target `Arc` bending down (towards −z)."""
    source = Line(length)
    target = Arc(radius, length, tangent=(1.0, 0.0, 0.0), normal=(0.0, 0.0, -1.0))
    return source, target


def run_demo(out: str | os.PathLike = DEFAULT_OUT, *, figure: bool = True, log=print) -> list:
    """Bends the creature with every method, writes the meshes and a figure into `out`.

    Files written: `creature.obj` (the input), `creature-<method>.obj` for each of `METHODS`,
    and `demo.png` (when `figure`).

    **Returns:** a list of rows `(name, volume, relative change, invalid vertices)`, the first
    for the input.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    mesh = creature()
    source, target = demo_spines()
    v0 = float(volume(np.asarray(mesh.vertices), mesh.faces))
    write_mesh_atomic(mesh, out / "creature.obj")
    rows, meshes = [("input", v0, 0.0, 0)], {"input": mesh}
    for method in METHODS:
        log(f"bending {len(mesh.vertices)} vertices with {method} ...")
        bent = deform_mesh(mesh, source, target, method=method)
        v1 = float(volume(np.asarray(bent.vertices), bent.faces))
        invalid = int(np.sum(~bent.vertex_attributes["valid"]))
        rows.append((method, v1, (v1 - v0) / v0, invalid))
        meshes[method] = bent
        write_mesh_atomic(bent, out / f"creature-{method}.obj")
    if figure:
        save_figure(meshes, rows, out / "demo.png")
    return rows


def format_table(rows) -> str:
    """The demo's volume table as aligned text."""
    lines = [f"{'method':<10} {'volume':>10} {'change':>11} {'invalid':>8}"]
    for name, vol, change, invalid in rows:
        lines.append(f"{name:<10} {vol:>10.6f} {100 * change:>+10.4f}% {invalid:>8d}")
    return "\n".join(lines)


def save_figure(meshes: dict, rows, path) -> None:
    """One 3D panel per mesh (side view), titled with its volume change; headless (Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    changes = {name: change for name, _, change, _ in rows}
    everything = np.concatenate([np.asarray(m.vertices) for m in meshes.values()])
    lo, hi = everything.min(0), everything.max(0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    fig = plt.figure(figsize=(3.2 * len(meshes), 3.6))
    for i, (name, mesh) in enumerate(meshes.items()):
        ax = fig.add_subplot(1, len(meshes), i + 1, projection="3d")
        triangles = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
        normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-30
        shade = 0.35 + 0.65 * np.clip(normals @ np.array([0.3, -0.6, 0.75]), 0, 1)
        colour = np.array([0.85, 0.45, 0.3]) if name == "skinning" else np.array([0.3, 0.55, 0.85])
        collection = Poly3DCollection(triangles, facecolors=shade[:, None] * colour, linewidths=0)
        ax.add_collection3d(collection)
        for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
            setter(c - half, c + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=12, azim=-75)
        ax.set_axis_off()
        title = name if name == "input" else f"{name}: {100 * changes[name]:+.3f}% volume"
        ax.set_title(title)
    fig.suptitle("Bending a creature: skinning changes its volume, fleshing keeps it")
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(path, dpi=110)
    plt.close(fig)

"""Shared helpers of the paper's experiments: float64, output folders, batching, tables."""

from __future__ import annotations

from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)  # scripts, not the library: measure at round-off

import numpy as np  # noqa: E402

import fleshing_jax as fj  # noqa: E402

HERE = Path(__file__).resolve().parent
FIGURES = HERE / "figures"
DATA = HERE.parents[1].parent / "shared" / "data"  # ../shared/data from the repository root
FLESHINGS = ("radial", "normal", "binormal")
ALL_METHODS = ("skinning", *FLESHINGS)


def flesh_many(point_sets, source, target, methods=ALL_METHODS, twist=0.0):
    """Fleshes several point sets with several methods, registering and compiling once.

    **Returns:** `{method: [(deformed (N_i, 3), valid (N_i,)) for each set]}` (NumPy).
    """
    sizes = [len(p) for p in point_sets]
    points = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in point_sets])
    registration = fj.register(points, source)
    out = {}
    for method in methods:
        deformed, valid = fj.pose(registration, target, method=method, twist=twist)
        deformed, valid = np.asarray(deformed), np.asarray(valid)
        splits = np.cumsum(sizes)[:-1]
        out[method] = list(zip(np.split(deformed, splits), np.split(valid, splits)))
    return out


def markdown_table(headers, rows) -> str:
    """A Markdown table (strings are used as they are)."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def figure_path(name: str) -> Path:
    FIGURES.mkdir(parents=True, exist_ok=True)
    return FIGURES / name


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def render(ax, vertices, faces, colour=(0.3, 0.55, 0.85), view=(15, -75), y_up=False):
    """Draws a shaded triangle/quad mesh on a 3D axis, with equal scales and no axes.

    `y_up`: the mesh's up axis is y (as for the bunny): it is turned to matplotlib's z.
    """
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    vertices, faces = np.asarray(vertices), fj.triangulate(faces)
    if y_up:  # a rotation about x: (x, y, z) → (x, −z, y)
        vertices = vertices[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0])
    light = (0.3, -0.6, 0.75)
    triangles = vertices[faces]
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-30
    light = np.asarray(light) / np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.clip(normals @ light, 0, 1)
    ax.add_collection3d(
        Poly3DCollection(triangles, facecolors=shade[:, None] * np.asarray(colour), linewidths=0)
    )
    lo, hi = vertices.min(0), vertices.max(0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(*view)
    ax.set_axis_off()


def spine_points(spine, count=100):
    s = np.linspace(0.0, float(spine.length), count)
    return np.asarray(jax.vmap(spine)(jax.numpy.asarray(s)))

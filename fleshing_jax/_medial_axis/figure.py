"""A picture of a medial mesh: its spheres, cones and slabs inside a translucent surface."""

from __future__ import annotations

import numpy as np

from .medial_mesh import MedialMesh

# Proper rotations (no mirror) that bring each axis to the picture's vertical z.
_UPRIGHT = {
    "x": np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]]),  # (x, y, z) → (y, z, x)
    "y": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),  # (x, y, z) → (x, −z, y)
    "z": np.eye(3),
}


def default_up(surface) -> str:
    """`"y"` for a mesh read from an OBJ file (the format's convention: y up), else `"z"`."""
    metadata = getattr(surface, "metadata", None) or {}
    names = (metadata.get("file_type", ""), metadata.get("file_name", ""), metadata.get("name", ""))
    return "y" if any(str(n).lower().endswith("obj") for n in names) else "z"


def upright(points, up: str) -> np.ndarray:
    """(N, 3) `points` turned so that the axis `up` (`"x"`, `"y"` or `"z"`) points up (z)."""
    if up not in _UPRIGHT:
        raise ValueError(f"`up` must be 'x', 'y' or 'z', got {up!r}.")
    return np.asarray(points, dtype=np.float64) @ _UPRIGHT[up].T


def plot_medial(medial: MedialMesh, surface=None, *, ax=None, elev=10.0, azim=-60.0, up=None):
    """Draws `medial` on a matplotlib 3D axis: slabs as triangles between their sphere
    centres, cones as lines, spheres as points whose area follows their radius, and the
    `surface` (a `trimesh.Trimesh`, optional) translucent around them.

    **Arguments:**

    - `medial`, `surface`: as above; `ax`: the 3D axis to draw on (default: a new figure's).
    - `elev`, `azim`: the view (matplotlib's, degrees).
    - `up`: the model's vertical axis, `"x"`, `"y"` or `"z"`, turned to point up in the
      picture. Default: `"y"` for a `surface` read from an OBJ file (the format's convention:
      spot, most scanned models), else `"z"`.

    **Returns:** the axis (a new figure's when `ax` is `None`).
    """
    if not isinstance(medial, MedialMesh):
        raise TypeError(f"`medial` must be a MedialMesh, got {type(medial).__name__}")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    up = default_up(surface) if up is None else up
    centers, radii, edges, faces = medial.numpy()
    centers = upright(centers, up)
    if ax is None:
        ax = plt.figure(figsize=(8, 7)).add_subplot(projection="3d")
    points = centers
    if surface is not None:
        vertices = upright(surface.vertices, up)
        shell = Poly3DCollection(
            vertices[np.asarray(surface.faces)], facecolor=(0.6, 0.6, 0.6, 0.06), linewidths=0
        )
        ax.add_collection3d(shell)
        points = np.concatenate([centers, vertices])
    if len(faces):
        slabs = Poly3DCollection(
            centers[faces], facecolor=(0.95, 0.55, 0.2, 0.55), edgecolor=(0.6, 0.3, 0.1, 0.3),
            linewidths=0.3,
        )  # fmt: skip
        ax.add_collection3d(slabs)
    if len(edges):
        ax.add_collection3d(Line3DCollection(centers[edges], colors="tab:blue", linewidths=1.0))
    scale = 60.0 / max(float(radii.max()), 1e-300)
    ax.scatter(*centers.T, s=scale * radii, color="tab:blue", alpha=0.6, depthshade=False)
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_box_aspect((1, 1, 1), zoom=1.2)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    return ax

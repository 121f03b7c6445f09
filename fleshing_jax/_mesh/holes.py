"""Closing the boundary loops of open meshes, keeping the input's vertices and faces first."""

from __future__ import annotations

import numpy as np
import trimesh


def cap_holes(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Closes every boundary loop of `mesh` with a fan of triangles around the loop's centroid.

    The input's vertices come first, in order (one new vertex per loop is appended), and its
    faces come first too, so a deformation of the input carries over to the capped mesh.
    Suited to roughly planar holes such as the bottom of the Stanford bunny.

    **Returns:** a new `Trimesh` (unchanged copy if the mesh had no boundary), with a copy of
    the input's `metadata` (where it was read from: an OBJ file's y-up convention, which
    `fj.plot_skeleton` and `fj.plot_medial` follow, is kept).
    """
    faces = np.asarray(mesh.faces)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = edges[counts[inverse.reshape(-1)] == 1]
    # Boundary half-edges a→b of the faces; the caps run them backwards (b→a).
    following: dict[int, list[int]] = {}
    for a, b in boundary:
        following.setdefault(int(b), []).append(int(a))
    vertices = [np.asarray(mesh.vertices)]
    new_faces = [faces]
    next_index = len(mesh.vertices)
    while following:
        start = next(iter(following))
        loop, current = [start], start
        while True:
            successors = following.get(current)
            if not successors:
                break
            nxt = successors.pop()
            if not successors:
                del following[current]
            if nxt == start:
                break
            loop.append(nxt)
            current = nxt
        if len(loop) < 3:
            continue
        loop = np.asarray(loop)
        vertices.append(np.asarray(mesh.vertices)[loop].mean(axis=0, keepdims=True))
        new_faces.append(np.stack([loop, np.roll(loop, -1), np.full_like(loop, next_index)], 1))
        next_index += 1
    capped = trimesh.Trimesh(np.concatenate(vertices), np.concatenate(new_faces), process=False)
    capped.metadata.update(dict(getattr(mesh, "metadata", None) or {}))
    return capped

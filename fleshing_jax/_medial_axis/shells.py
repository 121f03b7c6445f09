"""The shells of a closed mesh (its face-connected components): nesting, orientation, overlap.

A closed mesh may hold several shells: separate bodies, or a body and the cavities inside
it. Each must face away from the volume it bounds: a body's shell outwards (positive signed
volume), a cavity's inwards (negative), i.e. a shell nested in an odd number of others is a
cavity. The sign of the whole mesh's volume says nothing about one shell: a body turned
inside out next to a larger one went unnoticed (issue 30: 608 spheres for 30 asked, none
joined). And two shells that cross each other (two overlapping spheres) bound no volume
that the inner Voronoi complex can follow.

Nesting is read from generalised winding numbers (Jacobson et al. 2013; the solid angle of
each triangle by Van Oosterom & Strackee's formula): a vertex of shell `a` is inside shell
`b` where `b`'s winding number there is ±1. Every vertex of `a` inside `b`: `a` is nested in
`b`; none: apart; some: they cross. Only pairs of shells whose bounding boxes overlap are
tested, in chunks of a fixed size. A shell that crosses itself is not detected.
"""

from __future__ import annotations

import numpy as np

from .connect import components

_CHUNK = 2_000_000  # (vertex, triangle) pairs per block of winding numbers


def shells(faces) -> tuple[int, np.ndarray]:
    """The face-connected components of a mesh: `(count, label of each face (F,))`."""
    faces = np.asarray(faces, np.int64)
    n = int(faces.max()) + 1
    count, vertex_label = components(n, np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]]))
    # Unused vertices are components of their own: renumber the labels that faces use.
    used, label = np.unique(vertex_label[faces[:, 0]], return_inverse=True)
    return len(used), label


def winding(points, a, b, c) -> np.ndarray:
    """Generalised winding numbers `(P,)` of `points (P, 3)` for triangles `a, b, c (T, 3)`
    (1 inside an outward closed surface, −1 inside an inward one, 0 outside)."""
    total = np.zeros(len(points))
    step = max(1, _CHUNK // max(len(a), 1))
    for start in range(0, len(points), step):
        p = points[start:start + step, None, :]
        x, y, z = a[None] - p, b[None] - p, c[None] - p
        lx, ly, lz = (np.linalg.norm(v, axis=2) for v in (x, y, z))
        det = np.einsum("pti,pti->pt", x, np.cross(y, z))
        div = (lx * ly * lz + np.einsum("pti,pti->pt", x, y) * lz
               + np.einsum("pti,pti->pt", y, z) * lx + np.einsum("pti,pti->pt", z, x) * ly)
        total[start:start + step] = np.arctan2(det, div).sum(axis=1) / (2 * np.pi)
    return total


def orient_shells(vertices, faces) -> tuple[np.ndarray, list[int]]:
    """Faces `(F, 3)` with every shell facing away from its volume, and the shells flipped.

    **Raises:** `ValueError` naming two shells that cross each other.
    """
    count, label = shells(faces)
    if count == 1:
        return faces, []
    vertices, volume = _volumes(vertices, faces, count, label)
    depth = nesting(vertices, faces, count, label)
    # A body's shell (nested in an even number of others) encloses positive volume.
    flip = np.flatnonzero((volume > 0) != (depth % 2 == 0))
    faces = faces.copy()
    wrong = np.isin(label, flip)
    faces[wrong] = faces[wrong][:, ::-1]
    return faces, flip.tolist()


def _volumes(vertices, faces, count: int, label) -> tuple[np.ndarray, np.ndarray]:
    """`(vertices about their box's centre, the signed volume each shell encloses (count,))`.
    About the centre: a small shell's volume is a sum of triple products that cancel, and far
    from the origin their rounding outgrew it (a 26-vertex shell of a mesh moved 1e6
    diagonals away was flipped)."""
    vertices = vertices - 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    corners = [vertices[faces[:, k]] for k in range(3)]
    signed = np.einsum("ij,ij->i", corners[0], np.cross(corners[1], corners[2])) / 6
    return vertices, np.bincount(label, weights=signed, minlength=count)


def nesting(vertices, faces, count: int, label) -> np.ndarray:
    """`(count,)` int: in how many other shells each shell lies (`shells`' `count` and face
    `label`s): 0 for a body, 1 for a cavity in it, 2 for a body inside that cavity…

    **Raises:** `ValueError` naming two shells that cross each other.
    """
    inside = _Inside(vertices, faces, count, label)
    depth = np.zeros(count, np.int64)
    for s in range(count):
        for t in range(count):
            within = inside(s, t)
            if within.all():
                depth[s] += 1
            elif within.any():
                raise ValueError(f"mesh shells {min(s, t)} and {max(s, t)} (face-connected "
                                 f"components) cross each other: {within.sum()} of the "
                                 f"{len(within)} vertices of shell {s} lie inside shell {t}. A "
                                 "self-intersecting mesh bounds no single volume: merge them "
                                 "into one closed surface first (e.g. a mesh boolean union)")
    return depth


def riders(vertices, faces) -> np.ndarray:
    """The shells that cross a larger one (`(k,)` shell labels of `shells`): a character's
    eyes, teeth or hat modelled as closed parts pushed through its head. Largest first, a
    shell is kept unless it crosses a kept one; a shell inside another without crossing it
    (a cavity, a body in a cavity) is kept."""
    count, label = shells(faces)
    if count == 1:
        return np.zeros(0, np.int64)
    _, volume = _volumes(vertices, faces, count, label)
    inside = _Inside(vertices, faces, count, label)
    kept, crossing = [], []
    for s in np.argsort(-np.abs(volume), kind="stable"):
        cross = False
        for t in kept:
            a, b = inside(s, t), inside(t, s)
            cross = (a.any() and not a.all()) or (b.any() and not b.all())
            if cross:
                break
        (crossing if cross else kept).append(int(s))
    return np.sort(np.array(crossing, np.int64))


class _Inside:
    """`inside(s, t)`: which vertices of shell `s` lie inside shell `t` (`(m,)` bool; none
    when their bounding boxes are apart or `s == t`)."""

    def __init__(self, vertices, faces, count: int, label):
        self.vertices = vertices
        self.corners = [vertices[faces[:, k]] for k in range(3)]
        self.members = [np.flatnonzero(label == s) for s in range(count)]
        self.points = [np.unique(faces[m]) for m in self.members]
        self.lo = np.array([vertices[p].min(axis=0) for p in self.points])
        self.hi = np.array([vertices[p].max(axis=0) for p in self.points])

    def __call__(self, s: int, t: int) -> np.ndarray:
        p = self.vertices[self.points[s]]
        inside = np.zeros(len(p), bool)
        if s == t or (self.lo[s] > self.hi[t]).any() or (self.hi[s] < self.lo[t]).any():
            return inside
        near = ((p >= self.lo[t]) & (p <= self.hi[t])).all(axis=1)
        if near.any():
            tri = [x[self.members[t]] for x in self.corners]
            inside[near] = np.abs(winding(p[near], *tri)) > 0.5
        return inside


def bodies(vertices, faces) -> list[tuple[np.ndarray, float]]:
    """The separate bodies of a closed mesh (faces oriented outwards): for each shell nested
    in an even number of others (a body, not a cavity), `(its face indices, the volume it
    encloses)`, the largest volume first."""
    count, label = shells(faces)
    vertices, volume = _volumes(vertices, faces, count, label)
    depth = nesting(vertices, faces, count, label) if count > 1 else np.zeros(1, np.int64)
    found = [(np.flatnonzero(label == s), abs(float(volume[s])))
             for s in np.flatnonzero(depth % 2 == 0)]
    return sorted(found, key=lambda body: -body[1])

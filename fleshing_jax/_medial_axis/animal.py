"""Procedural four-legged animals: the thin-limbed test shapes of issues 30 and 33.

A body, a head, four legs, a thin tail and two thin, tapering horns: the features on which
medial meshes lost accuracy and fell apart. Each is built as the envelope of a hand-made
medial mesh (one cone per limb), so it is closed and manifold at any resolution
(`envelope`), with no mesh boolean, and its medial axis is known.

- `animal`: each leg a cone from its hip sphere (radius 0.1) to its foot (0.05), so the two
  legs of a pair meet below the body down to their feet (a V with two feet);
- `quadruped`: four separate cylindrical legs of radius 5 % of the body's length, from
  inside the body (a real animal's legs, which a skeleton must tell apart).
"""

from __future__ import annotations

import numpy as np
import trimesh

from .medial_mesh import MedialMesh


def animal_medial(leg: float = 0.05, tail: float = 0.025, horn: float = 0.02) -> MedialMesh:
    """The animal's own medial mesh: a body from x = 0.2 to 0.8 (length 1 with the head
    and tail), legs tapering from the hips to a radius `leg` at z = −0.05, a tail of radius
    `tail` tapering to 0.8 of it, horns from 1.5 `horn` to `horn` (thinner tips fall apart
    into loose blobs on the envelope's grid at coarse resolutions)."""
    return _medial(leg, tail, horn, apart=None)


def quadruped_medial(leg: float = 0.05, tail: float = 0.025, horn: float = 0.02,
                     apart: float = 0.08) -> MedialMesh:
    """`animal_medial` with four cylindrical legs of radius `leg`, each a cone of two equal
    spheres from inside the body (z = 0.4, joined to its hip sphere) down to z = −0.05, at
    `±apart` across the body: the legs of a pair `2 (apart − leg)` apart."""
    return _medial(leg, tail, horn, apart)


def _medial(leg, tail, horn, apart) -> MedialMesh:
    spheres, edges = [], []

    def add(centre, radius, parent=None):
        spheres.append((*centre, radius))
        if parent is not None:
            edges.append((parent, len(spheres) - 1))
        return len(spheres) - 1

    hind = add((0.2, 0, 0.45), 0.10)
    front = add((0.8, 0, 0.45), 0.10, add((0.5, 0, 0.47), 0.12, hind))
    head = add((0.95, 0, 0.6), 0.07, front)
    for side in (-1, 1):
        add((1.02, 0.1 * side, 0.85), horn, add((0.98, 0.06 * side, 0.72), 1.5 * horn,
                                                      head))
        for x, hip in ((0.25, hind), (0.75, front)):
            if apart is None:
                add((x, 0.06 * side, -0.05), leg, hip)
            else:
                add((x, apart * side, -0.05), leg, add((x, apart * side, 0.4), leg, hip))
    add((-0.1, 0, 0.5), 0.8 * tail, add((0.05, 0, 0.55), tail, hind))
    spheres = np.array(spheres)
    return MedialMesh(spheres[:, :3], spheres[:, 3], np.array(edges))


def animal(resolution: int = 48, **thickness) -> trimesh.Trimesh:
    """The animal's closed, manifold surface: the envelope of `animal_medial(**thickness)`
    at `resolution` (9,274 vertices at the default 48; one shell from 40 up, while below
    the horns' tips, thinner than a grid cell, come loose)."""
    return animal_medial(**thickness).envelope(resolution)


def quadruped(resolution: int = 48, **thickness) -> trimesh.Trimesh:
    """The closed, manifold surface of `quadruped_medial(**thickness)` at `resolution`
    (3,080 vertices at 28, its horn tips loose; 4,256 at 32; 9,654 at 48): four legs
    that a skeleton can tell apart."""
    return quadruped_medial(**thickness).envelope(resolution)

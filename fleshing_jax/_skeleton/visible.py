"""Whether a bend of a limb visibly moves the surface: a limb that it would not is none.

A pose bends a limb from its joint: the vertices of its region that project on its spine
past the joint move, with all its descendants' regions; those before the joint stay still.
A bend moves something a user sees when it moves at least `FEWEST` of the limb's own
vertices and one moved vertex lies at least `VISIBLE` of the mesh's diagonal from the joint
(a 30° bend moves it by half that distance). Else the limb is a bump or a medial mesh's
spike (an insect's limbs of 3–33 vertices; a 25-vertex knob by the bunny's front paws, one
of them past its joint, which counting the vertices before the joint kept), and it joins its
parent.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .regions import spine_samples
from .skeleton import descendants, merge_limb

# A limb's bend moves at least this many of its own vertices, and one moved vertex (its own
# or its descendants') at least this fraction of the mesh's diagonal from its joint.
FEWEST = 12
VISIBLE = 0.04


def moves_visibly(spine, joint: float, own: np.ndarray, carried: np.ndarray,
                  diagonal: float) -> bool:  # fmt: skip
    """Whether bending a limb at `joint` visibly moves the surface.

    **Arguments:** `spine`: the limb's rest spine; `joint`: its joint's arc length; `own`:
    (m, 3) its region's vertices (those projecting past `joint` move); `carried`: (c, 3) its
    descendants' region vertices (all move with it); `diagonal`: the mesh's diagonal.

    **Returns:** `True` when at least `FEWEST` of `own` project past the joint and a moved
    vertex lies at least `VISIBLE * diagonal` from the joint's point.
    """
    s, points, _ = map(np.asarray, spine_samples(spine))
    past = own[s[cKDTree(points).query(own)[1]] > joint] if len(own) else own
    moved = np.concatenate([past.reshape(-1, 3), carried.reshape(-1, 3)])
    # The joint's point between its samples (evaluating the spine there, eagerly, compiled its
    # operations one by one: 3.4 s of a 47k-vertex spot's 11 s skeleton, cold).
    at = np.array([np.interp(joint, s, points[:, k]) for k in range(3)])
    far = np.linalg.norm(moved - at, axis=1).max(initial=0.0)
    return len(past) >= FEWEST and float(far) >= VISIBLE * diagonal


def box_diagonal(vertices: np.ndarray) -> float:
    """The diagonal of `vertices`' (n, 3) bounding box."""
    return float(np.linalg.norm(np.ptp(vertices, axis=0)))


def visible(limbs: list, region: np.ndarray, vertices: np.ndarray):
    """`(limbs, region)` with every limb that a bend would not visibly move (`moves_visibly`)
    merged into its parent, the deepest first (a limb's merged children count as its own
    vertices, where they lie past its joint); the limbs renumbered."""
    size = box_diagonal(vertices)
    k = len(limbs) - 1
    while k >= 0:
        below = descendants(limbs)[k]
        own, carried = vertices[region == k], vertices[np.isin(region, below)]
        if not moves_visibly(limbs[k].spine, float(limbs[k].joint), own, carried, size):
            limbs, region = merge_limb(limbs, region, k)
        k -= 1
    return limbs, region

"""A skeleton from chains of joints a user places, as an animator places bones in Blender.

`fj.skeleton(mesh, chains=[[p0, p1, …, pn], …])`: each chain runs from the body outwards,
`p0` where the limb leaves its parent (a hip, a shoulder, the base of a neck), `p1 … p(n−1)`
its joints (knee, ankle), `pn` its tip, every point inside the shape. A chain of n + 1
points is n limbs, each the parent of the next (thigh → shin → foot). Limb i's spine runs
from about a radius before `p(i)` through `p(i+1) … pn` to the surface beyond `pn`; its
region is cut out of limb i − 1's at `p(i)`, the first one's out of the region holding
`p0` when the earlier chains are cut (the body; the head for an ear's chain listed after
the head's). The local radius at each point is its distance to the surface (the spine's
curvature bound and its region's reach, as the medial radius is for a found limb): a point
just outside, or a tip just within the surface, is first moved to the middle of the shape
there (`inside.placed_inside`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._checks import check_finite_points
from .inside import placed_inside
from .limb_fit import fit_limb
from .limbs import LimbPath
from .skeleton import Limb


def check_chains(chains, vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """`chains` as a list of (k, 3) float64 arrays, k ≥ 2, every point inside the mesh (one
    just past it moved inside: `inside.placed_inside`) and no two consecutive points equal;
    else `TypeError`/`ValueError` naming the chain and point."""
    if isinstance(chains, str | bytes) or not hasattr(chains, "__len__") or len(chains) == 0:
        raise TypeError(
            "`chains` must be a non-empty list of chains, each a list of points [p0, p1, …] "
            f"from the body outwards, got {type(chains).__name__}."
        )
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    checked = []
    for i, chain in enumerate(chains):
        points = check_finite_points(chain, f"chains[{i}]")
        if points.ndim != 2 or len(points) < 2:
            raise ValueError(
                f"`chains[{i}]` must hold at least 2 points (where the limb leaves its parent, "
                f"then its joints and its tip), got shape {points.shape}."
            )
        steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
        if np.any(steps <= 1e-9 * diagonal):
            j = int(np.argmax(steps <= 1e-9 * diagonal))
            raise ValueError(f"`chains[{i}]`: points {j} and {j + 1} are the same point.")
        points = placed_inside(points, [f"`chains[{i}][{j}]`" for j in range(len(points))],
                               vertices, faces, "chains", np.arange(len(points)) == len(points) - 1)
        steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
        if np.any(steps <= 1e-9 * diagonal):
            j = int(np.argmax(steps <= 1e-9 * diagonal))
            raise ValueError(f"`chains[{i}]`: points {j} and {j + 1} lie past the surface: "
                             "moved inside, they are the same point.")
        checked.append(points)
    return checked


def given_limbs(chains, vertices, faces, adjacency, margin):
    """The limbs and region (n,) of the user's `chains` (see the module's docstring): each
    chain's limbs in order, parents before children. `margin`: the valid region's that posing
    will use. Raises `ValueError` naming the chain and point where a limb gets no region."""
    tree = cKDTree(vertices)
    region = np.full(len(vertices), -1)
    limbs: list[Limb] = []
    for c, points in enumerate(check_chains(chains, vertices, faces)):
        parent = int(region[tree.query(points[0])[1]])
        for i in range(len(points) - 1):
            limb = chain_limb(points, i, parent, tree, region, vertices, adjacency, margin)
            parent = add_limb(limbs, region, limb, (
                f"`chains[{c}]`: the limb from point {i} to its tip gets no part of the "
                "surface to move (no vertex past the point within the spine's reach, or "
                "less than a radius to bend): move the point towards the body or drop it."))
    return limbs, region


def add_limb(limbs: list, region: np.ndarray, limb, refusal: str) -> int:
    """`limb` (`chain_limb`'s `(Limb, vertex indices)`) appended to `limbs` and its vertices
    given to it in `region` (in place); its index. `ValueError(refusal)` where it is `None`."""
    if limb is None:
        raise ValueError(refusal)
    region[limb[1]] = len(limbs)
    limbs.append(limb[0])
    return len(limbs) - 1


def chain_limb(points, i, parent, tree, region, vertices, adjacency, margin):
    """The limb of the chain of joints `points` ((k, 3)) from its point `i` to its tip, cut out
    of the region of limb `parent` (−1: the body; `region` (n,) the limbs' so far):
    `(Limb, its region's vertex indices)`, or `None` when it gets no part of the surface.
    `tree`: a `cKDTree` of `vertices`."""
    radius = tree.query(points)[0]  # the distance to the surface, at a vertex's precision
    # As spheres: a point a radius before p0 (inside the parent: the spine starts there),
    # then the chain's points.
    out = (points[1] - points[0]) / np.linalg.norm(points[1] - points[0])
    centers = np.concatenate([(points[0] - radius[0] * out)[None], points])
    radii = np.r_[radius[0], radius]
    path = np.arange(i + 1, len(centers))  # p(i) … pn
    found = LimbPath(path, i, np.zeros(0, int), path, parent)
    spine, part = fit_limb(found, centers, radii, vertices, adjacency, region == parent,
                           margin, cut_at=points[i])  # fmt: skip
    return None if part is None else (Limb(spine, part.joint, parent), part.vertices)

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
there (`inside.placed_inside`). A chain bent at rest at a joint past what one spine follows
(a dinosaur's or an insect's leg up to its knee, then down) has the limb before that joint
fitted up to it, its region the chain's own vertices (nearer to it than to the other chains
or bones), as a found limb bent at rest is (`rest_bend`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._checks import check_finite_points
from .chains import TURN
from .inside import bisectors, on_axis, placed_inside
from .limb_fit import WIDE, fit_limb
from .limbs import LimbPath
from .regions import REACH, spine_samples
from .skeleton import Limb

# A bone shorter than this many times the shape's thickness at its head (its distance to the
# surface) is the body's: a torso's spine bone, a coxa or a clavicle from the torso's middle.
# Bent at rest into its limb, it is not fitted up to its joint as a leg is (`chain_limb`).
SHORT = 2.0
# A chain's first segment leaves the part it starts in (a head, for an ear's bone from its
# middle) at a waist, where that part is this many times as thick as the chain past the waist,
# and the waist this many times thinner (`leaves_part`).
THICKER = 2.0


def check_chains(chains, vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """`chains` as a list of (k, 3) float64 arrays, k ≥ 2, every point inside the mesh (one
    just past it moved inside: `inside.placed_inside`; a joint off its limb's axis moved onto
    it: `inside.on_axis`) and no two consecutive points equal; else `TypeError`/`ValueError`
    naming the chain and point."""
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
    # Joints off the limb's axis (a knee placed at its front) moved onto it (`on_axis`).
    inner = [(i, j) for i, points in enumerate(checked) for j in range(1, len(points) - 1)]
    if inner:
        at = np.array([checked[i][j] for i, j in inner])
        axes = bisectors(np.array([checked[i][j - 1] for i, j in inner]), at,
                         np.array([checked[i][j + 1] for i, j in inner]))
        moved = on_axis(at, axes, vertices, faces, [f"`chains[{i}][{j}]`" for i, j in inner],
                        "chains")
        for (i, j), point in zip(inner, moved, strict=True):
            checked[i][j] = point
    return checked


def given_limbs(chains, vertices, faces, adjacency, margin):
    """The limbs and region (n,) of the user's `chains` (see the module's docstring): each
    chain's limbs in order, parents before children. `margin`: the valid region's that posing
    will use. Raises `ValueError` naming the chain and point where a limb gets no region."""
    tree = cKDTree(vertices)
    region = np.full(len(vertices), -1)
    limbs: list[Limb] = []
    checked = check_chains(chains, vertices, faces)
    for c, points in enumerate(checked):
        parent = int(region[tree.query(points[0])[1]])
        for i in range(len(points) - 1):
            limb = chain_limb(points, i, parent, tree, region, vertices, adjacency, margin,
                              _segments([*checked[:c], points[:i + 1], *checked[c + 1:]]))
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


def _segments(chains) -> np.ndarray:
    """(m, 2, 3): the segments of the polylines `chains` (each (k, 3), k ≥ 1)."""
    pieces = [np.stack([c[:-1], c[1:]], axis=1) for c in chains if len(c) > 1]
    return np.concatenate(pieces) if pieces else np.zeros((0, 2, 3))


def chain_limb(points, i, parent, tree, region, vertices, adjacency, margin, others=None,
               name: str = "", at_root: bool = False):
    """The limb of the chain of joints `points` ((k, 3)) from its point `i` to its tip, cut out
    of the region of limb `parent` (−1: the body; `region` (n,) the limbs' so far):
    `(Limb, its region's vertex indices)`, or `None` when it gets no part of the surface.
    `tree`: a `cKDTree` of `vertices`; `others`: (m, 2, 3) the other bones' or chains'
    segments (where a chain bent at rest has its own vertices); `name`: the limb's name;
    `at_root`: a chain's first limb cut where it leaves the part `p0` lies in
    (`leaves_part`: an armature's bone from a head's middle to an ear), not at `p0` (a
    user's chain starts where its limb leaves its parent)."""
    radius = tree.query(points)[0]  # the distance to the surface, at a vertex's precision
    # As spheres: a point a radius before p0 (inside the parent: the spine starts there),
    # then the chain's points.
    out = (points[1] - points[0]) / np.linalg.norm(points[1] - points[0])
    centers = np.concatenate([(points[0] - radius[0] * out)[None], points])
    radii = np.r_[radius[0], radius]
    path = np.arange(i + 1, len(centers))  # p(i) … pn
    found = LimbPath(path, i, np.zeros(0, int), path, parent)
    allowed = region == parent
    cut = leaves_part(points, tree) if at_root and i == 0 else points[i]
    spine, part = fit_limb(found, centers, radii, vertices, adjacency, allowed, margin,
                           cut_at=cut)
    if (part is not None and i + 2 < len(points) and turn_at(points, i + 1) >= TURN
            and np.linalg.norm(points[i + 1] - points[i]) >= SHORT * radius[i]
            and part.joint > arc_at(spine, points[i + 1])):
        # Bent at rest at its next joint (a dinosaur's or an insect's leg, up to the knee and
        # down), past what one spine follows: the spine cuts the knee's corner, and the
        # region grown from the tip lost the limb's own bone (see `rest_bend`). Its spine is
        # then fitted up to that joint only, its region grown among the chain's vertices
        # beyond p(i) whatever their distance to that spine; the next limbs cut theirs out.
        # (Only a limb as long as the shape is thick at its start: a torso's spine bones,
        # shorter, are its body, not a leg bent at rest.)
        top = np.arange(i + 1, i + 3)  # p(i), p(i+1)
        chain = allowed & _nearest_segments(points[i:], radius[i:], others, vertices, tree)
        top_spine, top_part = fit_limb(LimbPath(top, i, np.zeros(0, int), top, parent),
                                       centers, radii, vertices, adjacency, allowed, margin,
                                       cut_at=points[i], owned=chain)  # fmt: skip
        if top_part is not None and top_part.joint < arc_at(top_spine, points[i + 1]):
            spine, part = top_spine, top_part
    return None if part is None else (Limb(spine, part.joint, parent, name), part.vertices)


def leaves_part(points: np.ndarray, tree) -> np.ndarray:
    """(3,): where a chain `points` ((k, 3)) leaves the part its first point lies in: that
    point, unless the part is at least `THICKER` times as thick there as the chain's first
    segment is past a waist it narrows to, itself `THICKER` times thinner than that (the
    distances to the surface, a `cKDTree` `tree` of the vertices): a bone from a head's
    middle to an ear's tip, which leaves the head at the ear's root. Cut there, the ear's
    region is the ear, not the half of the head on its side, and it bends at its root. (A
    horn modelled as a cone from the head's middle narrows all its length; a tail's bone from
    its root, as thick, passes near its curved surface: neither is cut further out.)"""
    along = np.linspace(0.0, 1.0, 65)[:, None]
    samples = points[0] + along * (points[1] - points[0])
    depth = tree.query(samples)[0]
    waist = int(np.argmin(depth))
    beyond = depth[waist:].max()  # the chain's own thickness past its waist
    if THICKER * depth[waist] > beyond or depth[0] < THICKER * beyond:
        return points[0]
    return samples[waist]


def turn_at(points: np.ndarray, j: int) -> float:
    """The angle (degrees) between the segments before and after `points[j]`."""
    a, b = points[j] - points[j - 1], points[j + 1] - points[j]
    cosine = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def arc_at(spine, point: np.ndarray) -> float:
    """The arc length of `spine`'s sample nearest to `point` (3,)."""
    s, samples, _ = map(np.asarray, spine_samples(spine))
    return float(s[np.argmin(np.linalg.norm(samples - point, axis=1))])


def _nearest_segments(points, radius, others, vertices, tree) -> np.ndarray:
    """(n,) bool: the `vertices` within `WIDE · REACH` local radii of the polyline `points`
    (k, 3) (the radius interpolated along each segment between its ends' `radius` (k,)) and
    nearer to it, in local radii, than to any of the `others` segments ((m, 2, 3) or `None`:
    the other bones or chains; their radii the distances of their ends to the surface, a
    `cKDTree` `tree` of `vertices`), as a found limb's own vertices are those nearest to its
    medial spheres: a thigh's, not the body's around its hip."""
    gap, reach = _segment_gaps(points[:-1], points[1:], vertices, radius[:-1], radius[1:])
    own = np.min(gap / reach, axis=0)
    near = own <= WIDE * REACH
    if others is not None and len(others):
        ends = tree.query(others.reshape(-1, 3))[0].reshape(-1, 2)
        gap, reach = _segment_gaps(others[:, 0], others[:, 1], vertices, ends[:, 0], ends[:, 1])
        near &= own <= np.min(gap / reach, axis=0)
    return near


def _segment_gaps(a, b, vertices, ra, rb):
    """`(gaps (k, n), radii (k, n))`: each vertex's distance to each segment `a[j]`–`b[j]`
    ((k, 3) each), and the radius there interpolated between `ra` and `rb` ((k,), > 0)."""
    gaps, radii = [], []
    for p, q, r0, r1 in zip(a, b, ra, rb, strict=True):
        t = np.clip((vertices - p) @ (q - p) / max(float((q - p) @ (q - p)), 1e-300), 0.0, 1.0)
        gaps.append(np.linalg.norm(vertices - (p + t[:, None] * (q - p)), axis=1))
        radii.append(np.maximum(r0 + t * (r1 - r0), 1e-300))
    return np.array(gaps), np.array(radii)

"""The part of the surface that each limb moves: its region, cut where it leaves its parent.

Our own construction. A limb's region is grown over the mesh's edges from the vertex nearest
to its tip, through the vertices of its parent's region that project on the limb's spine
beyond the cut (the arc length where the spine leaves the parent) and lie within the spine's
reach (nearer than the radius of curvature, and than `REACH` local medial radii: a flat
belly next to a leg projects beyond the leg's cut too, but far from its spine); the pieces
of the parent's region that this cuts off from its largest part join the limb. Limbs are
cut from their parents' regions in topological order, children out of their parent's.
The joint is then the largest arc length of the region's border vertices (at least the cut),
so that a bend starting there leaves the border still; a limb with less than its radius left
to bend beyond its joint is none (a knob). Last, a chain's top's slanted border with its
parent (the body, or a head for an ear) is levelled across its spine (`levelled`): the joint
rises to the border's top, over the parent's vertices that face away from the spine (the
limb's own outer side, not a flank across a gap from it).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from .skeleton import Limb

SAMPLES = 512  # arc-length samples of a spine for the vertices' projections
REACH = 1.5  # a region vertex lies within this many local medial radii of its spine
# A body vertex past the top of a limb's slanted border, within this many times the limb's
# own thickness there (`levelled`), is the limb's shoulder.
LEVEL = 1.5


@dataclasses.dataclass(frozen=True)
class LimbRegion:
    """A limb's `vertices` (indices) and its `joint` (arc length) on its spine; `bent`: the
    limb is bent at rest past what one spine within reach of its region can follow
    (`limb_fit`), to be split at its bend."""

    vertices: np.ndarray
    joint: float
    bent: bool = False


@eqx.filter_jit
def spine_samples(spine, count: int = SAMPLES):
    """`count` arc lengths evenly spaced on `spine`, its points there and its curvature."""
    s = jnp.linspace(0.0, spine.length, count)
    curvature = jnp.linalg.norm(jax.vmap(spine.curvature_vector)(s), axis=1)
    return s, jax.vmap(spine)(s), curvature


def mesh_adjacency(vertices: np.ndarray, faces: np.ndarray) -> sparse.csr_matrix:
    """The mesh's edges as a symmetric sparse graph on its vertices."""
    n = len(vertices)
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return (graph + graph.T).tocsr()


def limb_region(spine, cut: float, tip: np.ndarray, arc, radius, vertices, adjacency, allowed,
                reach_factor: float = REACH, own=None, owned=None):
    """The region of one limb, or `None` when no vertex qualifies or it is a knob.

    **Arguments:** `spine`: the limb's rest spine; `cut`: the arc length where it leaves its
    parent; `tip`: (3,) the point its region grows from; `arc`, `radius`: (k,) the local medial
    radius at arc lengths `arc` along the spine; `vertices`: (n, 3) the mesh's;
    `adjacency`: `mesh_adjacency`; `allowed`: (n,) bool, the parent's region;
    `reach_factor`: how many local medial radii a vertex may lie from the spine (`REACH`);
    `own`: (n,) bool or `None`, the vertices that may lie beyond `REACH` radii (up to
    `reach_factor`) when given: the limb's own surface, not a neighbour's; `owned`: (n,) bool
    or `None`, when given the region is grown among these vertices (those nearest to the
    limb's medial spheres) instead of within a reach of its spine: a part wider or flatter
    than its spine's radii say, whose reach band borders the rest of it the band's whole
    length (a flat ear's strip) or lies against the parent (a foot's knob under a body).
    """
    s, points, curvature = map(np.asarray, spine_samples(spine))
    tree = cKDTree(points)
    # A vertex outside the parent's region, or farther from every sample than the reach's
    # largest radius (outside their box grown by it), is in no candidate region: its
    # nearest sample is not searched for (most of a large mesh, for each limb tried: the
    # search was 75 % of the bunny's skeleton's region time); its arc length is NaN, found
    # below if it borders the region. (`owned` regions are bounded by the focal distance
    # alone: searched wherever allowed.)
    bound = np.inf if owned is not None else max(reach_factor, REACH) * float(np.max(radius))
    searched = np.asarray(allowed, bool) & np.all(
        (vertices > points.min(axis=0) - bound) & (vertices < points.max(axis=0) + bound), axis=1)
    distance, nearest = np.full(len(vertices), np.inf), np.zeros(len(vertices), np.int64)
    distance[searched], nearest[searched] = tree.query(vertices[searched],
                                                       distance_upper_bound=bound)
    searched &= nearest < len(s)
    nearest = np.where(searched, nearest, 0)
    along = np.where(searched, s[nearest], np.nan)
    local = np.interp(along, arc, radius)
    focal = 1.0 / np.maximum(curvature[nearest], 1e-300)
    within = distance < np.minimum(reach_factor * local, focal)
    if own is not None:
        within = (distance < np.minimum(REACH * local, focal)) | (within & own)
    if owned is not None:
        within = owned & (distance < focal)
    candidate = allowed & (along > cut) & within
    seed = int(np.argmin(np.where(candidate, np.linalg.norm(vertices - tip, axis=1), np.inf)))
    if not candidate[seed]:
        return None
    inside = sparse.diags(candidate.astype(float))
    _, labels = csgraph.connected_components(inside @ adjacency @ inside, directed=False)
    member = candidate & (labels == labels[seed])
    # The parent keeps the largest part of what is left; pieces cut off from it (vertices
    # beyond the spine's reach, enclosed by the limb) go with the limb, or they would tear.
    rest = allowed & ~member
    if not rest.any():
        return None  # it would take all its parent's region: no still part to leave
    outside = sparse.diags(rest.astype(float))
    _, labels = csgraph.connected_components(outside @ adjacency @ outside, directed=False)
    kept = rest & (labels == np.argmax(np.bincount(labels[rest])))
    member = allowed & ~kept
    region = np.flatnonzero(member)
    border = region[adjacency[region] @ kept.astype(float) > 0]
    unsearched = border[~searched[border]]  # (a piece cut off beyond the reach, bordering)
    along[unsearched] = s[tree.query(vertices[unsearched])[1]]
    joint = max(cut, float(along[border].max()) if len(border) else cut)
    # Just beyond the border's last vertex (a bend from there leaves them all still).
    joint += 1e-9 * float(s[-1])
    if float(s[-1]) - joint < np.interp(joint, arc, radius):
        return None  # less than a radius left to bend: a knob (spot's tail tuft), no limb
    return LimbRegion(region, joint)


def within_reach(points: np.ndarray, samples: np.ndarray, curvature: np.ndarray,
                 margin: float, chunk: int = 2048) -> np.ndarray:
    """`in_reach`'s `within` (m,) bool alone, the same values, its distances computed only to
    the samples that could fail a point: `κ(t) (|X − C(t)| + δ) ≥ 1` with `|X − C(t)|`
    below the point's nearest distance `d₀` plus `2δ` needs `κ(t) (d₀ + 3δ) > 1`, so a sample
    whose curvature keeps it below for the farthest point's `d₀` is never read (on a
    limb's mostly straight spine, none is: the bunny's limbs, 100 ms a call by all of
    `in_reach`'s distances)."""
    nearest = cKDTree(samples).query(points)[1]
    least = np.linalg.norm(points - samples[nearest], axis=-1)  # (`in_reach`'s minimum)
    risky = np.flatnonzero(curvature * (least.max(initial=0.0) + 3 * margin) * (1 + 1e-9) >= 1)
    within = np.ones(len(points), bool)
    for start in range(0, len(points) if len(risky) else 0, chunk):
        distance = np.linalg.norm(points[start : start + chunk, None] - samples[None, risky],
                                  axis=-1)  # fmt: skip
        near = distance < least[start : start + chunk, None] + 2 * margin
        within[start : start + chunk] = ~np.any(
            near & (curvature[risky] * (distance + margin) >= 1.0), axis=1)
    return within


def in_reach(points: np.ndarray, samples: np.ndarray, curvature: np.ndarray, margin: float,
             chunk: int = 2048):
    """Whether each of `points` (m, 3) lies within the reach of a spine (sampled: `samples`
    (k, 3), their `curvature` (k,)) with the `margin` `δ` around it: `κ(t) (|X − C(t)| + δ)
    < 1` at every sample `C(t)` nearer than the point's nearest plus `2δ` (the points the
    valid region's test reads around the foot). Returns `(within (m,) bool, far (k,))`, `far`
    the largest distance to each sample of the points it is near."""
    within, far = np.ones(len(points), bool), np.zeros(len(samples))
    for start in range(0, len(points), chunk):
        distance = np.linalg.norm(points[start : start + chunk, None] - samples[None], axis=-1)
        near = distance < distance.min(axis=1, keepdims=True) + 2 * margin
        within[start : start + chunk] = ~np.any(near & (curvature * (distance + margin) >= 1.0),
                                                axis=1)  # fmt: skip
        far = np.maximum(far, np.max(np.where(near, distance, 0.0), axis=0))
    return within, far


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) unit normals of a mesh's vertices (its faces' normals weighted by their areas;
    outwards for faces oriented outwards, as `closed_mesh_arrays` gives them)."""
    face = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                    vertices[faces[:, 2]] - vertices[faces[:, 0]])  # fmt: skip
    summed = np.stack([sum(np.bincount(faces[:, c], face[:, d], len(vertices)) for c in range(3))
                       for d in range(3)], axis=1)  # fmt: skip
    return summed / np.maximum(np.linalg.norm(summed, axis=1, keepdims=True), 1e-300)


def levelled(limbs: list, region: np.ndarray, vertices: np.ndarray, normals: np.ndarray,
             adjacency, tops, margin: float):
    """`(limbs, region)` with each limb of `tops` (the top of each chain: a limb that leaves
    the body or another limb's region, not a piece of a chain below its joint) grown, ring
    by ring from its border, over its parent's vertices (the body's, or its parent limb's)
    that project on its spine past the border's top (its least arc length) within `LEVEL`
    times the limb's thickness there (its own vertices' largest distance from the spine
    between the border's top and bottom), face away from the spine (`normals`: (n, 3),
    the vertices' outward normals) and lie within its reach with the valid region's `margin`
    (`in_reach`: a vertex beyond it, which posing would flag, would also give the border an
    arc length of no meaning); its joint then the new border's last arc length.

    A leg meeting a belly at a slant (spot's front legs: the body runs down the shoulder's
    outer side 60 % of the leg) puts the joint past the border's lowest vertex, so that a
    bend moved only the leg's lower part: "lift the leg" flicked a hoof. The shoulder's
    vertices beside the leg's top join the leg (about 30 on spot), the border runs across
    the spine, and the joint rises (spot's front legs: 59 % and 51 % of the spine → 33 %).
    An ear on a head alike (spot's at seed 0: the head down its side from 18 % to 67 % of
    its spine, the joint at 67 % → 33 %). Only the parent's vertices move: siblings and
    children keep their regions. The parent keeps its region's largest connected part
    (pieces the growth cuts off go with the limb).

    A vertex facing the spine lies across a gap from the limb, on a neighbouring surface,
    and is the parent's: the limb's own such vertices (touching no third region) go back to
    it first, ring by ring from it, and the growth passes over none. An arm hanging beside
    the torso (cheburashka's) lies within reach of the flank, which faces it: the arm's
    region, within `REACH` medial radii of its spine, missed the upper arm's outer side (the
    body ran down it to 66 % of the spine) and took flank vertices (bordering the body at
    49 %); levelled over the flank too, the border ran down past the hand and was refused,
    and the arm bent from the wrist (66 % of its spine; now 42 %). Its other arm keeps 44 %:
    its spine turns down at the shoulder with a radius of curvature (0.026) below the
    shoulder's distance from it (0.03–0.04), beyond its reach.
    """
    limbs, region = list(limbs), region.copy()
    for k in sorted(tops):  # (parents first: a limb's region is final when its children grow)
        limb = limbs[k]
        s, points, curvature = map(np.asarray, spine_samples(limb.spine))
        distance, nearest = cKDTree(points).query(vertices)
        along = s[nearest]
        member, rest = region == k, region == limb.parent
        border = member & (adjacency @ rest.astype(float) > 0)
        if not border.any():
            continue
        top, bottom = along[border].min(), along[border].max()
        span = member & (along >= top) & (along <= bottom)
        outwards = np.einsum("ij,ij->i", normals, vertices - points[nearest]) > 0
        near = (distance <= LEVEL * distance[span].max()) & outwards
        candidates = np.flatnonzero(near & rest & (along > top))
        near[candidates] = within_reach(vertices[candidates], points, curvature, margin)
        # Its own vertices facing the spine past the border's top (the flank's within its
        # spine's reach) go back to the parent, ring by ring from it; not those touching a
        # third region (a child's: it would border the parent, before the limb's joint).
        others = adjacency @ ((region != k) & (region != limb.parent)).astype(float) > 0
        for _ in range(64):
            back = (member & ~outwards & ~others & (along > top)
                    & (adjacency @ rest.astype(float) > 0))  # fmt: skip
            if not back.any():
                break
            member &= ~back
            rest |= back
        for _ in range(64):  # (a ring a step; a slanted border is a few rings tall)
            grow = rest & near & (along > top) & (adjacency @ member.astype(float) > 0)
            if not grow.any():
                break
            member |= grow
            rest &= ~grow
        if not rest.any():
            continue  # (it would take its parent's whole region: nothing left)
        inside = sparse.diags(rest.astype(float))
        _, labels = csgraph.connected_components(inside @ adjacency @ inside, directed=False)
        rest &= labels == np.argmax(np.bincount(labels[rest]))
        border = member & (adjacency @ rest.astype(float) > 0)
        joint = float(along[border].max()) + 1e-9 * float(s[-1])
        grown = region.copy()
        grown[(region == limb.parent) & ~rest] = k
        grown[(region == k) & rest] = limb.parent
        # Kept only where the joint rises and every other region bordering the parent still
        # does (spot at 60 spheres: an ear's growth enclosed a horn beside it, which then
        # bordered the ear alone).
        if joint < float(limb.joint) and _neighbours(grown, limb.parent, adjacency) >= (
                _neighbours(region, limb.parent, adjacency) - {k}):  # fmt: skip
            region = grown
            limbs[k] = Limb(limb.spine, joint, limb.parent, limb.name)
    return limbs, region


def _neighbours(region: np.ndarray, k: int, adjacency) -> set:
    """The regions (limb numbers, −1 the body) other than `k` that border region `k`."""
    touching = adjacency @ (region == k).astype(float) > 0
    return set(np.unique(region[touching & (region != k)]).tolist())

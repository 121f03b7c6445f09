"""One limb's rest spine and region: the spine fitted through its path of spheres, the
region cut where it leaves its parent, and straighter fits until the region lies within the
spine's reach. Shared by `skeleton` (a limb found on the medial graph) and its jointed chains
(`chains`: the pieces of a limb past each joint)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .fit import extend_beyond, fit_bspline
from .limbs import LimbPath
from .regions import REACH, in_reach, limb_region, spine_samples, within_reach
from .visible import box_diagonal, moves_visibly

# Every limb's spine has one static structure (count of control points, subdivisions per
# span), so that one compiled program serves all (here and when posing them).
LIMB_CONTROL_POINTS = 8
LIMB_SUBDIVISIONS = 32
REFITS = 3  # straighter fits, at most, until the region lies within the spine's reach
# A straighter fit bounds the curvature by the region's distances to the spine (`far`), or by
# these shares of them when the full bound leaves no region (a knob): on spot at seed 1 the
# head's spine, made straight for its ears at 0.6, let its region end 0.13 from its tip, and
# the head with its ears and horns stayed in the body; at 0.75 of it every vertex is valid.
STRAIGHTER = (1.0, 0.75, 0.5)
# A limb from the body starts inside it, as an animator's hip or shoulder does: its region is
# cut this many radii of its first sphere before where its spine leaves the body's core (at
# most at the spine's start), where that raises its joint and keeps the region within the
# spine's reach (`fit_limb`). Spot's legs, 0.3 long below the belly, had their joints at
# the belly (a third of their spines), so a 30° bend moved the hooves by 2.4-3.2 % of the
# diagonal; now at 18-24 %, 0.04-0.08 higher.
TOP_INSIDE = 1.0
TOP_STRAIGHT = 4.0
# Times `regions.REACH`: how far a limb's region may reach among its own vertices (those
# nearest to its medial spheres) when the usual reach leaves it none.
WIDE = 2
# A straighter fit keeping less than this share of the region's vertices lost the limb past a
# bend at rest (the procedural and modelled insects' legs kept 35-49 %; spot's, the
# quadrupeds', the biped's, cheburashka's and the modelled human's and cow's skeletons are
# unchanged by the rule).
BENT_KEEPS = 0.6
# A route whose points (its start, spheres and tip) span less than this fraction of its
# thickest sphere's radius (or its parent's there) has no length: no spine (a hand's knuckle
# at one seed: its start, sphere and tip within 2e-6 of each other; in float32 its spine's
# control points coincided and `fj.skeleton` raised).
DEGENERATE = 1e-3


def fit_limb(found: LimbPath, centers, radii, vertices, adjacency, allowed, margin,
             cut_at=None, wide=None, owned=None):
    """The limb's rest spine and its region among the `allowed` vertices (`None` if none);
    `margin`: the valid region's that posing will use; `cut_at`: (3,) the point where the
    limb leaves its parent (a chain's joint), default where its spine leaves the parent's
    core spheres; `wide`: (n,) bool or `None`, the vertices that may lie up to `WIDE` times
    as far from the spine as usual when the usual reach leaves the limb no region; `owned`:
    (n,) bool or `None`, when given the limb's own vertices (nearest to its medial spheres),
    among which its region is grown instead, whatever their distance to the spine.

    A limb from the body is also cut `TOP_INSIDE` radii further in, its spine fitted
    `TOP_STRAIGHT` times straighter; that region is kept where its joint lies farther from
    the limb's end and it lies within its (refitted) spine's reach."""
    args = (found, centers, radii, vertices, adjacency, allowed, margin, cut_at, wide, owned)
    spine, part, _, tip = _fit(*args)
    # (Not a bump a bend would not visibly move: cut further in, it would be kept.)
    if part is not None and found.parent == -1 and cut_at is None and moves_visibly(
            spine, part.joint, vertices[part.vertices], np.empty((0, 3)), box_diagonal(vertices)):
        inner_spine, inner, arc, _ = _fit(*args, deeper=TOP_INSIDE)
        if (inner is not None
                and _lever(inner_spine, inner.joint, tip) > _lever(spine, part.joint, tip)
                and reach_needed(inner_spine, inner, vertices, arc, margin) is None):
            return inner_spine, inner
    return spine, part


def _lever(spine, joint: float, tip: np.ndarray) -> float:
    """The distance from the joint's point on `spine` to the limb's `tip` (3,) (a bend's
    lever: the straighter spine's own end may fall short of the tip)."""
    s, points, _ = map(np.asarray, spine_samples(spine))
    at = np.array([np.interp(joint, s, points[:, k]) for k in range(3)])
    return float(np.linalg.norm(tip - at))


def _fit(found, centers, radii, vertices, adjacency, allowed, margin, cut_at, wide, owned,
         deeper=0.0):
    """`fit_limb`'s spine and region, the cut `deeper` radii of the path's first sphere
    further in, the arc lengths of the spine's fitted points (`limb_spine`'s `arc`) and the
    limb's tip; all `None` for a route with no spine (`limb_spine`)."""
    fitted = limb_spine(found, centers, radii, vertices, margin, cut_at=cut_at, deeper=deeper)
    if fitted is None:
        return None, None, None, None
    spine, cut, tip, arc, local = fitted
    # A part wider than its spine's medial radii say: a head's crown beyond them (the region
    # grown within them is its lower half, bordering the body its whole length, a knob:
    # spot's head at seeds 6 and 11), a flat ear's lobe (a slab: its radius is its half
    # thickness; spot's ears at seeds 1, 2 and 10). Wider still, or against its parent (a
    # disc of an ear whose strip around the spine borders the rest of the disc its whole
    # length, a foot under a body: cheburashka's), the limb's own surface (`owned`).
    tries = [{"reach_factor": REACH}]
    if wide is not None:
        tries.append({"reach_factor": WIDE * REACH, "own": wide})
    if owned is not None:
        tries = [{"owned": owned}]
    for how in tries:
        part = limb_region(spine, cut, tip, arc, local, vertices, adjacency, allowed, **how)
        if part is not None:
            break
    lost = False
    for _ in range(REFITS):
        # The region's far vertices (the back of a head beyond its medial spheres, a haunch
        # beside a leg's start) may lie beyond the spine's reach: a straighter fit there.
        far = reach_needed(spine, part, vertices, arc, margin) if part is not None else None
        if far is None:
            break
        for share in STRAIGHTER:
            refit = limb_spine(found, centers, radii, vertices, margin, share * far, cut_at,
                               deeper)
            refit_part = (None if refit is None
                          else limb_region(*refit, vertices, adjacency, allowed, **how))
            if refit_part is not None:
                break
        # Straightened, a limb bent at rest (an insect's leg rising to its knee, then down)
        # loses its region, or most of it (the straight spine cuts the knee: the leg kept
        # only its shin): it is split at its bend (`rest_bend`). Where no straighter fit
        # has a region, it keeps the fit before (its far vertices flagged by any pose).
        lost |= refit_part is None or len(refit_part.vertices) < BENT_KEEPS * len(part.vertices)
        if refit_part is None:
            break
        spine, cut, tip, arc, local = refit
        part = refit_part
    if part is not None and lost:
        part = dataclasses.replace(part, bent=True)
    return spine, part, arc, tip


def reach_needed(spine, part, vertices, arc, margin, chunk=2048):
    """`None` when every vertex `X` of the region `part` lies within the reach of `spine`
    with the `margin` `δ` around it: `κ(t) (|X − C(t)| + δ) < 1` at every spine point `C(t)`
    nearer than its foot's distance plus `2δ` (the points the valid region's test reads
    around the foot). Else (k,) the largest distance of the region's vertices to the spine
    points near them, around the arc lengths `arc` (for a straighter fit)."""
    s, points, curvature = map(np.asarray, spine_samples(spine))
    if within_reach(vertices[part.vertices], points, curvature, margin, chunk).all():
        return None  # (most regions: the distances to every sample are not needed)
    _, far = in_reach(vertices[part.vertices], points, curvature, margin, chunk)
    # Over a window of arc lengths: the refitted spine's feet move a little.
    window = len(s) // 16
    padded = np.pad(far, window, mode="edge")
    far = np.max(np.lib.stride_tricks.sliding_window_view(padded, 2 * window + 1), axis=1)
    return np.interp(arc, s, far)


def limb_spine(found: LimbPath, centers, radii, vertices, margin, far=None, cut_at=None,
               deeper=0.0):
    """The limb's rest spine, the arc length where it leaves its parent, the point at its
    tip, and the medial radius at arc lengths along it (at least `far` at each path point, when
    given: the curvature bound then keeps those distances within reach), the cut `deeper`
    radii of the path's first sphere further in (at most at the spine's start); `None` for a
    route with no length (`DEGENERATE`) or none within the curvature bound."""
    path = centers[found.path]
    inside = centers[found.inside]
    # s = 0 a little inside the parent: towards the last sphere inside it, at most two
    # radii (a thick limb's first sphere, a head's, may lie far beyond its parent's surface).
    back = inside - path[0]
    gap = np.linalg.norm(back)
    start = path[0] + back * (min(gap, 2 * radii[found.path[0]]) / gap)
    tip = extend_beyond(np.concatenate([path[::-1], inside[None]]), radii[found.path[-1]],
                        vertices)  # fmt: skip
    points = np.concatenate([start[None], path, tip[None]])
    thickest = max(radii[found.inside], radii[found.path].max())
    if np.linalg.norm(np.ptp(points, axis=0)) < DEGENERATE * thickest:
        return None  # a route with no length (its sphere's centre and tip as one): none
    # At the start, the parent's radius: the spine may not turn there tighter than the
    # parent is thick (an ear's spine, from inside the head).
    local = radii[np.r_[found.inside, found.path, found.path[-1]]]
    bound = local if far is None else np.maximum(local, far)
    bound = bound * (1.0 + (TOP_STRAIGHT - 1.0) * min(deeper, 1.0))
    # Straight at both ends: the spine's continuations past its ends (osculating circles,
    # the closest-point search's range) are then its tangent lines, as the rigid motion of
    # the points beyond them is; a circle curving back towards the region (a haunch behind
    # a leg's start) put a cut locus among its vertices, which no pose could then move.
    # The curvature bound holds a margin beyond the radius (or beyond the distance of the
    # vertices that needed a straighter fit): the surface around the spine must stay clear
    # of its focal set by the valid region's margin.
    spine = fit_bspline(points, bound + margin, LIMB_CONTROL_POINTS, bounded=True,
                        subdivisions=LIMB_SUBDIVISIONS, straight_ends=True, strict=True)
    if spine is None:
        # No curve within the bound follows the route (far shorter than its radii): no
        # spine. (Its straight segment instead, fitted for the deeper cut of the Blender
        # insect's head at seed 2, left that head in the body.)
        return None
    s, samples, _ = map(np.asarray, spine_samples(spine))
    chord = np.r_[0, np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))]
    arc = chord * (s[-1] / chord[-1])
    if cut_at is not None:  # the spine's point nearest to it
        return spine, float(s[np.argmin(np.linalg.norm(samples - cut_at, axis=1))]), tip, arc, local
    # Where the spine leaves the parent's spheres that held the limb's last inner one.
    gaps = np.linalg.norm(samples[:, None] - centers[found.core], axis=-1)
    held = np.flatnonzero(np.any(gaps < radii[found.core], axis=1))
    cut = float(s[held[-1]]) if len(held) else 0.0
    return spine, max(0.0, cut - deeper * float(radii[found.path[0]])), tip, arc, local

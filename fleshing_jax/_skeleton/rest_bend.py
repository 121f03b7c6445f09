"""Limbs bent at rest: an insect's leg rising from the thorax to its knee, then down.

One spine cannot follow such a limb within its reach: its curvature is bounded by the
limb's radius (`fit.fit_bspline`), so it cuts the knee's corner, the thigh's vertices lie
beyond its reach, and the limb's region began past the knee (the modelled and the procedural
insects' legs: the thigh left in the body, "raise the leg" bent the shin). Straightening the
spine for its far vertices (`limb_fit`) lost the thigh the same way.

Where a limb's path turns by at least `BENT` degrees at a sphere (`rest_bend`) and its
region lost the part before that turn (it holds under `LOST` of the vertices nearest to the
path's spheres before it), or by `chains.TURN` where a straighter fit lost most of the
region (`LimbRegion.bent`), the limb is fitted as two pieces: its top on the path up to the
bend (a straight thigh), its region grown among the vertices nearest to its spheres (the
whole leg, whatever their distance from that spine), then its chain split at the bend first
(`chains.split_chains`): the shin's spine fitted from the knee on, its region cut out of the
top's there.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .chains import TURN, WINDOW, turning
from .limb_fit import fit_limb
from .limbs import LimbPath

BENT = 2 * TURN  # degrees: a turn this sharp at rest is a joint one spine cannot follow
LOST = 0.5  # a region holding under this share of the thigh's own vertices lost it


def rest_bend(path: np.ndarray, centers: np.ndarray, radii: np.ndarray,
              least: float = BENT) -> int | None:
    """The index in `path` (sphere indices) of its sharpest turn (`chains.turning` over
    ±`WINDOW` radii), at least `WINDOW` radii from both ends, if it turns by `least` degrees
    or more; else `None`."""
    line, r = centers[path], radii[path]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))]
    turn = turning(arc, line, arc, WINDOW * r)
    inner = (arc >= WINDOW * r) & (arc <= arc[-1] - WINDOW * r)
    turn = np.where(inner, turn, 0.0)
    m = int(np.argmax(turn))
    return m if turn[m] >= least else None


def fit_bent(route: LimbPath, part, centers, radii, vertices, adjacency, allowed, margin,
             nearest, others):
    """`(route, spine, part)` of the top piece of the limb fitted on `route` as `part`
    (`fit_limb`'s region) where it is bent at rest (see the module's docstring; the route's
    `bend` set), else `None`. `nearest` (n,): each vertex's nearest medial sphere;
    `allowed` (n,) bool: the parent's region; `others`: the spheres on other limbs' paths."""
    # (A straighter fit that lost most of the region names the bend: a chain's joint turn
    # is then enough.)
    m = rest_bend(route.path, centers, radii, TURN if part.bent else BENT)
    if m is None:
        return None
    thigh = allowed & np.isin(nearest, route.path[: m + 1])
    if not part.bent and (not thigh.any()
                          or np.isin(np.flatnonzero(thigh), part.vertices).mean() >= LOST):
        return None
    top = dataclasses.replace(route, path=route.path[: m + 1])
    # (Its spheres' vertices, its strips' below the hip too, but not another limb's path's:
    # a leg's `spheres` may hold its neighbour's, hung below it.)
    owned = allowed & np.isin(nearest, np.setdiff1d(route.spheres, others))
    spine, top_part = fit_limb(top, centers, radii, vertices, adjacency, allowed, margin,
                               owned=owned)
    if top_part is None:
        return None
    return dataclasses.replace(route, bend=m), spine, top_part

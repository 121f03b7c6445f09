"""Joints placed on or just past the surface, moved inside.

An armature's joints are not always inside the mesh: a tip bone's tail at the hoof's sole or a
fingertip, a joint where a subdivided skin shrank away from the cage it was modelled on
(Blender's skin modifier: 9 of the cow's 22 joints lie up to 0.026 outside its surface, the
tail's base among them). Blender does not mind; a limb does, since a joint's distance to the
surface is its radius there. A point outside by less than the shape's thickness at its
closest surface point is moved to the centre of the largest ball inside the surface that
touches that point (the medial ball there: the middle of a limb's cross-section, the centre
of a hoof's rounded end); one farther outside is misplaced (other units, other axes) and is
refused by the caller.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._medial_axis.surface import SurfaceQuery, first_hits, ray_inside

_STEPS = 32  # shrinking-ball steps (each halves the error or better; 5–10 on the cow)
# Chord midpoints a joint is moved by (`on_axis`): a round tube's off-axis knee is on its axis
# after the first; an oval one's nearer with each.
ROUNDS = 3


def placed_inside(points: np.ndarray, labels: list[str], vertices: np.ndarray,
                  faces: np.ndarray, argument: str, tips: np.ndarray) -> np.ndarray:
    """`points (k, 3)` (named by `labels` in messages) moved inside as `moved_inside` moves
    them (`tips (k,)` bool: a chain's last points), with a warning naming them;
    `ValueError` naming `argument` and the first point lying farther outside than the shape
    is thick at its closest surface point."""
    moved, distance, diameter = moved_inside(points, vertices, faces, tips)
    far = np.flatnonzero(distance > diameter)
    if len(far):
        i = int(far[0])
        raise ValueError(
            f"`{argument}`: {labels[i]} {np.asarray(points)[i].tolist()} lies outside the mesh, "
            f"{distance[i]:.3g} from its surface, farther than the shape is thick there "
            f"({diameter[i]:.3g}): place each joint inside the shape, in the mesh's units and "
            "axes (a tip a little inside its end)."
        )
    near = np.flatnonzero(np.isfinite(diameter))
    if len(near):
        named = ", ".join(f"{labels[i]} by {np.linalg.norm(moved[i] - points[i]):.3g}"
                          for i in near[:4])
        warnings.warn(
            f"`{argument}`: {len(near)} points on, past or (tips) just within the surface "
            f"moved to the middle of the shape there ({named}{', …' if len(near) > 4 else ''})",
            stacklevel=5,  # (the caller of fj.skeleton)
        )
    return moved


def moved_inside(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 tips: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`points (k, 3)` with those outside the closed mesh, and the `tips` (`(k,)` bool)
    inside it nearer its surface than half the medial radius there, moved to the centre of
    the medial ball at their closest surface point. (A tip's distance to the surface is its
    radius: a tip 0.02 within a leg's sole of radius 0.05 left the leg no region.)

    **Returns:** `(points (k, 3), outside (k,) how far each lay outside (0 inside),
    diameter (k,) of the ball it was moved to the centre of (inf where not moved))`.
    """
    points = np.array(points, np.float64)
    tips = np.zeros(len(points), bool) if tips is None else np.asarray(tips, bool)
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    outside = ~ray_inside(points, a, b, c)
    distance = np.zeros(len(points))
    diameter = np.full(len(points), np.inf)
    ask = np.flatnonzero(outside | tips)
    if len(ask) == 0:
        return points, distance, diameter
    surface = SurfaceQuery(vertices, faces)
    gap, foot, _ = surface.query(points[ask])
    # The inward normal at the closest point: from outside towards it, from inside away.
    sign = np.where(outside[ask], 1.0, -1.0)
    normal = sign[:, None] * (foot - points[ask]) / np.maximum(gap, 1e-300)[:, None]
    radius = _medial_radius(surface, foot, normal)
    move = outside[ask] | (gap < 0.5 * radius)
    ask, foot, normal, radius = ask[move], foot[move], normal[move], radius[move]
    points[ask] = foot + radius[:, None] * normal
    distance[ask] = np.where(outside[ask], gap[move], 0.0)
    diameter[ask] = 2 * radius
    return points, distance, diameter


def _medial_radius(surface: SurfaceQuery, foot: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """`(m,)` the radius of the largest ball inside the surface touching each `foot` with
    centre along its inward `normal`: shrinking from a ball as large as the shape, each step
    to the ball through the foot and the closest surface point of the last one's centre."""
    diagonal = float(np.linalg.norm(np.ptp(surface.vertices, axis=0)))
    radius = np.full(len(foot), diagonal)
    for _ in range(_STEPS):
        _, near, _ = surface.query(foot + radius[:, None] * normal)
        d = near - foot
        # The ball with its centre on the normal through the foot and `near`: taken where
        # they are at least 60° apart seen from its centre (|d| ≥ its radius). Closer, they
        # are two faces of one curved part, tessellated: a polygonal tube's ball through
        # one face and the next shrinks towards their shared edge (a 16-sided tube's from
        # its axis, 0.294, to 0.03).
        along = np.einsum("ij,ij->i", d, normal)
        smaller = np.einsum("ij,ij->i", d, d) / np.maximum(2 * along, 1e-300)
        # (The first ball, as large as the shape, is no ball inside: always shrunk.)
        apart = (along > 0) & ((np.linalg.norm(d, axis=1) >= smaller) | (radius >= diagonal))
        smaller = np.where(apart, np.minimum(smaller, radius), radius)
        if np.all(smaller >= radius * (1 - 1e-9)):
            break
        radius = smaller
    return radius


def on_axis(points: np.ndarray, axes: np.ndarray, vertices: np.ndarray,
            faces: np.ndarray, labels: list[str] | None = None,
            argument: str = "") -> np.ndarray:
    """`points (k, 3)`, joints inside the mesh, with those lying off their limb's axis moved
    onto it, across the limb (`axes (k, 3)`: the limb's unit direction at each, the bisector
    of the bones that meet there), with a warning naming `argument` and the joints by their
    `labels` when given.

    Animators place a knee or an elbow towards the front of the joint, where it bends best in
    Blender (the insect's knees 0.3 of the way across the leg, the kangaroo's 0.45). A joint's
    distance to the surface is the limb's radius there, and a spine through the front of a
    knee does not reach the back of the leg: the leg's region began far below the knee. In
    the plane through the joint across the limb, the chord through it away from its closest
    surface point is cut in its middle, `ROUNDS` times. The move is kept where the joint lay
    nearer the surface than half the moved point's distance to it, and moved no farther than
    that distance: a knee goes to the middle of the leg, where a hip at the body's junction,
    whose chord crosses the torso, and a centred joint (every joint of the human's and the
    cow's armatures) stay."""
    points = np.array(points, np.float64)
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    surface = SurfaceQuery(vertices, faces)
    gap, _, _ = surface.query(points)
    moved = points.copy()
    for _ in range(ROUNDS):
        _, foot, _ = surface.query(moved)
        away = moved - foot
        away -= np.einsum("ij,ij->i", away, axes)[:, None] * axes
        length = np.linalg.norm(away, axis=1)
        ok = length > 0
        away = away / np.where(ok, length, 1.0)[:, None]
        ahead = first_hits(moved, away, a, b, c)
        behind = first_hits(moved, -away, a, b, c)
        ok &= np.isfinite(ahead) & np.isfinite(behind)
        moved[ok] += (0.5 * (ahead - behind))[ok, None] * away[ok]
    new_gap, _, _ = surface.query(moved)
    by = np.linalg.norm(moved - points, axis=1)
    keep = (gap < 0.5 * new_gap) & (by <= new_gap)
    if labels is not None and keep.any():
        near = np.flatnonzero(keep)
        named = ", ".join(f"{labels[i]} by {by[i]:.3g}" for i in near[:4])
        warnings.warn(
            f"`{argument}`: {len(near)} joints off their limb's axis (nearer the surface "
            f"than half the limb's radius) moved across the limb to its middle ({named}"
            f"{', …' if len(near) > 4 else ''})",
            stacklevel=5,  # (the caller of fj.skeleton)
        )
    return np.where(keep[:, None], moved, points)


def bisectors(before: np.ndarray, at: np.ndarray, after: np.ndarray) -> np.ndarray:
    """`(k, 3)` the unit direction of a chain at its joints `at (k, 3)`, between the points
    `before` and `after` it (each (k, 3)): the bisector of its two bones' directions."""
    into = (at - before) / np.linalg.norm(at - before, axis=1, keepdims=True)
    out = (after - at) / np.linalg.norm(after - at, axis=1, keepdims=True)
    both = into + out
    # (A chain folded back on itself at a joint, by 180°, runs along either bone there.)
    length = np.linalg.norm(both, axis=1, keepdims=True)
    return np.where(length > 1e-9, both / np.maximum(length, 1e-300), into)

"""Jointed chains: a long limb split at its joints into limbs, each the parent of the next.

Our own construction on the limb's path of medial spheres, placing joints where an animator
places bones (thigh → shin → foot, upper arm → forearm → hand, neck → head). A piece of a
limb (from its joint, or from a split, to the next split or its tip) is split at a sphere
of its path, at least `SEGMENT` of that sphere's radii from either end of the piece, where:

1. the medial radius narrows: a local minimum over ±`WINDOW` radii, at most `NARROW` times
   the piece's thickest radius (a knee, an ankle, a wrist, a neck below a head); the
   narrowest first;
2. else the axis (the polyline of the path's centres) turns by at least `TURN` degrees
   within ±`WINDOW` radii (an elbow or a knee held bent, an ankle); the sharpest first;
3. else, a piece at least `LONG` radii long: in its middle (a knee on a leg of even
   thickness, where an animator would put it: the medial axis gives no better cue).

A limb bent at rest (`rest_bend`: its top fitted on its path up to the bend) is split at
its bend first, then its piece past the bend as any limb is. Both pieces are examined again,
up to `PIECES` pieces per limb. The piece past a split is a child limb: its spine fitted on
the path from about a radius before the split sphere to the tip (`fit_limb`), its region
cut out of the piece before it at the split sphere's centre.
A child of the whole limb (an ear on a head split into neck and head) goes to the piece its
region borders most.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .limb_fit import fit_limb
from .limbs import LimbPath
from .regions import spine_samples
from .skeleton import Limb

NARROW = 0.85  # a joint's radius is at most this fraction of its piece's thickest
TURN = 30.0  # degrees: the axis turns at least this much at a bent joint
LONG = 6.0  # a piece at least this many radii long is split in its middle
SEGMENT = 2.0  # each piece is at least this many radii long
WINDOW = 1.5  # radii on either side of a sphere: its neighbourhood for the tests above
PIECES = 3  # at most this many pieces per limb (hip → knee → ankle)


def chain_splits(found: LimbPath, spine, joint: float, centers, radii) -> list[int]:
    """The indices into `found.path` of the spheres where the limb (its rest `spine`, the arc
    length `joint` where it leaves its parent) is split, in order from its base."""
    path = found.path
    s, points, _ = map(np.asarray, spine_samples(spine))
    # Each path sphere's foot on the spine (non-decreasing: the path runs out to the tip).
    at = np.maximum.accumulate(s[cKDTree(points).query(centers[path])[1]])
    r = radii[path]
    # A median of three against the medial radii's noise (a sphere a few % off its neighbours).
    r = np.median(np.stack([np.r_[r[0], r[:-1]], r, np.r_[r[1:], r[-1]]]), axis=0)
    # The turn of the path's centres, not of the spine: the spine is smoothed (its curvature
    # below 0.8 / r), which turned the biped's ankle by 17° where its foot turns by 90°.
    line = centers[path]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))]
    turn = turning(arc, line, arc, WINDOW * r)
    splits, pieces = [], [(float(joint), float(s[-1]))]
    while pieces and len(splits) < PIECES - 1:
        low, high = pieces.pop(0)
        m = _split(at, r, turn, low, high)
        if m is not None:
            splits.append(m)
            pieces += [(low, float(at[m])), (float(at[m]), high)]
    return sorted(splits)


def _split(at, r, turn, low, high) -> int | None:
    """The sphere where the piece between arc lengths `low` and `high` is split, or `None`."""
    piece = np.flatnonzero((at >= low) & (at <= high))
    if len(piece) < 3:
        return None
    thick = float(np.median(r[piece]))
    # Each side at least `SEGMENT` radii of the joint's own: a foot as thin as its ankle
    # is 3 of them long, under 2 of its shin's (the biped's ankle was put mid-shin).
    inner = piece[(at[piece] >= low + SEGMENT * r[piece])
                  & (at[piece] <= high - SEGMENT * r[piece]) & (piece > 0)]
    if len(inner) == 0:
        return None
    middle = 0.5 * (low + high)

    def local(m, values, extreme):
        near = piece[np.abs(at[piece] - at[m]) <= WINDOW * thick]
        return values[m] == extreme(values[near])

    narrow = [m for m in inner if r[m] <= NARROW * r[piece].max() and local(m, r, np.min)]
    if narrow:  # the narrowest; among equals (a neck of even thickness), the middle one
        return min(narrow, key=lambda m: (round(r[m] / thick, 2), abs(at[m] - middle)))
    bent = [m for m in inner if turn[m] >= TURN and local(m, turn, np.max)]
    if bent:
        return max(bent, key=lambda m: turn[m])
    if high - low >= LONG * thick:
        return int(inner[np.argmin(np.abs(at[inner] - middle))])
    return None


def turning(s, points, at, half) -> np.ndarray:
    """Degrees the spine (sampled: `points` at arc lengths `s`) turns between the chords from
    `at − half` to `at` and from `at` to `at + half`."""

    def point(arc):
        arc = np.clip(arc, s[0], s[-1])
        return np.stack([np.interp(arc, s, points[:, k]) for k in range(3)], axis=-1)

    before, here, after = point(at - half), point(at), point(at + half)
    u, v = here - before, after - here
    norms = np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-300)
    cosine = np.clip(np.sum(u * v, axis=1) / norms, -1.0, 1.0)
    return np.degrees(np.arccos(cosine))


def split_chains(limbs, founds, region, centers, radii, vertices, adjacency, margin):
    """Each limb of `limbs` (in topological order, found on the medial graph as `founds`:
    their `LimbPath`s) split into its chain; `region` (n,) the limb of each vertex (−1: the
    body). Returns `(limbs, region, tops)`: the pieces, still in topological order, their
    region, and the index of each limb's first piece (its chain's top)."""
    out: list[Limb] = []
    label = np.full(len(region), -1)
    pieces: list[list[int]] = []  # per original limb: its pieces' indices in `out`
    for k, (limb, found) in enumerate(zip(limbs, founds, strict=True)):
        own = region == k
        parent = _parent_piece(limb.parent, pieces, label, own, adjacency)
        first = len(out)
        out.append(Limb(limb.spine, limb.joint, parent, limb.name))
        label[own] = first
        chain = [first]
        fit = (centers, radii, vertices, adjacency, margin)
        if found.bend is None:
            for m in chain_splits(found, limb.spine, float(limb.joint), centers, radii):
                if _cut_piece(found, m, out, label, chain, *fit) is None:
                    break  # no room past this joint: the rest stays in the piece before it
        elif (shin := _cut_piece(found, found.bend, out, label, chain, *fit)) is not None:
            # Bent at rest (`rest_bend`): its top is the path up to the bend; the rest, from
            # the bend on, is split as any limb is.
            below = out[chain[-1]]
            for m in chain_splits(shin, below.spine, float(below.joint), centers,
                                  radii)[: PIECES - 2]:
                if _cut_piece(shin, m, out, label, chain, *fit) is None:
                    break
        pieces.append(chain)
    return out, label, [chain[0] for chain in pieces]


def _cut_piece(found, m, out, label, chain, centers, radii, vertices, adjacency, margin):
    """The piece of `found` past its path's sphere `m`, fitted and cut out of the region of
    the chain's last limb `chain[-1]` as its child (appended to `out`, `label` and `chain`
    in place): its `LimbPath`, or `None` where it gets no region."""
    piece = _piece(found, m, radii, centers)
    spine, part = fit_limb(piece, centers, radii, vertices, adjacency, label == chain[-1],
                           margin, cut_at=centers[found.path[m]])
    if part is None:
        return None
    label[part.vertices] = len(out)
    out.append(Limb(spine, part.joint, chain[-1]))
    chain.append(len(out) - 1)
    return piece


def _piece(found: LimbPath, m: int, radii, centers) -> LimbPath:
    """The path past the split at `found.path[m]`, its spine starting about one radius
    before the split sphere (inside the piece before it, as a limb's starts in its parent)."""
    path = found.path
    back = np.cumsum(np.linalg.norm(np.diff(centers[path[m::-1]], axis=0), axis=1))
    before = m - 1 - min(int(np.searchsorted(back, radii[path[m]])), m - 1)
    return LimbPath(path[m:], int(path[before]), np.zeros(0, int), found.spheres, found.parent)


def _parent_piece(parent: int, pieces, label, own, adjacency) -> int:
    """The piece of the original limb `parent` (−1: the body) whose region the region `own`
    borders most."""
    if parent < 0:
        return -1
    chain = pieces[parent]
    if len(chain) == 1:
        return chain[0]
    borders = adjacency[np.flatnonzero(own)].sum(axis=0).A1  # edges from `own` to each vertex
    return max(chain, key=lambda piece: float(borders[label == piece].sum()))

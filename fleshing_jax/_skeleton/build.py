"""`skeleton`: a shape's tree of limbs, found on its medial mesh."""

from __future__ import annotations

import dataclasses
import itertools
import warnings

import numpy as np
from scipy.spatial import cKDTree

from .._checks import check_number
from .._medial_axis.medial_mesh import MedialMesh
from .._medial_axis.shells import bodies
from .._medial_axis.unit import UnitFrame
from .._mesh.deform import longest_edge
from .bones import bone_limbs, check_bones, connected_bones, forked
from .chains import TURN, split_chains
from .fit import nearest_spheres, sphere_gaps, spine_from_unit
from .given import SHORT, arc_at, given_limbs, turn_at
from .limb_fit import fit_limb
from .limbs import ROUTES, find_limbs
from .regions import levelled, mesh_adjacency, spine_samples, vertex_normals
from .rest_bend import fit_bent
from .skeleton import Limb, Skeleton, descendants, merge_limb
from .visible import FEWEST, box_diagonal, moves_visibly, visible

# A child's region meets its parent's at least this many spine samples beyond where the
# parent's region meets the rest (`_room_to_bend`; `register_skeleton` projects exactly).
ROOM = 2
# Bones with limbs above a last bone from a fork (a muzzle) whose joints are all less than this
# fraction as deep as the armature's deepest bone head lie in a neck and a head, not in the
# torso: the muzzle, with no room or left nothing, moves with the head (`_bones_in_the_body`).
NECK = 0.5
# A medial mesh belongs to a mesh when its centres lie in the mesh's bounding box (up to this
# fraction of its diagonal), no sphere's radius exceeds `REACHES` times the distance from its
# centre to the nearest vertex, and every vertex lies within this fraction of the diagonal
# from a sphere.
BELONGS = 0.1
# Unfitted, a merged sphere may stand out of the surface: on spot at seed 1 (200 spheres),
# one 2.4 times as large as that distance (at twice, the library's own medial mesh was
# refused). A medial mesh of another shape is off by far more.
REACHES = 4
# A separate body enclosing less than this fraction of the largest body's volume is a loose
# piece of it, not another character (`_one_body`).
LOOSE = 0.05


def skeleton(mesh, *, medial: MedialMesh | None = None, spheres: int = 200,
             seed: int = 0, chains=None, bones=None) -> Skeleton:  # fmt: skip
    """The limbs of a closed mesh, found on its medial mesh, and the part of the surface each
    one moves.

    Each elongated branch of the medial mesh (a chain of cones, or a strip of slabs) that
    leaves a thicker part becomes a limb (`skeleton.limbs`, see `_skeleton.limbs`): the thick
    rest is the body (region −1), and a branch leaving a limb's thick part (a horn on a head)
    is that limb's child; two strands side by side that fork (an insect's head, one strand
    per antenna) are one limb, the forks its children. A limb's rest spine is an
    `fj.BSpline` (float64 under `jax_enable_x64`), exactly arc-length, its curvature below
    `0.8 / r` (`r` the local medial radius: see `fit.fit_bspline`), from a little inside its
    parent (`s = 0`, at most one radius in) to where it meets the surface beyond its tip.
    Its region (see `_skeleton.regions`) is contiguous on the surface, within the spine's
    reach (where no reach leaves it one: the vertices nearest to its own medial spheres, a
    flat ear's disc, a foot against the body), and its border vertices project on the spine
    at arc lengths ≤ `joint`.

    A long limb is then split at its joints into a chain of limbs, each the parent of the
    next (`_skeleton.chains`: where the medial radius narrows, else where the axis turns,
    else in the middle of a limb 6 radii long; a limb bent at rest past what one spine
    follows, an insect's leg rising to its knee, at its bend first: `_skeleton.rest_bend`),
    and a limb a 30° bend would not visibly move joins its parent (`_skeleton.visible`:
    fewer than `FEWEST` of its vertices past its joint, or none of those and its
    descendants' `VISIBLE` of the diagonal from it).

    A shape with no thicker part for a branch to leave (a tube, a capsule) is a body and one
    limb: the body the end sphere of the medial axis's longest path (a cap one radius deep),
    the limb the rest, along that path (jointed like any other). A limb needs a still part
    to leave, so that a pose bends it from its joint as Fleshing bends a tube from its base;
    one limb and no body would leave nothing still to pose against.

    Where a child limb's region would begin before its parent's joint, the shorter of the
    two gives way: a child shorter than its parent's bendable part (a horn split into a
    base and a tip on a small head) joins its parent's region; a parent shorter than its
    child (a head too short before its ears) leaves its region to its own parent and its
    children to it. Every skeleton returned registers (`fj.register_skeleton`) and leaves
    each limb room to bend. A mesh of fewer than `FEWEST` vertices (a box) is a body, no
    limb. The limbs are found on the mesh moved near the origin and scaled by a power of two
    (`_medial_axis.unit`), with the same tolerances in any units and at any place: scaled by
    a power of two or moved by a multiple of it, the same skeleton, mapped; scaled by 10 or
    moved by 0.1, the input rounds differently and the medial mesh and its limbs may differ
    (see that module).

    On spot (`fj.data.spot()`): the head and neck (its ears and horns as child limbs) and
    four legs. Its tail is a tuft on the rump: the medial mesh ends it with one small sphere,
    which leaves less than its radius to bend beyond the rump, so it stays in the body.

    **Arguments:**

    - `mesh`: a closed `trimesh.Trimesh` or `(vertices (n, 3), faces (f, 3))`; an unwelded
      mesh (texture seams) is welded for the medial mesh and its copies of a vertex share
      a region. Closed parts pushed through a larger one (eyes through a head, teeth, a
      hat: shells that cross it) are set apart with a warning: the limbs are found on the
      rest, and each of their vertices rides in the region of the nearest vertex of the
      rest (a pose moves it by that limb's map, as the space around it).
    - `medial`: the mesh's `MedialMesh` (default: `fj.medial_mesh(mesh, spheres, seed=seed,
      refine=0)`, computed: the spines are fitted to the spheres anyway).
    - `spheres`: integer ≥ 2, the medial mesh's sphere count when it is computed.
    - `seed`: integer, the seed of its surface samples.
    - `chains`: the limbs a user places instead (no medial mesh is computed): a list of
      chains, each a list of points inside the shape `[p0, p1, …, pn]` from the body
      outwards (where the limb leaves its parent, its joints, its tip), as bones are placed
      in Blender; a chain is `n` limbs, each the parent of the next, cut at its points
      (`_skeleton.given`). A chain whose `p0` lies in an earlier chain's region (an ear on a
      head) hangs from that limb. A joint off the limb's axis (a knee placed at its front)
      is moved across the limb to its middle (`_skeleton.inside.on_axis`).

    - `bones`: the limbs of an armature instead, as Blender exports it: `(heads (m, 3),
      tails (m, 3), parents (m,))` (parents: each bone's parent's index, −1 for a root
      bone), optionally with the bones' names as a fourth entry. Each bone is a limb named as
      the bone (`Limb.name`, "bone b" without names: poses and functions that take a limb
      index take the name, `skeleton.index(name)` gives the index; the limbs in the bones'
      order when every parent comes before its children, as Blender lists them), except the
      bones inside the body (a rig's pelvis, spine and neck bones: no limbs; a warning names
      them, `_bones_in_the_body`). A bone whose head is its parent's tail continues its
      parent's chain of joints, and the chains are cut as `chains` are (`_skeleton.bones`); a
      bone starting elsewhere (a clavicle on the chest) starts a chain of its own, hanging
      from the limb of its nearest ancestor (its parent first) whose region holds its head:
      the body for a root bone, and for a thigh under a root bone that points up into the
      torso; where it starts in the middle of a thicker part with other bones (an ear's
      bone from the head's middle), its region begins where it leaves that part, at the
      ear's root. The body is what no bone takes: a torso is the body, not a tube to bend.

    **Returns:** an `fj.Skeleton` whose `vertices` are the mesh's (n, 3), in its order.

    **Raises:** `TypeError`/`ValueError` naming the argument: a `mesh` that is not a closed
    triangle mesh (see `fj.medial_mesh`), `spheres` < 2, a `medial` that is not a
    `MedialMesh` or does not belong to `mesh`; a `mesh` of several separate bodies (two
    characters side by side: find each one's skeleton) when the limbs are found; `chains`
    with a point far outside the mesh, a limb that gets no surface, or a child cut before
    its parent leaves room to bend; `bones` of zero length, far outside the mesh, with
    parents out of range or in a cycle, or none that gets any surface to move (each error
    names the bone).
    """
    from .._medial_axis.surface import closed_mesh_arrays

    spheres = check_number(spheres, "spheres", 2, 1e6, integer=True)
    seed = check_number(seed, "seed", 0, 2**63 - 1, integer=True)
    given = mesh.vertices if hasattr(mesh, "vertices") else None
    vertices, faces = closed_mesh_arrays(mesh, ride=True)
    adjacency = mesh_adjacency(vertices, faces)
    margin = 0.5 * longest_edge(vertices, faces)  # `register_skeleton`'s default
    if chains is not None and bones is not None:
        raise ValueError("`chains` and `bones` exclude each other: give the limbs one way.")
    if chains is not None or bones is not None:
        name = "chains" if chains is not None else "bones"
        if medial is not None:
            raise ValueError(f"`medial` and `{name}` exclude each other: {name} are the limbs.")
        if chains is not None:
            limbs, region = given_limbs(chains, vertices, faces, adjacency, margin)
            names = [f"limb {k}" for k in range(len(limbs))]
        else:
            limbs, region, names = _bones_in_the_body(check_bones(bones, vertices, faces),
                                                      vertices, adjacency, margin)
        conflict = _conflict(limbs, region, vertices, adjacency)
        if conflict is not None:
            parent, child = names[conflict[0]], names[conflict[1]]
            raise ValueError(
                f"`{name}`: {child}'s region begins before its parent {parent} leaves its own "
                f"parent: no room to bend {parent}; move their joints apart."
            )
    else:
        _one_body(vertices, faces)
        limbs, region = _found_limbs(vertices, faces, medial, spheres, seed, adjacency,
                                     margin)
    given = np.asarray(mesh.vertices if given is not None else mesh[0], np.float64)
    if len(given) != len(vertices) or not np.array_equal(given, vertices):
        # Welded or with unused vertices dropped: each given vertex takes its copy's region.
        region = region[cKDTree(vertices).query(given)[1]]
    return Skeleton(tuple(limbs), region.astype(np.int32), given)


def _bones_in_the_body(checked, vertices, adjacency, margin):
    """`(limbs, region, names)` of an armature's bones (`bones.check_bones`'s `checked`)
    without the bones inside the body, with a warning naming them: a rig's pelvis, spine,
    neck and clavicle bones start in the torso's middle, where no limb leaves.

    A bone that gets no part of the surface is no limb (`bones.bone_limbs`: a clavicle).
    Where one continues a chain from a limb (a tail bone after a bone from the rump's
    middle, whose region took the rump's back and left the tail in the body), or a limb's
    child begins before the limb leaves its parent (no room to bend it: a neck bone from the
    chest's middle takes the chest above it), the bone deepest in the body of it and its
    ancestors with limbs (the distance to the surface at its head; where a child has no
    room, at its limb's joint: the spine bone's is in the chest's middle, the neck bone's
    where its region leaves the chest) joins the body's bones and the limbs are found
    again. A child with no room is settled first, unless a limb above it left a bone of its
    own chain nothing (a dinosaur's hip bone from the pelvis's middle took the thigh's part,
    and the shin below has no room for the foot): that bone's case is settled first, where
    the cause lies. A last bone from a fork, where the bones above it are a neck's and a
    head's (their joints less than `NECK` as deep as the deepest bone's head), moves with its
    parent's limb instead, when it has no room (a horse's muzzle, beside its ears from the
    head's middle, after a short head bone from the neck's top) or its parent left it
    nothing (a kangaroo's snout): the neck and head stay limbs. (Chains a user places are
    refused instead.)"""
    heads, tails, parents, labels = checked[0], checked[1], checked[2], checked[3]
    tree = cKDTree(vertices)
    # The bones of the body bent at rest into their limbs (a coxa from the thorax's middle
    # into a thigh): shorter than `SHORT` radii at their heads, from the body's middle out to
    # where the limb leaves it (their tails less than half as deep as their heads), their
    # chains turning by at least `TURN` at their tails. Not fitted up to their tails
    # (`chain_limb`), their spines through the bent joint took a part of the leg. (A neck
    # bone into a head, as deep at both ends, is the head's.)
    deep = tree.query(np.concatenate([heads, tails]))[0].reshape(2, -1)
    short = (np.linalg.norm(tails - heads, axis=1) < SHORT * deep[0]) & (deep[1] < 0.5 * deep[0])
    bent = np.zeros(len(heads), bool)
    for c in np.flatnonzero(connected_bones(heads, tails, parents, vertices)):
        p = parents[c]
        bent[p] |= short[p] and turn_at(np.stack([heads[p], tails[p], tails[c]]), 1) >= TURN

    def depth(b, limbs, kept, joint: bool) -> float:
        """How deep in the body bone `b` starts: at its limb's joint, or at its head. A limb
        whose region begins past the tail of its bone, bent at rest into its limb (`bent`),
        lost its bone: it is the first to go (a coxa; the thigh after it was deeper)."""
        if not joint:
            return float(tree.query(heads[b])[0])
        limb = limbs[kept.index(b)]
        if bent[b] and float(limb.joint) > arc_at(limb.spine, tails[b]):
            return np.inf
        return float(tree.query(np.asarray(limb.spine(float(limb.joint))))[0])

    # A last bone from a fork (a muzzle beside ears), which may rejoin its parent's limb.
    last = forked(heads, vertices) & ~np.isin(np.arange(len(heads)), parents)
    neck = NECK * deep[0].max()
    body, joined = set(), set()
    while True:
        limbs, region, names, kept, before = bone_limbs(checked, vertices, adjacency, margin,
                                                        frozenset(body))
        conflict = _conflict(limbs, region, vertices, adjacency)

        def line(b) -> list[int]:  # bone `b`, then its ancestors with limbs
            up, a = [b], int(parents[b])
            while a >= 0:
                up += [a] if a in kept else []
                a = int(parents[a])
            return up

        def in_neck(bones) -> bool:  # (their limbs' joints, `NECK`)
            return max((depth(a, limbs, kept, True) for a in bones), default=np.inf) < neck

        # A last bone from a fork (a snout) its parent, in a neck, left nothing moves with it.
        joined |= {b for b, c in before.items() if c in kept and last[b] and in_neck(line(b)[1:])}
        # A child with no room first, unless a limb above it left a bone of its chain
        # nothing (it took that bone's part: a hip bone from the pelvis's middle took the
        # thigh's, and the shin's foot has no room below it); then the bones left nothing.
        left = [(b, False) for b, c in before.items() if c in kept and b not in joined]
        starts = [(kept[conflict[0]], True)] if conflict is not None else []
        above = [(b, j) for b, j in left if starts and before[b] in line(starts[0][0])]
        starts = above + starts + left
        chosen = None
        if conflict is not None and conflict[1] is not None and not above:
            k, child = kept[conflict[0]], kept[conflict[1]]
            if last[child] and in_neck(line(k)):
                # (A neck's bones going into the body would leave the muzzle a limb alone.)
                joined.add(child)
                body.add(child)
                continue
        for start, joint in starts:
            deepest = max(line(start), key=lambda b: depth(b, limbs, kept, joint))
            if deepest in kept:  # (else the bone itself: it stays no limb)
                chosen = deepest
                break
        if chosen is None:
            break
        body.add(chosen)
    joined -= set(kept)
    inside = sorted(set(range(len(heads))) - set(kept) - joined)
    if not limbs:
        raise ValueError(
            f"`bones`: {labels[inside[0]]} gets no part of the surface to move (no vertex past "
            "its head within reach of its spine, or less than a radius to bend), nor does any "
            "other bone: start each limb's first bone where the limb leaves the body."
        )
    if inside:
        named = [labels[b] for b in inside]
        warnings.warn(
            f"`bones`: {len(named)} bones lie inside the body ({', '.join(named[:6])}"
            f"{', …' if len(named) > 6 else ''}): no limbs, their children hanging from their "
            "parents; each other bone a limb, named as the bone (`skeleton.index(name)`)",
            stacklevel=3,  # (the caller of fj.skeleton)
        )
    if joined:
        named = ", ".join(labels[b] for b in sorted(joined))
        warnings.warn(
            f"`bones`: {named}: no limb, moving with its parent's limb (a last bone from a "
            "head's middle, a muzzle beside the ears, that its parent has no room to bend "
            "before or leaves nothing: the neck and head stay limbs)",
            stacklevel=3,
        )
    return limbs, region, names


def _one_body(vertices, faces) -> None:
    """`ValueError` for a mesh of several separate bodies (closed shells, none inside another:
    two characters side by side), each enclosing at least `LOOSE` of the largest's volume:
    the limbs are found from one body's hub, and the other body became a limb of it,
    silently. A smaller loose piece (a thin tail's or wrist's tip come loose in a coarse
    envelope: 0.004–1.7 % of the character's volume) stays with the body: no pose moves it."""
    found = bodies(vertices, faces)
    found = [(ids, volume) for ids, volume in found if volume >= LOOSE * found[0][1]]
    if len(found) > 1:
        sizes = ", ".join(str(len(np.unique(faces[ids]))) for ids, _ in found[:4])
        raise ValueError(
            f"`mesh` holds {len(found)} separate bodies (closed shells, none inside another; "
            f"{sizes}{', …' if len(found) > 4 else ''} vertices): a skeleton is one body's "
            "tree of limbs, and the others would become its limbs. Find each body's skeleton "
            "on its own mesh (e.g. trimesh's mesh.split(only_watertight=False)), or give the "
            "limbs (`chains`, `bones`)."
        )


def _found_limbs(vertices, faces, medial, spheres, seed, adjacency, margin):
    """`(limbs, region)` found on the medial mesh (`medial`, computed when None), each limb
    split into its jointed chain, every limb left room to bend.

    Found on the mesh moved near the origin and scaled to a diagonal near 1 (`UnitFrame`,
    exactly), the limbs mapped back: the same tolerances in any units and at any place."""
    from .._medial_axis.construct import medial_mesh

    if medial is not None and not isinstance(medial, MedialMesh):
        raise TypeError(f"`medial` must be a MedialMesh or None, got {type(medial).__name__}.")
    if len(vertices) < FEWEST:
        # A limb moves at least `FEWEST` vertices: a box of 8 is a body, as a finer one is.
        return [], np.full(len(vertices), -1)
    frame = UnitFrame.of(vertices)
    unit = frame.to_unit(vertices)
    if medial is None:
        medial = medial_mesh((unit, faces), spheres, seed=seed, refine=0, progress=False)
        centers, radii, edges, _ = medial.numpy()
    else:
        # Only a medial mesh the user gives is checked: the library's own belongs by
        # construction, and where a character's skin overlaps itself (legs modelled into a
        # body, Blender's skin modifier at a branch) vertices lie inside the volume, nearer
        # its unfitted spheres' centres than they reach (a kangaroo's and a spider's: 4.1-4.8
        # times), and it was refused.
        centers, radii, edges, _ = medial.numpy()
        centers, radii = frame.to_unit(centers), radii / frame.scale
        _check_belongs(centers, radii, unit)
    limbs, region = _unit_limbs(unit, vertex_normals(unit, faces), centers, radii, edges,
                                adjacency, 0.5 * longest_edge(unit, faces))  # fmt: skip
    return [_from_unit(limb, frame) for limb in limbs], region


def _from_unit(limb: Limb, frame: UnitFrame) -> Limb:
    """`limb` (found in the unit frame) in the mesh's: its spine mapped, its joint's arc
    length scaled."""
    return Limb(spine_from_unit(limb.spine, frame), frame.scale * float(limb.joint), limb.parent,
                limb.name)


def _unit_limbs(vertices, normals, centers, radii, edges, adjacency, margin):
    """`_found_limbs`'s limbs and region, in the unit frame (`normals`: (n, 3), the vertices'
    outward normals)."""
    found_limbs = find_limbs(centers, radii, edges)
    nearest = nearest_spheres(vertices, centers, radii)
    empty = _Fitted(np.full(len(vertices), -1), [], {}, [], set())
    start: dict[int, int] = {}  # a found limb's number → its route tried first
    fitted, saved = _fit_from(found_limbs, start, 0, empty, centers, radii, vertices,
                              adjacency, margin, nearest)  # fmt: skip
    # A parent whose region leaves a child no room to bend it on every route of the child's
    # (spot scaled by 0.01: the head's spine to its snout, its region leaving the body
    # obliquely, 0 to 0.02 along it, and an ear at the back of the head meeting it at
    # 0.008) tries the routes along which its children leave it farther out (`ROUTES` of
    # them, the farthest first: to its crown, between its ears and horns); the route that
    # leaves the fewest children without room is kept, then the one giving its children the
    # most vertices (a dinosaur's chest, from which a small arm leaves: on its first route
    # its region took the arm's hand, the arm 59 vertices; on its second 418), the first on
    # a tie.
    for number in sorted({found_limbs[c].parent for c in fitted.early}):
        if number < 0 or number not in fitted.index:
            continue
        found = found_limbs[number]
        routes = [(found.path, found.inside), *found.alternatives]
        children = [f for f in found_limbs if f.parent == number]
        along = [_children_along(route, children, centers) for route in routes]
        farther = [k for k in np.argsort(along, kind="stable")[::-1] if along[k] > along[0]]
        best = (_lost(found_limbs, fitted, number), fitted, saved, start)
        for first in farther[:ROUTES]:
            if best[0][0] == 0:
                break
            trial_start = {**start, number: int(first)}
            trial, trial_saved = _fit_from(found_limbs, trial_start, number, saved[number],
                                           centers, radii, vertices, adjacency, margin,
                                           nearest)  # fmt: skip
            if number in trial.index and _lost(found_limbs, trial, number) < best[0]:
                best = (_lost(found_limbs, trial, number), trial,
                        {**{k: v for k, v in saved.items() if k < number}, **trial_saved},
                        trial_start)  # fmt: skip
        _, fitted, saved, start = best
    limbs, region, tops = split_chains(fitted.limbs, fitted.founds, fitted.region, centers,
                                       radii, vertices, adjacency, margin)  # fmt: skip
    # Levelled first: a bend moves what lies past the joint, which a slanted border put far
    # out (spot's ear at seed 0: 27 vertices past its joint at 67 % of its spine, within 3.8 %
    # of the diagonal from it; levelled, at 33 %).
    limbs, region = levelled(limbs, region, vertices, normals, adjacency, tops, margin)
    limbs, region = visible(limbs, region, vertices)
    return _room_to_bend(limbs, region, vertices, adjacency)


@dataclasses.dataclass
class _Fitted:
    """The limbs fitted so far: `region` (n,), `limbs`, `index` (a found limb's number → its
    index in `limbs`, kept ones), `founds` (the kept limbs' routes), `early` (the numbers
    of the children whose every route's region left their parent no room to bend)."""

    region: np.ndarray
    limbs: list
    index: dict
    founds: list
    early: set

    def copy(self) -> _Fitted:
        return _Fitted(self.region.copy(), list(self.limbs), dict(self.index),
                       list(self.founds), set(self.early))  # fmt: skip


def _children_along(route, children, centers) -> float:
    """How far along `route` (`(path, inside)`, a limb's) the first of `children` (found
    limbs) leaves it: the least arc length, on the polyline from `inside` through the path's
    centres, of the point nearest to a child's first sphere."""
    path, inside = route
    line = centers[np.r_[inside, path]]
    arc = np.r_[0, np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))]
    least = np.inf
    for child in children:
        point = centers[child.path[0]]
        a, b = line[:-1], line[1:]
        t = np.clip(np.einsum("ij,ij->i", point - a, b - a)
                    / np.maximum(np.einsum("ij,ij->i", b - a, b - a), 1e-300), 0, 1)
        gap = np.linalg.norm(a + t[:, None] * (b - a) - point, axis=1)
        k = int(np.argmin(gap))
        least = min(least, arc[k] + t[k] * (arc[k + 1] - arc[k]))
    return float(least)


def _lost(found_limbs, fitted: _Fitted, number: int) -> tuple[int, int]:
    """How many children of found limb `number` got no region or no room to bend, and minus
    the vertices its children's regions hold: the smaller, the better the parent's route."""
    children = [c for c, found in enumerate(found_limbs) if found.parent == number]
    held = sum(int(np.sum(fitted.region == fitted.index[c])) for c in children
               if c in fitted.index)  # fmt: skip
    return sum(c in fitted.early or c not in fitted.index for c in children), -held


def _fit_from(found_limbs, start, first, fitted, centers, radii, vertices, adjacency, margin,
              nearest):
    """The found limbs from number `first` on fitted after `fitted` (the state before it,
    kept), each trying its route `start.get(number, 0)` first; returns the state after the last
    and the state before each of them (`{number: _Fitted}`)."""
    parents = {found.parent for found in found_limbs}  # the limbs other limbs leave
    fitted, saved = fitted.copy(), {}
    region, limbs, index = fitted.region, fitted.limbs, fitted.index
    # Where the usual reach leaves a limb no region, its region may reach farther from its
    # spine (`fit_limb`'s `wide`): a limb that other limbs leave (a head: its crown) among
    # all its parent's vertices; a child limb (a flat ear's lobe) among its own only, the
    # vertices whose nearest medial sphere is one of its spheres (a head's region kept to
    # its own lost cheburashka's crown). Not a limb from the body with no children: on the
    # quadruped at 60 spheres a horn found twice, by two routes, took its tip from the other
    # limb of the two that way, too small to pose. Where no reach does, its own vertices.
    for number in range(first, len(found_limbs)):
        saved[number] = fitted.copy()
        found = found_limbs[number]
        parent = index.get(found.parent, -1) if found.parent >= 0 else -1
        if found.parent >= 0 and found.parent not in index:
            continue  # its parent had no region: neither has it
        wide = None
        if number in parents:
            wide = np.ones(len(vertices), bool)
        elif found.parent >= 0:
            wide = np.isin(nearest, found.spheres)
        # The first route whose region leaves its parent room to bend before it (`_conflict`:
        # spot's ear at seed 2, its first region reaching the base of the head, which then
        # took it back); none does: the first region (`_room_to_bend` then decides).
        # Where no route's reach gives it a region, its own vertices (`fit_limb`'s `owned`),
        # not before (on the quadruped at 60 spheres, a horn's first route's own vertices
        # took less than its second route's reach did).
        choice = None
        routes = [(found.path, found.inside), *found.alternatives]
        routes.insert(0, routes.pop(start.get(number, 0)))  # the route tried first
        owned = np.isin(nearest, found.spheres)
        tries = [((r, None) for r in routes), ((r, owned) for r in routes)]  # reach, own
        if found.fork:
            # A forked limb's own vertices first (an insect's head: a strand's reach held
            # half of it), with those of its path's first spheres (the neck before the head:
            # without them, the joint lay a third of the way into the head).
            owned |= np.isin(nearest, found.path)
            tries.reverse()
        for (path, inside), own in itertools.chain(*tries):
            if own is not None and choice is not None:
                break
            # (A fork's spine along its midline: on its own path alone.)
            route = dataclasses.replace(found, path=path, inside=inside,
                                        midline=found.midline if path is found.path else None)
            spine, part = fit_limb(route, route.fitted_centers(centers), radii, vertices,
                                   adjacency, region == parent, margin, wide=wide, owned=own)
            if part is None or (own is not None and not moves_visibly(
                    spine, part.joint, vertices[part.vertices], np.empty((0, 3)),
                    box_diagonal(vertices))):
                # An own region that a bend would not visibly move is none: kept until
                # `visible` merged it, the 25 own vertices of a horn found twice were
                # missing from the other limb's region (the quadruped at 60 spheres).
                continue
            early = False
            if parent >= 0:
                tentative = region.copy()
                tentative[part.vertices] = len(limbs)
                early = _conflict([*limbs, Limb(spine, part.joint, parent)], tentative,
                                  vertices, adjacency, only=len(limbs)) is not None
            if choice is None or not early:
                choice = (route, spine, part, early)
            if not early:
                break
        if choice is None:
            continue
        route, spine, part, early = choice
        others = np.concatenate([np.zeros(0, int)]
                                + [f.path for f in found_limbs if f is not found])
        bent = fit_bent(route, part, route.fitted_centers(centers), radii, vertices, adjacency,
                        region == parent, margin, nearest, others)
        if bent is not None:
            route, spine, part = bent
        if early:
            fitted.early.add(number)
        index[number] = len(limbs)
        region[part.vertices] = len(limbs)
        limbs.append(Limb(spine, part.joint, parent))
        fitted.founds.append(route)
    return fitted, saved


def _room_to_bend(limbs: list[Limb], region: np.ndarray, vertices, adjacency):
    """`(limbs, region)` where every limb's children leave it beyond where it leaves the
    rest. `register_skeleton` bends a limb between those arc lengths and refused a skeleton
    with no room. Where a child's region meets its parent's too early (`_conflict`), the
    shorter of the two gives way: a child shorter than its parent's length past the
    joint (a horn split into a base and a tip on a small head) joins its parent's region; a
    parent shorter than the child (the bunny's head, 0.035 long, before ears 0.065–0.08
    long) leaves its region to its own parent and its children to it. A limb whose region
    leaves the rest where its spine ends (a crease's bump, wider than its spine is long: a
    cow modelled in Blender) has nothing to bend and joins its parent. The limbs are then
    renumbered."""
    while (conflict := _conflict(limbs, region, vertices, adjacency)) is not None:
        k, child, beyond = conflict
        if child is None:
            # It leaves the rest where its spine ends (a crease's bump, its region wider than
            # its spine is long): nothing past its joint to bend. It joins its parent.
            limbs, region = merge_limb(limbs, region, k)
            continue
        if float(limbs[child].spine.length) - float(limbs[child].joint) <= beyond:
            # The child joins its parent, with its descendants (the deepest first).
            gone = [child, *descendants(limbs)[child]]
        else:
            gone = [k]  # the parent gives its region and its children to its own parent
        for i in sorted(gone, reverse=True):
            limbs, region = merge_limb(limbs, region, i)
    return limbs, region


def _conflict(limbs, region, vertices, adjacency, only=None):
    """The first `(limb, child, length past the limb's joint)` where the child's region meets
    the limb's at arc lengths (on the limb's spine) within `ROOM` spine samples of where the
    limb's region meets anything else, or `(limb, None, 0)` where that is within them of the
    spine's end (`register_skeleton` would find no room to bend the limb), or `None`. With
    `only` (a child), that child's meeting with its parent alone."""
    below = descendants(limbs)
    for k, limb in enumerate(limbs):
        ids = np.flatnonzero(region == k)
        if not len(ids) or (only is not None and limbs[only].parent != k):
            continue
        s, points, _ = map(np.asarray, spine_samples(limb.spine))
        arc = s[cKDTree(points).query(vertices[ids])[1]]
        others = ~np.isin(region, [k, *below[k]])
        leaves = ids[adjacency[ids] @ others.astype(float) > 0]
        joint = max(float(limb.joint), float(arc[np.isin(ids, leaves)].max(initial=0.0)))
        room = ROOM * float(s[1] - s[0])
        if only is None and joint + room >= float(s[-1]):
            return k, None, 0.0
        for child in (c for c, other in enumerate(limbs) if other.parent == k):
            if only is not None and child != only:
                continue
            meets = adjacency[ids] @ np.isin(region, [child, *below[child]]).astype(float)
            if arc[meets > 0].min(initial=np.inf) <= joint + room:
                return k, child, float(s[-1]) - joint
    return None


def _check_belongs(centers, radii, vertices):
    """Raises `ValueError` unless the medial mesh `(centers, radii)` fits inside `vertices`."""
    if len(centers) < 2:
        raise ValueError(f"`medial` must have at least 2 spheres, got {len(centers)}.")
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    diagonal = float(np.linalg.norm(high - low))
    slack = BELONGS * diagonal
    outside = np.any((centers < low - slack) | (centers > high + slack), axis=1)
    clearance = cKDTree(vertices).query(centers)[0]
    # The largest gap between a vertex and the nearest sphere's surface.
    uncovered = float(sphere_gaps(vertices, centers, radii).max())
    if outside.any() or np.any(radii > REACHES * clearance + 1e-9 * diagonal) or uncovered > slack:
        raise ValueError(
            "`medial` does not belong to `mesh`: its spheres must lie inside the mesh and reach "
            f"its surface ({int(outside.sum())} centres outside the mesh's box, largest radius "
            f"{float(np.max(radii / np.maximum(clearance, 1e-300))):.3g} times the distance to "
            f"the nearest vertex, a vertex {uncovered:.3g} from every sphere; diagonal "
            f"{diagonal:.3g})."
        )

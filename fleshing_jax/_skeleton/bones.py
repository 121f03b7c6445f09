"""A skeleton from an armature's bones: what Blender exports (heads, tails, parents).

`fj.skeleton(mesh, bones=(heads, tails, parents))`, each bone a limb. A bone whose head is its
parent's tail (a connected bone: forearm after upper arm) continues its parent's chain of
joints; a bone starting elsewhere (a clavicle on the chest, a root bone) starts a chain of its
own that hangs from its nearest ancestor (its parent first) whose region holds its head (the
body when none does). The chains are then cut as `fj.skeleton(mesh, chains=…)` cuts them
(`_skeleton.given`): limb `k` is bone `k`'s, its spine from about a radius before its head
through the later joints of its chain to the surface, its region cut out of its parent's at
its head; a chain's first bone from the middle of a thicker part where other bones start
too (an ear's bone from the head's middle) where it leaves that part, at the waist a skin
makes at the ear's root (`given.leaves_part`).

The body is what no bone takes. A torso is the body, not a tube: a rig's pelvis, spine and
neck bones in it are no limbs (those that get no part of the surface here; those whose
limbs leave a child no room to bend them, `build._bones_in_the_body`), so the arms, legs
and neck of an armature hang from the body (parent −1, or under a root bone whose region
does not hold their heads). A bone's last tail is best a radius inside its end (a head bone through
the head's middle): the local radius is the tail's distance to the surface.
"""

from __future__ import annotations

import heapq

import numpy as np
from scipy.spatial import cKDTree

from .._checks import check_finite_points
from .given import add_limb, chain_limb
from .inside import bisectors, on_axis, placed_inside
from .skeleton import Limb

# A bone continues its parent's chain when its head lies within this fraction of the mesh's
# diagonal from the parent's tail (Blender writes a connected bone's head as its parent's
# tail; a float32 export rounds both alike).
CONNECTED = 1e-6


def bone_limbs(checked, vertices, adjacency, margin, body=frozenset()):
    """`(limbs, region, labels, kept, before)` of the armature `checked` (`check_bones`'s
    `(heads, tails, parents, labels, names)`; see the module's docstring): limb `k` bone
    `kept[k]`, named as the bone (`Limb.name`), parents before children (the bones' own order
    when they list every parent before its children, as Blender does), `labels[k]` how
    errors name it; the bones in `body` and those
    that get no part of the surface to move (a clavicle from the chest's middle) are no
    limbs, their children hanging from their parents (a chain of joints starting again after
    one); `before`: for each of the latter that continues a chain, the bone before it."""
    heads, tails, parents, labels, names = checked
    order = _order(parents)
    connected = connected_bones(heads, tails, parents, vertices)
    # Each bone's chain of joints (its first bone's head, then each bone's tail) and its
    # place in it: a bone continues its parent's chain when its head is the parent's tail
    # and no earlier sibling continues it already.
    continued = np.zeros(len(heads), bool)
    chain_of: dict[int, tuple[list[int], int]] = {}
    for b in order:
        p = int(parents[b])
        if connected[b] and p not in body and not continued[p]:
            continued[p] = True
            chain, _ = chain_of[p]
            chain.append(b)
            chain_of[b] = (chain, len(chain) - 1)
        else:
            chain_of[b] = ([b], 0)
    tree = cKDTree(vertices)
    segments = np.stack([heads, tails], axis=1)
    # Bones from one point (a head's ears and muzzle from its middle): each may leave the
    # part there further out (`given.leaves_part`).
    branch = forked(heads, vertices)
    region = np.full(len(vertices), -1)
    index = {}  # bone → limb (a bone in the body: its parent's limb, or −1)
    limbs: list[Limb] = []
    kept, inside = [], []
    for b in order:
        chain, i = chain_of[b]
        points = np.concatenate([heads[chain[0]][None], tails[chain]])
        parent = index[int(parents[b])] if parents[b] >= 0 else -1
        if i == 0 or chain[i - 1] in inside:
            parent = _holding(heads[b], b, parents, index, region, tree)
        # (The other bones, for where the chain's own vertices are: `chain_limb`.)
        others = segments[np.setdiff1d(np.arange(len(heads)), chain[i:])]
        limb = None if b in body else chain_limb(points, i, parent, tree, region, vertices,
                                                 adjacency, margin, others, names[b],
                                                 at_root=bool(branch[b]))
        if limb is None:
            index[b] = parent
            if b not in body:
                inside.append(b)
            continue
        index[b] = add_limb(limbs, region, limb, "")
        kept.append(b)
    # (For each bone inside the body that continues a chain, the bone before it.)
    before = {b: chain_of[b][0][chain_of[b][1] - 1] for b in inside if chain_of[b][1] > 0}
    return limbs, region, [labels[b] for b in kept], kept, before


def forked(heads, vertices) -> np.ndarray:
    """`(m,)` bool: each bone starts where another bone starts too (within `CONNECTED` of
    the mesh's diagonal): a head's muzzle and ears from its middle."""
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    return cKDTree(heads).query_ball_point(heads, CONNECTED * diagonal, return_length=True) > 1


def connected_bones(heads, tails, parents, vertices) -> np.ndarray:
    """`(m,)` bool: each bone's head is its parent's tail (within `CONNECTED` of the
    diagonal of `vertices`), as Blender writes a connected bone's."""
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    gap = np.linalg.norm(heads - tails[np.maximum(parents, 0)], axis=1)
    return (parents >= 0) & (gap <= CONNECTED * diagonal)


def _holding(head, b, parents, index, region, tree) -> int:
    """The limb of bone `b`'s nearest ancestor whose region holds its `head` (the region of
    the vertex nearest to it, as a chain's first point finds its parent), −1 (the body) if
    none: the thighs of a rig whose root bone (the hips) points up into the torso hang from
    the body, which holds them."""
    holder = int(region[tree.query(head)[1]])
    a = int(parents[b])
    while a >= 0:
        if index[a] == holder:
            return holder
        a = int(parents[a])
    return -1


def check_bones(bones, vertices, faces):
    """`(heads (n, 3), tails (n, 3), parents (n,) int, labels, names)` of `bones`, `(heads,
    tails, parents)` or `(heads, tails, parents, names)` (`names`: "bone b" where none are
    given; `labels` name the bones in errors); else `TypeError`/`ValueError` naming the
    bone: a bone of zero length, with its head or tail outside the mesh, a parent out of
    range or in a cycle."""
    if (
        isinstance(bones, str | bytes)
        or not isinstance(bones, tuple | list)
        or (len(bones) not in (3, 4))
    ):
        raise TypeError(
            "`bones` must be a tuple (heads (n, 3), tails (n, 3), parents (n,)) or with bone "
            f"names as a 4th entry, got {type(bones).__name__}."
        )
    heads = check_finite_points(bones[0], "bones[0]")
    tails = check_finite_points(bones[1], "bones[1]")
    n = len(heads) if heads.ndim == 2 else -1
    if heads.ndim != 2 or heads.shape[1:] != (3,) or n == 0:
        raise ValueError(
            f"`bones[0]` (the heads) must have shape (n, 3), n ≥ 1, got {heads.shape}."
        )
    if tails.shape != heads.shape:
        raise ValueError(f"`bones[1]` (the tails) must have the heads' shape {heads.shape}, got "
                         f"{tails.shape}.")  # fmt: skip
    parents = np.asarray(bones[2])
    if (
        parents.shape != (n,)
        or not (
            np.issubdtype(parents.dtype, np.integer)
            or (np.issubdtype(parents.dtype, np.floating) and np.all(parents == np.round(parents)))
        )
        or parents.dtype == bool
    ):
        raise ValueError(
            f"`bones[2]` (the parents) must be ({n},) integers (a bone's parent's index, -1 "
            f"for a root bone), got shape {parents.shape} and dtype {parents.dtype}."
        )
    parents = parents.astype(np.int64)
    names = bones[3] if len(bones) == 4 else None
    if names is not None and (isinstance(names, str) or len(names) != n):
        raise ValueError(f"`bones[3]` (the names) must be a list of {n} bone names.")
    labels = [f"bone {b}" + (f" ({names[b]!r})" if names is not None else "") for b in range(n)]
    names = [f"bone {b}" for b in range(n)] if names is None else list(names)
    if not all(isinstance(name, str) and name for name in names) or len(set(names)) < n:
        raise ValueError("`bones[3]` (the names) must be distinct non-empty strings.")
    bad = np.flatnonzero((parents < -1) | (parents >= n))
    if len(bad):
        b = int(bad[0])
        raise ValueError(f"`bones`: {labels[b]}'s parent {int(parents[b])} is not a bone index "
                         f"in [0, {n}) nor -1 (a root bone).")  # fmt: skip
    cycle = _cycle(parents)
    if cycle:
        raise ValueError("`bones`: the parents form a cycle: "
                         + " → ".join(labels[b] for b in cycle) + ".")  # fmt: skip
    # A tail no bone continues from is a chain's tip.
    connected = connected_bones(heads, tails, parents, vertices)
    continued = np.zeros(n, bool)
    continued[parents[connected]] = True
    ends = placed_inside(np.concatenate([heads, tails]),
                         [f"{label}'s {end}" for end in ("head", "tail") for label in labels],
                         vertices, faces, "bones", np.r_[np.zeros(n, bool), ~continued])
    # Each joint where a bone continues its parent's chain moved onto the limb's axis when
    # off it (`inside.on_axis`: a knee placed at its front), the child's head with it.
    child = np.full(n, -1)
    kids = np.flatnonzero(connected)
    joined, first = np.unique(parents[kids], return_index=True)
    child[joined] = kids[first]  # (each bone's first connected child)
    joints = np.flatnonzero(child >= 0)
    if len(joints):
        heads_, tails_ = ends[:n], ends[n:]
        axes = bisectors(heads_[joints], tails_[joints], tails_[child[joints]])
        tails_[joints] = on_axis(tails_[joints], axes, vertices, faces,
                                 [f"{labels[b]}'s tail" for b in joints], "bones")  # fmt: skip
        heads_[connected] = tails_[parents[connected]]
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    # (Checked after the move too: both ends past the surface may meet at one point.)
    short = np.flatnonzero(np.linalg.norm(ends[n:] - ends[:n], axis=1) <= 1e-9 * diagonal)
    if len(short):
        b = int(short[0])
        moved = "" if np.linalg.norm(tails[b] - heads[b]) <= 1e-9 * diagonal else (
            ", moved inside from past the surface")
        raise ValueError(f"`bones`: {labels[b]} has zero length (its head is its tail"
                         f"{moved}).")  # fmt: skip
    heads, tails = ends[:n], ends[n:]
    return heads, tails, parents, labels, names


def _cycle(parents: np.ndarray) -> list[int]:
    """The bones of a cycle of `parents` (the first bone repeated at its end), or []."""
    state = np.zeros(len(parents), int)  # 0: unseen, 1: on the current walk, 2: done
    for start in range(len(parents)):
        walk, b = [], start
        while b >= 0 and state[b] == 0:
            state[b] = 1
            walk.append(b)
            b = int(parents[b])
        if b >= 0 and state[b] == 1:
            return [*walk[walk.index(b) :], b]
        state[walk] = 2
    return []


def _order(parents: np.ndarray) -> list[int]:
    """The bones, each after its parent, otherwise in their own order (the identity when
    every parent comes first)."""
    children = [[] for _ in parents]
    for b, p in enumerate(parents):
        if p >= 0:
            children[p].append(b)
    ready = [b for b, p in enumerate(parents) if p < 0]
    heapq.heapify(ready)
    order = []
    while ready:
        b = heapq.heappop(ready)
        order.append(b)
        for c in children[b]:
            heapq.heappush(ready, c)
    return order

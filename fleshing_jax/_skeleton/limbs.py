"""The limbs of a medial mesh: the elongated branches that leave a thicker part.

Our own construction (neither paper gives one). On each level (the body, then each limb for
its child limbs):

1. The shortest-path tree of the medial graph from the level's root (for the body its hub,
   where the limbs meet: the thickest sphere unless that is an end such as an insect's head,
   `hub`, or a thick part beyond a thin neck finds more limbs, `_thick_parts`; where the
   limb leaves its parent for a limb), and its branches by *reach*
   (geodesic distance plus radius: how far the surface lies along the tree), each branch
   running from a tip (the sphere reaching farthest in its subtree) towards the root.
2. Along the path from the root to a tip, the *core*: its spheres up to the end of their
   first run (a limb's: of the run of its thickest sphere) at least `CORE` times as thick as
   the level's (the hub's; a limb's path's thickest) and as any sphere further out (the torso; a
   limb's thick part; never past a neck). A sphere whose centre lies inside a core sphere is
   *covered*: it is inside the parent. The tip's path: its spheres from the tip inwards up
   to the first covered one (excluded), less its first spheres far thinner than the limb (a
   crease's, `CREASE`). It is a limb when it protrudes: beyond the last covered sphere's
   surface by at least `ELONGATION` times its thickest radius (and, a child limb, when it is
   at most `THINNER` times as thick as its parent). A path half inside a limb's path spheres
   (or whose tip is) is another route to that limb (the same head reached through two strips
   of the neck, a strip's second tip), as is one joined to it by a sheet's edges, even
   through paths found after it (a flat ear's rim); one hanging below a limb in the tree is
   a child left to that limb's level, unless it is as thick as that limb (two legs side by
   side, one hanging from the other's top in the tree: a limb of its own). The spheres hanging below
   the limbs' first spheres go to the limb whose path is nearest (a strip of slabs hangs
   below its path).
3. Two limbs side by side, alike in thickness, that share their first part and fork (an
   insect's head, a strand per antenna; not a bird's wing beside its thicker neck) are one
   limb, the forks its children (`_forks`).
4. The limb's spine path runs to its own farthest sphere (not into a child, an ear; far
   counted with twice the radius, which prefers a head's snout to the base of its ears).

A shape without a core to leave (a tube: every sphere as thick as its neighbours) gets its
body at one end of its longest path (`tube`).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.sparse import csgraph

from .fit import farthest, medial_graph, sphere_gaps

CORE = 0.6  # a core sphere is at least this fraction of the thickest sphere's radius
# A limb from the body starts at its waist (a hip), where the core's radius falls to this
# fraction of its thickest before, even where it is still `CORE` as thick (`_waist`).
WAIST = 0.85
# A limb protrudes at least its thickest radius: shorter, it is a bump (issue 45: "shorter
# than its own radius"; the characters' bumps reach 0.86). Spot's stubby hind legs protrude
# 1.19-1.5 on its medial meshes: at 1.5 one was left in the body at seed 1, at 1.25 at seed 10.
ELONGATION = 1.0
# A child limb is at most this fraction of its parent's thickest radius: it grows from the
# parent's thick part (a horn on a head), where a limb that tapers (a tail) has none.
THINNER = 0.5
CREASE = 0.15  # a crease's spheres are thinner than this fraction of the limb's thickest
MAX_DEPTH = 3  # body, limbs, their children, grandchildren
# A path is another route to a limb whose spheres share medial edges with this fraction of its
# own (a flat ear's rim paths: 0.67-1; an insect's antennae from one base: 0.25; legs: < 0.35).
SHEET = 0.6
# Two limbs side by side are one forked limb where the part they share protrudes this many
# times its thickness from their first spheres (`_forks`): insects' heads 2.3-2.5; a leg and
# the crease beside its top 1.2, legs touching at the thorax 0-0.9.
FORK = 1.5
# ... and their strands are alike where they meet: the thinner at least this fraction of the
# thicker (insects' heads 0.85-0.95; a bird's wing beside its neck, leaving from one
# sphere, 0.67-0.70: taken as a fork, a stub at the shoulder carried the wing and the head).
ALIKE = 0.8
ROUTES = 3  # routes to a limb's own farthest spheres tried for its spine (`LimbPath`)


@dataclasses.dataclass(frozen=True)
class LimbPath:
    """A limb found on the medial graph: `path` the sphere indices from the first one outside
    its parent to the tip, `inside` the last sphere inside the parent (the path's
    continuation), `core` the parent's spheres that this one is inside, `spheres` every
    sphere of the limb (its strip and spikes too), `parent` the parent limb's index in the
    list, −1 for the body."""

    path: np.ndarray
    inside: int
    core: np.ndarray
    spheres: np.ndarray
    parent: int
    # Other routes through the limb, `(path, inside)` in order of preference, for when the
    # spine along `path` leaves the limb no region (`_skeleton.build`).
    alternatives: tuple = ()
    # A limb bent at rest (`rest_bend`): the index in `path` of its bend, where its chain is
    # split first (its spine, fitted up to there, is the top piece's).
    bend: int | None = None
    # Two strands side by side joined into one limb (`_forks`: an insect's head): the points
    # midway between them, one per sphere of the shared part of `path` (`(k,)` indices into
    # it, `(k, 3)` points), along which its spine runs; its region is its own surface first
    # (`_skeleton.build`), not one strand's reach (half a head).
    midline: tuple | None = None

    @property
    def fork(self) -> bool:
        """Whether two strands were joined into this limb (`_forks`)."""
        return self.midline is not None

    def fitted_centers(self, centers: np.ndarray) -> np.ndarray:
        """`centers` (m, 3) with the path's shared spheres moved to the midline (a fork's)."""
        if self.midline is None:
            return centers
        moved = centers.copy()
        moved[self.path[self.midline[0]]] = self.midline[1]
        return moved


def find_limbs(centers: np.ndarray, radii: np.ndarray, edges: np.ndarray) -> list[LimbPath]:
    """The limbs of the medial graph `(centers, radii, edges)`, parents before children.

    **Returns:** a list of `LimbPath`s; for a tube, one limb from a body at one end.
    """
    graph = medial_graph(centers, edges)
    _, labels = csgraph.connected_components(graph, directed=False)
    largest = np.flatnonzero(labels == np.argmax(np.bincount(labels)))
    thickest = int(largest[np.argmax(radii[largest])])
    first: list[LimbPath] = []
    _split(graph, centers, radii, largest, thickest, -1, first, depth=1)
    root = hub(graph, centers, radii, largest, thickest, first)
    limbs, chosen = first, thickest
    for other in [root] * (root != thickest) + _thick_parts(radii, thickest, first, root):
        found: list[LimbPath] = []
        _split(graph, centers, radii, largest, other, -1, found, depth=1)
        # The hub's limbs replace the first ones unless fewer of them hold more than two
        # spheres: a hand's hub lay on its palm's edge among the fingers' bases (the palm a
        # flat sheet, thin beside the forearm, its thickest), from which three of its five
        # fingers were no limbs. (Spurs of one or two spheres are no measure: an insect's
        # hub, its thorax, finds fewer of them than its head does.)
        if _count(found) > _count(limbs) or (other == root and _sized(found) >= _sized(limbs)):
            limbs, chosen = found, other
    # Forks are joined from the chosen root only: from another one (an abdomen), a path
    # runs through the thorax into a leg, and legs sharing the thorax would look like one.
    limbs = []
    _split(graph, centers, radii, largest, chosen, -1, limbs, depth=1, forks=True)
    if not limbs:
        limbs = tube(graph, centers, radii, largest)
    return limbs


def _thick_parts(radii, thickest: int, limbs: list[LimbPath], root: int) -> list[int]:
    """The body's other candidate roots: the thickest sphere of each limb found from the
    thickest sphere (`limbs`) that is at least `CORE` times as thick as it (not `root`, the
    hub): a thick part beyond a thin neck. Cheburashka's torso lies below a thicker head:
    from the head, the tips are its ears and one limb holding the torso with every arm and
    leg, and the hub stays in the head. The root kept is the one that the most limbs leave,
    then the one that finds the most limbs (`_count`; the hub on a tie)."""
    parts = []
    for limb in limbs:
        top = int(limb.spheres[np.argmax(radii[limb.spheres])])
        if (limb.parent == -1 and radii[top] >= CORE * radii[thickest] and top != root
                and top not in parts):
            parts.append(top)
    return parts


def _count(limbs: list[LimbPath]) -> tuple[int, int]:
    """`(limbs leaving the body, all limbs)`: a body's candidate root is better the more limbs
    leave it (the thorax's six legs, head and abdomen, against the abdomen's one thorax)."""
    return sum(limb.parent == -1 for limb in limbs), len(limbs)


def _sized(limbs: list[LimbPath]) -> int:
    """How many of `limbs` hold more than two spheres."""
    return sum(len(limb.spheres) > 2 for limb in limbs)


def hub(graph, centers, radii, nodes, thickest: int, limbs: list[LimbPath]) -> int:
    """The body's root sphere: where the limbs meet (a torso, a thorax), not merely the
    thickest part (an insect's head or abdomen, from which the thorax and its six legs would
    hang as one limb).

    The sphere of `nodes` nearest in total, along the medial graph, to the tips of the limbs
    found from `thickest` (`limbs`) that leave the body, and of the children of any one of
    them that more limbs leave than leave the body (their geodesic median: six legs pull it
    to the thorax; a head's ears and horns, fewer than the body's limbs, do not), then the
    thickest sphere that holds its centre, then uphill to its part's core (`_uphill`).
    `thickest` stays the root where the two belong to one thick part (joined by spheres at
    least `CORE` times as thick as it, as its core is defined): on a torso that is thickest
    itself, nothing changes."""
    top = [k for k, limb in enumerate(limbs) if limb.parent == -1]
    tips = [int(limbs[k].path[-1]) for k in top]
    for k in top:  # a limb more limbs leave than leave the body (a thorax hung from an
        children = [limb for limb in limbs if limb.parent == k]  # abdomen): its children
        if len(children) > len(top):
            tips += [int(limb.path[-1]) for limb in children]
    tips = np.unique(tips)
    if len(tips) < 2:
        return thickest
    distance = csgraph.dijkstra(graph, directed=False, indices=tips)[:, nodes]
    median = int(nodes[np.argmin(distance.sum(axis=0))])
    holding = nodes[np.linalg.norm(centers[nodes] - centers[median], axis=1) <= radii[nodes]]
    root = int(holding[np.argmax(radii[holding])])  # (the median holds itself)
    # Then uphill to that part's core: a median pulled out of the thorax by two antennae
    # (the Blender insect at seed 1) lay in the neck, whose spheres, 0.7 as thick as the
    # thorax's, held the head: the head in the body, the antennae limbs of the body.
    root = _uphill(graph, radii, root)
    _, predecessors = csgraph.dijkstra(graph, directed=False, indices=thickest,
                                       return_predecessors=True)  # fmt: skip
    between = _ancestors(root, predecessors)
    return thickest if np.all(radii[between] >= CORE * radii[thickest]) else root


def _uphill(graph, radii, sphere: int) -> int:
    """The sphere reached from `sphere` by stepping to its thickest neighbour on the medial
    graph while that one is thicker: the core of the thick part that `sphere` lies in."""
    graph = (graph + graph.T).tocsr()  # (its edges are stored one way)
    while True:
        neighbours = graph[sphere].indices
        step = int(neighbours[np.argmax(radii[neighbours])]) if len(neighbours) else sphere
        if radii[step] <= radii[sphere]:
            return sphere
        sphere = step


def _split(graph, centers, radii, nodes, root, parent, limbs, depth, forks=False,
           branches=(), thickness=None):
    """Appends to `limbs` the limbs among `nodes` (the level's spheres) that leave the level's
    core around `root`, then recursively their children. The level's `thickness`: the root's
    radius for the body (its hub, `hub`), for a limb's children the thickest sphere of its
    path (not of all its spheres: a bird's neck held a chest sphere beyond a crease, thicker
    than the neck, whose core then ended before the head, and a spur took the head). With
    `forks`, the body's limbs side by side that fork are joined (`_forks`); `branches`: the
    tips a joined limb's level takes as its children however thick."""
    inside = np.zeros(len(centers), bool)
    inside[nodes] = True
    sub = graph.multiply(inside[:, None]).multiply(inside[None, :]).tocsr()
    distance, predecessors = csgraph.dijkstra(sub, directed=False, indices=root,
                                              return_predecessors=True)  # fmt: skip
    reach = np.where(np.isfinite(distance), distance + radii, -np.inf)
    level = radii[root] if thickness is None else thickness
    groups = []  # per limb: its paths (the first one the main), last sphere inside, core
    hangs = []  # per limb: (n,) bool, the spheres below its first one in the tree
    waists = []  # per limb: `_waist`'s (spheres before its path, last inside, core), or None
    for tip in _tips(nodes, reach, predecessors, distance):
        chain = _ancestors(tip, predecessors)  # tip … root
        covered, core = _covered(centers, radii, chain, level, depth > 1)
        cut = np.flatnonzero(covered)
        if len(cut) == 0 or cut[0] == 0:
            continue
        path, last_inside = chain[: cut[0]][::-1], int(chain[cut[0]])  # path: out … tip
        # A crease where a limb meets its parent holds medial spheres far thinner than either:
        # the tree may enter the limb through one (a modelled cow's leg, through a sphere a
        # tenth as thick as the leg), whose spine would then start at the crease. The path
        # starts at its first sphere at least `CREASE` times as thick as its thickest.
        path = path[int(np.argmax(radii[path] >= CREASE * radii[path].max())):]
        group_spheres = [np.concatenate(g[0]) for g in groups]
        same = _same_limb(centers, radii, path, last_inside, [g[0] for g in groups], graph)
        if same is not None:
            groups[same][0].append(path)
            continue
        below = [k for k, mask in enumerate(hangs) if mask[tip]]
        if below:
            # Below a limb found already: a child (an ear on a head), left to that limb's
            # level, unless it is as thick as that limb (a leg hanging from the top of the
            # leg beside it in the tree): then a limb of its own.
            # Its own part: the spheres whose centres lie outside that limb's (a head is
            # often two near-equal spheres, and a path through the other one is the head's).
            spheres = group_spheres[below[0]]
            own = path[sphere_gaps(centers[path], centers[spheres], radii[spheres]) >= 0]
            if len(own) == 0 or radii[own].max() <= THINNER * radii[spheres].max():
                continue
        # How far the limb reaches beyond the last sphere inside the parent.
        length = distance[tip] - distance[last_inside] + radii[tip] - radii[last_inside]
        thickest = radii[path].max()
        if length < ELONGATION * thickest or (
                depth > 1 and thickest > THINNER * level and tip not in branches):
            continue
        groups.append(([path], last_inside, core))
        waists.append(_waist(centers, radii, chain, core, cut[0]) if depth == 1 else None)
        hangs.append(np.isin(np.arange(len(centers)),
                             _subtree(path[0], predecessors, distance, nodes)))  # fmt: skip
    groups, waists = _joined_routes(centers, radii, groups, graph, waists)
    found = [
        (paths[0], last_inside, core, spheres)
        for (paths, last_inside, core), spheres in zip(
            groups, _assign(centers, radii, [g[0] for g in groups], predecessors, distance, nodes)
        )
    ]
    stems = [None] * len(found)  # (a fork's: `_forks`)
    if depth == 1:
        found, groups, waists = _from_thicker_limbs(centers, radii, found, groups, waists)
        stems = [None] * len(found)
        if forks:
            found, groups, waists, stems = _forks(centers, radii, distance, found, groups,
                                                  waists)  # fmt: skip
        waists = [_unshared_waist(centers, radii, predecessors, found, k, w)
                  for k, w in enumerate(waists)]  # fmt: skip
    for (path, last_inside, core, spheres), (routes, _, _), waist, stem in zip(
            found, groups, waists, stems, strict=True):
        if len(spheres) == 0:
            # Every sphere went to the limbs beside it (`_assign`): none. (A spider's leg at
            # seed 1, found twice within a limb's level: the level's search, on the graph
            # restricted to its spheres, still steps through the stored zeros of the edges
            # cut off, and one route began at a sibling's sphere.)
            continue
        index = len(limbs)
        limbs.append(LimbPath(path, last_inside, core, spheres, parent))
        if depth < MAX_DEPTH and len(spheres) > 2:
            _split(graph, centers, radii, spheres, int(path[0]), index, limbs, depth + 1,
                   branches=() if stem is None else stem[1], thickness=radii[path].max())
        # The spine runs to the limb's own farthest sphere, not into a child (an ear): none
        # of the children's, none inside them, and far counted with twice the radius, so
        # that a head's runs to its snout, not to the base of an ear.
        children = np.array([v for c in limbs[index + 1 :] for v in c.spheres], int)
        own = np.setdiff1d(spheres, children)
        own = np.intersect1d(own, _subtree(path[0], predecessors, distance, spheres))
        # Not the parent's thick spheres hanging below the limb's top in the tree (the cow's
        # chest, reached through its front leg's top): a limb is no thicker than its path.
        own = own[radii[own] <= radii[path].max()]
        if len(children):
            outside = sphere_gaps(centers[own], centers[children], radii[children]) >= 0
            own = own[outside] if outside.any() else own
        # Where that spine leaves the limb no region (its reach covering only a thick head's
        # snout, whose border with the body then runs its whole length: spot at seed 2),
        # the next routes: to the next farthest own spheres off the routes before, then
        # the routes the limb was found by (into a child: a spine through the head's top).
        # A fork's spine runs along the part its strands share (a head), not up one of them
        # into a branch's base (an antenna's: the spine rose with it, the head's border with
        # the body slanted along it, the joint a third of the way into the head).
        paths = [] if stem is None else [stem[0]]
        for tip in own[np.argsort(-(distance[own] + 2 * radii[own]), kind="stable")]:
            if len(paths) == ROUTES or any(tip in p for p in paths):
                continue
            chain = _ancestors(int(tip), predecessors)[::-1]  # root … tip, through path[0]
            paths.append(chain[np.flatnonzero(chain == path[0])[0] :])
        paths += [p for p in routes if not any(np.array_equal(p, q) for q in paths)]
        first, *others = paths
        alternatives = tuple((p, int(predecessors[p[0]])) for p in others)
        if waist is not None and len(waist[0]):
            # Found as before (its spheres, its children); its routes from `path[0]` start
            # at its waist instead, the parent's core ending there.
            before, last_inside, core = waist
            first = np.r_[before, first]
            alternatives = tuple((np.r_[before, p], last_inside) if p[0] == path[0] else (p, i)
                                 for p, i in alternatives)  # fmt: skip
        midline = None
        if stem is not None:
            shift = len(first) - len(stem[0])  # (its waist's spheres before it)
            midline = (np.arange(len(stem[0])) + shift, stem[2])
        limbs[index] = LimbPath(first, last_inside, core, spheres, parent, alternatives,
                                midline=midline)


def _unshared_waist(centers, radii, predecessors, found, k: int, waist):
    """Limb `k`'s `waist` or, where it leads into other limbs too (`_shared_waist`), its next
    waist further out that does not (a dinosaur's neck, thick enough to be core: its waist at
    the chest held the small arms' tops, the next one up the neck none), or None."""
    if waist is None or len(waist[0]) == 0 or not _shared_waist(
            centers, radii, predecessors, found, k, waist):
        return waist
    path, inside = found[k][0], found[k][1]
    chain = _ancestors(int(path[-1]), predecessors)
    cut = int(np.flatnonzero(chain == inside)[0])
    for which in range(1, len(chain)):
        further = _waist(centers, radii, chain, found[k][2], cut, which)
        if len(further[0]) == 0:
            return None
        if not _shared_waist(centers, radii, predecessors, found, k, further):
            return further
    return None


def _shared_waist(centers, radii, predecessors, found, k: int, waist) -> bool:
    """Whether limb `k`'s `waist` (`_waist`'s, or None) leads into other limbs too: a waist
    leads into one limb alone. Its spheres before the path are the body's where they lie on
    another limb's way from the root (the front of a body, tapering towards two horns) or
    hold the sphere another limb leaves the body from (a dinosaur's chest, tapering towards
    its neck, its small arms below: taken as the neck's, they were in the neck's limb)."""
    if waist is None or len(waist[0]) == 0:
        return False
    before = waist[0]
    for j, (path, inside, _, _) in enumerate(found):
        if j == k:
            continue
        way = _ancestors(int(path[-1]), predecessors)
        if np.isin(before, way).any() or sphere_gaps(
                centers[[inside]], centers[before], radii[before])[0] < 0:
            return True
    return False


def _from_thicker_limbs(centers, radii, found, groups, waists):
    """`(found, groups, waists)` without the limbs that leave another limb rather than the body: a
    limb whose last sphere inside its parent lies inside another limb at least `1/THINNER`
    times as thick (an ear reached through a head as thick as the torso, no waist between:
    found from the body before the head was). Its spheres join that limb's, whose own level
    then finds it as a child."""
    keep = np.ones(len(found), bool)
    spheres = [f[3] for f in found]
    for a, (path, inside, _, _) in enumerate(found):
        for b, (other, _, _, held) in enumerate(found):
            if b == a or not keep[b] or radii[other].max() * THINNER < radii[path].max():
                continue
            if sphere_gaps(centers[[inside]], centers[held], radii[held])[0] < 0:
                keep[a] = False
                spheres[b] = np.union1d(spheres[b], spheres[a])
                break
    found = [(*f[:3], spheres[k]) for k, f in enumerate(found)]
    return ([f for f, k in zip(found, keep) if k], [g for g, k in zip(groups, keep) if k],
            [w for w, k in zip(waists, keep) if k])  # fmt: skip


def _forks(centers, radii, distance, found, groups, waists):
    """`(found, groups, waists, stems)` with the two limbs of each fork joined into one.
    A head whose medial axis is two strands side by side from the neck on, one into each
    antenna (an insect modelled in Blender, the procedural insect), was two limbs of the
    body: the head split lengthwise, each half carrying one antenna. Two limbs are one where
    one's first sphere meets the other's path, the spheres where they meet protrude `FORK`
    times their thickness from the paths' first spheres, are alike on both (at least
    `ALIKE` as thick), and at most one path runs on past them at least `WAIST` times as
    thick (a head's snout; legs side by side both do). The joined limb's path is that of the
    one leaving the body first (a neck), its spheres both. `stems`: per limb, `None` or, for
    a joined one, `(shared, tips, middle)`: the longer of the two paths' parts up to their
    last sphere meeting the other (its spine's route, after the joined limb's waist), the
    two paths' tips, which its level takes as its children
    however thick (an antenna, 0.6-0.7 times as thick as the head's spheres), and `(k, 3)`
    the points midway between the shared spheres and the other's nearest, along which its
    spine is fitted (`LimbPath.midline`)."""
    stems = [None] * len(found)
    merged = True
    while merged:
        merged = False
        for a, b in ((a, b) for a in range(len(found)) for b in range(len(found)) if a < b):
            pa, pb = found[a][0], found[b][0]
            if min(len(pa), len(pb)) < 2 or stems[a] is not None or stems[b] is not None:
                continue  # (two strands at most: a head's)
            meet = np.linalg.norm(centers[pa][:, None] - centers[pb][None], axis=-1) < (
                radii[pa][:, None] + radii[pb][None])
            if not (meet[0].any() or meet[:, 0].any()):
                continue
            last = [np.flatnonzero(meet.any(1))[-1], np.flatnonzero(meet.any(0))[-1]]
            thickness = [radii[pa[meet.any(1)]].max(), radii[pb[meet.any(0)]].max()]
            # Side by side out of the parent (a neck and head), not merely touching where
            # they leave it (legs, or a leg and an antenna, on a thorax), both alike there
            # (not a leg's top and a crease's bump beside it).
            out = max(distance[p[k]] - distance[p[0]] for p, k in zip((pa, pb), last))
            if out < FORK * max(thickness) or min(thickness) < ALIKE * max(thickness):
                continue
            if all(radii[p[k + 1 :]].max(initial=0) > WAIST * max(thickness)
                   for p, k in zip((pa, pb), last)):
                continue
            # (The one leaving the body first: at its waist, a neck.)
            start = [distance[w[0][0] if w is not None and len(w[0]) else f[0][0]]
                     for f, w in ((found[a], waists[a]), (found[b], waists[b]))]
            main, other = (a, b) if start[0] <= start[1] else (b, a)
            # Its spine's route: the longer of the two paths' parts up to where they last
            # meet (an insect's head: one strand meets the other's first sphere only), each
            # sphere moved midway to the nearest of the other's it meets.
            mine, theirs, meets = (pa, pb, meet) if last[0] >= last[1] else (pb, pa, meet.T)
            shared = mine[: max(last) + 1]
            gap = np.linalg.norm(centers[shared][:, None] - centers[theirs][None], axis=-1)
            gap[~meets[: len(shared)]] = np.inf
            nearest = theirs[np.argmin(gap, axis=1)]
            held = np.isfinite(gap.min(axis=1))[:, None]
            middle = np.where(held, (centers[shared] + centers[nearest]) / 2, centers[shared])
            path, inside, core, spheres = found[main]
            found[main] = (path, inside, core, np.union1d(spheres, found[other][3]))
            groups[main][0].extend(groups[other][0])
            stems[main] = (shared, np.array([pa[-1], pb[-1]]), middle)
            del found[other], groups[other], waists[other], stems[other]
            merged = True
            break
    return found, groups, waists, stems


def _joined_routes(centers, radii, groups, graph, waists):
    """`(groups, waists)`: `groups` (per limb: its paths, last sphere inside, core; `waists`
    alongside) with each limb whose main path
    is another route to an earlier one (`_same_limb`) by the paths that earlier one gained
    after this one was found joined to it, until none is. Tips come by decreasing reach, so
    a wide flat ear's rim may be reached first by two paths with no medial edge between
    them, and only later by the paths between (cheburashka's left ear: a second path's
    spheres 0.29 joined to the first's, 0.86 to a third found after it)."""
    merged = True
    while merged:
        merged = False
        for j in range(1, len(groups)):
            same = _same_limb(centers, radii, groups[j][0][0], groups[j][1],
                              [g[0] for g in groups[:j]], graph)  # fmt: skip
            if same is not None:
                groups[same][0].extend(groups[j][0])
                groups = groups[:j] + groups[j + 1 :]
                waists = waists[:j] + waists[j + 1 :]
                merged = True
                break
    return groups, waists


def _same_limb(centers, radii, path, inside: int, limbs, graph) -> int | None:
    """The index of the limb in `limbs` (each its paths, its main one first) that `path` is
    another route to (a head reached through two strips of the neck, a strip's second tip):
    of those whose spheres hold half of the path's centres, or its tip, the one holding most
    (a spur off one paw's top, which lies just inside the other paw's first sphere, is held
    by both: taken by the paw found first, it made that paw hold half of the other's path,
    and the two paws were one limb: the bunny's at seed 0), on a tie the one whose main path
    holds most (a spur at a bird's neck base, held whole by the neck's paths and by a wing's
    that reach its root: taken by the wing, the neck's thickest sphere with it, the neck was
    then a route through the wing); or, a sheet (a
    flat ear: its rim's tips each a path, side by side), whose spheres are joined by the
    medial mesh's edges to most of the path's own spheres (`SHEET`), at least two of them,
    its tip among them: two feet side by side (cheburashka's), touching along a crease, are
    joined by the crease's medial edges but their toes are free; taken as one sheet, the
    first foot found took the crease's paths, then the other foot's spheres they hold, then
    the other foot (`_joined_routes`): one limb of two feet, or a foot left in the body. A
    limb that holds the path claims it before one joined to it.
    Legs side by side, touching at the top, are two limbs; so are an insect's antennae from
    a shared base (a quarter of their own spheres joined). A path that widens past a neck
    (a sphere before its thickest less than `WAIST` times as thick, the last one `inside` the
    parent too: the neck itself may be the core's) into a limb at least `WAIST` and at most
    twice as thick as its thickest sphere, which lies inside that limb, runs through the
    limb's thick part: a head reached by a second strip of the neck and its other near-equal
    sphere, running on into an ear (cheburashka's, from its torso), is the head's route, and
    the head's level finds the ear; a bird's neck, its base inside a thinner wing's root, is
    not the wing's. (Horns side by side are thickest at their bases: no neck before.)"""
    widest = int(np.argmax(radii[path]))
    necked = np.any(radii[np.r_[inside, path[:widest]]] < WAIST * radii[path[widest]])
    def holds(spheres):  # (n,) whether each of the path's centres lies inside `spheres`
        return sphere_gaps(centers[path], centers[spheres], radii[spheres]) < 0

    every = [np.concatenate(paths) for paths in limbs]  # each limb's spheres
    held = [holds(spheres) for spheres in every]
    holders = [k for k, h in enumerate(held) if h.mean() >= 0.5 or h[-1]]
    if holders:  # (the one holding most of it, then by its main path; the first on a tie)
        return max(holders, key=lambda k: (held[k].mean(), holds(limbs[k][0]).mean()))
    for k, (h, spheres) in enumerate(zip(held, every)):
        if necked and h[widest] and (WAIST * radii[path[widest]] <= radii[spheres].max()
                                     <= 2 * radii[path[widest]]):
            return k
    for k, spheres in enumerate(every):  # (a limb that holds it first)
        own = path[~np.isin(path, spheres)]  # (in order: the path's tip last, if own)
        if len(own) >= 2:
            joined = (graph[own][:, spheres].getnnz(axis=1) > 0) | (
                graph[spheres][:, own].getnnz(axis=0) > 0)
            if joined.mean() >= SHEET and (joined[-1] or own[-1] != path[-1]):
                return k
    return None


def _assign(centers, radii, paths, predecessors, distance, nodes) -> list[np.ndarray]:
    """The spheres of each limb (given by its `paths`): those hanging below a limb's first
    sphere in the tree, each to the limb whose path spheres' surfaces are nearest (two legs
    side by side may hang one from the other's top in the tree)."""
    if not paths:
        return []
    hanging = np.unique(np.concatenate(
        [_subtree(p[0], predecessors, distance, nodes) for group in paths for p in group]
    ))  # fmt: skip
    groups = [np.concatenate(group) for group in paths]
    gaps = np.stack([sphere_gaps(centers[hanging], centers[g], radii[g]) for g in groups])
    nearest = np.argmin(gaps, axis=0)
    # Each limb keeps its main path (the first limb a shared top sphere).
    for k in range(len(paths) - 1, -1, -1):
        nearest[np.isin(hanging, paths[k][0])] = k
    return [hanging[nearest == k] for k in range(len(paths))]


def tube(graph, centers, radii, nodes) -> list[LimbPath]:
    """One limb along the longest path of a shape with no core (a tube, a capsule), its body
    the sphere at the path's first end: a limb needs a still part to leave."""
    start = farthest(graph, int(nodes[0]), radii)
    end = farthest(graph, start, radii)
    distance, predecessors = csgraph.dijkstra(graph, directed=False, indices=start,
                                              return_predecessors=True)  # fmt: skip
    chain = _ancestors(end, predecessors)[::-1]  # start … end
    gap = np.linalg.norm(centers[chain] - centers[start], axis=1)
    out = np.flatnonzero(gap >= radii[start])
    if len(out) < 2:
        return []
    path = chain[out[0] :]
    spheres = _subtree(path[0], predecessors, distance, nodes)
    return [LimbPath(path, int(chain[out[0] - 1]), np.array([start]), spheres, -1)]


def _covered(centers, radii, chain, thickness, thickest_run=False):
    """(len(chain),) bool: the spheres of `chain` (tip … root) whose centres lie inside the
    core part of the chain: its spheres from the root outwards up to the end of their first
    run at least `CORE` times as thick as `thickness` (the level's: the hub's, a limb's
    thickest) and as every sphere further out; and the core part's sphere indices. With
    `thickest_run` (a limb's level), up to the end of the run holding the chain's thickest
    sphere instead: a limb's thick part is its head, not the base of its neck, thick enough
    on its own (spot at seed 8, whose ears and horns then hung from a core of one sphere).
    On the body's level, a root thinner than a part further out (a spider's thorax) has a
    core no longer than its own run at least `CORE` times as thick as `thickness`."""
    outwards = chain[::-1]
    # Thin: thinner than the level's thickest, or than a part further out (a neck before a
    # head thicker than the body's hub): a limb starts at a waist.
    beyond = np.maximum.accumulate(radii[outwards][::-1])[::-1]
    thick = radii[outwards] >= CORE * np.maximum(thickness, beyond)
    # Up to the end of the first thick run: a limb's first spheres may be thinner than its
    # thickest (a neck before a head), and belong to it all the same.
    first = int(np.argmax(thick)) if thick.any() else len(chain)
    if thickest_run and thick.any():
        first = int(np.argmax(np.where(thick, radii[outwards], -np.inf)))
    thin = np.flatnonzero(~thick[first:])
    end = first + thin[0] if len(thin) else len(chain)
    if first > 0 and not thickest_run:
        # The body's root thinner than a part further out (a spider's thorax before its
        # abdomen, twice as thick): the core ends where the root's own thickness does, if
        # sooner (at the waist between the two: the core ran on through the abdomen, in the
        # body, when no sphere of the thorax was thick beside it).
        own = np.flatnonzero(radii[outwards] < CORE * thickness)
        end = min(end, own[0] if len(own) else len(chain))
    core = outwards[:end]
    return sphere_gaps(centers[chain], centers[core], radii[core]) < 0, core


def _waist(centers, radii, chain, core, cut: int, which: int = 0):
    """`(before, last_inside, core)`: where a limb from the body found along `chain` (tip …
    root; its path `chain[:cut]`, `core` its parent's core along it) starts instead, at its
    waist (a hip): the core ends at its first sphere past the root at most `WAIST` times as
    thick as the core before it and at least as thick as any further out (the limb tapering
    away from there), where the core runs on beyond that sphere; `before` the spheres then
    added before the path (outwards). The
    biped's thighs, 0.6 as thick as its pelvis, were core down to 0.36 (its hips at 0.47):
    its knees, 1.1 radii from where the legs then left the body, were no joints. `which`: the
    waist to take among the core's spheres that qualify, outwards (`_unshared_waist`)."""
    outwards = radii[core]
    beyond = np.maximum.accumulate(radii[chain])[::-1][: len(core)]  # outwards, as `core`
    waist = np.flatnonzero((outwards <= WAIST * np.maximum.accumulate(outwards))
                           & (outwards >= beyond))  # fmt: skip
    waist = waist[waist > 0][which:]
    # Only where the core runs on past the waist's own sphere (a thigh's top; not a shoulder,
    # the core's last sphere there: moved into the arm, a 30° bend flagged its armpit).
    if not len(waist) or np.linalg.norm(
            centers[core[-1]] - centers[core[waist[0]]]) <= radii[core[waist[0]]]:
        return np.zeros(0, int), int(chain[cut]), core
    core = core[: waist[0]]
    covered = np.flatnonzero(sphere_gaps(centers[chain], centers[core], radii[core]) < 0)
    return chain[cut : covered[0]][::-1], int(chain[covered[0]]), core


def _tips(nodes, reach, predecessors, distance) -> np.ndarray:
    """The tips of the tree's branches (each the sphere that reaches farthest in the subtree of
    the branch's top), by decreasing reach."""
    best = np.arange(len(reach))
    for v in nodes[np.argsort(-distance[nodes])]:
        p = predecessors[v]
        if p >= 0 and reach[best[v]] > reach[best[p]]:
            best[p] = best[v]
    tips = np.unique(best[nodes])
    tips = tips[np.isfinite(reach[tips])]
    return tips[np.argsort(-reach[tips], kind="stable")]


def _ancestors(node: int, predecessors: np.ndarray) -> np.ndarray:
    """`node` and its ancestors in the shortest-path tree, up to the root."""
    chain = [node]
    while predecessors[chain[-1]] >= 0:
        chain.append(int(predecessors[chain[-1]]))
    return np.asarray(chain)


def _subtree(top: int, predecessors, distance, nodes) -> np.ndarray:
    """The `nodes` at or below `top` in the shortest-path tree."""
    below = np.zeros(len(predecessors), bool)
    below[top] = True
    for v in nodes[np.argsort(distance[nodes])]:
        p = predecessors[v]
        if p >= 0 and below[p]:
            below[v] = True
    return np.flatnonzero(below & np.isin(np.arange(len(predecessors)), nodes))

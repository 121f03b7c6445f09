"""One connected medial graph per volume of the shape: the pieces of an initial axis joined.

The inner Voronoi complex of surface samples (`voronoi`) falls apart where the shape is thin:
across a leg or a tail a handful of samples span Delaunay tetrahedra whose circumcentres
alternate inside and outside the surface, so the inside ones form short chains and lone
vertices with no kept neighbour. Edge collapses never join pieces, so each piece ended as a
sphere in no edge, or as a few spheres covering part of a limb (issue 30: 9–19 isolated
spheres on an animal mesh, and the rig refused the library's own medial mesh).

Our own remedy: the pieces of one volume are joined by an edge between their closest
centres (Borůvka's rounds over a k-d tree: every piece joins its nearest other piece, so
the pieces at least halve each round), before any collapse. In a thin part the closest
centres of two pieces lie along the part's axis, where the missing Voronoi vertices would
have been. The volumes are told apart by the surface: a sphere's contact samples lie on
one or more shells (face-connected components of the mesh), and shells touched by one
sphere bound the same volume (a hollow ball's two shells).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
from scipy.spatial import cKDTree

from .rows import row_keys, sorted_rows


def distinct(values):
    """The distinct values of an integer array, ascending: `np.unique(values)` by a sort
    (NumPy 2's hash-based `np.unique` took 1.5 s for 1.5M keys, a sort 0.08 s)."""
    values = np.sort(np.asarray(values).reshape(-1))
    return values[np.r_[True, values[1:] != values[:-1]]] if len(values) else values


def unique_rows(rows, n: int):
    """The distinct rows of `rows (m, k)` (indices below `n`), each sorted, in lexicographic
    order: as `np.unique(np.sort(rows, axis=1), axis=0)`, by one integer per row (a row sort
    of structured values took 1 s for a Voronoi complex of spot)."""
    rows = sorted_rows(rows)
    if float(n) ** rows.shape[1] >= 2.0**62:  # the keys would overflow
        return np.unique(rows, axis=0)
    key = distinct(row_keys(rows, n))
    out = np.empty((len(key), rows.shape[1]), np.int64)
    for k in range(rows.shape[1] - 1, -1, -1):
        key, out[:, k] = np.divmod(key, n)
    return out


def components(n: int, edges) -> tuple[int, np.ndarray]:
    """Connected components of a graph on `n` nodes with `edges (e, 2)`: `(count, labels
    (n,))`."""
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    graph = scipy.sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])),
                                    shape=(n, n))
    return scipy.sparse.csgraph.connected_components(graph, directed=False)


def volumes(face_shell, shell_count: int, contact_faces) -> tuple[int, np.ndarray]:
    """The volume of each sphere: `(count, labels (n,))`, from the faces of its contact
    samples `contact_faces (n, k)`; shells that one sphere touches bound the same volume."""
    touched = face_shell[contact_faces]  # (n, k)
    links = np.stack([np.repeat(touched[:, 0], touched.shape[1]), touched.reshape(-1)], 1)
    count, shell_volume = components(shell_count, links)
    return count, shell_volume[touched[:, 0]]


def _inside_links(other, gap, piece, start, end, inside, known=None):
    """`other (m, k)` with the links (row, column) that leave the shape dropped: those
    whose points at a quarter, half and three quarters of the way from `start (m, 3)` to
    `end (m, k, 3)` are not all `inside`. Only each piece's nearest link is looked for (by
    `gap (m, k)`; `piece (m,)` the rows' pieces): its candidates are tested in order of gap,
    in rounds of 1, 2, 4, ... per piece until one is inside; the links not tested are
    dropped too. Each piece then keeps its nearest inside link as it would
    with every link tested (ties in gap by row, then column, as `join_pieces` breaks them):
    on the thin-limbed animal most of the tests were of links never used (1.2 s of 4.5 s of
    its Voronoi complex). `known`: `(keys (m, k), found)` with `found` a dict of the links'
    keys already tested and their outcome (read and written here): a piece that looks
    further (larger `k`) would test its nearer links again (the animal: 38k of them)."""
    row, col = np.nonzero(other)
    order = np.lexsort((col, row, gap[row, col], piece[row]))
    row, col = row[order], col[order]
    group = piece[row]
    first = np.r_[True, group[1:] != group[:-1]]
    rank = np.arange(len(row)) - np.maximum.accumulate(np.where(first, np.arange(len(row)), 0))
    tested = np.zeros(len(row), bool)
    valid = np.zeros(len(row), bool)

    def test(sel):
        if known is not None:
            keys, memo = known
            key = keys[row[sel], col[sel]]
            seen = np.array([k in memo for k in key.tolist()], bool)
            tested[sel[seen]] = True
            valid[sel[seen]] = [memo[k] for k in key[seen].tolist()]
            sel = sel[~seen]
        a, b = start[row[sel]], end[row[sel], col[sel]]
        # The middle first, then the quarters of the links still inside only: the same
        # conjunction, and a link across a gap (most of the links tested) is out at once
        # (the animal's points queried 311k -> 108k, its Voronoi complex 3.1 -> 2.3 s).
        left = np.arange(len(sel))
        for t in (0.5, 0.25, 0.75):
            if len(left):
                left = left[inside(a[left] + t * (b[left] - a[left]))]
        ok = np.zeros(len(sel), bool)
        ok[left] = True
        tested[sel], valid[sel] = True, ok
        if known is not None:
            memo.update(zip(keys[row[sel], col[sel]].tolist(), ok.tolist()))

    low = 0
    while low < len(row):
        # Ranks [low, 2 low + 1) of the pieces with no inside link yet: each round tests at
        # most twice the links that the previous ones did.
        found = np.zeros(piece.max(initial=0) + 1, bool)
        found[group[valid]] = True
        sel = np.flatnonzero(~found[group] & (rank >= low) & (rank <= 2 * low))
        if not len(sel) and not (~found[group] & (rank > 2 * low)).any():
            break
        test(sel)
        low = 2 * low + 1
    out = np.zeros_like(other)
    out[row[valid], col[valid]] = True
    return out


def join_pieces(centers, edges, volume, inside=None) -> np.ndarray:
    """Edges `(e', 2)`: `edges` plus one edge per join, so that the spheres of each volume
    (`volume (n,)` labels) form one connected graph (see the module's notes). `inside`:
    `points (m, 3) → (m,) bool`; when given, a link is made only where its points at a
    quarter, half and three quarters lie inside (unless no sphere has one)."""
    centers = np.asarray(centers, np.float64)
    n = len(centers)
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    tree = cKDTree(centers)
    while True:
        count, piece = components(n, edges)
        size = np.bincount(piece, minlength=count)
        # The largest piece of each volume stays; every other piece links to its nearest
        # piece of the same volume.
        order = np.lexsort((-size[piece], volume))
        main = np.zeros(count, bool)
        main[piece[order[np.r_[True, volume[order][1:] != volume[order][:-1]]]]] = True
        todo = np.flatnonzero(~main[piece])
        if not len(todo):
            return edges
        k, strict = 8, inside is not None
        nearest = np.full(n, -1)
        tested = {}  # link key (sphere · n + sphere) → inside, for the rounds of larger k
        while len(todo):
            kk = min(k, n)
            gap, idx = tree.query(centers[todo], k=kk)
            gap, idx = gap.reshape(len(todo), kk), idx.reshape(len(todo), kk)
            other = (piece[idx] != piece[todo, None]) & (volume[idx] == volume[todo, None])
            if strict:
                # Only links inside the shape: the nearest piece may lie in the next leg,
                # and a cone across the gap would stand outside the surface.
                other = _inside_links(other, gap, piece[todo], centers[todo], centers[idx],
                                      inside, (todo[:, None] * n + idx, tested))
            hit = other.any(axis=1)
            nearest[todo[hit]] = idx[hit, np.argmax(other[hit], axis=1)]
            # The spheres of pieces with no link yet look further (a piece deep inside others
            # of its volume: few), unless k already spans every sphere.
            linked = np.zeros(count, bool)
            linked[piece[todo[hit]]] = True
            todo = todo[~linked[piece[todo]]]
            if kk == n:  # every sphere seen: the rest link outside the shape, or not at all
                todo, strict = (todo, False) if strict else (todo[:0], False)
            k *= 4
        ok = np.flatnonzero(nearest >= 0)
        gap = np.linalg.norm(centers[ok] - centers[nearest[ok]], axis=1)
        # Each piece's closest link found.
        order = np.lexsort((gap, piece[ok]))
        first = order[np.r_[True, piece[ok][order][1:] != piece[ok][order][:-1]]]
        new = np.sort(np.stack([ok[first], nearest[ok[first]]], 1), axis=1)
        edges = unique_rows(np.concatenate([edges, new]), n)

"""`Limb` and `Skeleton`: a shape as a tree of limbs on a body, each limb with its rest spine.

The data that `skeleton` finds on the medial axis and that posing reads: per limb a rest spine
(exactly arc-length, starting a little inside the parent), the arc length where it leaves its
parent, and the parent's index; per mesh vertex the limb it belongs to (−1: the body).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike
from scipy.spatial import cKDTree

from .._checks import check_finite_points, check_number, is_concrete
from .._spines.spine import AbstractSpine


class Limb(eqx.Module):
    """One limb of a `Skeleton`.

    **Arguments/fields:**

    - `spine`: the limb's rest spine (an `AbstractSpine`; `skeleton` gives an `fj.BSpline`
      in float64), exactly parameterised by arc length. `s = 0` lies inside the parent (the
      spine is continued a little into it) and `s = spine.length` at the limb's tip.
    - `joint`: scalar: the arc length on `spine` where the limb leaves its parent,
      `0 < joint < spine.length`.
    - `parent`: static int: the parent limb's index in `Skeleton.limbs`, or −1 for the body.
    - `name`: static str, "" for none: what a user calls the limb (an armature's bone name,
      `fj.skeleton(mesh, bones=…)`); poses and functions that take a limb index take it too.
    """

    spine: AbstractSpine
    joint: Array
    parent: int = eqx.field(static=True)
    name: str = eqx.field(static=True, default="")

    def __init__(self, spine: AbstractSpine, joint: ArrayLike, parent: int = -1,
                 name: str = ""):  # fmt: skip
        if not isinstance(spine, AbstractSpine):
            raise TypeError(f"`spine` must be an AbstractSpine, got {type(spine).__name__}.")
        if isinstance(parent, bool | np.bool_) or not isinstance(parent, int | np.integer):
            raise TypeError(f"`parent` must be an integer limb index or -1, got {parent!r}.")
        if parent < -1:
            raise ValueError(f"`parent` must be a limb index or -1 (the body), got {parent}.")
        self.spine = spine
        # The spine's float type, without computing its length (a compiled program).
        floats = [x for x in jax.tree.leaves(spine) if jnp.issubdtype(x.dtype, jnp.floating)]
        self.joint = jnp.asarray(joint, dtype=floats[0].dtype if floats else None)
        self.parent = int(parent)
        if not isinstance(name, str):
            raise TypeError(f"`name` must be a str, got {type(name).__name__}.")
        self.name = name

    def __check_init__(self):
        if self.joint.shape != ():
            raise ValueError(f"`joint` must be a scalar, got shape {self.joint.shape}.")
        if is_concrete(self.joint, self.spine.length):
            joint, length = float(self.joint), float(self.spine.length)
            if not 0 < joint < length:
                raise ValueError(
                    f"`joint` must lie inside the spine, in (0, {length:.6g}), got {joint:.6g}."
                )


def limb_index(k, names, argument: str, owner: str = "skeleton") -> int:
    """Limb `k` (an index, or a limb's name among `names`, a tuple with one per limb, "" for
    none) as an `int`, else `ValueError` naming the `argument`."""
    if isinstance(k, str):
        if k and k in names:
            return names.index(k)
        named = [name for name in names if name]
        listed = (f"named: {', '.join(named[:8])}{', …' if len(named) > 8 else ''}" if named
                  else "its limbs have no names")
        raise ValueError(f"`{argument}`: no limb of this {owner} is named {k!r} ({listed}).")
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 0 <= k < len(names):
        raise ValueError(f"`{argument}`: {k!r} is not a limb index of this {owner} "
                         f"(0 to {len(names) - 1}) nor a limb's name.")  # fmt: skip
    return int(k)


def descendants(limbs) -> list[list[int]]:
    """Each limb's descendants (children, their children, …) among `limbs` (a sequence of
    `Limb`s in topological order)."""
    below = [[] for _ in limbs]
    for k in reversed(range(len(limbs))):
        if limbs[k].parent >= 0:
            below[limbs[k].parent] += [k, *below[k]]
    return below


def merge_limb(limbs, region: np.ndarray, k: int):
    """`(limbs, region)` with limb `k` merged into its parent: its region and its children
    given to it, the later limbs renumbered. `limbs`: a sequence of `Limb`s in topological
    order; `region`: (n,) int, their regions (−1: the body)."""
    parent = limbs[k].parent
    merged = []
    for i, limb in enumerate(limbs):
        if i != k:
            up = parent if limb.parent == k else limb.parent
            merged.append(Limb(limb.spine, limb.joint, up - 1 if up > k else up, limb.name))
    region = np.where(region == k, parent, region)
    return merged, np.where(region > k, region - 1, region)


class Skeleton(eqx.Module):
    """A shape as a body and a tree of limbs (built by `fj.skeleton`: found on the medial
    mesh, from chains of joints, or from an armature's bones).

    Edited by hand with `merge(k)` (a joint removed: limb `k` joins its parent) and
    `split(k, point)` (a joint added: the part of limb `k` past the point a child limb);
    `fj.save_skeleton` writes it as JSON. `names` gives each limb's name (`Limb.name`: an
    armature's bone's) and `index(name)` its index.

    **Arguments/fields:**

    - `limbs`: tuple of `Limb`s in topological order: each limb's `parent` is −1 (the body) or
      the index of an earlier limb.
    - `region`: `(n,)` int32: the limb each mesh vertex belongs to, −1 for the body.
    - `vertices`: `(n, 3)` float: the rest vertices the regions were computed on.
    """

    limbs: tuple[Limb, ...]
    region: Array
    vertices: Array

    def __init__(self, limbs, region: ArrayLike, vertices: ArrayLike):
        limbs = tuple(limbs)
        for i, limb in enumerate(limbs):
            if not isinstance(limb, Limb):
                raise TypeError(f"`limbs[{i}]` must be a Limb, got {type(limb).__name__}.")
            if limb.parent >= i:
                raise ValueError(
                    f"`limbs[{i}].parent` must be -1 or an earlier limb's index (< {i}), "
                    f"got {limb.parent}."
                )
        self.limbs = limbs
        region = np.asarray(region) if not isinstance(region, jax.Array) else region
        if not jnp.issubdtype(region.dtype, jnp.integer):
            raise TypeError(f"`region` must hold integer limb indices, got dtype {region.dtype}.")
        self.region = jnp.asarray(region, jnp.int32)
        self.vertices = jnp.asarray(vertices)

    def __check_init__(self):
        n = self.region.shape[0] if self.region.ndim == 1 else -1
        if self.region.ndim != 1:
            raise ValueError(f"`region` must have shape (n,), got {self.region.shape}.")
        if self.vertices.shape != (n, 3):
            raise ValueError(f"`vertices` must have shape ({n}, 3), got {self.vertices.shape}.")
        # (Checked on the host: as device operations, each of the four reductions was a
        # program compiled in a new process, 0.3-0.5 s of CPU before a skeleton's first use.)
        if is_concrete(self.vertices) and not np.isfinite(np.asarray(self.vertices)).all():
            # (Else saved, it is a file `load_skeleton` refuses, and no mesh matches it.)
            raise ValueError("`vertices` must be finite (found NaN or inf).")
        names = [limb.name for limb in self.limbs if limb.name]
        twice = next((name for name in names if names.count(name) > 1), None)
        if twice is not None:
            raise ValueError(f"`limbs`: two limbs are named {twice!r}: names must be unique.")
        if is_concrete(self.region) and n:
            region = np.asarray(self.region)
            low, high = int(region.min()), int(region.max())
            if low < -1 or high >= len(self.limbs):
                raise ValueError(
                    f"`region` must hold limb indices in [-1, {len(self.limbs)}), "
                    f"got [{low}, {high}]."
                )

    @property
    def names(self) -> tuple[str, ...]:
        """Each limb's name ("" for none: a limb found on the medial axis)."""
        return tuple(limb.name for limb in self.limbs)

    def index(self, name: str) -> int:
        """The index of the limb named `name` (an armature's bone name, `Limb.name`); every
        function that takes a limb index takes its name too."""
        if not isinstance(name, str):
            raise TypeError(f"`name` must be a limb's name (str), got {type(name).__name__}.")
        return limb_index(name, self.names, "name")

    def _split_name(self, name: str) -> str:
        """A split limb's new part's name: `name.1` (`name.2`, … where taken), "" for ""."""
        count = 1
        while name and f"{name}.{count}" in self.names:
            count += 1
        return f"{name}.{count}" if name else ""

    def limb_at(self, point: ArrayLike) -> int:
        """The limb whose region holds the rest vertex nearest to `point` ((3,) finite), −1
        for the body."""
        point = check_finite_points(point, "point")
        if point.shape != (3,):
            raise ValueError(f"`point` must have shape (3,), got {point.shape}.")
        _, nearest = cKDTree(np.asarray(self.vertices, np.float64)).query(point)
        return int(self.region[int(nearest)])

    def children(self, index: int) -> tuple[int, ...]:
        """The indices of the limbs whose parent is limb `index` (−1: the body's limbs)."""
        index = self.index(index) if isinstance(index, str) else index
        if isinstance(index, bool | np.bool_) or not isinstance(index, int | np.integer):
            raise TypeError(f"`index` must be an integer limb index or -1, got {index!r}.")
        if not -1 <= index < len(self.limbs):
            raise ValueError(f"`index` must be in [-1, {len(self.limbs)}), got {index}.")
        return tuple(i for i, limb in enumerate(self.limbs) if limb.parent == index)

    def merge(self, index: int) -> Skeleton:
        """This skeleton with limb `index` merged into its parent (the body for a body's
        limb): its region and its children go to the parent, the later limbs are renumbered
        (a knee a user does not want: `skeleton.merge(knee)`)."""
        limbs, region = merge_limb(self.limbs, np.asarray(self.region), self._limb(index))
        return Skeleton(limbs, region, self.vertices)

    def _limb(self, index) -> int:
        """`index` as a limb index, else `ValueError`."""
        count = len(self.limbs)
        if (
            isinstance(index, bool | np.bool_)
            or not isinstance(index, int | np.integer)
            or not (0 <= index < count)
        ):
            raise ValueError(f"`index` must be a limb index in [0, {count}), got {index!r}.")
        return int(index)

    def split(self, index: int, point: ArrayLike | None = None, *,
              at: float | None = None) -> Skeleton:  # fmt: skip
        """This skeleton with limb `index` split in two at `point` or at the arc length `at`
        on its spine (a knee a user wants that the skeleton lacks): the part of its region
        past the split, the vertices whose nearest spine point lies beyond it, becomes a new
        limb `index + 1`, the child of limb `index` (the later limbs renumbered). The new
        limb bends on limb `index`'s rest spine from the split on (its `joint` there), as a
        chain's limbs do (each spine runs on to the chain's tip); limb `index` keeps its
        spine, and its region ends at the split. Each child limb of `index` goes to the piece
        holding its joint: the new limb when its joint's point lies beyond the split.

        **Arguments:** `index`: a limb index; `point`: (3,), a point on or near the limb's
        spine, inside the limb (the split is at the spine's point nearest to it); `at`: or
        the arc length of the split on the spine, instead of `point`.

        **Returns:** the new `Skeleton`; `skeleton.split(k, p).merge(k + 1)` is `skeleton`.

        **Raises:** `ValueError` naming the argument: a bad `index`, both or neither of
        `point` and `at`, a `point` outside the limb (farther from the spine than its surface
        there), or a split less than the limb's local thickness (the distance from its spine
        to its surface there) past its joint or before its spine's end.
        """
        from .regions import spine_samples

        index = self._limb(index)
        if (point is None) == (at is None):
            raise ValueError("Give the split's `point` or its arc length `at`, one of them.")
        limb = self.limbs[index]
        s, samples, _ = map(np.asarray, spine_samples(limb.spine))
        spine = cKDTree(samples)
        if point is not None:
            point = check_finite_points(point, "point")
            if point.shape != (3,):
                raise ValueError(f"`point` must have shape (3,), got {point.shape}.")
            gap, foot = spine.query(point)
            at = float(s[foot])
        else:
            at = check_number(at, "at", 0.0, float(s[-1]))
        region = np.asarray(self.region)
        ids = np.flatnonzero(region == index)
        distance, feet = spine.query(np.asarray(self.vertices, np.float64)[ids])
        along = s[feet]
        # The limb's local thickness: its farthest vertex from the spine among those whose
        # feet lie within its typical thickness of the split.
        window = float(np.median(distance)) if len(ids) else 0.0
        near = np.abs(along - at) <= window
        thickness = float(distance[near].max()) if near.any() else 0.0
        where = f"`point` {point.tolist()}" if point is not None else f"`at` = {at:.6g}"
        if point is not None and (not near.any() or gap > thickness):
            raise ValueError(
                f"{where} lies outside limb {index}: {gap:.4g} from its spine, where its "
                f"surface lies {thickness:.4g} from it."
            )
        joint = float(limb.joint)
        if not near.any() or at - joint < thickness or float(s[-1]) - at < thickness:
            raise ValueError(
                f"{where} is too near an end of limb {index}: the split (arc length {at:.4g}) "
                f"must lie at least its thickness there ({thickness:.4g}) past the limb's joint "
                f"({joint:.4g}) and before its spine's end ({float(s[-1]):.4g})."
            )
        beyond = np.zeros(len(region), bool)
        beyond[ids[along > at]] = True

        def parent(other: Limb) -> int:  # renumbered; a child of `index` to its piece
            if other.parent != index:
                return other.parent + (other.parent > index)
            base = np.asarray(other.spine(other.joint), np.float64)
            return index + (float(s[spine.query(base)[1]]) > at)

        limbs = [Limb(other.spine, other.joint, parent(other), other.name) for other in self.limbs]
        limbs.insert(index + 1, Limb(limb.spine, at, index, self._split_name(limb.name)))
        region = np.where(region > index, region + 1, region)
        return Skeleton(limbs, np.where(beyond, index + 1, region), self.vertices)

    def chain(self, index: int) -> tuple[int, ...]:
        """The limbs from the body down to limb `index` (a jointed chain: hip → knee → ankle),
        `index` last: the limbs whose poses move limb `index`'s region."""
        self.children(index)  # checks `index`
        chain = [int(index)] if index >= 0 else []
        while chain and self.limbs[chain[0]].parent >= 0:
            chain.insert(0, self.limbs[chain[0]].parent)
        return tuple(chain)

    def __repr__(self):
        parents = [limb.parent for limb in self.limbs]
        return f"Skeleton(limbs={len(self.limbs)}, parents={parents}, vertices={len(self.region)})"

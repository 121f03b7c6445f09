"""Fitting a skeleton's pose to where chosen vertices should go (`fit_skeleton_pose`).

Inverse kinematics on exact-volume posing: the `LimbPose` angles of some limbs that bring
chosen mesh vertices to target points, by nonlinear least squares (optimistix's
Levenberg–Marquardt, as `fit_spine`), differentiating through `pose_skeleton`.

- **Parameters.** Per fitted limb `(b₁, b₂, ψ)` in radians, `b = bend (cos direction,
  sin direction)`: the bend as a vector in the joint's normal plane. The bend turns the limb by
  `|b|` about `t × (b₁ I + b₂ J)`, smooth in `b` at the rest pose too, where `(bend, direction)`
  is singular: there a change of direction moves nothing, so a fit started at rest could only
  bend towards the first normal and would stop at a saddle for a target towards the second.
  Radians, because a radian moves a limb's tip by about its length: all three are on one scale.
- **Cost.** The solve poses only the chosen vertices (each limb's registration restricted to
  them), so that a step costs the same on a 100k-vertex mesh as on a small one; the reported
  rms and validity come from posing the whole mesh at the fitted angles.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float

from .._batching.buckets import bucket
from .._checks import check_vertex_ids
from .._exported import persistent
from .._fit.budget import limited
from .._fit.jacobian import compressed
from .._fit.problem import (
    AbstractFitOutcome,
    check_cloud,
    check_solve_options,
    default_solver,
    default_tolerance,
    stall_message,
    trust_radius,
)
from .._fit.stationarity import gauss_newton_step
from .._fleshing.methods import check_method
from .limb_pose import LimbPose
from .posing import (
    PER_POINT,
    PosedSkeleton,
    SkeletonRegistration,
    as_registration,
    carrying,
    check_limb_index,
    check_poses,
    pose_skeleton,
    posed,
)
from .skeleton import Skeleton, descendants

ADVICE = (
    "the loss is not smooth here (chosen vertices leaving their limb's valid space). Start "
    "closer (`init=`), fit fewer limbs (`limbs=`), or check that the targets are reachable."
)
# A fit stopped short of a minimum of its own loss (`_fit.stationarity`): the Gauss–Newton step
# at the fitted angles turns some limb by more than `SETTLED_STEP` degrees and predicts a
# decrease of more than `SETTLED_DECREASE` of the loss (a shape fit's: its last stage's).
SETTLED_STEP, SETTLED_DECREASE = 0.05, 1e-2
SETTLE_ADVICE = ("Give it more steps (`max_steps=`) or tighter tolerances (`rtol=`, `atol=`), "
                 "or fit again from the fitted pose (`init=fit.poses`).")


class SkeletonFit(AbstractFitOutcome):
    """The outcome of `fit_skeleton_pose`.

    **Fields:**

    - `poses`: dict limb index → `fj.LimbPose` (degrees; `bend ≥ 0`, `direction` in
      (−180, 180]): the fitted limbs' poses and the held ones of `init`, for `pose_skeleton`.
    - `rms`: root-mean-square distance between the chosen vertices posed by `poses` (the whole
      mesh posed, with the full validity check) and their targets.
    - `valid`: (k,) bool: which chosen vertices lie in their limb's valid space at `poses` (an
      invalid one is left where it was, and counts so in `rms`).
    - `posed`: the whole mesh posed by `poses` (`PosedSkeleton`: `vertices`, `valid`).
    - `result`: the `optimistix.RESULTS` of the solve; `num_steps`, `stats`: the solver's.
    - `loss`: the final objective, `rms²`.
    - `stalled`: "" or, for a solve that optimistix calls successful although its steps
      shrank to nothing without reducing the loss much, or although a Gauss–Newton step from
      its angles would still turn a limb by more than 0.05° and lower the loss by more than
      1 % (`stats["gauss_newton_step"]`, degrees by limb; `stats["predicted_decrease"]`: no
      minimum), what happened and what to try.

    `converged` is True only when the solver succeeded, did not stall and every chosen vertex
    is valid; `message` says otherwise why not.
    """

    poses: dict
    rms: Float[Array, ""]
    valid: Bool[Array, " k"]
    posed: PosedSkeleton
    result: optx.RESULTS
    num_steps: Array
    loss: Float[Array, ""]
    stats: dict
    stalled: str = eqx.field(static=True, default="")

    @property
    def num_invalid(self) -> int:
        """How many chosen vertices lie outside their limb's valid space at `poses`."""
        return int(jnp.sum(~self.valid))

    def _stall(self) -> str:
        if self.stalled:
            return self.stalled
        if self.num_invalid:
            return (
                f"{self.num_invalid} of the {self.valid.shape[0]} chosen vertices lie outside "
                "their limb's valid space at the fitted pose (left where they were): the "
                "targets ask for a bend the limbs cannot make. Check `posed.valid`."
            )
        return ""


def pose_of(y: Array) -> LimbPose:
    """The `LimbPose` (degrees) of one limb's parameters `y = (b₁, b₂, ψ)` (radians)."""
    b = y[:2]
    # At b = 0 exactly, the polar angle's derivative is 0/0; a bend of 1e-⁽²ᵉᵖˢ⁾ rad moves
    # nothing at round-off, and there the chain rule through |b| and atan2 gives the exact
    # derivative of the smooth map b ↦ pose (the direction's ∂/∂φ is ∝ |b| and is divided by it).
    tiny = jnp.finfo(b.dtype).eps ** 2
    b = b.at[0].add(jnp.where(jnp.all(b == 0), tiny, 0))
    bend = jnp.sqrt(jnp.sum(b**2))
    return LimbPose(jnp.rad2deg(bend), jnp.rad2deg(jnp.arctan2(b[1], b[0])), jnp.rad2deg(y[2]))


def parameters_of(pose: LimbPose, dtype) -> Array:
    """`(b₁, b₂, ψ)` (radians, (3,)) of a `LimbPose`: the inverse of `pose_of`."""
    bend, direction, twist = (np.deg2rad(float(v)) for v in (pose.bend, pose.direction,
                                                             pose.twist))
    return jnp.asarray([bend * np.cos(direction), bend * np.sin(direction), twist], dtype)


class PoseProblem(eqx.Module):
    """The residuals `y -> (k·3,)` of `fit_skeleton_pose`: `(x_i(y) − target_i) / √k`, whose
    sum of squares is the mean squared distance. `y` (L, 3): the fitted limbs' parameters."""

    registration: SkeletonRegistration  # restricted to the chosen vertices
    skeleton: Skeleton
    held: dict  # the poses of the limbs not fitted
    rows: Array  # (k,) each chosen vertex's row in the restricted registration
    targets: Array  # (k, 3)
    seeds: Array  # (c, L·3), moves (n, L·3): the parameters' dependence (`dependence`)
    moves: Array
    limbs: tuple[int, ...] = eqx.field(static=True)
    method: str = eqx.field(static=True)

    def poses(self, y: Array) -> dict:
        poses = dict(self.held)
        poses.update({k: pose_of(y[i]) for i, k in enumerate(self.limbs)})
        return poses

    def vertices(self, y: Array) -> Array:
        """The restricted registration's vertices (n, 3) posed at `y`."""
        # Without the global projection check (as `fit_spine`'s default): the local map is
        # smooth; the result's validity is checked on the whole mesh afterwards.
        return posed(self.registration, self.skeleton, self.poses(y), self.method, False,
                     stacked=True).vertices

    def residuals(self, vertices: Array) -> Array:
        """The residuals of the posed `vertices` (n, 3)."""
        diff = vertices[self.rows] - self.targets
        return diff.reshape(-1) / jnp.sqrt(jnp.asarray(self.rows.shape[0], diff.dtype))

    def __call__(self, y, args=None):
        return self.residuals(self.vertices(y))


def restricted(registration: SkeletonRegistration, ids: np.ndarray, bucketed: bool = True,
               bent: Sequence[int] = (), posed: Sequence[int] = ()):
    """`registration` reduced to the vertices `ids` (k,): `(registration, rows (k,), rigid)`,
    `rows` the vertices' positions in its `vertices`, `rigid` as `rigid_rows`' (with `bent`).

    Each limb keeps the rows of its region's chosen vertices (one row of its own if none,
    never used: only its end motion is), padded to one size for all: a bucket's (one
    compiled program for markers of nearby counts, `_batching.buckets`), or with `bucketed=False`
    the largest limb's own (a shape fit's whole regions: each posed limb is posed at that
    size, spot's head's 513 rows a bucket of 768). `bent`: the limbs posed by a `LimbPose`,
    whose rows before their joint or past their room's end are left out (`rigid_rows`), and
    whose largest sets the size (a larger limb keeps its own); `posed`: the other limbs the
    fit poses (which `WholeLimb`s its poses use)."""
    unique = np.unique(ids)
    # (Each limb's region, then each `WholeLimb`'s: the same rows chosen.)
    wholes = [w for w in registration.wholes if w is not None]
    regions = (*zip(registration.registrations, registration.indices),
               *((w.registration, w.indices) for w in wholes))
    picked = [np.flatnonzero(np.isin(np.asarray(i), unique)) for _, i in regions]
    # A bent limb's rows as its pose uses them: its `WholeLimb`'s where it has one and the fit
    # poses none of its descendants (`posing.carrying`), else its own.
    placed = carrying(registration, set(posed) | set(bent))[0]
    slot = {id(w): len(registration.indices) + i for i, w in enumerate(wholes)}
    rigid, sized = {}, []
    for k in bent:
        whole = registration.wholes[k]
        j = (slot[id(whole)] if whole is not None
             and placed.registrations[k] is whole.registration else k)
        bending, rigid[k] = _bending(placed, k, picked[j], unique)
        picked[j] = picked[j][bending]
        sized.append(j)
    # (With `bent`, at the largest of theirs: the other limbs are carried, unless a bent limb's
    # bend spills onto its child (`spill`), posed then beside it, not in its batch.)
    size = max(1, *(len(picked[j]) for j in (sized or range(len(picked)))))
    size = bucket(size) if bucketed else size
    parts = [_restricted_part(reg, limb_ids, rows, unique, size)
             for (reg, limb_ids), rows in zip(regions, picked)]
    registrations, indices = zip(*parts[: len(registration.indices)])
    restricted_wholes = iter(parts[len(registration.indices):])
    wholes = tuple(None if w is None else dataclasses.replace(
        w, **dict(zip(("registration", "indices"), next(restricted_wholes))))
        for w in registration.wholes)
    vertices = jax.device_put(np.asarray(registration.vertices)[unique])
    # No surface among chosen vertices: a pose past a range gives no volume back on them
    # (`restore`), which the whole mesh's pose does.
    # (A field replaced, not `eqx.tree_at`: no walk over the registration's leaves.)
    small = dataclasses.replace(
        registration, registrations=tuple(registrations), indices=tuple(indices), wholes=wholes,
        vertices=vertices, triangles=jnp.zeros((0, 3), jnp.int32),
        corners=jnp.zeros((len(unique), 0), jnp.int32))
    return small, jnp.asarray(np.searchsorted(unique, ids), jnp.int32), rigid


def _bending(registration: SkeletonRegistration, k: int, rows: np.ndarray,
             unique: np.ndarray) -> tuple[np.ndarray, tuple[Array, Array]]:
    """Of limb `k`'s registered `rows` (its region's chosen vertices), which its map may move
    otherwise than rigidly (bool, (len(rows),)), and the positions in `unique` of the others:
    `(past, before)`, validly registered rows past the limb's room to bend (`stops`: a
    `LimbPose`'s bend is complete there, and the map moves them with its end frame) and
    before its joint (where the bent spine is the rest spine: still)."""
    reg = registration.registrations[k]
    s = np.asarray(reg.arc_length)[rows]
    plain = (np.asarray(reg.valid)[rows] & ~np.asarray(reg.discontinuous)[rows]
             & np.isfinite(s))
    past = plain & (s > float(registration.stops[k]))
    before = plain & (s < float(registration.joints[k]))
    ids = np.asarray(registration.indices[k])[rows]
    return ~(past | before), tuple(jnp.asarray(np.searchsorted(unique, ids[m]), jnp.int32)
                                   for m in (past, before))


def rigid_rows(vertices: Array, rest: Array, carried: dict, rigid: dict,
               skeleton: Skeleton) -> Array:
    """`vertices` (n, 3) posed on a registration `restricted` with `bent` limbs, with each
    such limb's rows left out placed as its map places them (to round-off): those past its
    room to bend moved by its end motion, those before its joint by its parent's (or still).
    `rest` (n, 3): the registration's vertices; `carried`: `posed(..., motions=True)`'s;
    `rigid`: `restricted`'s. A shape fit's solve poses every vertex of its limbs, and the
    map's forward derivative at each point was most of a step (spot's head: 188 of its 513
    vertices bend, the rest move rigidly)."""
    for k, (past, before) in rigid.items():
        vertices = vertices.at[past].set(carried[k](rest[past]))
        outer = carried.get(skeleton.limbs[k].parent)
        if outer is not None:
            vertices = vertices.at[before].set(outer(rest[before]))
    return vertices


def _restricted_part(reg, limb_ids, rows: np.ndarray, unique: np.ndarray, size: int) -> tuple:
    """`(Registration, indices)` of a region's chosen `rows` (`restricted`), padded to `size`
    rows (one row of its own if none), the indices their positions in `unique`."""
    keep = rows if len(rows) else np.zeros(1, int)
    keep = np.pad(keep, (0, max(size, len(keep)) - len(keep)), mode="edge")  # (the last)
    fields = tuple(jax.device_put(np.asarray(getattr(reg, f))[keep]) for f in PER_POINT)
    reg = eqx.tree_at(lambda r: tuple(getattr(r, f) for f in PER_POINT), reg, fields)
    positions = np.searchsorted(unique, np.asarray(limb_ids)[rows])
    return reg, jnp.asarray(positions, jnp.int32)


def dependence(skeleton: Skeleton, limbs: tuple[int, ...], per_limb: int,
               ids: np.ndarray) -> tuple[Array, Array]:
    """Which fitted parameters move which vertices of `restricted(·, ids)`'s registration, for
    `_fit.jacobian.compressed`: `(seeds (c, L·per_limb), moves (n, L·per_limb))`. A limb's
    parameters move its region's vertices and its descendants' (children are carried), none
    other; limbs at one depth of the skeleton are never one another's ancestors, so they share
    their forward passes through the posing (spot's 9 limbs, 2 depths: 6 passes, were 27)."""
    parents = [limb.parent for limb in skeleton.limbs]

    def depth(k):
        return 0 if parents[k] < 0 else 1 + depth(parents[k])

    levels = sorted({depth(k) for k in limbs})
    region = np.asarray(skeleton.region)[np.unique(ids)]
    lineage = descendants(skeleton.limbs)
    seeds = np.zeros((len(levels) * per_limb, len(limbs) * per_limb), bool)
    moves = np.zeros((len(region), len(limbs) * per_limb), bool)
    for i, k in enumerate(limbs):
        columns = np.arange(i * per_limb, (i + 1) * per_limb)
        seeds[levels.index(depth(k)) * per_limb + np.arange(per_limb), columns] = True
        moves[np.ix_(np.isin(region, [k, *lineage[k]]), columns)] = True
    return jnp.asarray(seeds), jnp.asarray(moves)


# XLA's options for the solve: XLA CPU's older loop emitters, not its fusion emitters, which
# compile the solve's program (the posing's forward derivative in a loop: 46k equations for
# spot's three limbs) more slowly and make it run more slowly. Spot's shape fit, its first
# stage's solve compiled both ways in one process (load 3.6-5.6): compile 36-40 -> 26-31 s
# CPU, its 16 steps 633-804 -> 455-607 ms CPU. (JAX applies them to a top-level call: every
# fit calls the solve from the host.)
SOLVE_COMPILE = {"xla_cpu_use_fusion_emitters": False}


def _solving(problem: PoseProblem, solver, y0: Array, max_steps: int, throw: bool,
           linearised: bool = False, posed_end: bool = False):
    """`optimistix.least_squares` on `problem`: `(y, trust radius, result, stats, linear)`,
    and with `posed_end` `problem.vertices(y)` after them (a shape fit's surface where the
    solve ended: the candidates of its next solve's nearest vertices, `_fit.surface.pool`),
    for a solve of at least one step. For a least-squares solver of Gauss–Newton type they
    are the solver's auxiliary output at its last accepted point, read from the Jacobian's
    forward pass there (`compressed`'s `keep_inner`): no primal posing of their own in the
    program (spot's three-limb shape fit: 13k of its 44k operations, a third of its compile).
    The losses are read from eager poses outside, which share their programs with
    `pose_skeleton`. The residuals' Jacobian is materialised at each step for a least-squares
    solver (`_fit.jacobian`: the solve compiles in half the time). With `linearised`, `linear`
    is `(J (n, p), r (n,))` at `y`, read from the Gauss–Newton solver's last state (no second
    linearisation: `_fit.uncertainty` needs them), or None for another solver."""
    # The residuals traced once, to a jaxpr that every later use evaluates: the solver's
    # start and its step, and the Jacobian's forward passes (under `vmap`), each traced the
    # posing's Python again (two traces of a fit's three limbs: 2 × 4 s).
    traced = eqx.filter_closure_convert(problem.vertices, y0)
    if isinstance(solver, optx.AbstractLeastSquaresSolver):
        # (The Jacobian's forward passes shared by the limbs of one depth: `dependence`.)
        function = compressed(traced, problem.residuals, problem.seeds, problem.moves,
                              keep_inner=posed_end)
    else:
        def function(y, args=None):
            vertices = traced(y)
            residuals = problem.residuals(vertices)
            return (residuals, vertices) if posed_end else residuals

    solution = optx.least_squares(function, solver, y0, has_aux=posed_end, max_steps=max_steps,
                                  throw=throw)
    radius = trust_radius(solver, solution, y0.dtype)
    linear = _linear_state(solution.state) if linearised else None
    out = solution.value, radius, solution.result, solution.stats, linear
    if not posed_end:
        return out
    # (The state's, not the solution's `aux`: optimistix's Gauss–Newton step returns the
    # auxiliary output of the point accepted before, its state that of its own.)
    state = _inner_state(solution.state)
    if isinstance(getattr(state, "f_info", None), optx.FunctionInfo.ResidualJac):
        return (*out, state.aux)
    return (*out, traced(solution.value))


# With JAX's persistent cache on, the solve's traced program is kept too (`_exported`): a
# new process's first fit neither traces, lowers nor compiles it.
_solve = persistent(_solving, compiler_options=SOLVE_COMPILE)


def _inner_state(state):
    """A solver's state, under any `_fit.budget` wrapper's `(state, steps)`."""
    return state[0] if isinstance(state, tuple) else state


def _linear_state(state):
    """`(J, r)` of a Gauss–Newton-type solver's last accepted point (`state.f_info`, under any
    `_fit.budget` wrapper's `(state, steps)`), else None."""
    info = getattr(_inner_state(state), "f_info", None)
    if not isinstance(info, optx.FunctionInfo.ResidualJac):
        return None
    residual = jnp.concatenate([jnp.ravel(r) for r in jax.tree.leaves(info.residual)])
    return info.jac.as_matrix(), residual


def limb_steps(linear, limbs: tuple[int, ...], per_limb: int) -> tuple[dict, float]:
    """Each fitted limb's Gauss–Newton step at the fitted angles (degrees: the norm of its
    parameters' step, `_fit.stationarity`) from the solve's last `(J, r)` (`_solve`'s
    `linear`), and the decrease of the loss the step predicts (a fraction of it); NaN without
    them (a solver that is not of Gauss–Newton type)."""
    if linear is None:
        return {k: float("nan") for k in limbs}, float("nan")
    step, decrease = gauss_newton_step(*linear)
    turns = np.rad2deg(np.linalg.norm(step.reshape(len(limbs), per_limb), axis=1))
    return dict(zip(limbs, turns.tolist())), decrease


def unsettled(step: dict, decrease: float) -> str:
    """"" when the fit stopped at a stationary point of its loss (every limb's Gauss–Newton
    step `step` (limb → degrees) within `SETTLED_STEP`, or the decrease it predicts `decrease`
    (a fraction of the loss) within `SETTLED_DECREASE`), else which limbs would still move."""
    moving = {k: v for k, v in step.items() if v > SETTLED_STEP}
    if not moving or not decrease > SETTLED_DECREASE:
        return ""
    which = ", ".join(f"limb {k} by {v:.2g}°" for k, v in moving.items())
    return (
        f"the solve stopped short of a minimum: a Gauss–Newton step from the fitted pose would "
        f"still turn {which} (at most {SETTLED_STEP}° at a minimum) and lower the loss by "
        f"{100 * decrease:.2g} % (the fit explains its data, but a pose nearby explains them "
        f"better). {SETTLE_ADVICE}"
    )


def _default_limbs(skeleton: Skeleton, ids: np.ndarray) -> tuple[int, ...]:
    """The limbs whose regions hold vertices of `ids`, and their ancestors."""
    region = np.asarray(skeleton.region)
    limbs = set()
    for k in np.unique(region[ids]):
        while k >= 0 and k not in limbs:
            limbs.add(int(k))
            k = skeleton.limbs[k].parent
    return tuple(sorted(limbs))


def fit_skeleton_pose(
    mesh_or_registration,
    skeleton: Skeleton,
    vertex_ids: ArrayLike | None = None,
    targets: ArrayLike | None = None,
    *,
    target=None,
    limbs: Sequence[int] | None = None,
    init: dict | None = None,
    method: str = "radial",
    fit_twist: bool | None = None,
    solver: optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    max_steps: int = 64,
    throw: bool = False,
) -> SkeletonFit:
    """Finds the limbs' poses that bring the vertices `vertex_ids` to `targets` (markers),
    or the posed surface onto a `target` shape (no correspondences), or both.

    Nonlinear least squares over the bend, direction and twist of each limb of `limbs`,
    through `pose_skeleton` (each limb's region fleshed with `det J = 1`, children carried).
    Non-convergence is reported (`converged`, `message`), never raised (unless `throw`);
    a solve that stopped short of a minimum of its own loss (its steps too small or its
    tolerances too loose to go on, although a Gauss–Newton step from there would still move a
    limb) is not converged either.

    With `target=`, the objective is a robust (Cauchy) distance from each target point to the
    posed triangles, point to plane along the nearest triangle's normal (the posed-to-target
    direction is checked in the verdict, not solved: `_skeleton/fit_shape.py`), solved from
    `init` (the rest pose) at a decreasing robust scale (`_skeleton/fit_shape.py`): a partial
    scan (one side seen) and stray points are tolerated. `converged` is then also False when
    more than 2 % of the target lies farther from the posed surface than its own noise level
    allows (another shape, a wrong local minimum), when a fitted limb's part of it is not
    explained either way, or when a fitted limb's bend is determined by the target only to
    more than ±1° (its standard error, `stats["angle_spread"]`, degrees by limb: a short, thick
    limb barely moves its part of a sampled surface), with a message naming the limb.

    **Arguments:**

    - `mesh_or_registration`: the mesh `skeleton` was built on, or its `register_skeleton`
      (register once to fit many frames).
    - `skeleton`: an `fj.Skeleton`.
    - `vertex_ids`: (k,) int: the chosen vertices (indices into the mesh's vertices).
    - `targets`: (k, 3) finite: where each chosen vertex should go.
    - `target`: a shape the posed mesh should cover: (K, 3) finite points (a scan, another
      pose's vertices; more than 5,000 are sampled down) or a `trimesh.Trimesh` (its surface
      sampled, 5,000 points). The same units and placement as the mesh.
    - `limbs`: the limb indices whose poses are fitted; default: the limbs whose regions hold
      chosen vertices, and their ancestors (with `target=`: every limb).
    - `init`: dict limb index → `fj.LimbPose`: the starting poses of fitted limbs (default:
      the rest pose) and the poses (`LimbPose` or spine) of other limbs, held fixed.
    - `method`: the fleshing (`"radial"`, `"normal"`, `"binormal"`).
    - `fit_twist`: whether the twists are fitted (default: yes for markers; held at `init`'s
      for a `target`, where a round limb's turn about its own axis does not show).
    - `solver`: any optimistix least-squares solver or minimiser; default
      `LevenbergMarquardt(rtol, atol)` with tolerances from the dtype (1e-10 in float64,
      1e-5 in float32 and for a `target`, whose nearest neighbours change with the pose;
      for a `target` its damping starts at the loss's own curvature, not at 1).
    - `max_steps` (an integer in [1, 100000]), `throw`: passed to `optimistix.least_squares`;
      `rtol`, `atol`: in (0, 1].

    **Returns:** a `SkeletonFit` (its `poses` ready for `pose_skeleton`). Float32 works (the
    registration's dtype); its `rms` then stops near 1e-6 of the limbs' size. With `target=`,
    `rms` is `√(Chamfer / 2)` between the whole posed mesh's vertices and the target (plus
    the markers' mean squared distance), `valid` covers every vertex, and `num_steps` adds
    the stages' steps.

    **Raises:** `TypeError`/`ValueError` naming the argument: `vertex_ids` empty, not integer
    or out of range; `max_steps`, `rtol` or `atol` out of their bounds; `targets` not (k, 3)
    or not finite; `limbs` or `init` naming a limb the skeleton does not have; nothing to fit.
    """
    registration = as_registration(mesh_or_registration, skeleton)
    max_steps, rtol, atol = check_solve_options(max_steps, rtol, atol)
    if target is None and vertex_ids is None:
        raise ValueError("nothing to fit to: give `target=` (a shape), or `vertex_ids` and "
                         "`targets` (markers), or both.")
    if (vertex_ids is None) != (targets is None):
        raise ValueError("`vertex_ids` and `targets` go together: give both, or neither.")
    ids = None
    if vertex_ids is not None:
        ids = check_vertex_ids(vertex_ids, registration.vertices.shape[0])
        targets = check_cloud(targets, "targets")
        if targets.shape != (ids.shape[0], 3):
            raise ValueError(
                f"`targets` must have shape (k, 3) = ({ids.shape[0]}, 3), one point per vertex "
                f"of `vertex_ids`, got {targets.shape}."
            )
    method = check_method(method)
    init = check_poses({} if init is None else init, skeleton, "init")
    if limbs is None and target is not None:
        # A shape may move any limb: all are fitted.
        limbs = tuple(range(len(skeleton.limbs)))
    elif limbs is None:
        limbs = _default_limbs(skeleton, ids)
    else:
        limbs = tuple(sorted({check_limb_index(k, skeleton, "limbs") for k in limbs}))
    if not limbs:
        raise ValueError(
            "nothing to fit: `limbs` is empty, or every vertex of `vertex_ids` lies on the body "
            "(region −1), which no pose moves."
        )
    for k in limbs:
        if not isinstance(init.get(k, LimbPose()), LimbPose):
            raise TypeError(f"`init[{k}]` must be a LimbPose: limb {k} is fitted.")
    dtype = registration.vertices.dtype
    if solver is None:
        tol, damping = default_tolerance(dtype), None
        if target is not None:
            # Here to avoid an import cycle: the shape's fit builds on this module's pieces.
            from .fit_shape import SHAPE_DAMPING, SHAPE_TOLERANCE

            tol = max(SHAPE_TOLERANCE, tol)  # float32: its own
            damping = SHAPE_DAMPING
        # The tolerances as arrays, leaves of the solver: a fit with its own runs the default's
        # compiled solve.
        solver = default_solver(
            "least_squares", dtype,
            *(jnp.asarray(tol if t is None else t, dtype) for t in (rtol, atol)),
            damping=damping)
    if target is not None:
        from .fit_shape import fit_to_shape

        return fit_to_shape(registration, skeleton, target, ids=ids, targets=targets,
                            limbs=limbs, init=init, method=method,
                            fit_twist=bool(fit_twist), solver=solver, max_steps=max_steps,
                            throw=bool(throw))
    if fit_twist is False:
        raise ValueError("`fit_twist=False` is for a shape's fit (`target=`): markers show a "
                         "limb's twist.")
    targets = targets.astype(dtype)
    small, rows, _ = restricted(registration, ids)
    held = {k: v for k, v in init.items() if k not in limbs}
    problem = PoseProblem(small, skeleton, held, rows, targets,
                          *dependence(skeleton, limbs, 3, ids), limbs, method)
    y0 = jnp.stack([parameters_of(init.get(k, LimbPose()), dtype) for k in limbs])
    # (The steps a budget under one static limit: a fit cut short runs the default's program.)
    budget, limit = limited(solver, max_steps)
    y, radius, result, stats, linear = _solve(problem, budget, y0, limit, bool(throw), True)
    step, decrease = limb_steps(linear, limbs, 3)
    stats = {**stats, "gauss_newton_step": step, "predicted_decrease": decrease}

    def outcome(poses):
        whole = pose_skeleton(registration, skeleton, poses, method=method)
        distance = jnp.sum((whole.vertices[ids] - targets) ** 2, axis=-1)
        return whole, jnp.mean(distance)

    start = {**held, **{k: init.get(k, LimbPose()) for k in limbs}}
    poses = {**held, **{k: pose_of(y[i]) for i, k in enumerate(limbs)}}
    _, loss0 = outcome(start)
    whole, loss = outcome(poses)
    successful = bool(result == optx.RESULTS.successful)
    stalled = (stall_message((loss0, loss), radius, stats["num_steps"], ADVICE)
               or unsettled(step, decrease))
    return SkeletonFit(
        poses=dict(sorted(poses.items())),
        rms=jnp.sqrt(loss),
        valid=whole.valid[ids],
        posed=whole,
        result=result,
        num_steps=stats["num_steps"],
        loss=loss,
        stats=stats,
        stalled=stalled if successful else "",
    )


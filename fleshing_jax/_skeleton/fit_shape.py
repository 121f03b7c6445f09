"""Fitting a skeleton's pose to a target shape without correspondences (`fit_skeleton_pose`'s
`target=`).

The limbs' angles that bring the posed surface onto a target point cloud (a scan, another
pose's vertices, samples of a mesh), from the rest pose:

- **Objective.** A robust distance from each target point `yⱼ` (K) to the posed surface: to the
  closest point of the posed triangles around its nearest posed vertices (`_fit.surface`; to the
  vertices alone, a short leg's bend hid under the vertices' spacing), each difference `d` taken
  along that triangle's normal (point to plane: the surface sliding along itself moves no
  distance; the whole vector's derivative counted that sliding, spot's clean fit took 110 steps
  with other starts for its legs, now 32 without), weighted by the Cauchy loss `ρ(|d|²) = σ²
  log(1 + |d|²/σ²)`, as residuals `d √(ρ/|d|²)` over `σ √K` (their squares sum to the loss over
  σ², so Levenberg–Marquardt minimises exactly it). No posed-to-target term in the solve: each
  posed vertex to its nearest target point's plane (along the target's sampled normals) has a
  floor, their curvature between samples, that pulled spot's short legs 5–15° off; the result's
  check still reads that direction. The choices are made on stopped gradients: everything else
  is differentiated through the posing, end to end, but for the sections' blend past a joint's
  range (where another start bends a limb), valued exactly and differentiated as the map's own
  images (`posing._held_blend`): exact within the range, where a fit ends, and a solve's
  program 8 % smaller (spot's first fit 26–29 → 22–24.5 s of CPU).
  Cauchy's influence falls off as `1/|d|`: a stray scan point pulls ever less the farther it
  is; a partial scan simply has no points on its unseen side.
- **The solve's points.** At most `SOLVE_POINTS` of the target, shared out by the part of
  the posed surface each lies nearest to (a fitted limb with what it carries, or the body)
  before the last stage (`_shares`): a limb's bend depends on its own part only, and a short
  leg's part is small (spot's, 270 of 5,000 samples). A uniform sample kept a third of it:
  with 0.5 % noise the legs' bends were determined to ±4.9° and ±3.3° and fitted 6–8° off;
  with all of it, ±2.5° and 2°, which is the data's own bound (the Cramér–Rao bound of
  the legs' 5,000 samples at that noise, ±2.0–2.8°, `benchmarks/fit_pose.py`).
- **Continuation in σ.** From the rest pose a limb may lie a fifth of the diagonal from its
  target, where a small σ would see only outliers. The solve runs at σ = 10 %, 3 % and 1 % of
  the target's diagonal in turn, each stage from the last (one compiled program: σ and the
  step budget are leaves, `STAGES`).
- **Damping.** Each solve's Levenberg–Marquardt damping starts at `SHAPE_DAMPING` times
  the largest curvature of its loss (JᵀJ's largest diagonal entry), not at 1: in units of
  σ a leg's curvature is 1e-4 to 1e-3, and from λ = 1 its steps were that fraction of
  Gauss–Newton's until λ had come down to it (spot's clean fit 34 → 25 steps).
- **Other starts.** A short, thick limb's bend has minima of its own (spot's hind leg bent
  30° stopped at 15°, where its bending zone grows with the angle): a fitted limb whose part
  of the target stays unexplained (`_stuck`) is tried from half and all of `RESTART` more and
  less bent, the lowest loss kept (`_restarted`), until one leaves its part explained; before
  the last stage, which then runs once (run after it, the last stage's steps at the stuck pose,
  45 of spot's 230, went for nothing). After it, a limb whose part still lies off the posed
  surface while the body's lies on it (`_stuck` with the floor `SETTLED_FLOOR`: a clean
  target's parts at its minimum lie within 3e-7 σ² of it) is tried again from the same starts
  at the last stage's scale, and the last stage rerun from the best (`_resettled`): spot seen
  from one side (`benchmarks/fit_pose.py`, the rest spines read from their tables) stopped
  with leg 5 1.5° off at a minimum of its own, its part 3e-5 σ² off, and was converged.
- **Twist.** The surface of a round limb barely changes when it turns about its own axis: the
  twists are held at `init`'s unless `fit_twist=True`.
- **Honest convergence.** The fit explains the target when nearly every target point
  (`EXPLAINED`) lies within `3 σ̂ + h/4` of the posed triangles: `σ̂` the
  target's own noise (the rms distance of its points from the planes through their
  neighbours) and `h` the mesh's vertex spacing. Otherwise `converged` is False with a
  message. The same, per fitted limb,
  both ways: its part of the target (the points nearest its vertices), and its posed vertices
  (no farther from the target than the body's, which no pose moves). And every fitted limb's
  bend must be determined by the target to `ANGLE_SPREAD` (its standard error from the last
  stage's Jacobian, `_fit.uncertainty`; `stats["angle_spread"]`): a short, thick limb (spot's
  legs) fitted 15° off explains the target as well as at its true bend. And the solve must
  have stopped at a minimum of its own loss (`fit_pose.unsettled`, `_fit.stationarity`): not
  when the Gauss–Newton step at the fitted angles (from the last stage's `(J, r)`) turns a limb
  by more than `SETTLED_STEP` *and* predicts more than `SETTLED_DECREASE` of the loss
  (`stats["gauss_newton_step"]`, degrees by limb, `stats["predicted_decrease"]`): a leg 0.7°
  off explains a clean sample as well as the truth does, and a solve that stalled there
  (steps rejected on the piecewise-smooth loss until one tiny enough passed the solver's own
  test) would be reported successful.

Nearest vertices chosen inside the solve among a pool of each target point's nearest found by
a k-d tree on the host where the solve starts (`_solved`, `_fit.surface.pool`): while the
pool holds the moved surface's nearest, every Levenberg–Marquardt step sees its own
neighbours, as with the k-d tree called from inside the solve that it replaces (the true
gradient); where it no longer does when the solve stops, the solve goes on from there with
new pools. The solve's program then holds no host callback, and JAX's persistent cache
keeps it with its traced program (`_exported`): a new process's first fit neither traces
nor compiles it. scipy's `cKDTree` also serves the one-off checks outside the solve (the
noise level and the final distances).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import trimesh
from jaxtyping import Array
from scipy.spatial import cKDTree

from .._batching.quick import QUICK_COMPILE
from .._exported import persistent
from .._fit.budget import limited
from .._fit.problem import check_cloud
from .._fit.surface import NEAREST, POOL, covers, pool, rings, to_surface
from .._fit.uncertainty import block_spread, covariance
from .fit_pose import (
    SkeletonFit,
    _solve,
    dependence,
    limb_steps,
    parameters_of,
    pose_of,
    restricted,
    rigid_rows,
    unsettled,
)
from .limb_pose import LimbPose
from .posing import SkeletonRegistration, pose_skeleton, posed
from .skeleton import Skeleton, descendants

TARGET_POINTS = 5000  # a larger cloud (or a mesh's surface) is sampled down to this many
# Of the parts no pose moves (the body), the solve's surface keeps at most this many vertices
# (sampled past it, with every vertex of the triangles touching a moving limb). Every vertex of
# the moving limbs is posed: the target is measured to the posed triangles.
STILL_POINTS = 2048
# Of the target, in the solve (the check of the result reads them all), shared out among the
# fitted limbs' parts and the body's (`_shares`).
SOLVE_POINTS = 1500
# The continuation's stages: the Cauchy scale σ as a fraction of the target's diagonal.
STAGES = (0.1, 0.03, 0.01)
# The stages before the last only bring the pose near: at σ = 10 % of the diagonal their loss
# is flat near its minimum and the solve crept until its budget (16 steps, near the truth by
# the fourth), where the next stage's sharper loss converges in a few. Spot
# (`benchmarks/fit_pose.py`), steps at 16 / 4 (with `RESTART_STEPS` 16 / 8): clean 21 / 13,
# one side 41 / 21, 0.5 % noise 142 / 66, the ball 96 / 72; the tube's clean / one side /
# noisy fits (`tests/test_fit_pose.py`) 26 / 15, 24 / 14, 67 / 49; every verdict the same.
COARSE_STEPS = 4
# Each other start's budget (`_restarted`): a start kept is continued by the next solve, and
# those not kept went on for nothing (spot seen from one side: 29 steps with 16, 21 with 8).
RESTART_STEPS = 8
# The solver's default tolerances: the neighbours change with the pose, so the loss is only
# piecewise smooth and its last steps creep (spot's last stage: 64 steps to 1e-6, 46 to 1e-5,
# every angle within 0.01° of the truth either way).
SHAPE_TOLERANCE = 1e-5
# The default solver's damping at each solve's start, times the largest diagonal entry of
# `JᵀJ` there (`_fit.problem._ScaledTrustRegion`), not 1: in units of σ a leg's curvature is
# 1e-4 to 1e-3, the head's 0.3 to 35, and from λ = 1 a leg crept until a run of very good
# steps had brought λ down to it. Spot (`benchmarks/fit_pose.py`), steps at 1e-3 / 1e-4 /
# 1e-5 / 1e-6 against 1: clean 27 / 23 / 25 / 23 (34), one side 39 / 28 / 31 / 37 (48); the
# noisy and the sphere's rows not converged at each, for the same reasons.
SHAPE_DAMPING = 1e-5
RESTART = np.deg2rad(15.0)  # how much more and less bent each limb is tried from (`_starts`)
IMPROVED = 1e-9  # the relative decrease of the loss for which another start is kept
# A limb is tried from other starts when its part of the target's mean squared residual (in σ²)
# exceeds the body's this many times, plus the floor.
STUCK, STUCK_FLOOR = 4.0, 1e-4
# After the last stage the floor is this (σ²): a limb at a minimum of its own on a clean target
# (spot's leg 5 seen from one side, 1.5° off: 3e-5), against 2.6e-7 and below at the truth
# (spot's head: a few points of its snout off their candidate triangles, `_fit.surface`; the
# other parts 1e-10 and below). A noisy target's parts lie at its noise: `STUCK` times the
# body's.
SETTLED_FLOOR = 3e-6
# No limb is tried again when the body's part of the target lies farther from the posed
# surface than this (its mean squared residual, in σ², at the stage before the last: σ = 3 % of
# the diagonal, where 0.5 % noise is 0.03).
MISPLACED = 1.0
EXPLAINED = 0.98  # the fraction of the target that must lie near the fit
# How much more of a limb's posed vertices than of the body's may lie away from the target: a
# thin part leaves a few per cent at the true pose (spot's ear, 5.5 % against the body's 1.1 %
# from 5,000 clean samples: its two sides' samples lie closer than its vertices' spacing).
AWAY = 0.1
# The largest standard error (degrees) of a fitted limb's bend that `converged` accepts: a
# bend the target determines more loosely may be far off although the fit explains the target
# (`_fit.uncertainty`).
ANGLE_SPREAD = 1.0
NEIGHBOURS = 12  # for the target's noise level (local planes)
SHAPE_ADVICE = (
    "Check that the target is this character (same units and place: a scan may need its "
    "rigid alignment first), start closer (`init=`), or fit the limbs that moved (`limbs=`)."
)


def as_target(target, dtype) -> np.ndarray:
    """The target as (K, 3) points, at most `TARGET_POINTS` (a fixed-seed sample): a
    `trimesh.Trimesh`'s surface sampled by area, or a point array (checked as `target`)."""
    if isinstance(target, trimesh.Trimesh):
        if len(target.faces) == 0:
            raise ValueError("`target` is a mesh with no faces: pass its vertices as points.")
        points = np.asarray(trimesh.sample.sample_surface(target, TARGET_POINTS, seed=0)[0])
    else:
        points = np.asarray(check_cloud(target, "target"))
        if len(points) > TARGET_POINTS:
            keep = np.random.default_rng(0).choice(len(points), TARGET_POINTS, replace=False)
            points = points[np.sort(keep)]
    return points.astype(dtype)


def local_planes(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The planes through each point's `NEIGHBOURS` nearest of `points` (K, 3): their unit
    normals (K, 3) (sign arbitrary: they enter squared), and the median rms distance of the
    neighbours from them, the target's own noise (plus its curvature, small)."""
    k = min(NEIGHBOURS, len(points))
    if k < 4:
        raise ValueError(f"`target` must hold at least 4 points, got {len(points)}.")
    _, near = cKDTree(points).query(points, k)
    local = points[near] - points[near].mean(axis=1, keepdims=True)
    values, vectors = np.linalg.eigh(np.einsum("kni,knj->kij", local, local) / k)
    return vectors[:, :, 0], float(np.median(np.sqrt(np.maximum(values[:, 0], 0))))


def _sample(ids: np.ndarray, count: int, rng) -> np.ndarray:
    return ids if len(ids) <= count else np.sort(rng.choice(ids, count, replace=False))


def _shares(owner: np.ndarray, count: int, rng) -> np.ndarray:
    """Which of the target's points (indices, sorted) the solve reads, at most `count`: each
    part of the target (`owner` (K,): the fitted limb its point lies nearest to, -1 the body)
    gets an equal share, a part smaller than its share all of its points and what it leaves
    to the others. Only a limb's own points depend on its angles: a uniform sample of 1,500 of
    spot's 5,000 left 270 of its legs' 820, their bends' standard errors ±4.9° and ±3.3°
    with 0.5 % noise (over the legs' every point, the data's bound is ±2.0–2.8°)."""
    parts = sorted((np.flatnonzero(owner == k) for k in np.unique(owner)), key=len)
    kept, left = [], count
    for i, ids in enumerate(parts):
        kept.append(_sample(ids, left // (len(parts) - i), rng))
        left -= len(kept[-1])
    return np.sort(np.concatenate(kept))


def _owners(skeleton: Skeleton, limbs: tuple[int, ...]) -> np.ndarray:
    """For each limb of `skeleton`, the fitted limb (of `limbs`) it belongs to: itself or its
    nearest fitted ancestor, else -1 (the body, or a limb no fitted one carries). (L + 1,):
    the last entry is the body's (region -1)."""
    lineage = descendants(skeleton.limbs)
    out = np.full(len(skeleton.limbs) + 1, -1)
    # Ancestors first (more descendants), so that a fitted descendant keeps its own part.
    for k in sorted(limbs, key=lambda k: -len(lineage[k])):
        out[[k, *lineage[k]]] = k
    return out


def _padded(cloud: np.ndarray) -> tuple[Array, Array]:
    """`cloud` (K, 3) padded to `SOLVE_POINTS` rows with copies of its first point, and the
    rows' weights (1 for its points, 0 for the copies): every target, whatever its size (a
    partial scan, a sampled mesh), is solved by one compiled program."""
    pad = max(SOLVE_POINTS - len(cloud), 0)
    weights = np.concatenate([np.ones(len(cloud)), np.zeros(pad)]).astype(cloud.dtype)
    return (jnp.asarray(np.concatenate([cloud, np.repeat(cloud[:1], pad, axis=0)])),
            jnp.asarray(weights))


def _cauchy(d: Array, sigma: Array) -> Array:
    """Difference vectors `d` (…, 3) scaled to `d √(ρ(|d|²)/|d|²)`, `ρ` the Cauchy loss of
    scale `sigma`: their squares sum to `Σ ρ`. `ρ(s)/s = log1p(u)/u` (u = s/σ²) is smooth
    with value 1 at 0, taken from its series below 1e-4 (double `where`: finite gradients)."""
    u = jnp.sum(d**2, axis=-1) / sigma**2
    small = u < 1e-4
    safe = jnp.where(small, 1.0, u)
    ratio = jnp.where(small, 1 - u / 2 + u**2 / 3, jnp.log1p(safe) / safe)
    return d * jnp.sqrt(ratio)[..., None]


class ShapeProblem(eqx.Module):
    """The residuals `y -> (…)` of a shape fit (the module's docstring): `y` (L, p), `p = 3`
    (bend vector, twist) with `fit_twist`, else 2 and the twists held at `twists` (L,)."""

    registration: SkeletonRegistration  # restricted to the moving sample and the markers
    skeleton: Skeleton
    held: dict  # the poses of the limbs not fitted
    twists: Array  # (L,) radians: the fitted limbs' twists when they are held
    moving: Array  # (m,) rows of the moving sample in the restricted registration
    still: Array  # (s, 3) vertices no pose moves
    faces: Array  # (F, 3) the surface's triangles: rows of `moving` then of `still`
    rings: Array  # (m + s, R) each surface vertex's faces (`_fit.surface.rings`)
    cloud: Array  # (K, 3): the target's sample, padded to `SOLVE_POINTS` rows (`_padded`)
    weights: Array  # (K,): 1 for the target's points, 0 for the padding
    pool: Array  # (K, M): each point's candidate nearest surface vertices (`_solved`)
    sigma: Array  # (): the Cauchy scale of the stage (`STAGES`)
    markers: Array  # (k,) rows of the marker vertices (k = 0: none)
    marker_targets: Array  # (k, 3)
    seeds: Array  # (c, L·p), moves (n, L·p): the parameters' dependence (`fit_pose.dependence`)
    moves: Array
    rigid: dict  # the rows of the posed limbs that move rigidly (`fit_pose.restricted`)
    limbs: tuple[int, ...] = eqx.field(static=True)
    method: str = eqx.field(static=True)

    def parameters(self, y: Array) -> Array:
        """(L, 3): `y` with the held twists."""
        if y.shape[-1] == 3:
            return y
        return jnp.concatenate([y, self.twists[:, None]], axis=-1)

    def poses(self, y: Array) -> dict:
        full = self.parameters(y)
        return {**self.held, **{k: pose_of(full[i]) for i, k in enumerate(self.limbs)}}

    def vertices(self, y: Array) -> Array:
        """The restricted registration's vertices (n, 3) posed at `y`."""
        # Without the global projection check (as the markers' fit): the result's validity is
        # checked on the whole mesh afterwards.
        # The sections' blend past a joint's range (where another start bends a limb) is
        # valued exactly, differentiated as the map's images (`posing._held_blend`): exact
        # within the range, where a fit ends; its first call compiled in less time.
        # Only the rows the map may move otherwise than rigidly are fleshed; the others are
        # moved by their limb's end motion, or still (`fit_pose.rigid_rows`).
        out, carried = posed(self.registration, self.skeleton, self.poses(y), self.method,
                             False, stacked=True, blend_tangent=False, motions=True)
        return rigid_rows(out.vertices, self.registration.vertices, carried, self.rigid,
                          self.skeleton)

    def surface(self, vertices: Array) -> Array:
        """The solve's surface's vertices (m + s, 3) (the moving sample's, then the still
        ones) of the restricted registration's posed `vertices` (n, 3)."""
        return jnp.concatenate([vertices[self.moving], self.still])

    def residuals(self, vertices: Array) -> tuple:
        """The residuals of the posed `vertices` (n, 3): the target's, then the markers'."""
        # The target to the posed surface itself (its triangles), not to its vertices: zero at
        # the true pose, however far apart the vertices (`_fit.surface`).
        backward = _cauchy(to_surface(self.cloud, self.surface(vertices), self.faces,
                                      self.rings, self.pool, True),
                           self.sigma) * self.weights[:, None]
        # In units of σ: the loss is then on one scale whatever the mesh's size, and so are
        # the solver's tolerances on its decrease (in the mesh's units, a mean squared
        # distance of 1e-7 met any absolute tolerance: the solve stopped on a slope).
        out = (backward.reshape(-1) / (jnp.sqrt(jnp.sum(self.weights)) * self.sigma),)
        if self.markers.shape[0]:
            diff = vertices[self.markers] - self.marker_targets
            out = (*out, diff.reshape(-1) / (np.sqrt(self.markers.shape[0]) * self.sigma))
        return out

    def __call__(self, y, args=None):
        return self.residuals(self.vertices(y))


def _still(triangles: np.ndarray, region: np.ndarray, moving_limbs: list[int], rng):
    """The vertices of the surface that no fitted pose moves, in the solve: all of them up to
    `STILL_POINTS`; past it those of the triangles that touch a moving limb (where a target
    point may lie between the body and a limb) and a sample of the others."""
    still = np.flatnonzero(~np.isin(region, moving_limbs))
    if len(still) <= STILL_POINTS:
        return still
    touching = np.isin(region[triangles], moving_limbs).any(axis=1)
    band = np.intersect1d(np.unique(triangles[touching]), still)
    rest = np.setdiff1d(still, band)
    return np.union1d(band, _sample(rest, max(STILL_POINTS - len(band), 0), rng))


def surface_of(triangles: np.ndarray, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The surface of the vertices `kept` (m,) (indices into the mesh): the triangles of
    `triangles` (T, 3) with every corner kept, as rows of `kept` (T', 3), and each row's faces
    (m, R) (`_fit.surface.rings`). A kept vertex on no such triangle (a sampled one) is a
    triangle of its own, collapsed to that point."""
    position = np.full(int(max(triangles.max(initial=-1), kept.max(initial=-1))) + 1, -1)
    position[kept] = np.arange(len(kept))
    mapped = position[triangles]
    faces = mapped[(mapped >= 0).all(axis=1)]
    alone = np.setdiff1d(np.arange(len(kept)), faces)
    faces = np.concatenate([faces, np.repeat(alone[:, None], 3, axis=1)])
    return faces, rings(faces, len(kept))


def _on_tables(registration: SkeletonRegistration) -> SkeletonRegistration:
    """`registration` with each limb's rest spine read from its table where it has one (in
    double precision, `checks`: the table its projection check reads; in single precision the
    rest spines are those tables already). The solve's posing then looks the rest spine's
    frames up rather than inverting its arc length by Newton's method at every point and
    quadrature node: spot's three-limb solve (float64) 65.6k -> 38.3k operations, its XLA
    compile 28 -> 19 s of CPU. The tables' error (1e-9 relative, `_spines.table`) moves the
    solve's minimum by far less than any target's sampling does (spot's clean fit, `fit_pose.py`:
    the angles within 1e-7° of the exact solve's); the result is posed exactly."""
    rests = tuple(rest if table is None else table
                  for rest, table in zip(registration.rests, registration.checks))
    return dataclasses.replace(registration, rests=rests)


def _moving_limbs(skeleton: Skeleton, posed_limbs) -> list[int]:
    lineage = descendants(skeleton.limbs)
    return sorted({j for k in posed_limbs for j in (k, *lineage[k])})


def fit_to_shape(registration: SkeletonRegistration, skeleton: Skeleton, target, *,
                 ids: np.ndarray | None, targets: Array | None, limbs: tuple[int, ...],
                 init: dict, method: str, fit_twist: bool, solver, max_steps: int,
                 throw: bool) -> SkeletonFit:
    """`fit_skeleton_pose` with `target=` (its arguments checked there; `ids`/`targets`: the
    markers, or None)."""
    dtype = registration.vertices.dtype
    cloud = as_target(target, dtype)
    rest = np.asarray(registration.vertices)
    region = np.asarray(skeleton.region)
    rng = np.random.default_rng(0)
    held = {k: v for k, v in init.items() if k not in limbs}
    moving_limbs = _moving_limbs(skeleton, [*limbs, *held])
    triangles = np.asarray(registration.triangles)
    moving = np.flatnonzero(np.isin(region, moving_limbs))
    still = _still(triangles, region, moving_limbs, rng)
    faces, ring = surface_of(triangles, np.concatenate([moving, still]))
    markers = np.zeros(0, np.int64) if ids is None else ids
    # (Each posed limb at the largest limb's own size, not a bucket's: the solve poses whole
    # regions, and every padded row costs its forward derivative.)
    bent = [k for k in moving_limbs if isinstance(init.get(k, LimbPose()), LimbPose)
            and (k in limbs or k in held)]
    small, rows, rigid = restricted(registration, np.concatenate([moving, markers]),
                                    bucketed=False, bent=bent, posed=[*limbs, *held])
    small = _on_tables(small)
    marker_targets = (jnp.zeros((0, 3), dtype) if targets is None
                      else jnp.asarray(targets, dtype))
    diagonal = float(np.linalg.norm(np.ptp(cloud, axis=0)))
    normals, noise = local_planes(cloud)
    solved = _sample(np.arange(len(cloud)), SOLVE_POINTS, rng)
    starts = jnp.stack([parameters_of(init.get(k, LimbPose()), dtype) for k in limbs])
    problem = ShapeProblem(
        small, skeleton, held, starts[:, 2], rows[: len(moving)], jnp.asarray(rest[still]),
        jnp.asarray(faces), jnp.asarray(ring), *_padded(cloud[solved]),
        jnp.zeros((SOLVE_POINTS, POOL), jnp.int32), jnp.zeros((), dtype), rows[len(moving):],
        marker_targets,
        *dependence(skeleton, limbs, 3 if fit_twist else 2, np.concatenate([moving, markers])),
        rigid, limbs, method)
    y = starts if fit_twist else starts[:, :2]
    steps = 0
    kept = np.concatenate([moving, still])
    owners = _owners(skeleton, limbs)
    # The solve's surface where each solve starts (`_solved`'s pools): at rest, the rest's.
    surface = rest[kept] if not held and not np.any(np.asarray(starts)) else None
    for i, sigma in enumerate(STAGES):
        problem = dataclasses.replace(problem, sigma=jnp.asarray(sigma * diagonal, dtype))
        last = i == len(STAGES) - 1
        # Each stage's step budget is a value (`_fit.budget`): the stages share one compiled
        # solve (two, with `throw`: the last stage's own).
        problem, y, result, stats, linear, surface = _solved(
            problem, solver, y, max_steps if last else min(max_steps, COARSE_STEPS), max_steps,
            throw and last, surface)
        steps += int(stats["num_steps"])
        if i == len(STAGES) - 2:
            parts = region[kept]
            # Neither when the body's part of the target is itself unexplained (`MISPLACED`):
            # another shape, or a scan not aligned, which no limb's start explains (a ball's
            # fit tried 8 starts for nothing) and whose parts are no limb's.
            if _body_level(*_parts(problem, linear, surface, parts)) <= MISPLACED:
                y, tried, posed_y = _restarted(problem, solver, y, linear, max_steps, surface,
                                               parts)
                steps += tried
                # The last stage's points shared out by the parts they lie nearest to here.
                # (The stages before keep the uniform sample: from the rest pose a limb far
                # from its part owns others, and re-chosen before the middle stage, spot's
                # clean fit took 45 steps, not 36.) The whole mesh's vertices: the solve's
                # surface holds every moving one.
                whole = rest.copy()
                whole[moving] = surface[: len(moving)]
                owner = owners[region[cKDTree(whole).query(cloud)[1]]]
                shared, weights = _padded(cloud[_shares(owner, SOLVE_POINTS, rng)])
                problem = dataclasses.replace(problem, cloud=shared, weights=weights)
                surface = posed_y  # (at y: where another start was kept, its solve's)
    again, tried = _resettled(problem, solver, y, linear, max_steps, surface, region[kept],
                              throw)
    steps += tried
    if again is not None:
        problem, y, result, stats, linear, surface = again
    y, wound = _within_half_a_turn(y)
    poses = dict(sorted(problem.poses(y).items()))
    # The result posed exactly (the solve's posing reads the rest spines' tables).
    whole = pose_skeleton(registration, skeleton, poses, method=method)
    vertices = np.asarray(whole.vertices)
    backward, nearest = cKDTree(vertices).query(cloud)
    forward, nearest_to = cKDTree(cloud).query(vertices)
    # To the posed triangles: a target point between vertices is not unexplained (along the
    # target's normals to the nearest vertex, a thin ear's sides seen from one side were).
    off = np.linalg.norm(np.asarray(_distances(
        jnp.asarray(cloud), whole.vertices, registration.triangles,
        jnp.asarray(rings(triangles, len(vertices))), jnp.asarray(pool(cloud, vertices, NEAREST)))),
        axis=-1)
    loss = (np.mean(forward**2) + np.mean(backward**2)) / 2
    if ids is not None:
        loss = loss + np.mean(np.sum((vertices[ids] - np.asarray(targets)) ** 2, axis=-1))
    successful = bool(result == optx.RESULTS.successful)
    # No trust-region stall test (`fit_pose`'s): a solve that stopped short of a minimum is
    # told by its Gauss–Newton step (`unsettled`), tested on every successful solve.
    owner = region[nearest]  # the limb (or body, -1) of each target point's nearest vertex
    # (A vertex whose nearest target point lies on its own limb's posed surface: `_ahead`.)
    own = (owner[nearest_to] == region) & (off[nearest_to] <= _reach(noise, rest)[0])
    ahead = _ahead(vertices, triangles, cloud, nearest_to, normals, own)
    spread = _spreads(linear, limbs, y.shape[-1])
    step, decrease = limb_steps(linear, limbs, y.shape[-1])
    stats = {**stats, "angle_spread": spread, "gauss_newton_step": step,
             "predicted_decrease": decrease}
    # A target the fit does not explain is said so even when the solve stopped short (a ball
    # fitted with spot: its limbs tried far from rest, out of steps).
    message = _unexplained(off, noise, rest, owner, moving_limbs, ahead, region, limbs)
    if not message:
        message = _unseen(owner, limbs)
    if successful and not message:
        message = unsettled(step, decrease) or _undetermined(spread)
    if wound:
        message = " ".join([f"limb {limbs[i]}'s fitted bend or twist ran to {a:.0f} degrees "
                            "(held at half a turn):" for i, a in wound]
                           + [message or "the target is not this character posed, or far "
                              "from where the fit started (try `init=`)."])
    return SkeletonFit(
        poses=poses,
        rms=jnp.sqrt(jnp.asarray(loss, dtype)),
        valid=whole.valid,
        posed=whole,
        result=result,
        num_steps=jnp.asarray(steps),
        loss=jnp.asarray(loss, dtype),
        stats=stats,
        stalled=message,
    )


_distances = eqx.filter_jit(to_surface)


def _posed_surface(problem: ShapeProblem, y: Array) -> Array:
    """The solve's surface (m + s, 3) posed at `y` as the solve poses it (`ShapeProblem`):
    where a solve starts away from the last one's end (another start, `init`), for its pools.
    (The solve's program holds no posing of its own beside its Jacobian's: `fit_pose._solve`.)"""
    return problem.surface(problem.vertices(y))


# Run once per start, on a few thousand points: compiled quickly (a third of the solve's
# operations, no derivatives).
_surface_at = persistent(_posed_surface, compiler_options=QUICK_COMPILE)


def _solved(problem: ShapeProblem, solver, y: Array, steps: int, max_steps: int, throw: bool,
            surface: np.ndarray | None = None):
    """`problem` solved from `y` for at most `steps` steps (`fit_pose._solve`, under the
    static limit of `_fit.budget.limited(·, max_steps)`), each target point's nearest surface
    vertices chosen among its `_fit.surface.POOL` nearest where the solve starts (found on the
    host, `_fit.surface.pool`: no host callback in the program), and solved again from where
    it stopped, with pools found there, while they do not hold that surface's nearest
    (`covers`: the solve's own choice is then the k-d tree's) and steps are left. `surface`
    (m + s, 3): the solve's surface posed at `y` (`ShapeProblem.surface`), else posed here
    (`_surface_at`).
    `(problem with its last pools, y, result, stats (num_steps: every round's), linear,
    the surface at y)`, `y`, `result`, `linear` as `_solve`'s."""
    cloud = np.asarray(problem.cloud)

    def solve(problem, y, budget, throw=throw):
        bounded, limit = limited(solver, max_steps, budget)
        y, _, result, stats, linear, vertices = _solve(problem, bounded, y, limit, throw, True,
                                                       True)
        return y, result, stats, linear, np.asarray(problem.surface(vertices))

    if surface is None:
        surface = np.asarray(_surface_at(problem, y))
    taken, candidates = 0, pool(cloud, surface)
    while True:
        problem = dataclasses.replace(problem, pool=jnp.asarray(candidates))
        y, result, stats, linear, surface = solve(problem, y, steps - taken)
        taken += int(stats["num_steps"])
        if taken < steps and result == optx.RESULTS.successful:
            # (One k-d tree on the moved surface: its pools, whose first columns are its
            # nearest, tell whether the old ones held them.)
            moved = pool(cloud, surface)
            if not covers(candidates, moved):
                candidates = moved
                continue
        return problem, y, result, {**stats, "num_steps": taken}, linear, surface


def _within_half_a_turn(y: Array) -> tuple[Array, list]:
    """`y` (L, 2 or 3: bend vector, twist; radians) with each limb's bend and twist held at
    half a turn, and `(limb row, degrees)` of those that ran past a full turn. The solve has
    no bound: a target that is not the character (a ball) can send a limb round and round,
    and a pose past a full turn is refused (`LimbPose`); the fit is then not converged."""
    values = np.array(y, dtype=float)
    bend = np.linalg.norm(values[:, :2], axis=1)
    twist = np.abs(values[:, 2]) if values.shape[1] == 3 else np.zeros(len(values))
    wound = [(i, float(np.degrees(max(bend[i], twist[i])))) for i in range(len(values))
             if max(bend[i], twist[i]) > 2 * np.pi]
    if not wound:
        return y, []
    rows = np.array([i for i, _ in wound])
    scale = np.minimum(1.0, np.pi / np.maximum(bend[rows], 1e-300))
    values[rows, :2] *= scale[:, None]
    if values.shape[1] == 3:
        values[rows, 2] = np.clip(values[rows, 2], -np.pi, np.pi)
    return jnp.asarray(values, y.dtype), wound


def _loss(linear) -> float:
    return float(jnp.sum(linear[1] ** 2))


def _starts(b: np.ndarray) -> list[np.ndarray]:
    """Other starts for one limb's bend vector `b` (2,) (radians): half and all of `RESTART`
    more and less bent in its direction, or, for a limb barely bent, bent by `RESTART` in four
    directions."""
    size = float(np.hypot(*b))
    if size < RESTART / 3:
        return [RESTART * np.array([np.cos(a), np.sin(a)]) for a in np.arange(4) * np.pi / 2]
    return [b * (size + d) / size for d in RESTART * np.array([0.5, 1, -0.5, -1])
            if size + d > 0]


def _restarted(problem: ShapeProblem, solver, y: Array, linear, max_steps: int,
               surface: np.ndarray, region: np.ndarray, floor: float | None = None):
    """`y` improved limb by limb from other starts (`_starts`, the other limbs held where they
    are, each tried for `RESTART_STEPS` steps at `problem`'s scale): a short, thick limb's bend
    has local minima where its bending zone grows with the angle (spot's hind leg bent 30°
    stopped at 15° from the rest pose, where the target's distance to the posed surface has a
    minimum of its own). Only the limbs whose part of the target stays unexplained
    (`_stuck`), each until a start leaves its part explained (the other starts of spot's legs
    cost 8 steps each), and those whose bend the target determines loosely (their spread
    over `ANGLE_SPREAD`), each until a start lowers the loss: with noise every part of the
    target lies at its noise level and none is stuck (spot's legs with 0.5 % noise stopped
    5° and 13° short of their bends from rest, the loss at the truth lower). `(y, steps
    taken, the solve's surface posed at y)` (`surface` itself if no start was kept: the
    next solve starts from it without posing it again); the best start's solve is to be
    continued. With `floor`: only the limbs `_stuck` at that floor (`_resettled`)."""
    best, taken, kept = _loss(linear), 0, surface
    if floor is None:
        spread = _spreads(linear, problem.limbs, y.shape[-1])
        tried = {i for i, k in enumerate(problem.limbs) if spread[k] > ANGLE_SPREAD}
        tried.update(_stuck(problem, linear, surface, region))
        floor = STUCK_FLOOR
    else:
        tried = set(_stuck(problem, linear, surface, region, floor))
    for i in sorted(tried):
        for start in _starts(np.asarray(y[i, :2])):
            _, trial, _, stats, out, ended = _solved(
                problem, solver, y.at[i, :2].set(start), min(max_steps, RESTART_STEPS),
                max_steps, False)
            taken += int(stats["num_steps"])
            if _loss(out) < best * (1 - IMPROVED):
                y, best, kept = trial, _loss(out), ended
                # (Its part read as before: the target points nearest its vertices posed stuck.)
                if i not in _stuck(problem, out, surface, region, floor):
                    break
    return y, taken, kept


def _parts(problem: ShapeProblem, linear, surface: np.ndarray, region: np.ndarray):
    """The limb (or body, -1) of each point of the solve's target (its nearest of the posed
    `surface` (m + s, 3), whose limbs are `region` (m + s,)), and its squared residual (σ²)."""
    cloud = np.asarray(problem.cloud)[np.asarray(problem.weights) > 0]  # (padded at the end)
    owner = region[cKDTree(surface).query(cloud)[1]]
    backward = np.asarray(linear[1])[: 3 * len(cloud)].reshape(-1, 3)
    return owner, len(cloud) * np.sum(backward**2, axis=1)  # (the residuals are over √K)


def _body_level(owner: np.ndarray, squared: np.ndarray) -> float:
    return float(np.mean(squared[owner < 0])) if (owner < 0).any() else 0.0


def _resettled(problem: ShapeProblem, solver, y: Array, linear, max_steps: int,
               surface: np.ndarray, region: np.ndarray, throw: bool):
    """After the last stage (`problem` at its scale, `(y, linear)` its solve's end, `surface`
    and `region` as `_stuck`'s): the limbs still `_stuck` at `SETTLED_FLOOR` tried from other
    starts (`_restarted`) and the last stage run again from the best, `(that solve's outputs
    as `_solve`'s, steps taken)` where it lowers the loss, else `(None, steps taken)`. None
    tried when the body's part is itself unexplained (`MISPLACED`)."""
    if _body_level(*_parts(problem, linear, surface, region)) > MISPLACED:
        return None, 0
    start, taken, posed_start = _restarted(problem, solver, y, linear, max_steps, surface,
                                           region, SETTLED_FLOOR)
    if start is y:  # (no start lowered the loss)
        return None, taken
    again = _solved(problem, solver, start, max_steps, max_steps, throw, posed_start)
    taken += int(again[3]["num_steps"])
    return (again if _loss(again[4]) < _loss(linear) * (1 - IMPROVED) else None), taken


def _stuck(problem: ShapeProblem, linear, surface: np.ndarray, region: np.ndarray,
           floor: float = STUCK_FLOOR) -> list[int]:
    """The positions in `problem.limbs` of the fitted limbs whose part of the solve's target
    (its points nearest to their posed vertices) lies farther from the posed surface than the
    body's part does (`STUCK` times its mean squared residual, plus `floor` σ²): a limb
    at a minimum of its own. A noisy target's parts are all at its noise: none. `surface`
    (m + s, 3): the solve's surface vertices posed; `region` (m + s,): their limbs."""
    owner, squared = _parts(problem, linear, surface, region)
    body = _body_level(owner, squared)
    return [i for i, k in enumerate(problem.limbs) if (owner == k).any()
            and float(np.mean(squared[owner == k])) > STUCK * body + floor]


def _unexplained(distances: np.ndarray, noise: float, rest: np.ndarray, owner: np.ndarray,
                 limbs: list[int], ahead: np.ndarray | None = None,
                 region: np.ndarray | None = None, fitted=None) -> str:
    """"" when the posed surface explains the target both ways, else what is left unexplained
    and what to try.

    Target to posed: at least `EXPLAINED` of the target lies within `3 σ̂ + h/4` of the posed
    vertices' planes, over the whole target and over the target points nearest to each moving
    limb (`limbs`; `owner` (K,): the limb of each point's nearest vertex, -1 the body).
    `distances` (K,): from each target point along its normal to its nearest vertex; `noise`
    σ̂, `h` the vertices' spacing (a quarter of it for the surface's curvature between
    vertices). Per limb, because a small limb fitted wrongly (a stubby leg, under 2 % of the
    surface) leaves the whole target explained.

    Posed to target (`ahead` (V,): each posed vertex's distance along its nearest target
    point's normal where that point lies outside the posed surface, `_ahead`; `region` (V,):
    the vertices' limbs): each moving limb's vertices beyond the same reach make at most
    `AWAY` more of it than of the body's, which no pose moves: a limb fitted where the target
    has nothing leaves its own; a scan of one side leaves the far sides inside the target's
    reach of nothing outside them (not counted)."""
    reach, spacing = _reach(noise, rest)
    stated = (f"{reach:.3g} (3 × the target's noise {noise:.2g} + a quarter of the vertex "
              f"spacing {spacing:.2g})")
    parts = [("the target", np.ones(len(distances), bool))]
    parts += [(f"limb {k}'s part of it", owner == k) for k in limbs]
    for name, part in parts:
        if not part.any():
            continue
        near = float(np.mean(distances[part] <= reach))
        if near < EXPLAINED:
            return (
                f"the posed surface does not explain {name}: {100 * (1 - near):.1f} % of its "
                f"points lie farther than {stated} from it (at most "
                f"{100 * (1 - EXPLAINED):.0f} % may). " + SHAPE_ADVICE
            )
    if ahead is None:
        return ""
    body = region < 0
    unseen = float(np.mean(ahead[body] > reach)) if body.any() else 0.0
    # (The fitted limbs only (`fitted`, default `limbs`): a limb carried by a fitted one
    # follows it, and a one-sided scan may show none of it, as none of spot's far ear.)
    for k in limbs if fitted is None else fitted:
        away = float(np.mean(ahead[region == k] > reach)) if (region == k).any() else 0.0
        if away > unseen + AWAY:
            return (
                f"limb {k} is posed where the target has no surface: {100 * away:.1f} % of its "
                f"vertices lie farther than {stated} from the target, against "
                f"{100 * unseen:.1f} % of the body's (the part of it the target does not "
                "show). " + SHAPE_ADVICE
            )
    return ""


def _reach(noise: float, rest: np.ndarray) -> tuple[float, float]:
    """`(3 σ̂ + h/4, h)`: how far from the fit a point of a target of noise `σ̂` may lie and
    still be explained, `h` the median vertex spacing of `rest` (V, 3)."""
    spacing = float(np.median(cKDTree(rest).query(rest, 2)[0][:, 1]))
    return 3 * noise + spacing / 4, spacing


def _unseen(owner: np.ndarray, fitted) -> str:
    """"" when every fitted limb (`fitted`) owns target points (`owner` (K,): the limb of each
    point's nearest posed vertex), else which does not. A limb the target does not show, left
    at rest beside the body, passes the other checks (its vertices' nearest target points lie
    behind them, as a partial scan's far side does), and its spread reads only the points
    beside its joint."""
    for k in fitted:
        if not (owner == k).any():
            return (f"the target shows nothing of limb {k}: no target point lies nearest to its "
                    "posed vertices, so nothing says how it is bent. " + SHAPE_ADVICE)
    return ""


def _ahead(vertices: np.ndarray, triangles: np.ndarray, cloud: np.ndarray,
           nearest: np.ndarray, normals: np.ndarray, own: np.ndarray | None = None) -> np.ndarray:
    """Each posed vertex's (V, 3) distance (V,) along its nearest target point's normal
    (`nearest` (V,) into `cloud` (K, 3), `normals` (K, 3)), counted only where that point
    lies outside the posed surface (`triangles` (T, 3), outward): a partial scan's points lie
    inside the limbs and body whose far side it did not see (spot's leg, 51 % of its vertices
    away against the body's 38 %, its visible part exact), whereas a limb posed where the
    target has nothing has the target outside it, on the side it faces. `own` (V,) bool: the
    vertices whose nearest target point lies on their own part of the posed surface (within
    the target's reach of it, and nearest to a vertex of their own limb), counted 0: a scan's
    points around a limb's rim are nearest to the rim's far-side vertices too, outside them
    along their normals, and lie on the limb's surface (spot's leg 8 seen from one side, at
    its true pose: 16.9 % of its vertices away, against 3.3 % of the body's; 0 % with them
    counted 0), whereas a limb posed where the target has nothing finds its nearest target
    points on other parts, or off the posed surface."""
    outward = trimesh.Trimesh(vertices, triangles, process=False).vertex_normals
    gap = cloud[nearest] - vertices
    along = np.abs(np.sum(gap * normals[nearest], axis=-1))
    outside = np.sum(gap * outward, axis=-1) > 0
    return np.where(outside if own is None else outside & ~own, along, 0.0)


def _spreads(linear, limbs: tuple[int, ...], per_limb: int) -> dict:
    """Each fitted limb's bend's standard error (degrees; `_fit.uncertainty`: the bend vector's
    worst-determined direction) from the last stage's `(J, r)`; NaN without them (a solver
    that is not of Gauss–Newton type)."""
    if linear is None:
        return {k: float("nan") for k in limbs}
    cov = covariance(*linear, group=3)  # each target point's (or marker's) 3 components
    blocks = [[i * per_limb, i * per_limb + 1] for i in range(len(limbs))]
    return dict(zip(limbs, np.rad2deg(block_spread(cov, blocks)).tolist()))


def _undetermined(spread: dict) -> str:
    """"" when every fitted limb's bend is determined by the target to `ANGLE_SPREAD` degrees
    (`spread`: limb → standard error), else which limbs are not and what to try."""
    loose = {k: v for k, v in spread.items() if v > ANGLE_SPREAD}
    if not loose:
        return ""
    which = ", ".join(f"limb {k} ±{v:.2g}°" for k, v in loose.items())
    return (
        f"the target hardly depends on some fitted bends ({which}; at most ±{ANGLE_SPREAD}° "
        "is trusted): the posed surface explains the target, but so would those limbs bent "
        "noticeably otherwise (a short or thick limb moves its part of the target by less "
        "than the samples' spacing). Sample those limbs more densely, add markers on them "
        "(`vertex_ids`, `targets`), start them closer (`init=`), or hold them (leave them out "
        "of `limbs`)."
    )

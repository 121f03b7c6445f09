"""Fitting handle targets so that chosen vertices of a medial rig reach given positions
(`fit_handles`), in the spirit of `fit_spine`.

Nonlinear least squares over the handles' target centres `y (h, 3)`: each residual
evaluation poses the medial mesh by ARAP (`arap_medial`'s solver, a fixed number of
iterations, so the residuals are smooth in `y`) and skins the rig (`rig.pose`); optimistix's
Levenberg–Marquardt differentiates both. Not in Lan et al. 2017 (our addition, for the same
inverse problem `fit_spine` solves for a spine).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

from .._checks import check_vertex_ids
from .._fit.correspondences import weighted_rms
from .._fit.jacobian import for_solver
from .._fit.problem import (
    AbstractFitOutcome,
    check_cloud,
    check_solve_options,
    default_solver,
)
from .._medial_axis.medial_mesh import MedialMesh
from .arap import (
    ITERATIONS,
    SMOOTHNESS,
    _cells,
    _check_options,
    _check_rotations,
    check_handles,
    solve,
)
from .cells import ArapCells
from .pose import MedialPose
from .rig import MedialRig, check_method


class HandleFitResult(AbstractFitOutcome):
    """The outcome of `fit_handles`.

    **Fields:**

    - `targets`: `(h, 3)` fitted handle centres (pass them to `arap_medial` to pose again).
    - `pose`: the `MedialPose` they give.
    - `vertices`: `(k, 3)` the posed chosen vertices.
    - `rms`: root-mean-square (weighted) distance between `vertices` and `vertex_targets`.
    - `loss`: the final sum of squared residuals.
    - `result`: the `optimistix.RESULTS` of the solve; `converged` tells whether it succeeded.
    - `num_steps`: number of solver steps taken; `stats`: the solver's statistics.
    """

    targets: Float[Array, "h 3"]
    pose: MedialPose
    vertices: Float[Array, "k 3"]
    rms: Float[Array, ""]
    loss: Float[Array, ""]
    result: optx.RESULTS
    num_steps: Array
    stats: dict



class _Problem(eqx.Module):
    """Residuals `y -> √(wᵢ/Σw) (posed vertex_idsᵢ − vertex_targetsᵢ)`, flattened `(3k,)`."""

    rig: MedialRig
    medial: MedialMesh
    cells: ArapCells
    rotations: Array | None
    vertex_ids: Array
    vertex_targets: Array
    weights: Array
    iterations: int = eqx.field(static=True)
    solver: str = eqx.field(static=True)
    method: str = eqx.field(static=True)
    implicit: bool = eqx.field(static=True)

    def pose(self, y) -> MedialPose:
        centers, rotations, _ = solve(self.cells, y, self.rotations, self.iterations,
                                      self.solver)
        return MedialPose(self.medial, centers, rotations)

    def images(self, pose: MedialPose):
        vertices, _ = self.rig.pose(pose, self.method, implicit=self.implicit)
        return vertices[self.vertex_ids]

    def residuals(self, images):
        scale = jnp.sqrt(self.weights / jnp.sum(self.weights))
        return (scale[:, None] * (images - self.vertex_targets)).reshape(-1)

    def __call__(self, y, args=None):
        return self.residuals(self.images(self.pose(y)))


@eqx.filter_jit
def _solve(problem: _Problem, solver, y0, max_steps: int, throw: bool):
    # The residuals traced once, their Jacobian materialised by forward mode at each step
    # (`_fit.jacobian`, as the spine and skeleton fits): the solver's loop then carries a
    # matrix, not the linearised ARAP solve and skin.
    traced = eqx.filter_closure_convert(lambda y: problem(y), y0)
    solution = optx.least_squares(for_solver(lambda y, args=None: traced(y), solver), solver,
                                  y0, max_steps=max_steps, throw=throw)
    y = solution.value
    # The solution's pose, images and loss from one ARAP solve and one skin (each traced
    # again made the program larger: a first call 13.6 -> 13.3 s of CPU, test_arap's fit).
    pose = problem.pose(y)
    images = problem.images(pose)
    loss = jnp.sum(problem.residuals(images) ** 2)
    rms = weighted_rms(images - problem.vertex_targets, problem.weights,
                       jnp.ones(images.shape[0], bool))
    return y, pose, images, rms, loss, solution.result, solution.stats


def _rig_medial(rig: MedialRig) -> MedialMesh:
    """The rig's medial mesh, rebuilt from its arrays (its cone table lists the edges, then
    lone spheres as `(i, i)`)."""
    cones = np.asarray(rig.cones)
    return MedialMesh(np.asarray(rig.rest_centers), np.asarray(rig.radii),
                      cones[cones[:, 0] != cones[:, 1]], np.asarray(rig.medial_faces))


def _check_weights(weights, k: int, dtype):
    if weights is None:
        return jnp.ones((k,), dtype)
    w = np.asarray(weights, np.float64)
    if w.shape != (k,) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
        raise ValueError(f"`weights` must be a finite non-negative (k,) = ({k},) array, not "
                         f"all zero, got shape {w.shape}.")
    return jnp.asarray(w, dtype)


def fit_handles(
    rig: MedialRig,
    handles: ArrayLike,
    vertex_ids: ArrayLike,
    vertex_targets: ArrayLike,
    *,
    method: str = "medial",
    implicit: bool = False,
    init: ArrayLike | None = None,
    rotations: ArrayLike | None = None,
    weights: ArrayLike | None = None,
    medial: MedialMesh | None = None,
    iterations: int = ITERATIONS,
    solver: str = "global",
    smoothness: float = SMOOTHNESS,
    optimiser: optx.AbstractLeastSquaresSolver | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    max_steps: int = 256,
    throw: bool = False,
) -> HandleFitResult:
    """Finds the handle target centres whose ARAP pose puts `vertex_targets` under
    `vertex_ids`.

    Minimises `Σᵢ wᵢ |x_{vertex_ids[i]}(y) − vertex_targets[i]|² / Σ w` over the handle
    targets `y (h, 3)`, where `x(y) = rig.pose(arap_medial(medial, handles, y, ...), method,
    implicit=implicit)`. Non-convergence is reported in `result`/`converged`, never raised
    (unless `throw=True`). Handles not constrained by any chosen vertex are only held by the
    solver's damping: choose vertices near every handle, or fix what must not move by giving
    it as a handle whose target the vertices pin down.

    **Arguments:**

    - `rig`: a `MedialRig`.
    - `handles`: `(h,)` sphere indices (as `arap_medial`).
    - `vertex_ids`: `(k,)` indices of the rig's vertices that have targets (bound validly).
    - `vertex_targets`: `(k, 3)` where they should go (finite); its dtype is the fit's.
    - `method`, `implicit`: passed to `rig.pose`. Without the implicit correction by default:
      its contact stop and relaxation are only piecewise smooth, and Levenberg–Marquardt
      stalls on them (measured: a 60° bend of a 20-sphere capsule chain from 165 of its
      vertices is recovered to 1e-14 in 28 steps without it; with it the fit stops at an rms
      of 2e-3 after 64 steps). Pose the fitted targets with `implicit=True` afterwards.
    - `init`: `(h, 3)` initial handle centres (default: their rest centres).
    - `rotations`: optional `(h, 3, 3)` prescribed handle rotations, held fixed.
    - `weights`: optional `(k,)` non-negative per-vertex weights.
    - `medial`: the rig's medial mesh (default: rebuilt from the rig's arrays).
    - `iterations`, `solver`, `smoothness`: passed to the ARAP solve (as `arap_medial`).
    - `optimiser`: any optimistix least-squares solver; default Levenberg–Marquardt with
      tolerances from the dtype (1e-10 in float64, 1e-5 in float32), as `fit_spine`.
    - `rtol`, `atol`: the default optimiser's tolerances (in (0, 1]; default from the dtype).
    - `max_steps` (in [1, 100000]), `throw`: passed to `optimistix.least_squares`.

    **Returns:** a `HandleFitResult`.
    """
    if not isinstance(rig, MedialRig):
        raise TypeError(f"`rig` must be a MedialRig, got {type(rig)}.")
    check_method(method)
    medial = _rig_medial(rig) if medial is None else medial
    if not isinstance(medial, MedialMesh):
        raise TypeError(f"`medial` must be a MedialMesh, got {type(medial).__name__}.")
    if medial.fingerprint() != rig.fingerprint():
        raise ValueError(f"`medial` must be the rig's MedialMesh ({rig.n_spheres} spheres); "
                         "it is another one (other spheres or topology).")
    iterations, smoothness = _check_options(iterations, solver, smoothness)
    max_steps, rtol, atol = check_solve_options(max_steps, rtol, atol)
    handles = check_handles(handles, rig.n_spheres)
    ids = check_vertex_ids(vertex_ids, rig.rest_vertices.shape[0])
    invalid = ids[~np.asarray(rig.valid)[ids]]
    if invalid.size:
        raise ValueError(f"`vertex_ids` must be validly bound vertices of the rig; "
                         f"{invalid.tolist()[:10]} are not.")
    targets = check_cloud(vertex_targets, "vertex_targets")
    if targets.shape != (len(ids), 3):
        raise ValueError(f"`vertex_targets` must have shape (k, 3) = ({len(ids)}, 3), one per "
                         f"vertex id, got shape {targets.shape}.")
    dtype = targets.dtype
    if init is None:
        y0 = jnp.asarray(np.asarray(medial.centers)[handles], dtype)
    else:
        y0 = check_cloud(init, "init").astype(dtype)
        if y0.shape != (len(handles), 3):
            raise ValueError(f"`init` must have shape (h, 3) = ({len(handles)}, 3), got shape "
                             f"{y0.shape}.")
    problem = _Problem(
        rig=rig, medial=medial, cells=jax.tree.map(jnp.asarray, _cells(medial, handles,
                                                                         smoothness, dtype)),
        rotations=_check_rotations(rotations, len(handles), dtype),
        vertex_ids=jnp.asarray(ids, jnp.int32), vertex_targets=targets,
        weights=_check_weights(weights, len(ids), dtype), iterations=iterations,
        solver=solver, method=method, implicit=bool(implicit),
    )
    if optimiser is None:
        optimiser = default_solver("least_squares", dtype, rtol, atol)
    y, pose, images, rms, loss, result, stats = _solve(problem, optimiser, y0, max_steps,
                                                       bool(throw))
    return HandleFitResult(targets=y, pose=pose, vertices=images, rms=rms, loss=loss,
                           result=result, num_steps=stats["num_steps"], stats=stats)

"""Fitting a spine to target positions of corresponding points (nonlinear least squares).

Given the rest shape `source` around its spine `C₀` and where its points should go, `target`,
find the bent spine `C₁` minimising `Σᵢ wᵢ |M(xᵢ) − yᵢ|²` (plus regularisers), where `M` is the
fleshing from `C₀` to `C₁`. The source is registered on `C₀` once; each residual evaluation is
then one pose, differentiable with respect to `C₁`'s parameters and the twist (through the
frames, the arc-length reparameterisation and the closed-form maps).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike

from .._batching.buckets import bucket, pad_batch, unpad_batch
from .._fleshing.projection import Registration
from . import coarse, start, verdict
from .budget import limited
from .continuation import AUTO_STAGES, staged_targets
from .problem import (
    EXPLAINED,
    AbstractPoseProblem,
    FitResult,
    Parameters,
    Regularizers,
    check_cloud,
    check_tolerance,
    default_solver,
    explain,
    fit,
    prepare,
    solve,
)

STAGE_STEPS = 32  # the step budget of a continuation's stages before the last
TIGHTER, TIGHTER_ROUNDS = 0.1, 3  # `_finished`: its creep stops' rms, each round's factor

ADVICE = (
    "start closer: more `continuation=` stages (the target reached in steps from the rest "
    "pose), an `Arc` fitted first with a free-form `init` on it, or `fixed=` for the root's "
    "control points."
)


def weighted_rms(diff: Array, weights: Array, counted: Array) -> Array:
    """`√(Σ wᵢ|dᵢ|² / Σ wᵢ)` over the counted points (NaN when none is counted)."""
    w = jnp.where(counted, weights, 0)
    total = jnp.sum(w)
    squared = jnp.sum(w * jnp.sum(jnp.where(counted[:, None], diff, 0) ** 2, axis=-1))
    return jnp.where(total > 0, jnp.sqrt(squared / jnp.where(total > 0, total, 1)), jnp.nan)


class Correspondence(AbstractPoseProblem):
    """The residual function `y -> (data residuals, *regularisers)` of `fit_spine`.

    Data residuals are `√(wᵢ/Σw) (M(xᵢ) − yᵢ)`, flattened (3N,): their sum of squares is the
    weighted mean squared distance. Invalid images are zeroed (`invalid="exclude"`) or kept as
    the unmoved source point (`"penalize"`, what `flesh` returns for them).
    """

    parameters: Parameters
    registration: Registration
    target: Array
    weights: Array
    twist: Array
    regularizers: Regularizers
    method: str = eqx.field(static=True)
    invalid: str = eqx.field(static=True)
    check_projection: bool = eqx.field(static=True)

    def __call__(self, y, args=None):
        images, valid = self.images(y)
        diff = images - self.target
        if self.invalid == "exclude":
            diff = jnp.where(valid[:, None], diff, 0)
        scale = jnp.sqrt(self.weights / jnp.sum(self.weights))
        data = (scale[:, None] * diff).reshape(-1)
        return (data, *self.regularizers(self.spine_and_twist(y)[0]))

    def rms(self, images, valid):
        counted = valid if self.invalid == "exclude" else jnp.ones_like(valid)
        return weighted_rms(images - self.target, self.weights, counted)

    def distances(self, images, valid):
        counted = valid if self.invalid == "exclude" else jnp.ones_like(valid)
        d = jnp.linalg.norm(images - self.target, axis=-1)
        return d, jnp.where(counted, self.weights, 0)

    def data(self):
        return self.target


def fit_spine(
    source_spine,
    init,
    source: ArrayLike,
    target: ArrayLike,
    *,
    method: str = "radial",
    twist: ArrayLike = 0.0,
    fit_twist: bool = False,
    params: Callable | None = None,
    fixed=None,
    length="free",
    smoothness: float = 0.0,
    regularizers: Sequence[Callable] | None = None,
    weights: ArrayLike | None = None,
    invalid: str = "penalize",
    check_projection: bool = False,
    solver: optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    max_steps: int = 256,
    throw: bool = False,
    tolerance: float | None = verdict.TOLERANCE,
    continuation: int | str = "auto",
) -> FitResult:
    """Fits the bent spine `C₁` that fleshes `source[i]` (around `C₀`) onto `target[i]`.

    Nonlinear least squares over the free parameters of `init` (and optionally the twist),
    solved with optimistix (Levenberg–Marquardt by default). Non-convergence is reported in
    `result`/`converged`, never raised (unless `throw=True`) and never hidden: `converged` is
    True only when the loss stopped decreasing *and* the rms is within `tolerance` of the
    targets' bounding-box diagonal; otherwise `message` says which failure it most likely is
    (stall, local minimum, unreachable target, invalid targets) and what to try.

    A far target (a bend of 60–90° from the rest spine) is reached from the targets' own
    shape: by default (`continuation="auto"`), a free-form `init` (a `BSpline` whose control
    points are fitted) starts with its control points fitted by linear least squares to
    where the targets say the bent spine runs (`_fit.start`), or from the circular arc
    closest to that spine, or from the circular arc closest to where the targets say the
    spine runs, whichever poses the source closest to the targets (`init` too),
    each with the twist (when fitted) that rolls it onto them best (`start.turned`).
    A fit that does not converge with its rms above the tolerance is retried from where it
    stopped, the target solved first with every point posed by the map's formula (no cliffs
    where points leave the valid space), then as asked; if still not, by continuation from
    `init`: the target approached in 4 stages, each fit started from the one before
    (`_fit.continuation`). The default solver
    stops once it creeps (steps no longer halving the loss) with the rms at a hundredth of
    the tolerance: a free-form spine's control points slide along the curve almost freely,
    and its solve would otherwise creep on until `max_steps`. Where its solve explains the
    data but the full projection check finds points invalid (an image near the focal set of
    a stretch whose curvature still ripples), it is solved on with creep stops 10, 100 and
    1000 times tighter, until the check agrees.

    **Arguments:**

    - `source_spine`: the rest spine `C₀` (any `AbstractSpine`).
    - `init`: the initial guess for `C₁` (any `AbstractSpine`; the fit returns the same type).
    - `source`: (N, 3) rest points (finite), registered once on `C₀`.
    - `target`: (N, 3) where each source point should go (finite).
    - `method`: `"radial"`, `"normal"`, `"binormal"` or `"skinning"`.
    - `twist`: scalar twist in radians (the initial guess when `fit_twist`).
    - `fit_twist`: also fit the twist.
    - `params`: function `spine -> leaf or tuple of leaves` (as for `eqx.tree_at`) selecting
      the array leaves to fit; default: the shape parameters (control points of a free-form
      spine; `radius, length` of an `Arc`; `radius, pitch, length` of a `Helix`).
    - `fixed`: boolean mask(s) of entries held at their `init` value: one per parameter leaf
      (a tuple), or a single one when there is one parameter leaf. Each mask's shape is a
      prefix of its leaf's shape: `(K,)` fixes whole rows of `(K, 3)` control points (e.g.
      the first two: the root position and direction of a limb).
    - `length`: `"free"`; `"fixed"` (stiff penalty `10⁶ (L₁ − L₀)²`, `L₀ = C₀.length`); or a
      weight `w` for the penalty `w (L₁ − L₀)²`.
    - `smoothness`: weight of the bending energy `∫|k₁|² ds` of the fitted spine.
    - `regularizers`: extra callables `spine -> residual array`, whose squares are added.
    - `weights`: optional (N,) non-negative per-point weights.
    - `invalid`: how points outside the valid space of the current `C₁` count: `"penalize"`
      (as the unmoved point, which is what `flesh` returns) or `"exclude"` (not at all).
    - `check_projection`: use the global projection check inside the objective (slower, and
      piecewise); the final `valid` and `rms` always use it.
    - `solver`: any optimistix least-squares solver or minimiser; default
      `LevenbergMarquardt(rtol, atol)` with tolerances from the dtype (1e-10 in float64,
      1e-5 in float32).
    - `max_steps`, `throw`: passed to `optimistix.least_squares` (each stage's).
    - `tolerance`: the rms the data allows, as a fraction of the targets' bounding-box
      diagonal (default 1e-3): about the targets' noise over the diagonal for noisy targets;
      `None` for no residual test (the solver's alone, e.g. a regularised fit that trades
      data for smoothness on purpose).
    - `continuation`: `"auto"` (the default: a plain fit from the closest of `init`, the
      start from the targets' shape and its closest arc, retried from where it stopped
      without cliffs, then in 4 stages from `init`, while it does not converge with its rms
      above the tolerance; the lowest rms is kept, and
      when both stop at the same rms at a minimum the target is reported unreachable), or
      the number of stages `n ≥ 1` (1: one plain fit). Stage `k` targets each point's
      rest position moved `k/n` of the way: the best rigid motion onto the targets followed
      `k/n` of its angle and shift, plus `k/n` of the rest; the last stage is `target`
      itself. Every stage poses each point by the map's formula, valid or not (no
      jump back to its rest position on the way); the fit as asked (`invalid=`) follows.

    **Returns:** a `FitResult`. Its `rms` is the weighted root-mean-square distance between
    the fleshed source and `target` over all points (`"penalize"`) or over the valid ones
    (`"exclude"`).

    Notes:

    - The fitted spine keeps the static configuration of `init`: a straight B-spline guess
      gets the coarse arc-length/frame resolution of a straight curve, which limits the rms
      it can reach on a strongly bent target (about 1e-7 here); pass
      `BSpline(..., subdivisions=...)` sized for the expected bend. A finer `init` (a curved
      rest spine: the insect's body gets 192 subdivisions a span) is solved first at 24
      (`_fit.coarse`: its steps several times cheaper), then finished at its own.
    - `"exclude"` lets the solver lower the loss by making points invalid; with a poor guess it
      can drift there. `"penalize"` (the default) cannot.
    - Parameters are unconstrained: an `Arc`'s radius could in principle cross zero. Fix what
      must not move, and start from a reasonable guess.
    """
    source = check_cloud(source, "source")
    target = check_cloud(target, "target")
    if target.shape != source.shape:
        raise ValueError(
            f"`source` and `target` must have the same shape (N, 3): got `source` of shape "
            f"{source.shape} and `target` of shape {target.shape}."
        )
    dtype = source.dtype
    target = check_cloud(target, "target").astype(dtype)
    weights = _check_weights(weights, source.shape[0], dtype)
    # Padded to a bucket of sizes (`_batching.buckets`): copies of the last point with weight
    # 0 add no residual and no gradient, and fits of clouds of similar sizes share one
    # compiled solve instead of compiling one per point count.
    n = source.shape[0]
    size = bucket(n)
    source, target = pad_batch((source, target), size)
    weights = jax.device_put(np.pad(np.asarray(weights), (0, size - n)))
    setup = prepare(
        source_spine,
        init,
        source,
        method=method,
        twist=twist,
        fit_twist=fit_twist,
        params=params,
        fixed=fixed,
        length=length,
        smoothness=smoothness,
        regularizers=regularizers,
        invalid=invalid,
    )
    problem = Correspondence(
        target=target,
        weights=weights,
        **setup.problem_fields(invalid, check_projection),
    )
    tolerance = check_tolerance(tolerance)
    tighter = []
    if solver is None:
        explained = EXPLAINED * tolerance * verdict.diagonal(problem.data())
        solver = default_solver("least_squares", dtype, rtol, atol, explained)
        # The same solve stopping once it creeps at a tenth, a hundredth … of that rms (a
        # value: the same compiled program), for fits the full projection check disagrees
        # with (`_finished`).
        tighter = [
            default_solver("least_squares", dtype, rtol, atol, explained * TIGHTER**k)
            for k in range(1, TIGHTER_ROUNDS + 1)
        ]

    coarser = coarse.coarser(setup.parameters)
    rough = problem if coarser is None else dataclasses.replace(problem, parameters=coarser)

    def staged(stages: int, y, follow: bool = False) -> FitResult:
        # Each stage only moves the start: its solve alone, every point posed by the map's
        # formula (`followed_images`: no cliffs on the way). The target itself is solved so
        # too before the fit as asked (in one stage too with `follow`): near it, points at
        # the edge of the valid space would otherwise stop the solve at their cliffs.
        goals = staged_targets(source, target, weights, stages) if stages > 1 else (
            [target] if follow else [])
        # A stage before the last only brings the next start closer, and its target (a blend
        # of the rest and the bend) is no bend: its solve creeps (spot's tail bent 60°: still
        # 4.1e-3 of the diagonal, 0.05 % a step, after 32 steps) until `max_steps`. A short
        # budget, in the program of the full one (`limited`: a value, not a static limit).
        # A curved `init` with fine frames: every solve but the last on coarser ones (`coarse`),
        # the target as asked too, whose answer the last solve then starts near.
        solves = [
            (
                dataclasses.replace(rough, target=jnp.asarray(goal), invalid="follow"),
                min(STAGE_STEPS, int(max_steps)) if k < len(goals) else int(max_steps),
            )
            for k, goal in enumerate(goals, 1)
        ]
        if rough is not problem:
            solves.append((rough, int(max_steps)))
        for staged_problem, steps in solves:
            budget, limit = limited(solver, max_steps, steps)
            spine, twist_k, _, _, _, stats = solve(staged_problem, budget, y, limit, False)
            y = setup.parameters.of(spine, twist_k if fit_twist else None)
        # (The coarse solve of the target as asked counts among the fit's steps.)
        before = int(stats["num_steps"]) if rough is not problem else 0
        result = fit(problem, solver, y, max_steps, throw, tolerance, ADVICE)
        return dataclasses.replace(result, stages=stages, num_steps=result.num_steps + before)

    if continuation == "auto":
        shaped = start.initial(setup.parameters, setup.registration, source_spine,
                               target, weights, setup.y0[1])
        arced = start.arc(setup.parameters, shaped)
        circled = start.initial(setup.parameters, setup.registration, source_spine, target,
                                weights, setup.y0[1], circular=True)
        starts = [start.turned(problem, y, target, weights) for y in (shaped, arced, circled)]
        result = staged(1, start.closer(problem, setup.y0, *starts))
        result = _finished(problem, setup.parameters, result, solver, tighter, fit_twist,
                           max_steps, throw, tolerance)
        if not _explained(result):
            # Often stopped near the answer at a cliff (a point posed invalid, its target
            # valid: the insect's body bent 90°, 200 points, 1.3e-2 of the diagonal): from
            # there, the target solved without cliffs first, then the fit as asked.
            polished = staged(1, setup.parameters.of(result.spine, result.twist if fit_twist
                                                     else None), follow=True)
            result = polished if float(polished.rms) < float(result.rms) else result
        if not _explained(result):
            retried = _finished(problem, setup.parameters, staged(AUTO_STAGES, setup.y0),
                                solver, tighter, fit_twist, max_steps, throw, tolerance)
            low, high = sorted((float(result.rms), float(retried.rms)))
            stopped = [r.result == optx.RESULTS.successful for r in (result, retried)]
            same = all(stopped) and high < verdict.SAME_RESIDUAL * low and not (
                result.stalled and retried.stalled
            )
            result = retried if float(retried.rms) <= float(result.rms) else result
            if same and not result.converged:
                # Two starts, one residual (a stall there: the second start was already at
                # the minimum): most likely the best this spine can do.
                result = explain(problem, dataclasses.replace(result, stalled=""), tolerance,
                                 ADVICE, same_from_elsewhere=True)
    else:
        result = staged(_check_stages(continuation), setup.y0)
    return eqx.tree_at(lambda r: r.valid, result, unpad_batch(result.valid, n))


def _explained(result: FitResult) -> bool:
    """Whether a fit converged or stopped with its rms within its tolerance (no retry)."""
    return result.converged or float(result.rms) <= float(result.tolerance)


def _finished(
    problem: Correspondence,
    parameters: Parameters,
    result: FitResult,
    solver,
    tighter: list,
    fit_twist: bool,
    max_steps: int,
    throw: bool,
    tolerance: float,
) -> FitResult:
    """`result` solved on from where it stopped, while its own solve explained the data
    (its loss within the tolerance²) but it did not converge: with each of the `tighter`
    solvers in turn while the full projection check disagrees (rms above the tolerance),
    with `solver` (the usual stop) where it agrees but the solve ran out of steps.

    The solve poses its points checked at their feet alone (`check_projection=False`); the
    reported rms checks each image against the whole fitted spine. A target near the valid
    space's edge (spot's tail bent 60°: one point at `k·d* = 0.55` of the radial map's 0.577)
    is posed validly at its foot by a spine that explains the data to the creep stop's rms,
    yet its image lies past the focal set of a stretch nearby, whose curvature still ripples
    (a free-form spine's control points slid along it): it counts as unmoved. Solved on, with
    a creep stop ten times tighter each round, the spine comes nearer the answer, whose
    curvature passes the check, and the fit is then reported as what it is."""
    steps = result.num_steps
    for tight in tighter:
        if result.converged or float(result.loss) > float(result.tolerance) ** 2:
            break
        y = parameters.of(result.spine, result.twist if fit_twist else None)
        agrees = float(result.rms) <= float(result.tolerance)
        on = fit(problem, solver if agrees else tight, y, max_steps, throw, tolerance, ADVICE)
        steps = steps + on.num_steps
        if float(on.rms) < float(result.rms) or agrees:
            result = dataclasses.replace(on, num_steps=steps, stages=result.stages)
    return result


def _check_stages(continuation) -> int:
    if isinstance(continuation, bool) or not isinstance(continuation, int | np.integer) or (
        continuation < 1
    ):
        raise ValueError(
            f"`continuation` must be 'auto' or a number of stages ≥ 1, got {continuation!r}."
        )
    return int(continuation)


def _check_weights(weights, n: int, dtype) -> Array:
    if weights is None:
        return jnp.ones((n,), dtype)
    weights = np.asarray(weights, dtype=np.float64)
    if weights.shape != (n,) or not np.isfinite(weights).all() or (weights < 0).any():
        raise ValueError(
            f"`weights` must be a finite non-negative (N,) = ({n},) array, got shape "
            f"{weights.shape}."
        )
    if weights.sum() <= 0:
        raise ValueError("`weights` must not all be zero.")
    return jnp.asarray(weights, dtype)

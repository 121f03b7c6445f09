"""What every spine fit shares: the parameterisation, the regularisers and the result.

A fit optimises some array leaves of an initial spine `init` (by default its shape parameters:
the control points of a free-form spine, the radius and length of an arc, …), with some entries
optionally held at their initial values (`fixed`), and optionally the global twist. Only the
free entries enter the optimiser; the spine is rebuilt from them with `eqx.tree_at`, so fixed
entries stay *exactly* at their initial values and everything else about `init` (its type, its
static configuration) is kept.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float

from .._checks import as_float_array, as_points, as_twist, check_number, is_concrete
from .._fleshing.methods import check_method
from .._fleshing.pipeline import Poser, pose, pose_points, register
from .._fleshing.projection import Registration
from .._numerics import cast_floats
from .._spines.analytic import Arc, Helix, Line
from .._spines.bspline import BSpline
from .._spines.spine import AbstractSpine
from . import verdict
from .budget import limited, unbudgeted
from .jacobian import for_solver

INVALID_MODES = ("penalize", "exclude")
SMOOTHNESS_SAMPLES = 16  # midpoint samples of the bending energy ∫|k|² ds
# A least-squares solve that optimistix reports as successful is reported as stalled when it
# stopped without reducing the loss meaningfully (the rms not even halved: loss above a
# quarter of its start) while its trust region had shrunk a thousandfold from its start (1):
# its steps shrank to nothing because the local model no longer predicted the loss, so the
# point is no minimum. A fit started at its minimum ends after a few steps, its trust region
# intact; one that reduced its loss a lot is left to optimistix's own test.
COLLAPSED_TRUST_REGION = 1e-3
MEANINGFUL_LOSS_RATIO = 0.25
# A fit's default solver may stop once its rms is this fraction of its tolerance, the data
# explained far within what they allow (`_LevenbergMarquardt`) …
EXPLAINED = 1e-2
MEANINGFUL_STEP = 0.5  # … once its accepted steps no longer halve the loss
# Its trust region grows after a step whose loss fell by at least this share of the local
# model's prediction (the textbook 3/4; optimistix's 0.99 grew it only after near-exact
# predictions, and along a free-form spine's sliding directions the model predicts within a
# few percent: the damping stayed and the solve crept, 2 % a step, to `max_steps`).
GOOD_STEP = 0.75


@dataclasses.dataclass(frozen=True)
class Fields:
    """The `where` function `spine -> (spine.<name>, ...)`: hashable, so fits of the same
    configuration reuse their compilation."""

    names: tuple[str, ...]

    def __call__(self, spine) -> tuple:
        return tuple(getattr(spine, name) for name in self.names)


def _floating_leaves(spine) -> tuple:
    return tuple(jax.tree.leaves(eqx.filter(spine, eqx.is_inexact_array)))


def default_parameters(spine: AbstractSpine) -> Callable:
    """The leaves a fit optimises unless told otherwise (a `where` function, as `eqx.tree_at`).

    The shape parameters that keep the spine well formed, with its placement kept: `(length,)`
    for a `Line`, `(radius, length)` for an `Arc`, `(radius, pitch, length)` for a `Helix`,
    the control points (`control_points`, else `points`) of a free-form spine, and every
    floating array leaf of any other spine.
    """
    if isinstance(spine, Line):
        return Fields(("length",))
    if isinstance(spine, Arc):
        return Fields(("radius", "length"))
    if isinstance(spine, Helix):
        return Fields(("radius", "pitch", "length"))
    for name in ("control_points", "points"):
        if isinstance(getattr(spine, name, None), jax.Array | np.ndarray):
            return Fields((name,))
    return _floating_leaves


def _as_tuple(value) -> tuple:
    return tuple(value) if isinstance(value, tuple | list) else (value,)


class Parameters(eqx.Module):
    """The free entries of a spine's parameter leaves (and the twist), as an optimiser's `y`.

    `y = (values, twist)`: `values` is a tuple with one flat (F_i,) array per parameter leaf
    (its free entries), `twist` a scalar or `None` when the twist is not fitted.
    """

    base: AbstractSpine
    free: tuple[Array, ...]  # flat indices of the free entries of each parameter leaf
    where: Callable = eqx.field(static=True)

    def initial(self, twist: Array | None):
        leaves = _as_tuple(self.where(self.base))
        return tuple(leaf.reshape(-1)[i] for leaf, i in zip(leaves, self.free)), twist

    def of(self, spine: AbstractSpine, twist: Array | None):
        """The `y` of `spine` (a fit's result: the same structure as `base`) and `twist`."""
        return Parameters(spine, self.free, self.where).initial(twist)

    def spine(self, y) -> AbstractSpine:
        leaves = _as_tuple(self.where(self.base))
        new = tuple(
            leaf.reshape(-1).at[i].set(v).reshape(leaf.shape)
            for leaf, i, v in zip(leaves, self.free, y[0])
        )
        return eqx.tree_at(lambda s: _as_tuple(self.where(s)), self.base, new)


def make_parameters(init: AbstractSpine, params, fixed) -> Parameters:
    """Validates `params`/`fixed` (see `fit_spine`) and builds the `Parameters`."""
    where = default_parameters(init) if params is None else params
    if not callable(where):
        raise TypeError("`params` must be a function `spine -> leaf or tuple of leaves`.")
    leaves = _as_tuple(where(init))
    for leaf in leaves:
        if not (isinstance(leaf, jax.Array) and jnp.issubdtype(leaf.dtype, jnp.floating)):
            raise TypeError(f"`params` must select floating array leaves of `init`, got {leaf!r}.")
    if fixed is None:
        masks = (False,) * len(leaves)
    elif isinstance(fixed, tuple | list):
        masks = tuple(fixed)
    else:
        masks = (fixed,)
    if len(masks) != len(leaves):
        raise ValueError(
            f"`fixed` must give one mask per parameter leaf ({len(leaves)} selected by "
            f"`params`), got {len(masks)}."
        )
    free = []
    for leaf, mask in zip(leaves, masks):
        mask = np.asarray(mask)
        if mask.dtype != bool or mask.shape != leaf.shape[: mask.ndim]:
            raise ValueError(
                "each mask in `fixed` must be a boolean array whose shape is a prefix of its "
                f"leaf's shape {leaf.shape} (e.g. (K,) for (K, 3) control points), got "
                f"{mask.dtype} of shape {mask.shape}."
            )
        mask = mask.reshape(mask.shape + (1,) * (leaf.ndim - mask.ndim))
        mask = np.broadcast_to(mask, leaf.shape)
        free.append(jnp.asarray(np.flatnonzero(~mask.reshape(-1)), dtype=jnp.int32))
    return Parameters(init, tuple(free), where)


def check_spine(spine, name: str) -> None:
    """Raises `TypeError` unless `spine` is an `AbstractSpine`."""
    if not isinstance(spine, AbstractSpine):
        raise TypeError(f"`{name}` must be a spine (AbstractSpine), got {type(spine)}.")


def check_cloud(points: ArrayLike, name: str) -> Array:
    """A finite (N, 3) floating array, else `ValueError` (`TypeError` for values that are not
    real numbers, or half precision) naming `name`."""
    points = as_float_array(points, name)
    if points.ndim == 2 and points.shape[-1] == 3:
        points = as_points(points, name)  # the dtype checks
    if points.ndim != 2 or points.shape[-1] != 3 or points.shape[0] == 0:
        raise ValueError(f"`{name}` must have shape (N, 3) with N ≥ 1, got shape {points.shape}.")
    bad = ~np.isfinite(np.asarray(points)).all(axis=-1)
    if bad.any():
        raise ValueError(
            f"`{name}` must be finite: {int(bad.sum())} of its points hold NaN or inf "
            f"(first at index {int(np.flatnonzero(bad)[0])})."
        )
    return points


def check_options(invalid: str, length, smoothness) -> tuple[Array | None, float]:
    """Validates `invalid`, `length` and `smoothness`; returns the length-penalty weight."""
    if invalid not in INVALID_MODES:
        raise ValueError(f"`invalid` must be one of {INVALID_MODES}, got {invalid!r}.")
    if isinstance(length, str):
        if length not in ("free", "fixed"):
            raise ValueError(f"`length` must be 'free', 'fixed' or a weight ≥ 0, got {length!r}.")
        weight = None if length == "free" else 1e6
    else:
        weight = float(length)
        if not np.isfinite(weight) or weight < 0:
            raise ValueError(f"`length` must be 'free', 'fixed' or a weight ≥ 0, got {length!r}.")
    smoothness = float(smoothness)
    if not np.isfinite(smoothness) or smoothness < 0:
        raise ValueError(f"`smoothness` must be a finite weight ≥ 0, got {smoothness!r}.")
    return weight, smoothness


def default_tolerance(dtype) -> float:
    """Solver tolerance: 1e-10 in float64, 1e-5 in float32."""
    return 1e-10 if jnp.dtype(dtype) == jnp.float64 else 1e-5


class _TrustRegion(optx.ClassicalTrustRegion):
    """optimistix's classical trust region, with its step size in the dtype of `y`.

    The stock one starts from a default-float step size, which under `jax_enable_x64` turns
    the damped system of a float32 fit into float64 and breaks the linear solve.
    """

    def init(self, y, f_info_struct):
        state = super().init(y, f_info_struct)
        dtype = jnp.result_type(*jax.tree.leaves(y))
        return eqx.tree_at(lambda s: s.step_size, state, state.step_size.astype(dtype))


class _ScaledTrustRegion(_TrustRegion):
    """`_TrustRegion` whose damping starts at `scale` times the largest diagonal entry of
    `JᵀJ` at the start (the Levenberg–Marquardt parameter `λ = 1 / step size`), not at 1:
    the usual start of Madsen, Nielsen and Tingleff's Levenberg–Marquardt, whatever the
    residuals' units. With `λ = 1`, a parameter whose curvature is far below 1 steps by only
    that fraction of its Gauss–Newton step until a run of very good steps (each `λ / 3.5`)
    has brought `λ` down to it (a shape fit's legs: `JᵀJ`'s eigenvalues 1e-3 to 1e-4, 11
    steps to walk one leg 0.5° onto its target). `scale`: an array (a leaf: one program for
    every value)."""

    scale: Array | float = 1e-3

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        step_size, accept, result, state = super().step(first_step, y, y_eval, f_info,
                                                        f_eval_info, state)
        # (At the first step `f_eval_info` is the start's; its step size is not changed.)
        jac = f_eval_info.jac.as_matrix()
        largest = jnp.max(jnp.sum(jac**2, axis=0))
        curved = largest > 0
        start = 1 / (self.scale * jnp.where(curved, largest, 1.0))
        step_size = jnp.where(first_step & curved, start.astype(step_size.dtype), step_size)
        return step_size, accept, result, eqx.tree_at(lambda s: s.step_size, state, step_size)


class _LevenbergMarquardt(optx.LevenbergMarquardt):
    """optimistix's Levenberg–Marquardt, which also stops once it creeps where the data are
    explained: an accepted step that did not halve the residuals' sum of squares, with their
    root at most `explained` (a fit's rms at `EXPLAINED` of its tolerance).

    Its own test (Cauchy: a small change in `y` *and* in the residuals) may never pass on a
    free-form spine: a control point slid along the curve changes it only to second order,
    so `JᵀJ` has near-null directions, the damping holds them, and the solve creeps along
    them (the loss down a few percent a step, far below what the data can tell) until it
    runs out of steps. A solve converging as Gauss–Newton does (the loss down by orders a
    step) is left to the Cauchy test, to full precision.
    """

    explained: Array

    def __init__(self, rtol: float, atol: float, explained):
        super().__init__(rtol=rtol, atol=atol)
        self.explained = explained

    def step(self, fn, y, args, options, state, tags):
        y, new, aux = super().step(fn, y, args, options, state, tags)

        def squares(info):
            return sum(jnp.sum(r**2) for r in jax.tree.leaves(info.residual))

        before, after = squares(state.f_info), squares(new.f_info)
        # (Before its first step the state holds no residuals yet.)
        accepted = jnp.logical_and(jnp.logical_not(state.first_step),
                                   new.num_accepted_steps > state.num_accepted_steps)
        creeping = jnp.logical_and(after > MEANINGFUL_STEP * before,
                                   after <= self.explained**2)
        stop = jnp.logical_or(new.terminate, jnp.logical_and(accepted, creeping))
        return y, eqx.tree_at(lambda s: s.terminate, new, stop), aux


def default_solver(kind: str, dtype, rtol: float | None, atol: float | None,
                   explained: float | None = None, damping: float | None = None):
    """`LevenbergMarquardt` (`kind="least_squares"`) or `BFGS` (`"minimise"`), with tolerances
    from the dtype unless given; with `explained` (a least-squares fit whose residuals' sum
    of squares is its rms², e.g. `fit_spine`'s), a Levenberg–Marquardt that also stops once
    it creeps with the rms at most `explained` (`_LevenbergMarquardt`; an infinite `explained`,
    no tolerance, stops it as optimistix's own: the same program, `explained` a value),
    its trust region grown after steps that fall by `GOOD_STEP` of their prediction.
    With `damping`, its damping starts at `damping` times the largest diagonal entry of `JᵀJ`
    at the start, not at 1 (`_ScaledTrustRegion`)."""
    tol = default_tolerance(dtype)
    rtol, atol = (tol if rtol is None else rtol), (tol if atol is None else atol)
    if kind == "minimise":
        return optx.BFGS(rtol=rtol, atol=atol)
    if explained is None:
        solver, search = optx.LevenbergMarquardt(rtol=rtol, atol=atol), _TrustRegion()
    else:
        # (No rms is at most 0 but a zero one, which no step creeps from: never stops early.)
        explained = explained if np.isfinite(explained) else 0.0
        solver = _LevenbergMarquardt(rtol, atol, jnp.asarray(explained, dtype))
        search = _TrustRegion(high_cutoff=GOOD_STEP)
    if damping is not None:
        search = _ScaledTrustRegion(scale=jnp.asarray(damping, dtype))
    return eqx.tree_at(lambda s: s.search, solver, search)


class Regularizers(eqx.Module):
    """The residuals added to a fit's data term, for the spine being fitted.

    - length: `√w (L − L₀)` when a length weight `w` is given;
    - smoothness: the bending energy `w ∫|k|² ds` as `SMOOTHNESS_SAMPLES` midpoint residuals;
    - `extra`: user callables `spine -> array of residuals`.
    """

    reference_length: Array
    length_weight: Array | None
    smoothness: Array | None
    extra: tuple[Callable, ...] = eqx.field(static=True)

    def __call__(self, spine: AbstractSpine) -> list[Array]:
        out = []
        if self.length_weight is not None:
            out.append(jnp.sqrt(self.length_weight) * (spine.length - self.reference_length)[None])
        if self.smoothness is not None:
            m = SMOOTHNESS_SAMPLES
            s = (jnp.arange(m, dtype=spine.length.dtype) + 0.5) * (spine.length / m)
            k = jax.vmap(spine.curvature_vector)(s)
            out.append(jnp.sqrt(self.smoothness * spine.length / m) * k.reshape(-1))
        out.extend(jnp.ravel(jnp.asarray(f(spine))) for f in self.extra)
        return out


def make_regularizers(reference_length, length_weight, smoothness, extra, dtype) -> Regularizers:
    extra = tuple(extra)
    if not all(callable(f) for f in extra):
        raise TypeError("`regularizers` must be a sequence of callables `spine -> residuals`.")

    def weight(w):
        return None if w is None or w == 0 else jnp.asarray(w, dtype)

    return Regularizers(
        jnp.asarray(reference_length, dtype), weight(length_weight), weight(smoothness), extra
    )


class AbstractFitOutcome(eqx.Module):
    """What every fit's result says about its solve: the optimistix `result`, read through
    `converged` and `message` (shared by `FitResult` and the medial `HandleFitResult`)."""

    result: eqx.AbstractVar[optx.RESULTS]

    def _stall(self) -> str:
        """Why a solve that optimistix reports as successful is no minimum ("" if none)."""
        return ""

    @property
    def converged(self) -> bool:
        """Whether the solver reported success, did not stall and (a spine fit) explained
        its data to the tolerance (never trust the fitted values when this is False)."""
        return bool(self.result == optx.RESULTS.successful) and not self._stall()

    @property
    def message(self) -> str:
        """Why the fit did not converge, with what to try ("" on success)."""
        return self._stall() or optx.RESULTS[self.result]


class FitResult(AbstractFitOutcome):
    """The outcome of a spine fit.

    **Fields:**

    - `spine`: the fitted spine (same type and static configuration as `init`).
    - `twist`: scalar twist (fitted, or the one given), from the source's first normal carried
      to the fitted spine's start (`_fleshing.ends`), as `flesh` and `pose` take it.
    - `rms`: root-mean-square distance between the fleshed `source` and the target (see each
      fitting function for exactly which points count), with the full projection check.
    - `valid`: (N,) bool, which source points map validly onto the fitted spine.
    - `result`: the `optimistix.RESULTS` of the solve; `converged` tells whether it succeeded.
    - `num_steps`: number of solver steps taken on the target (a `fit_spine` of a finely
      subdivided `init`: its solve on coarser frames first too, `_fit.coarse`).
    - `loss`: the final value of the objective (sum of squared residuals, regularisers included).
    - `stats`: the solver's statistics dictionary.
    - `stalled`: "" or, for a solve that optimistix reports as successful although its
      steps shrank to nothing without reducing the loss meaningfully (no minimum) and whose
      rms is above `tolerance`, what happened and what to try; `converged` is then False and
      `message` says it.
    - `tolerance`: the rms the data allows (absolute): the `tolerance=` given to the fit times
      the targets' bounding-box diagonal (`inf` with `tolerance=None`).
    - `unexplained`: "" or, for a solve that stopped (no stall) with `rms` above `tolerance`,
      which failure it most likely is (local minimum, unreachable target, invalid targets:
      `_fit.verdict`) and what to try; `converged` is then False and `message` says it. (Also
      a note for a solve that ran out of steps with its rms already within `tolerance`.)
    - `stages`: how many stages the fit took (1: one solve from `init`; more: a continuation,
      see `fit_spine`).
    """

    spine: AbstractSpine
    twist: Float[Array, ""]
    rms: Float[Array, ""]
    valid: Bool[Array, " N"]
    result: optx.RESULTS
    num_steps: Array
    loss: Float[Array, ""]
    stats: dict
    stalled: str = eqx.field(static=True, default="")
    tolerance: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(jnp.inf))
    unexplained: str = eqx.field(static=True, default="")
    stages: int = eqx.field(static=True, default=1)

    def _stall(self) -> str:
        # Not converged either: a solve that stopped without explaining its data.
        return self.stalled or self.unexplained

    @property
    def num_invalid(self) -> int:
        """How many source points do not map validly onto the fitted spine."""
        return int(jnp.sum(~self.valid))


class AbstractPoseProblem(eqx.Module):
    """A fit's residual function `y -> residuals`: poses the registered source on the spine
    rebuilt from `y = (free values, twist or None)`.

    Subclasses also hold the static fields `method: str`, `invalid: str` and
    `check_projection: bool`.
    """

    parameters: eqx.AbstractVar[Parameters]
    registration: eqx.AbstractVar[Registration]
    twist: eqx.AbstractVar[Array]
    regularizers: eqx.AbstractVar[Regularizers]

    def spine_and_twist(self, y) -> tuple[AbstractSpine, Array]:
        spine = self.parameters.spine(y)
        return spine, self.twist if y[1] is None else y[1]

    def images(self, y, check_projection: bool | None = None) -> tuple[Array, Array]:
        spine, twist = self.spine_and_twist(y)
        if self.invalid == "follow":
            return followed_images(self.registration, spine, self.method, twist)
        check = self.check_projection if check_projection is None else check_projection
        return pose_points(self.registration, spine, self.method, twist, check)

    @abc.abstractmethod
    def rms(self, images: Array, valid: Array) -> Array:
        """The fit's reported root-mean-square distance for final `images` (N, 3)."""

    @abc.abstractmethod
    def distances(self, images: Array, valid: Array) -> tuple[Array, Array]:
        """Each source point's distance to its target at final `images`, and its weight in
        `rms`: `(d (N,), w (N,))`, `rms = √(Σ w d² / Σ w)` over the forward term."""

    @abc.abstractmethod
    def data(self) -> Array:
        """The target points (K, 3), whose bounding-box diagonal scales the tolerance."""

    @property
    def regularized(self) -> bool:
        """Whether any regulariser is on (it may hold the fit away from the data)."""
        r = self.regularizers
        return r.length_weight is not None or r.smoothness is not None or bool(r.extra)


def followed_images(registration: Registration, spine, method: str, twist) -> tuple[Array, Array]:
    """Every registered point bent by the map's formulas continued past their conditions
    (`invalid="follow"`, the stages of a continuation; `Poser`'s `fallback`): `(images (N, 3),
    valid (N,))`. A point leaving the valid space then moves on continuously instead of
    jumping back to its rest position: the cliffs that stop a far fit are gone, and the
    stages only bring the last one's start closer (it checks validity as asked)."""
    poser = Poser(spine, method, twist, False, 0.0, registration.ends, fallback=True)
    return poser.pose_all(registration)


class Setup(eqx.Module):
    """Everything `prepare` checks and builds for a fit."""

    registration: Registration
    parameters: Parameters
    y0: tuple
    twist: Array
    regularizers: Regularizers
    method: str = eqx.field(static=True)

    def problem_fields(self, invalid: str, check_projection: bool) -> dict:
        """The keyword arguments every `AbstractPoseProblem` takes from this set-up."""
        return dict(
            parameters=self.parameters,
            registration=self.registration,
            twist=self.twist,
            regularizers=self.regularizers,
            method=self.method,
            invalid=invalid,
            check_projection=bool(check_projection),
        )


def straight_line(spine) -> Line | None:
    """The `Line` that a straight B-spline traces, or `None`: for a concrete B-spline with
    clamped knots whose control points lie in order along one line (to a few ulps of its
    length), which is then the segment from its first to its last control point (in order:
    its derivative's control points all point one way). The fit's usual rest spine: its
    registration on the line is the same to round-off (the same foot, arc length and frame)
    and compiles in a fraction of the time (closed-form feet, no tables or reach bounds)."""
    if not isinstance(spine, BSpline) or not is_concrete((spine.control_points, spine.knots)):
        return None
    dtype = spine.control_points.dtype
    p, u, d = np.asarray(spine.control_points, np.float64), np.asarray(spine.knots), spine.degree
    chord = p[-1] - p[0]
    length = float(np.linalg.norm(chord))
    if not (length > 0 and np.all(u[:d + 1] == u[0]) and np.all(u[-d - 1:] == u[-1])):
        return None
    direction = chord / length
    along = (p - p[0]) @ direction
    across = np.linalg.norm(p - p[0] - along[:, None] * direction, axis=1)
    if across.max() > 8 * np.finfo(dtype).eps * length or np.any(np.diff(along) < 0):
        return None
    return Line(np.asarray(length, dtype), origin=p[0].astype(dtype),
                tangent=direction.astype(dtype))


def prepare(
    source_spine,
    init,
    source,
    *,
    method,
    twist,
    fit_twist,
    params,
    fixed,
    length,
    smoothness,
    regularizers,
    invalid,
) -> Setup:
    """The checks and set-up shared by the fits of a posed spine (`source` already checked)."""
    check_spine(source_spine, "source_spine")
    check_spine(init, "init")
    method = check_method(method)
    length_weight, smoothness = check_options(invalid, length, smoothness)
    dtype = source.dtype
    source_spine, init = cast_floats((source_spine, init), dtype)
    parameters = make_parameters(init, params, fixed)
    twist = as_twist(twist, dtype)
    y0 = parameters.initial(twist if fit_twist else None)
    if sum(v.size for v in y0[0]) == 0 and not fit_twist:
        raise ValueError("nothing to fit: every parameter is `fixed` and `fit_twist` is False.")
    registration = register(source, straight_line(source_spine) or source_spine)
    if not bool(jnp.any(registration.valid)):
        raise ValueError("no point of `source` lies in the valid space of `source_spine`.")
    extra = () if regularizers is None else tuple(regularizers)
    regs = make_regularizers(source_spine.length, length_weight, smoothness, extra, dtype)
    return Setup(registration, parameters, y0, twist, regs, method)


@eqx.filter_jit
def solve(problem: AbstractPoseProblem, solver, y0, max_steps: int, throw: bool):
    """Runs `optimistix.least_squares` on `problem`.

    **Returns:** `(spine, twist, losses, radius, result, stats)`: `losses` the sums of squared
    residuals at `y0` and at the solution, `radius` the final trust-region size of a
    trust-region solver (else 1). The final validity check runs outside, through the public
    (jitted) `pose`, whose compilation is shared with ordinary fleshing of the same spine type.
    """
    # The residuals traced once, to a jaxpr that every later use evaluates: the solver's start
    # and step, the materialised Jacobian's forward passes (`jacobian`, under `vmap`) and the
    # two losses each traced the fleshing's Python again (5 traces of a spine fit: 1 now).
    traced = eqx.filter_closure_convert(lambda y: problem(y), y0)

    def residuals(y, args=None):
        return traced(y)

    solution = optx.least_squares(for_solver(residuals, solver), solver, y0,
                                  max_steps=max_steps, throw=throw)
    y = solution.value

    def loss(y):
        return sum(jnp.sum(r**2) for r in jax.tree.leaves(traced(y)))

    spine, twist = problem.spine_and_twist(y)
    radius = trust_radius(solver, solution, loss(y).dtype)
    return spine, twist, (loss(y0), loss(y)), radius, solution.result, solution.stats


def trust_radius(solver, solution: optx.Solution, dtype) -> Array:
    """The final trust-region size of a trust-region `solver`'s `solution`, else 1 (a line
    search's step says nothing about the local model's quality)."""
    solver, state = unbudgeted(solver, solution.state)
    search = getattr(state, "search_state", None)
    radius = getattr(search, "step_size", None)
    if radius is None or not isinstance(getattr(solver, "search", None),
                                        optx.ClassicalTrustRegion):
        return jnp.ones((), dtype)
    return radius


SPINE_ADVICE = (
    "the loss is not smooth here (points leaving the valid space, or the spine's start frame "
    "turning). Try a closer `init` (fit an `Arc` first and start the free-form spine on it), "
    "`fixed=` for the root's control points, a finer `init` (`subdivisions=`), or "
    "`smoothness=`."
)


def stall_message(losses, radius, steps, advice: str = SPINE_ADVICE) -> str:
    """Why a successful-looking solve is no minimum, with what to try (`advice`; "" when it
    is one)."""
    start, end = (float(v) for v in losses)
    if float(radius) >= COLLAPSED_TRUST_REGION or end <= MEANINGFUL_LOSS_RATIO * start:
        return ""
    return (
        f"stalled: after {int(steps)} steps the solver's trust region had shrunk to "
        f"{float(radius):.1e} with the loss only down from {start:.3e} to {end:.3e}, so this is "
        f"no minimum: {advice}"
    )


MAXIMUM_STEPS = 100_000  # a solve's `max_steps`: more is a typo, not a budget


def check_solve_options(max_steps, rtol, atol) -> tuple[int, float | None, float | None]:
    """A fit's `max_steps` (an integer in [1, `MAXIMUM_STEPS`]) and its solver's `rtol` and
    `atol` (None: from the dtype; else a number in (0, 1]), checked before any work: a
    `TypeError`/`ValueError` naming the argument (`max_steps=1.7` was truncated, `"a"` raised
    int's own error, and `rtol=nan` stopped no solve)."""
    max_steps = check_number(max_steps, "max_steps", 1, MAXIMUM_STEPS, integer=True)
    rtol, atol = (None if t is None else check_number(t, name, 0, 1, above=True)
                  for t, name in ((rtol, "rtol"), (atol, "atol")))
    return max_steps, rtol, atol


def check_tolerance(tolerance) -> float:
    """`tolerance=` of a fit: a finite number > 0, or `None` (no residual test: `inf`)."""
    if tolerance is None:
        return np.inf
    value = float(tolerance)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"`tolerance` must be a finite number > 0 or None, got {tolerance!r}.")
    return value


def fit(
    problem: AbstractPoseProblem,
    solver,
    y0,
    max_steps: int,
    throw: bool,
    tolerance: float,
    advice: str,
) -> FitResult:
    """Solves `problem` and reports the fit, validity checked with the full projection test.

    A solve that optimistix calls successful but that stalled (`stall_message`), or that
    stopped with its rms above `tolerance` times the targets' diagonal (`explain`, with
    `advice` at a local minimum), is reported as not converged."""
    # (The steps a budget, under one static limit: `max_steps=3` runs the default's program.)
    budget, limit = limited(solver, max_steps)
    spine, twist, losses, radius, result, stats = solve(problem, budget, y0, limit, bool(throw))
    successful = bool(result == optx.RESULTS.successful)
    out = FitResult(
        spine=spine,
        twist=twist,
        rms=jnp.zeros((), twist.dtype),  # set by `explain`
        valid=jnp.ones(problem.registration.points.shape[0], bool),
        result=result,
        num_steps=stats["num_steps"],
        loss=losses[1],
        stats=stats,
        stalled=stall_message(losses, radius, stats["num_steps"]) if successful else "",
    )
    return explain(problem, out, tolerance, advice)


def explain(
    problem: AbstractPoseProblem,
    out: FitResult,
    tolerance: float,
    advice: str,
    same_from_elsewhere: bool | None = None,
) -> FitResult:
    """`out` with its `rms`, `valid`, `tolerance` and `unexplained` from posing `problem`'s
    source on its spine (the full projection test): `verdict.verdict`, told whether a fit from
    another start ended at the same rms (`same_from_elsewhere`; `None`: not known)."""
    images, valid = pose(problem.registration, out.spine, method=problem.method, twist=out.twist)
    rms = problem.rms(images, valid)
    scale = verdict.diagonal(problem.data())
    bound = tolerance * scale
    unexplained = ""
    if out.stalled and float(rms) <= bound:
        # Stopped where the data are explained: a stall there is the solver starting at (or
        # reaching) the best the spine can do, its steps rejected for round-off, not a cliff.
        out = dataclasses.replace(out, stalled="")
    if bool(out.result == optx.RESULTS.nonlinear_max_steps_reached) and float(rms) <= bound:
        unexplained = (  # not converged (the solver had not stopped), but say it is close
            f"{optx.RESULTS[out.result]} The rms {float(rms):.3g} is already within the "
            f"tolerance ({float(rms) / scale:.1e} of the targets' diagonal): raise `max_steps=` "
            "or loosen `rtol=`/`atol=` for the solver to stop there."
        )
    if bool(out.result == optx.RESULTS.successful) and not out.stalled:
        distances, weights = problem.distances(images, valid)
        unexplained = verdict.verdict(
            rms, distances, weights, valid, bound, scale=scale, advice=advice,
            regularized=problem.regularized, same_from_elsewhere=same_from_elsewhere,
        )
    return dataclasses.replace(
        out, rms=rms, valid=valid, tolerance=jnp.asarray(bound, rms.dtype),
        unexplained=unexplained,
    )

"""A start from the target's own shape: a free-form spine's control points fitted, by linear
least squares, to where the targets say the bent spine runs.

A fit from the rest spine onto a far bend (60–90°) starts far from its answer: on the way,
points leave the valid space or the spine folds to meet the far end first, and the solve stops
at a local minimum or runs out of steps. The targets themselves say where the bent spine runs.
Every map bends one cross-section at a time (a point keeps its arc length `sᵢ`): its target is
`yᵢ = C₁(sᵢ) + R₁(sᵢ) dᵢ′`, with `dᵢ′` its rest offset `dᵢ = xᵢ − C₀(sᵢ)` carried by the
frames and changed by the bend only to second order (`O(κ |dᵢ|²)`). Around each of `M`
stations along `C₀`, the weighted best rigid motion of the nearby points onto their targets
(`continuation.rigid_motion`, Gaussian weights in arc length, about a control-point spacing
wide) gives the rotation `Rⱼ`; each point then says where the bent spine runs at its foot,

    ĉᵢ = yᵢ − Rⱼ₍ᵢ₎ dᵢ,

to within `O(|dᵢ|)` of the rotation's error and the bend's change: points near the axis say it
best, so each counts with weight `wᵢ / (|dᵢ|² + r₀²)` (`r₀`: `AXIS_SCALE` of the length). Legs
or a tail off the axis still fix the rotations, so they do not bias it (a centroid would). A
B-spline is linear in its control points, `C(t) = Σₖ Nₖ(t) Pₖ`: with `tᵢ` the parameter of
`init` at the same fraction of its length, the free control points solve the linear least
squares `min Σᵢ ωᵢ |Σₖ Nₖ(tᵢ) Pₖ − ĉᵢ|²`, fixed ones held, with a tiny ridge towards `init` moved
by the global rigid motion (for control points no point sees).

A second start smooths the first: the same spine's control points on the circular arc
closest to it (`arc`). The first is only as good as each station's rotation; its wiggles can
hold the solve in a local minimum that a smooth start of the same overall bend avoids (the
insect's body bent 90°: 0.11 of the diagonal from the first, 5e-6 in 17 steps from its arc).
A third skips the spline: the circular arc closest to the points `ĉᵢ` themselves, weighted
`ωᵢ` (`initial(..., circular=True)`). Where they scatter (the insect's body, 200 points), the
first start's spline follows the scatter (its length 2.77 for 1.70, its arc's radius 0.51 for
1.08) but their weighted circle does not (1.077; the source posed on it 1.1e-3 of the
diagonal from the targets).

Host-side (NumPy, one evaluation of `C₀` at the feet): it runs once, and only starts the solve.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._fleshing.pipeline import pose
from .._fleshing.projection import Registration
from .._spines.bspline import BSpline, _de_boor
from .continuation import rigid_motion
from .problem import Fields, Parameters

STATIONS_PER_CONTROL_POINT = 3  # rotations estimated along the rest spine
AXIS_SCALE = 1e-2  # r₀ / length: below this distance from the axis, points count alike
RIDGE = 1e-8  # relative weight of the pull towards `init` moved rigidly (unseen control points)
PARAMETER_SAMPLES = 64  # per knot span, for the parameter at a given arc length


def applies(parameters: Parameters) -> bool:
    """Whether a fit of `parameters` can start from the targets: its initial spine a concrete
    `BSpline` whose fitted leaves are exactly its control points."""
    init = parameters.base
    return (
        isinstance(init, BSpline)
        and isinstance(parameters.where, Fields)
        and parameters.where.names == ("control_points",)
        and not isinstance(init.control_points, jax.core.Tracer)
    )


def spine_points(arc_length, points, target, weights, feet, length: float, count: int) -> tuple:
    """Where the targets say the bent spine runs at each point's foot (module docstring).

    **Arguments:**

    - `arc_length`: (N,) each source point's arc length `sᵢ` on the rest spine `C₀`.
    - `points`, `target`: (N, 3) the source points and their targets.
    - `weights`: (N,) non-negative (0: not counted, e.g. invalid or padding).
    - `feet`: (N, 3) `C₀(sᵢ)`.
    - `length`: the length of `C₀`; `count`: how many stations (rotations) along it.

    **Returns:** `(ĉ, ω, motions)`: (N, 3) the bent spine's estimated points at the feet, (N,)
    their weights (0 where the point is not counted or no rotation could be estimated near
    it), and each station's rigid motion `(c, c′, R)` (`None` where none was estimated).
    """
    s = np.asarray(arc_length, np.float64)
    w = np.asarray(weights, np.float64)
    x, y = np.asarray(points, np.float64), np.asarray(target, np.float64)
    stations = (np.arange(count) + 0.5) * (length / count)
    width = STATIONS_PER_CONTROL_POINT * length / count
    nearest = np.clip(np.floor(s / length * count).astype(int), 0, count - 1)
    offsets = x - np.asarray(feet, np.float64)
    centre = np.zeros_like(x)
    seen = np.zeros(len(s), bool)
    motions = [None] * count
    for j, station in enumerate(stations):
        here = (nearest == j) & (w > 0)
        g = w * np.exp(-0.5 * ((s - station) / width) ** 2)
        if not here.any() or np.count_nonzero(g > 1e-6 * g.max(initial=0.0)) < 3:
            continue
        motions[j] = rigid_motion(x, y, g)
        centre[here] = y[here] - offsets[here] @ motions[j][2].T
        seen |= here
    r0 = AXIS_SCALE * length
    omega = np.where(seen, w / (np.sum(offsets**2, axis=-1) + r0**2), 0.0)
    return centre, omega, motions


def continued(motions, rest, shortest: int = STATIONS_PER_CONTROL_POINT) -> np.ndarray:
    """Where the bent spine runs at the stations past either end of those the points say it
    (a tail's rest spine started inside the rump, whose points are no targets): `C₀` there
    (`rest`, (M, 3) at the M stations) moved by the rigid motion of the last estimated station
    before them (`motions`, as `spine_points` returns them). (M, 3), NaN rows elsewhere and
    for an unseen end shorter than `shortest` stations (a control point's spacing: the seen
    stations' spline holds it, as within a gap between seen ones).

    Without them, the control points there were the seen stretch's polynomial extrapolated
    (spot's tail bent 90°: the first half of its spine unseen, the start 1.2 of the
    diagonal from the targets, farther than the rest spine's 0.41); such a stretch only has
    to keep its length and meet the seen one's start and direction."""
    known = np.flatnonzero([m is not None for m in motions])
    out = np.full_like(np.asarray(rest, np.float64), np.nan)
    if len(known) == 0:
        return out
    ends = (
        (np.arange(known[0]), known[0]),
        (np.arange(known[-1] + 1, len(motions)), known[-1]),
    )
    for unseen, edge in ends:
        if len(unseen) >= shortest:
            c, c_, r = motions[edge]
            out[unseen] = c_ + (rest[unseen] - c) @ r.T
    return out


def parameters_at(spline: BSpline, fractions) -> np.ndarray:
    """The parameters `t` (M,) of a concrete `spline` at the given fractions (M,) of its
    length (from its chords, `PARAMETER_SAMPLES` per knot span)."""
    u = np.asarray(spline.knots, np.float64)
    p = np.asarray(spline.control_points, np.float64)
    lo, hi = u[spline.degree], u[len(p)]
    grid = np.linspace(lo, hi, PARAMETER_SAMPLES * len(spline.spans) + 1)
    chords = np.linalg.norm(np.diff(_de_boor(p, u, spline.degree, grid), axis=0), axis=-1)
    along = np.concatenate([[0.0], np.cumsum(chords)])
    return np.interp(np.asarray(fractions) * along[-1], along, grid)


def control_points(init: BSpline, free, q, omega, fractions, prior) -> np.ndarray:
    """The control points (n, 3) of `init`'s shape closest to points `q` (M, 3) with weights
    `omega` (M,) at `fractions` (M,) of its length; the entries outside `free` (flat indices
    into the (n, 3) array) held at `init`'s values; `prior` (n, 3): where the free ones are
    pulled, weakly (`RIDGE`), so that the system is never singular."""
    return control_points_at(init, free, q, omega, parameters_at(init, fractions), prior)


def control_points_at(init: BSpline, free, q, omega, t, prior) -> np.ndarray:
    """`control_points` with the points `q` (M, 3) at the parameters `t` (M,) of the spline
    (instead of at fractions of `init`'s length, which carry `init`'s speed)."""
    p0 = np.asarray(init.control_points, np.float64)
    n = len(p0)
    basis = _de_boor(np.eye(n), np.asarray(init.knots, np.float64), init.degree, t)  # (M, n)
    a = np.kron(basis, np.eye(3))  # rows (M·3) of the flattened points, columns (n·3)
    root = np.sqrt(np.repeat(omega, 3))
    free = np.asarray(free)
    held = np.setdiff1d(np.arange(3 * n), free)
    rhs = root * (q.reshape(-1) - a[:, held] @ p0.reshape(-1)[held])
    lhs = root[:, None] * a[:, free]
    ridge = RIDGE * max(float(np.sum(lhs**2)) / max(len(free), 1), 1e-300)
    normal = lhs.T @ lhs + ridge * np.eye(len(free))
    solution = np.linalg.solve(normal, lhs.T @ rhs + ridge * prior.reshape(-1)[free])
    out = p0.reshape(-1).copy()
    out[free] = solution
    return out.reshape(n, 3)


def from_targets(init: BSpline, free, arc_length, source_spine, points, target, weights,
                 circular: bool = False):
    """`init`'s control points (n, 3) moved onto where the targets say the bent spine runs
    (module docstring; at the stations no point says it, `continued`), or with `circular`
    onto the circular arc closest to those points (`through_circle`); `None` when too few
    points say it (or, `circular`, when they lie on a line).

    **Arguments:**

    - `init`: a concrete `BSpline`, the fit's initial spine (its knots and degree are kept).
    - `free`: flat indices of the free entries of its (n, 3) control points.
    - `arc_length`: (N,) the source points' arc lengths on the rest spine `C₀` (their
      registration); `source_spine`: `C₀`.
    - `points`, `target`: (N, 3); `weights`: (N,) (0 for invalid points and padding).
    """
    n = init.control_points.shape[0]
    length = float(source_spine.length)
    count = STATIONS_PER_CONTROL_POINT * n
    at = (np.arange(count) + 0.5) / count  # the stations, as fractions of the length
    # `C₀` at the feet and at the stations, in one eager evaluation.
    stations = jnp.asarray(at * length, arc_length.dtype)
    on_rest = np.asarray(jax.vmap(source_spine)(jnp.concatenate([arc_length, stations])))
    feet, rest = on_rest[: len(arc_length)], on_rest[len(arc_length) :]
    centre, omega, motions = spine_points(arc_length, points, target, weights, feet, length, count)
    if np.count_nonzero(omega) < init.degree + 1:
        return None
    fractions = np.clip(np.asarray(arc_length, np.float64) / length, 0.0, 1.0)
    c, c_, r = rigid_motion(points, target, weights)
    prior = c_ + (np.asarray(init.control_points, np.float64) - c) @ r.T
    if circular:
        seen = omega > 0
        return through_circle(init, free, centre[seen], fractions[seen], omega[seen], prior)
    # The unseen stations count as much as a typical seen point (the median's weight).
    unseen = continued(motions, rest)
    filled = np.isfinite(unseen[:, 0])
    typical = np.median(omega[omega > 0])
    centre = np.concatenate([centre, unseen[filled]])
    omega = np.concatenate([omega, np.full(np.count_nonzero(filled), typical)])
    fractions = np.concatenate([fractions, at[filled]])
    return control_points(init, free, centre, omega, fractions, prior)


def initial(parameters: Parameters, registration: Registration, source_spine, target, weights,
            twist, circular: bool = False):
    """The optimiser's start `y` (as `Parameters.initial`) with the control points of
    `parameters.base` moved onto where the (N, 3) `target` says the bent spine runs (with
    `circular`, onto the circular arc closest to that), the (N,) `weights` counted over the
    points valid on the rest spine `source_spine` and `twist` (or `None`) kept; `None` when
    this does not apply (`applies`) or too few points say it."""
    if not applies(parameters):
        return None
    init = parameters.base
    counted = np.where(np.asarray(registration.valid), np.asarray(weights, np.float64), 0.0)
    points = from_targets(init, np.asarray(parameters.free[0]), registration.arc_length,
                          source_spine, registration.points, target, counted, circular)
    if points is None or not np.isfinite(points).all():
        return None
    dtype = init.control_points.dtype
    spine = eqx.tree_at(lambda s: s.control_points, init, jnp.asarray(points, dtype))
    return parameters.of(spine, twist)


def turned(problem, y, target, weights):
    """The optimiser's start `y` (as `Parameters.initial`) with its twist turned to the one
    that best rolls the source, posed on `y`'s spine, onto the (N, 3) `target` ((N,)
    `weights`); `y` itself when the twist is not fitted (`y[1] is None`), `y` is `None`, or
    no valid point says it.

    The start from the targets' shape bends the spine where the targets say, but keeps the
    twist it was given: a twisted target then starts a full twist away (the biped's arm bent
    90° and twisted 0.5: 2.5e-2 of the diagonal at twist 0, 3e-3 at 0.5; the solve stopped at
    a local minimum from the first). The twist rolls each cross-section about the bent
    spine's tangent `Tᵢ` at its image's foot `fᵢ = C₁(λ sᵢ)` (`λ = L₁/L₀`), so from the
    images `pᵢ` at the start's twist, the roll that brings them closest to their targets
    `yᵢ`, `min_θ Σ wᵢ |rot(Tᵢ, θ) pᵢ⊥ − yᵢ⊥|²` over the parts across the tangents
    (`·⊥`, about `fᵢ`), is `θ = atan2(Σ wᵢ Tᵢ · (pᵢ⊥ × yᵢ⊥), Σ wᵢ pᵢ⊥ · yᵢ⊥)`, added to it."""
    if y is None or y[1] is None:
        return y
    spine, twist = problem.spine_and_twist(y)
    images, valid = pose(problem.registration, spine, method=problem.method, twist=twist)
    reg = problem.registration
    s1 = spine.length / reg.length * reg.arc_length
    feet = np.asarray(jax.vmap(spine)(s1), np.float64)
    tangents = np.asarray(jax.vmap(jax.jacfwd(spine))(s1), np.float64)
    tangents = tangents / np.linalg.norm(tangents, axis=-1, keepdims=True)

    def across(points):
        d = np.asarray(points, np.float64) - feet
        return d - np.sum(d * tangents, axis=-1, keepdims=True) * tangents

    p, q = across(images), across(target)
    w = np.where(np.asarray(valid), np.asarray(weights, np.float64), 0.0)
    sine = np.sum(w * np.sum(tangents * np.cross(p, q), axis=-1))
    cosine = np.sum(w * np.sum(p * q, axis=-1))
    if not (np.isfinite(sine) and np.isfinite(cosine)) or sine == cosine == 0:
        return y
    return y[0], (twist + np.arctan2(sine, cosine)).astype(twist.dtype)


def closer(problem, *starts):
    """Of the optimiser's `starts` (`y`s of `problem`, an `AbstractPoseProblem`; `None`s
    skipped), the one whose posed source is closest to the data (its `rms`, every point
    checked as in the final report): the first on a tie."""
    best, low = None, np.inf
    for y in starts:
        if y is None:
            continue
        spine, twist = problem.spine_and_twist(y)
        images, valid = pose(problem.registration, spine, method=problem.method, twist=twist)
        rms = float(problem.rms(images, valid))
        if best is None or rms < low:
            best, low = y, rms
    return best


ARC_SAMPLES = 64  # points of a start's spine that its circle is fitted to


def circle(points, weights=None) -> tuple:
    """The circle best through `points` (M, 3), M ≥ 3, with optional `weights` (M,) (default
    equal): `(centre (3,), radius, e₁ (3,), e₂ (3,))`, `e₁, e₂` an orthonormal basis of its
    plane (the points' best plane); `None` when the points lie on a line (no circle, or one
    too large to tell)."""
    p = np.asarray(points, np.float64)
    w = np.ones(len(p)) if weights is None else np.asarray(weights, np.float64)
    mean = (w[:, None] * p).sum(0) / w.sum()
    root = np.sqrt(w)[:, None]
    _, sigma, vt = np.linalg.svd(root * (p - mean))
    if not sigma[1] > 1e-6 * sigma[0]:
        return None
    e1, e2 = vt[0], vt[1]
    u, v = (p - mean) @ e1, (p - mean) @ e2
    # Algebraic fit (Kåsa): u² + v² = 2a u + 2b v + c, linear in (a, b, c).
    a, b, c = np.linalg.lstsq(root * np.c_[2 * u, 2 * v, np.ones_like(u)],
                              root[:, 0] * (u**2 + v**2), rcond=None)[0]
    radius2 = c + a**2 + b**2
    if not (np.isfinite(radius2) and radius2 > 0):
        return None
    return mean + a * e1 + b * e2, float(np.sqrt(radius2)), e1, e2


def on_arc(init: BSpline, free, spine: BSpline):
    """The control points (n, 3) of `init`'s shape on the circular arc closest to `spine` (a
    concrete `BSpline`, e.g. the start from the targets' shape), its free entries (flat
    indices `free` into the (n, 3) array) fitted to the arc at the fractions of its length
    where `spine` has its samples, the others held; `None` when `spine` is straight.

    A second start for a far bend: the start from the targets is only as good as each
    station's rotation, and its wiggles can put the solve in a local minimum that a smooth
    start of the same overall bend avoids (the insect's body bent 90°)."""
    u = np.asarray(spine.knots, np.float64)
    p = np.asarray(spine.control_points, np.float64)
    grid = np.linspace(u[spine.degree], u[len(p)], PARAMETER_SAMPLES * len(spine.spans) + 1)
    dense = _de_boor(p, u, spine.degree, grid)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=-1))])
    fractions = np.linspace(0.0, 1.0, ARC_SAMPLES)
    samples = np.stack([np.interp(fractions * along[-1], along, dense[:, k]) for k in range(3)],
                       -1)
    return through_circle(init, free, samples, fractions, np.ones(ARC_SAMPLES), p)


def through_circle(init: BSpline, free, samples, fractions, weights, prior):
    """The control points (n, 3) of `init`'s shape on the circular arc closest to `samples`
    (M, 3) at `fractions` (M,) of the length with `weights` (M,): the circle best through them
    (`circle`), the angle along it linear in the fraction, its free entries (flat indices
    `free`) fitted to `ARC_SAMPLES` points of it, the others held (`prior` (n, 3): the weak
    pull of `control_points`); `None` when the samples lie on a line."""
    fitted = circle(samples, weights)
    if fitted is None:
        return None
    centre, radius, e1, e2 = fitted
    order = np.argsort(fractions, kind="stable")
    along, w = np.asarray(fractions, np.float64)[order], np.asarray(weights, np.float64)[order]
    d = np.asarray(samples, np.float64)[order] - centre
    angle = np.unwrap(np.arctan2(d @ e2, d @ e1))
    # The angle along the arc, linear in the fraction of length (a circle at constant speed).
    slope, offset = np.polyfit(along, angle, 1, w=np.sqrt(w))
    fractions = np.linspace(0.0, 1.0, ARC_SAMPLES)
    theta = offset + slope * fractions
    q = centre + radius * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2)
    # The circle at `init`'s speed (its parameters at those fractions of its length), or at
    # constant speed (parameters even in the fraction), whichever follows it closer. A curved
    # rest spine's speed (the insect's body from `rest_spine`: its curvature up to 27) forced
    # onto a circle ripples the fitted curvature ±20 %: enough to put the images of the legs
    # bent 90° (1 − k·d = 0.19) past the focal set (the true bend put so: 9 of 200 points
    # invalid, 3e-2 of the diagonal); at constant speed the same 16 control points follow
    # the arc to 3e-10 (1.7e-8 of the diagonal, none invalid).
    # (Fixed control points keep `init`'s speed at the root: there `init`'s may follow closer.)
    ones = np.ones(ARC_SAMPLES)
    lo, hi = np.asarray(init.knots)[[init.degree, len(init.control_points)]]
    candidates = [
        control_points_at(init, free, q, ones, t, prior)
        for t in (parameters_at(init, fractions), lo + fractions * (hi - lo))
    ]
    return min(candidates, key=lambda c: _off_circle(init, c, centre, radius, e1, e2))


def _off_circle(init: BSpline, points, centre, radius: float, e1, e2) -> float:
    """The largest distance from the spline of `init`'s knots on control `points` (n, 3) to
    the circle (`centre`, `radius`, in the plane of `e1`, `e2`), over `PARAMETER_SAMPLES`
    points a knot span."""
    u = np.asarray(init.knots, np.float64)
    grid = np.linspace(u[init.degree], u[len(points)], PARAMETER_SAMPLES * len(init.spans) + 1)
    d = _de_boor(np.asarray(points, np.float64), u, init.degree, grid) - centre
    return float(np.hypot(np.hypot(d @ e1, d @ e2) - radius, d @ np.cross(e1, e2)).max())


def arc(parameters: Parameters, y):
    """The optimiser's start `y` (as `Parameters.initial`, e.g. from `initial`) with the
    control points of its spine moved onto the circular arc closest to it (`on_arc`), the
    twist kept; `None` when `y` is `None` or its spine is straight."""
    if y is None:
        return None
    spine = parameters.spine(y)
    points = on_arc(parameters.base, np.asarray(parameters.free[0]), spine)
    if points is None or not np.isfinite(points).all():
        return None
    dtype = spine.control_points.dtype
    return parameters.of(eqx.tree_at(lambda s: s.control_points, spine,
                                     jnp.asarray(points, dtype)), y[1])

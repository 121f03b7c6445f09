"""Whether a fit explains its data: the residual test behind every spine fit's `converged`.

A solver's own test says only that the loss stopped decreasing. That is also true at a local
minimum far from the data, at a target no spine of the fitted type can reach, and where a few
targets could never be reached (points outside the valid space, outliers). A fit therefore
counts as converged only when, besides that, its rms distance is at the level the data allows:
at most `tolerance` times the targets' bounding-box diagonal (default `TOLERANCE`; noisy targets
need a looser one: about their noise's rms). When it is not, `verdict` says which of these it
most likely is and what to try, from the per-point distances at the end of the fit:

- **invalid targets**: the rms over the points that map validly onto the fitted spine, or over
  all but the worst few percent (outliers), is within the tolerance: the others' targets
  cannot be reached;
- **unreachable target**: the fit stopped at the same rms from the rest spine and from a
  continuation (`fit_spine(..., continuation=...)`): two different paths ending at one residual,
  most likely the best this spine's parameters can do;
- **local minimum**: otherwise.

Host-side (NumPy) arithmetic on a finished fit: nothing here is traced.
"""

from __future__ import annotations

import numpy as np

TOLERANCE = 1e-3  # rms as a fraction of the targets' bounding-box diagonal
OUTLIER_SHARE = 0.05  # "a few targets": at most this share of the points (by weight)
# Two fits that end within this ratio of each other's rms stopped at the same residual.
SAME_RESIDUAL = 1.5


def diagonal(points) -> float:
    """The length of the bounding-box diagonal of (N, 3) `points`."""
    points = np.asarray(points, np.float64)
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def _rms(distances, weights) -> float:
    total = weights.sum()
    return float(np.sqrt((weights * distances**2).sum() / total)) if total > 0 else np.nan


def verdict(
    rms: float,
    distances,
    weights,
    valid,
    bound: float,
    *,
    scale: float,
    advice: str,
    regularized: bool = False,
    same_from_elsewhere: bool | None = None,
) -> str:
    """Why a fit whose solver succeeded does not explain its data ("" when it does).

    **Arguments:**

    - `rms`: the fit's reported rms.
    - `distances`: (N,) each point's distance to its target at the end of the fit (for a fit
      without correspondences, to its nearest target).
    - `weights`: (N,) the points' weights (0 for padding).
    - `valid`: (N,) whether each point maps validly onto the fitted spine.
    - `bound`: the rms the data allows (absolute; `inf` or NaN: no residual test).
    - `scale`: the targets' diagonal, to state the rms relative to it.
    - `advice`: what to try at a local minimum (the fit's own options).
    - `regularized`: whether regularisers (smoothness, a length penalty, extra terms) were on:
      they may hold the fit away from the data on purpose.
    - `same_from_elsewhere`: whether a second fit from another start stopped at the same rms
      (`None`: there was none).
    """
    d = np.asarray(distances, np.float64)
    w = np.asarray(weights, np.float64)
    valid = np.asarray(valid, bool)
    rms = float(rms)
    if not np.isfinite(bound) or rms <= bound:
        return ""
    stated = (
        f"rms {rms:.3g} ({rms / scale:.2e} of the targets' diagonal) above the tolerance "
        f"{bound:.3g} ({bound / scale:.1e} of it)"
    )
    invalid = (~valid) & (w > 0)
    if invalid.any() and _rms(d, np.where(valid, w, 0)) <= bound:
        return (
            f"invalid targets: {stated}, but within it over the points that map validly: "
            f"{int(invalid.sum())} source points fall outside the valid space of the fitted "
            "spine and their targets cannot be reached (they count as unmoved). Leave them "
            "out (`invalid=\"exclude\"`, or weight 0 in `weights=`), or check that the "
            "targets came from valid points (`flesh`'s `valid`)."
        )
    order = np.argsort(-np.where(w > 0, d, -np.inf))
    worst = np.cumsum(w[order]) <= OUTLIER_SHARE * w.sum()
    if worst.any():
        kept = w.copy()
        kept[order[worst]] = 0
        if _rms(d, kept) <= bound:
            return (
                f"invalid targets: {stated}, but within it without the {int(worst.sum())} "
                f"farthest targets (up to {d[order[0]]:.3g} away): outliers the others' fit "
                "does not explain. Weight them 0 (`weights=`) or fix them."
            )
    held = (
        " The regularisers (smoothness, length, extra terms) may hold the fit there: if "
        "that trade is intended, pass a looser `tolerance=` (or `tolerance=None`)."
        if regularized
        else ""
    )
    noisy = (
        " If the targets are noisy, pass `tolerance=` about their noise's rms over the "
        "diagonal."
    )
    if same_from_elsewhere:
        return (
            f"unreachable target: {stated}, the same from the rest spine and from a "
            "continuation, so most likely the best this spine can do (else a local minimum "
            "both starts share): give it more freedom (more control points or "
            "`subdivisions`, `fit_twist=True`, `length=\"free\"`, fewer `fixed` entries), "
            f"start closer, or check the targets.{held}{noisy}"
        )
    return f"local minimum: {stated}: {advice}{held}{noisy}"

"""Continuation: a far target reached in stages, each fit started from the one before.

A fit from the rest spine straight onto a strongly bent target can stop at a local minimum: on
the way, points leave the valid space of the spine being fitted (and count as unmoved), or the
spine folds to meet the far end first. Staged targets keep every fit close to its start: stage
`k` of `n` moves each source point a fraction `t = k/n` of the way to its target,

    yᵢ(t) = c + t (c′ − c) + Rᵗ (xᵢ − c) + t (yᵢ − (c′ + R (xᵢ − c))),

the best rigid motion `x ↦ c′ + R (x − c)` of the source onto the target (weighted Kabsch)
followed a fraction `t` of its rotation angle and translation, plus that fraction of what is
left (the bend). The stages in between need not be reachable exactly (a linear blend of a bend
is not a bend); each only brings the next start closer. The last stage is the target itself.
`fit_spine` solves each stage with every point posed by the map's formula, valid or not
(`problem.followed_images`), then the target as asked from there.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

AUTO_STAGES = 4  # `continuation="auto"`: the stages of the retry after a local minimum


def rigid_motion(source, target, weights):
    """The weighted least-squares rigid motion of `source` (N, 3) onto `target`:
    `(c, c′, R)` with `target ≈ c′ + (source − c) Rᵀ`."""
    w = np.asarray(weights, np.float64)[:, None]
    x, y = np.asarray(source, np.float64), np.asarray(target, np.float64)
    c, c_ = (w * x).sum(0) / w.sum(), (w * y).sum(0) / w.sum()
    u, _, vt = np.linalg.svd(((x - c) * w).T @ (y - c_))
    d = np.sign(np.linalg.det(u @ vt))  # a rotation, never a reflection
    return c, c_, (u @ np.diag([1.0, 1.0, d]) @ vt).T


def staged_targets(source, target, weights, stages: int) -> list[np.ndarray]:
    """The `stages` targets (N, 3) of a continuation from `source` to `target` (see the module
    docstring), in the dtype of `target`; the last is `target` itself."""
    c, c_, r = rigid_motion(source, target, weights)
    x = np.asarray(source, np.float64)
    rest = np.asarray(target, np.float64) - (c_ + (x - c) @ r.T)
    turn = Rotation.from_matrix(r).as_rotvec()
    out = []
    for k in range(1, stages):
        t = k / stages
        rt = Rotation.from_rotvec(t * turn).as_matrix()
        out.append((c + t * (c_ - c) + (x - c) @ rt.T + t * rest).astype(target.dtype))
    return [*out, np.asarray(target)]

"""How well the data determine a least-squares fit's parameters: their standard errors.

A fit can explain its data (every residual at the data's level) and still be wrong where the
data hardly depend on a parameter: a short, thick limb bent 15° too little moves its part of a
scan by a fraction of the samples' spacing, and a sampled objective's minimum may then lie
anywhere in that flat valley. The residuals alone cannot tell; their slope can. At the solution
`y` of residuals `r(y)` (n,) with Jacobian `J` (n, p), the sandwich estimate of the parameters'
covariance,

    C = (JᵀJ)⁻¹ Jᵀ diag(r²) J (JᵀJ)⁻¹,

takes the data's level from the residuals themselves (no noise level to guess, no assumption
that the residuals share one scale). A parameter whose standard error `√C_ii` is large is not
determined by the data, whatever the fit's residual. Host-side NumPy on a finished fit.
"""

from __future__ import annotations

import numpy as np

# Relative floor of JᵀJ's eigenvalues (to its largest): a parameter the residuals do not depend
# on at all (a limb the target does not see) gets an enormous standard error, not zero.
FLOOR = 1e-14


def covariance(jacobian, residuals, group: int = 1) -> np.ndarray:
    """The sandwich covariance (p, p) of the parameters (module docstring) from the Jacobian
    `jacobian` (n, p) and the residuals `residuals` (n,) at the solution. With `group` > 1 the
    rows come in consecutive groups of that many, the components of one point's residual
    vector, which share that point's noise: the meat sums each group's score `Σ rᵢ Jᵢ` (p,)
    squared (`diag(r²)` counted a point-to-surface residual, whose 3 components all follow its
    one distance along the normal, as independent draws: up to √3 too narrow)."""
    j = np.asarray(jacobian, np.float64)
    r = np.asarray(residuals, np.float64).reshape(-1)
    if j.ndim != 2 or j.shape[0] != r.shape[0]:
        raise ValueError(f"`jacobian` must have shape (n, p) with n = {r.shape[0]}, the "
                         f"residuals' count, got {j.shape}.")
    if group < 1 or len(r) % group:
        raise ValueError(f"`group` must be a positive divisor of the residuals' count "
                         f"{len(r)}, got {group}.")
    normal = j.T @ j
    values, vectors = np.linalg.eigh(normal)
    floor = FLOOR * max(float(values.max()), np.finfo(np.float64).tiny)
    inverse = (vectors / np.maximum(values, floor)) @ vectors.T
    scores = (j * r[:, None]).reshape(-1, group, j.shape[1]).sum(axis=1)
    meat = scores.T @ scores
    # The sandwich is 0 along a direction the residuals do not depend on (its meat is 0 too):
    # there the classical estimate `s² (JᵀJ)⁻¹`, at the floor, stands in (enormous).
    null = vectors[:, values < floor]
    level = float(np.sum(r**2)) / max(len(r) - j.shape[1], 1)
    return inverse @ meat @ inverse + (level / floor) * (null @ null.T)


def block_spread(cov: np.ndarray, blocks) -> np.ndarray:
    """For each block of parameter indices in `blocks` (a sequence of index lists), the
    standard error along the block's worst-determined direction: `√λ_max` of its covariance
    sub-block. (B,)"""
    cov = np.asarray(cov, np.float64)
    return np.array([np.sqrt(max(float(np.linalg.eigvalsh(cov[np.ix_(b, b)]).max()), 0.0))
                     for b in blocks])

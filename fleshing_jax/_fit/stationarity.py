"""Whether a least-squares fit stopped at a stationary point of its own loss: the Gauss–Newton
step there.

A solver's own stopping test (optimistix's Cauchy test: a small step *and* a small change in
the residuals) also passes where the steps have shrunk to nothing short of a minimum (a trust
region that shrank after steps rejected on a piecewise-smooth loss, or tolerances too loose),
and a residual test cannot tell: a fit explains its data as soon as its residuals are at the
data's level, and a short limb's bend can lie a degree off before its samples move by a
quarter of the vertex spacing (spot's clean shape fit, a leg 0.74° off, explained the sample as
well as the truth). The slope at the solution can: with residuals `r` (n,) and Jacobian `J`
(n, p) there, the Gauss–Newton step `δ = −(JᵀJ)⁺ Jᵀ r` is where the local linear model puts the
minimum, and `‖J δ‖²` the decrease of the loss `‖r‖²` it predicts. At a minimum both vanish
(`Jᵀ r = 0`). A fit stopped short has both: a step of its own size, and a decrease that is a
noticeable part of its loss. Either alone is not enough: at a noisy fit's minimum the loss is
only piecewise smooth (the nearest points change with `y`), and a loosely determined direction
turns a tiny kink of its slope into a sizeable step that predicts next to nothing; a clean
fit's loss is round-off, whose predicted relative decrease is arbitrary. Host-side NumPy on a
finished fit's `(J, r)` (the solver's last linearisation: no new program).
"""

from __future__ import annotations

import numpy as np

from .uncertainty import FLOOR


def gauss_newton_step(jacobian, residuals) -> tuple[np.ndarray, float]:
    """The Gauss–Newton step `δ` (p,) at a solution with Jacobian `jacobian` (n, p) and
    residuals `residuals` (n,), and the decrease of the loss `‖r‖²` it predicts, `‖J δ‖²`, as
    a fraction of the loss (0 for a zero loss). A direction the residuals do not depend on (an
    eigenvalue of `JᵀJ` under `FLOOR` of its largest: a limb the data do not show) takes no
    step."""
    j = np.asarray(jacobian, np.float64)
    r = np.asarray(residuals, np.float64).reshape(-1)
    if j.ndim != 2 or j.shape[0] != r.shape[0]:
        raise ValueError(f"`jacobian` must have shape (n, p) with n = {r.shape[0]}, the "
                         f"residuals' count, got {j.shape}.")
    values, vectors = np.linalg.eigh(j.T @ j)
    kept = values > FLOOR * max(float(values.max(initial=0.0)), np.finfo(np.float64).tiny)
    slope = vectors[:, kept].T @ (j.T @ r)  # the gradient in `JᵀJ`'s eigenvectors (over 2)
    step = -vectors[:, kept] @ (slope / values[kept])
    loss = float(r @ r)
    return step, (float(np.sum(slope**2 / values[kept])) / loss if loss > 0 else 0.0)

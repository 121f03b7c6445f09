"""Fitting a spine to a target point cloud without correspondences (Chamfer objective).

The objective is the symmetric Chamfer distance between the fleshed source `{M(xᵢ)}` and the
cloud `{yⱼ}`:

    (1/N) Σᵢ minⱼ |M(xᵢ) − yⱼ|² + (1/K) Σⱼ minᵢ |M(xᵢ) − yⱼ|².

It is written as residuals `M(xᵢ) − y_{nn(i)}` and `yⱼ − M(x_{nn(j)})` with the nearest
neighbours chosen on stopped gradients: the sum of their squares is the Chamfer distance and its
gradient is the Chamfer gradient (wherever the neighbours are unique), so any optimistix
minimiser (BFGS by default) or least-squares solver can minimise it. Like every ICP-type
objective it is not convex: start from a reasonable guess.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, ArrayLike

from .._fleshing.projection import Registration
from . import verdict
from .problem import (
    AbstractPoseProblem,
    FitResult,
    Parameters,
    Regularizers,
    check_cloud,
    check_tolerance,
    default_solver,
    fit,
    prepare,
)

ADVICE = (
    "start closer: `init` from a fit with correspondences or an `Arc` fitted first, a few "
    "starts (keep the lowest rms), or `fixed=` for the root's control points."
)


def _nearest(a: Array, b: Array, usable: Array) -> Array:
    """For each row of `a` (N, 3), the index of its nearest usable row of `b` (K, 3)."""
    a, b = jax.lax.stop_gradient((a, b))
    squared = jnp.sum((a[:, None, :] - b[None, :, :]) ** 2, axis=-1)
    return jnp.argmin(jnp.where(usable[None, :], squared, jnp.inf), axis=-1)


class Chamfer(AbstractPoseProblem):
    """The residual function of `fit_spine_to_points` (see the module docstring)."""

    parameters: Parameters
    registration: Registration
    cloud: Array
    twist: Array
    regularizers: Regularizers
    method: str = eqx.field(static=True)
    invalid: str = eqx.field(static=True)
    check_projection: bool = eqx.field(static=True)

    def differences(self, images: Array, valid: Array):
        """Forward (N, 3) and backward (K, 3) difference vectors, and the forward mask."""
        used = valid if self.invalid == "exclude" else jnp.ones_like(valid)
        everywhere = jnp.ones(self.cloud.shape[0], dtype=bool)
        forward = images - self.cloud[_nearest(images, self.cloud, everywhere)]
        backward = self.cloud - images[_nearest(self.cloud, images, used)]
        return jnp.where(used[:, None], forward, 0), backward, used

    def __call__(self, y, args=None):
        images, valid = self.images(y)
        forward, backward, used = self.differences(images, valid)
        n = jnp.maximum(jnp.sum(used), 1).astype(forward.dtype)
        k = self.cloud.shape[0]
        residuals = (forward.reshape(-1) / jnp.sqrt(n), backward.reshape(-1) / k**0.5)
        return (*residuals, *self.regularizers(self.spine_and_twist(y)[0]))

    def rms(self, images, valid):
        """`√(Chamfer distance / 2)`: nearest-neighbour distances averaged both ways."""
        forward, backward, used = self.differences(images, valid)
        n = jnp.maximum(jnp.sum(used), 1)
        chamfer = jnp.sum(forward**2) / n + jnp.mean(jnp.sum(backward**2, axis=-1))
        return jnp.sqrt(chamfer / 2)

    def distances(self, images, valid):
        """The forward term's distances: each counted image to its nearest cloud point."""
        forward, _, used = self.differences(images, valid)
        return jnp.linalg.norm(forward, axis=-1), used.astype(forward.dtype)

    def data(self):
        return self.cloud


def fit_spine_to_points(
    source_spine,
    init,
    source: ArrayLike,
    cloud: ArrayLike,
    *,
    method: str = "radial",
    twist: ArrayLike = 0.0,
    fit_twist: bool = False,
    params: Callable | None = None,
    fixed=None,
    length="free",
    smoothness: float = 0.0,
    regularizers: Sequence[Callable] | None = None,
    invalid: str = "penalize",
    check_projection: bool = False,
    solver: optx.AbstractMinimiser | optx.AbstractLeastSquaresSolver | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    max_steps: int = 256,
    throw: bool = False,
    tolerance: float | None = verdict.TOLERANCE,
) -> FitResult:
    """Fits the bent spine `C₁` whose fleshing of `source` best matches an unordered `cloud`.

    Minimises the symmetric Chamfer distance (see the module docstring) over the free
    parameters of `init` (and optionally the twist): no correspondence between `source` and
    `cloud` is needed, and they may have different sizes (a scan of the bent shape, or the
    vertices of a deformed mesh). Start from a reasonable initial guess: the objective has
    local minima.

    **Arguments:** as for `fit_spine`, with `cloud`: (K, 3) finite target points instead of
    `target`, and `solver`: any optimistix minimiser or least-squares solver (default
    `optimistix.BFGS(rtol, atol)`, tolerances from the dtype). `invalid="exclude"` leaves
    invalid images out of both terms; `"penalize"` counts them as unmoved points. As for
    `fit_spine`, `converged` is True only when the solve stopped with the rms within
    `tolerance` (default 1e-3) of the cloud's bounding-box diagonal; otherwise `message`
    says what most likely went wrong and what to try.

    **Returns:** a `FitResult` whose `rms` is `√(Chamfer distance / 2)`: the root-mean-square
    of the nearest-neighbour distances, averaged over both directions.
    """
    source = check_cloud(source, "source")
    dtype = source.dtype
    cloud = check_cloud(cloud, "cloud").astype(dtype)
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
    problem = Chamfer(
        cloud=cloud,
        **setup.problem_fields(invalid, check_projection),
    )
    if solver is None:
        solver = default_solver("minimise", dtype, rtol, atol)
    return fit(problem, solver, setup.y0, max_steps, throw, check_tolerance(tolerance), ADVICE)

"""A last pass over a simplified medial mesh: its spheres fitted to the surface samples.

Our own addition; Q-MAT (Li et al. 2015) stops at the edge collapses. Later works optimise
the spheres of a medial mesh against the surface as well (MATFP, Coverage Axis++), each
in its own way. Here the connectivity stays fixed and the centres and radii of all spheres
minimise the squared signed distances of the surface samples to the union of spheres,
cones and slabs, by damped Gauss-Newton (Levenberg-Marquardt) steps:

- the signed distance of a point to a primitive is `min |p − c(w)| − r(w)` over the
  spheres `(c(w), r(w))` interpolated linearly with weights `w` between the primitive's
  spheres (`primitives`); by the envelope theorem its derivative with respect to sphere
  `k` is `−w_k (u, 1)` with `u` the unit vector from `c(w)` to `p`, so each sample's row of
  the Jacobian has at most 12 non-zeros and the normal equations are sparse;
- a sample's distance to the union is that of its closest primitive (inside the union: the
  deepest). Moving every sphere by at most `δ` (centre plus radius) changes every distance
  by at most `δ`, so the (sample, primitive) pairs whose distance is within `2 margin` of
  the sample's best stay the only candidates while no sphere has moved more than `margin`
  since they were found: steps are clipped to that, and the candidates found again when a
  step would leave it (`candidates`: the search tests bounding spheres in blocks, and each
  evaluation skips the pairs that the spheres' moves since the search prove too far);
- samples that the union misses pull its boundary out; samples inside it (a bulge) push the
  primitive that covers them deepest back in;
- points inside the shape are fitted too, to minus their depth, so that the union does not
  open holes inside (whose boundary would be far from the surface);
- and each sphere is kept inside the surface (`max(0, s(c) + r)`, `s` its signed distance):
  without it, a sphere shrunk to radius 0 slid out of the bunny's ear, the tip of a needle
  that holds too few samples for a least-squares fit to notice (envelope → surface 10 %);
- the samples' squares are reweighted at every step (iteratively reweighted least squares)
  by `(1 + (d/σ)²)^(p/2 − 1)`, `σ` the residuals' root mean square, which approximates
  `Σ |d|^p` for the large residuals: the targets are one-sided Hausdorff distances (maxima),
  and a plain least-squares fit leaves a few badly covered samples (a box's sharp edges and
  corners) for many slightly better ones. `p = 4` (`power`) took the box at 200 spheres
  from 1.19 to 0.94 % and the bunny from 1.11 to 0.99 % (benchmarks/README.md); `p = 6`
  did better on the box but let the bunny's envelope overshoot (3.1 % at 50 spheres);
- no edge shrinks below half its length (`SHORTEST`; a one-sided penalty, weighted as the
  containment): the samples do not see a sphere slide along a tube's axis, and without it
  the spheres of a capsule's chain slid past each other (edges across three spheres); the
  envelope was as good, but the medial mesh deformed by handles folded (a capsule bent 90°
  by `arap_medial` lost 77 % of its radius in places, +1.5 % of volume; now 6 % and
  −0.01 %). Holding every edge vector, even weakly, kept the box's spheres from its corners
  and spot's from its extremities (1.59 % and 1.15 % at 200 spheres).
- after the fit's `iterations` steps, up to `extra` more in rounds of `ROUND`, with twice
  the margin (so steps twice as long) and every centre kept inside the surface: a round is
  kept only if it brings the worst sample (or sphere past the surface) nearer, else the fit
  stops. The box's spheres must travel far to reach its corners and edges, which the short
  steps do not allow in 20 steps (box at 50 spheres 3.09 → 1.44 %, at 200 1.03 → 0.88 %,
  spot at 200 0.98 → 0.68 %); the bunny's fits, whose long steps overshoot (2.12 → 2.43 %
  at 50 spheres when every step is long), drop the first round. Without the guard on the
  centres (`_centres_kept_inside`), the long steps moved spheres of the box at 60 spheres
  out of it (by up to 1.2 % of the diagonal): the samples at its corners pull their small
  spheres outwards, and the containment penalty on `s(c) + r` is soft.

- where nearly every primitive lies within every sample's band (over `CROWDED` candidate
  pairs a sample: a sphere-like shape, whose spheres all sit near its centre), the fit keeps
  a regular selection of its samples, for about `THIN` pairs: each search and evaluation
  measured every (sample, primitive) pair, 23M pairs a search on an icosphere at 100
  spheres (the fit 29 s of 37), and the search's cap then narrowed the steps eightfold.
  Thinned, the icosphere's distances stay at 0.07 % of the diagonal (30 and 100 spheres:
  15k and 1.6k of 26k samples); spot, the animal, the capsule (61 pairs a sample), the
  torus, box, flat ellipsoid and bunny (16–37) are not thinned.

`medial_mesh` fits the samples the initial axis was built from, and centres of that axis.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as sparse_linalg

from .candidates import closest as _closest, prune, search as _search
from .normal_matrix import sphere_blocks, weighted_gram
from .pairs import jacobian_rows
from .primitives import UnionPrimitives
from .rows import norm
from .surface import SurfaceQuery, ray_inside


def _moved(params, anchor):
    """How far `(n,)` each sphere of `params (n, 4)` lies from `anchor (n, 4)`: the centre's
    move plus the radius's."""
    return norm(params[:, :3] - anchor[:, :3]) + np.abs(params[:, 3] - anchor[:, 3])


def _jacobian(points, spheres, weights, params):
    """Sparse Jacobian `(N, 4n)` of the samples' distances with respect to the spheres'
    `(x, y, z, r)`: `−w_k (u, 1)` in the columns of sphere `k` (see the module's notes)."""
    n = len(params)
    # (`np.take`, not `params[spheres]`: the same rows, several times faster.)
    foot = np.einsum("ij,ijk->ik", weights, np.take(params[:, :3], spheres, axis=0))
    u = points - foot
    u /= np.maximum(norm(u), 1e-300)[:, None]
    # Its CSR arrays in one loop (`pairs.jacobian_rows`): the matrix of twelve entries a row
    # with its repeated spheres summed (`sum_duplicates`), the same arrays, without NumPy's
    # passes over (N, 3, 4) products and SciPy's sort of every row.
    return sparse.csr_matrix(jacobian_rows(np.ascontiguousarray(spheres, np.int64),
                                           np.ascontiguousarray(weights, np.float64), u),
                             shape=(len(points), 4 * n))


def _interpolated(points, spheres, weights, params):
    """`|p − c| − r` `(N,)` of each sample `p` for the sphere `(c, r)` interpolated with
    `weights (N, 3)` between its `spheres (N, 3)` of `params (n, 4)`: an upper bound of its
    distance to the primitive of those spheres (which holds every interpolated sphere)."""
    sphere = np.einsum("ij,ijk->ik", weights, np.take(params, spheres, axis=0))
    return norm(points - sphere[:, :3]) - sphere[:, 3]


def _weights(residual, samples: int, power: float):
    """Weights `(R,)` of the squared residuals: `(1 + (d/σ)²)^(power/2 − 1)` for the first
    `samples` (σ their root mean square), 1 for the rest (containment and edge penalties)."""
    weight = np.ones(len(residual))
    if power != 2:
        d = residual[:samples]
        sigma = max(np.sqrt(np.mean(d**2)), 1e-300)
        weight[:samples] = (1 + (d / sigma) ** 2) ** (power / 2 - 1)
    return weight


def _centres_kept_inside(surface: SurfaceQuery, params, trial):
    """`trial` spheres `(n, 4)` whose centres do not leave the surface: a sphere whose step
    from `params` takes its centre outside (further out, for one already outside) is moved
    only up to where its centre's signed distance, linearly interpolated along the step,
    reaches the surface; one still outside there keeps still."""
    def signed(centres):
        # Not certified (`exact=False`): a centre deep inside keeps the best of its nearest
        # faces, whose sign is unambiguous, and one near the surface, where the guard acts,
        # is certified by them anyway. Certifying every centre on a capsule's axis (a ring
        # of equidistant faces) took 0.5 s a call, 107 s of its fit at 200 spheres.
        distance, _, inside = surface.query(centres, exact=False)
        return np.where(inside, -distance, distance)

    before, after = signed(params[:, :3]), signed(trial[:, :3])
    limit = np.maximum(before, 0.0)
    out = after > limit
    if out.any():
        trial = trial.copy()
        # 0.9 of the way: short of the surface, as the interpolation is exact on planes only.
        part = 0.9 * (limit - before)[out] / (after - before)[out]
        trial[out] = params[out] + part[:, None] * (trial[out] - params[out])
        still = np.flatnonzero(out)[signed(trial[out, :3]) > limit[out]]
        trial[still] = params[still]
    return trial


ROUND = 3  # the longer steps after the fit are taken, and kept or dropped, this many at a time

CROWDED = 100  # candidate pairs per sample beyond which the fit thins its samples (see below)

THIN = 2_000_000  # about the candidate pairs a thinned fit keeps

SHORTEST = 0.5  # an edge may shrink to this fraction of its length before the fit (see below)


def _shrunk_edges(edges, centers, rest, weight: float):
    """Residuals `(e,)` `weight min(0, ℓ − SHORTEST ℓ₀)` of the edges' lengths `ℓ` against
    their lengths `ℓ₀` before the fit, and their sparse Jacobian `(e, 4n)` (rows of the
    edges not shrunk that far are zero)."""
    n = len(centers)
    vector = centers[edges[:, 0]] - centers[edges[:, 1]]
    length = np.linalg.norm(vector, axis=1)
    short = np.minimum(length - SHORTEST * rest, 0.0)
    unit = vector / np.maximum(length, 1e-300)[:, None] * (short < 0)[:, None]
    rows = np.repeat(np.arange(len(edges)), 6)
    cols = np.concatenate([4 * edges[:, :1] + np.arange(3), 4 * edges[:, 1:] + np.arange(3)], 1)
    values = weight * np.concatenate([unit, -unit], 1)
    jac = sparse.csr_matrix((values.reshape(-1), (rows, cols.reshape(-1))),
                            shape=(len(edges), 4 * n))
    return weight * short, jac


def refine_spheres(points, targets, centers, radii, edges, faces, *, scale: float,
                   surface: SurfaceQuery | None = None, iterations: int = 12,
                   margin: float = 0.01, power: float = 4.0, extra: int = 21):
    """Fits the spheres of a medial mesh to surface samples, its connectivity fixed.

    **Arguments:**

    - `points`: `(N, 3)` samples: on the surface, and inside it (see `targets`).
    - `targets`: `(N,)` their signed distances to the surface (0 on it, minus the depth
      inside): the fit makes the union's signed distance match them.
    - `centers (n, 3)`, `radii (n,)`, `edges (e, 2)`, `faces (f, 3)`: the medial mesh.
    - `scale`: the mesh's bounding-box diagonal.
    - `surface`: the closed mesh (`SurfaceQuery`); when given, every sphere is also kept
      inside it (a penalty on `max(0, s(c) + r)`, `s` the signed distance to the surface).
    - `iterations`: Levenberg-Marquardt steps taken (each accepted or damped further).
    - `margin`: the largest move of a sphere (centre plus radius) before the candidate
      primitives of each sample are searched again, in units of `scale`.
    - `power`: the samples' residuals are weighted to approximate `Σ |d|^power` (2: plain
      least squares; see the module's notes).
    - `extra`: most steps taken after `iterations` with twice the `margin`, centres kept
      inside `surface`, in rounds of `ROUND` kept while they bring the worst sample nearer
      (see the module's notes; 0: none).

    **Returns:** `(centers (n, 3), radii (n,))`, radii `>= 0`; every accepted step lowers
    the weighted sum of squares of that step's weights. With `surface`, the last pass
    (`_kept_inside`) puts every centre inside and clamps each sphere's overhang to the
    farthest surface sample outside the union.
    """
    points = np.asarray(points, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    params = np.concatenate([centers, radii[:, None]], axis=1).astype(np.float64)
    edges, faces = np.asarray(edges).reshape(-1, 2), np.asarray(faces).reshape(-1, 3)
    margin = margin * scale
    n = len(params)
    # A sphere's containment weighs a tenth of its share of the samples: more (1, 10) kept
    # the merged spheres, which overhang the surface a little by design, too small (the
    # capped bunny at 50 spheres lost 2.5 % and 5.8 % of its volume).
    contain_weight = np.sqrt(0.1 * len(points) / n)
    # No edge shrinks below `SHORTEST` of its length: along a tube the samples do not see a
    # sphere slide along the axis, and without this term the spheres of a capsule's chain slid
    # past each other (see the module's notes).
    rest = np.linalg.norm(params[edges[:, 0], :3] - params[edges[:, 1], :3], axis=1)
    blocks = sphere_blocks(n, edges)  # the normal matrix's 4 x 4 blocks (`normal_matrix`)

    def search(params, margin, attained=None):
        """The candidate pairs of `params`, valid while no sphere moves by over `margin`;
        `attained`: the spheres and weights of each sample's closest pair at spheres near
        `params`, whose interpolated sphere bounds its distance (fewer pairs to test)."""
        union = UnionPrimitives(params[:, :3], params[:, 3], edges, faces)
        upper = None if attained is None else _interpolated(points, *attained, params)
        return _search(points, union, params, margin, upper)

    def evaluate(params, pairs, attained=None):
        """Residuals and Jacobian of the samples, then of the spheres' containment;
        `attained`: as in `search`."""
        union = UnionPrimitives(params[:, :3], params[:, 3], edges, faces)
        upper = None if attained is None else _interpolated(points, *attained, params)
        pairs = prune(pairs, union, params, len(points), 1e-9 * scale, upper)
        value, spheres, weights = _closest(points, *pairs, union)
        residual, jac = value - targets, _jacobian(points, spheres, weights, params)
        attained = spheres, weights
        if surface is not None:
            # max(0, s(c) + r) with `s` the signed distance to the surface (its gradient
            # the unit vector from the closest point, flipped inside).
            distance, foot, inside = surface.query(params[:, :3], exact=False)
            sign = np.where(inside, -1.0, 1.0)
            out = np.maximum(sign * distance + params[:, 3], 0.0)
            grad = sign[:, None] * (params[:, :3] - foot) / np.maximum(distance, 1e-300)[:, None]
            rows = sparse.csr_matrix((np.concatenate([grad, np.ones((n, 1))], 1).reshape(-1)
                                      * np.repeat(out > 0, 4),
                                      (np.repeat(np.arange(n), 4), np.arange(4 * n))),
                                     shape=(n, 4 * n))
            residual = np.concatenate([residual, contain_weight * out])
            jac = sparse.vstack([jac, contain_weight * rows]).tocsr()
        shrunk, rows = _shrunk_edges(edges, params[:, :3], rest, contain_weight)
        return np.concatenate([residual, shrunk]), sparse.vstack([jac, rows]).tocsr(), attained

    def worst(residual):
        """The largest distance the fit sees: of a sample, or of a sphere past the surface."""
        over = residual[len(points):len(points) + n] / contain_weight if surface else 0.0
        return max(np.abs(residual[:len(points)]).max(), np.max(over, initial=0.0))

    def descend(params, pairs, fitted, iterations, margin, guard):
        """`iterations` damped Gauss-Newton steps from `params` (`pairs`: its candidates
        for `margin`, or None: found at the first trial; `fitted`: its `evaluate`);
        `guard`: keep the centres inside `surface`."""
        damping = 1e-3
        residual, jac, attained = fitted

        def trial_of(step, limit):
            # No sphere moves by more than half of `limit` in one step, so that the
            # candidates serve a few steps (see the module's notes).
            move = np.linalg.norm(step[:, :3], axis=1) + np.abs(step[:, 3])
            trial = params + step * np.minimum(1.0, limit / 2 / np.maximum(move, 1e-300))[:,
                                                                                          None]
            trial[:, 3] = np.maximum(trial[:, 3], 0.0)
            if surface is not None and guard:
                trial = _centres_kept_inside(surface, params, trial)
            return trial

        for _ in range(iterations):
            weight = _weights(residual, len(points), power)
            hessian = weighted_gram(jac, weight, blocks)  # (jac.T @ diags(weight) @ jac)
            gradient = jac.T @ (weight * residual)
            diagonal = hessian.diagonal()
            # Spheres that no sample sees keep still (a tiny ridge makes the system regular).
            ridge = diagonal + 1e-9 * max(diagonal.max(), 1e-300)
            current = np.sum(weight * residual**2)
            for _ in range(8):
                step = -sparse_linalg.spsolve((hessian + sparse.diags(damping * ridge)).tocsc(),
                                              gradient).reshape(-1, 4)
                trial = trial_of(step, margin if pairs is None else pairs.margin)
                if pairs is None or _moved(trial, pairs.anchor).max() > pairs.margin:
                    # Outside the candidates' validity: found again at the trial, not at
                    # `params`, so that they serve the next step from either (both within
                    # half the margin; on spot 9 searches instead of 14). Narrowed to the
                    # budget, they serve this trial still (their anchor), and the steps
                    # after it shorten with their margin.
                    pairs = search(trial, margin, attained)
                t_residual, t_jac, t_attained = evaluate(trial, pairs, attained)
                if np.sum(weight * t_residual**2) < current:
                    params, residual, jac, attained = trial, t_residual, t_jac, t_attained
                    damping = max(damping / 3, 1e-7)
                    break
                damping *= 4
            else:
                break  # no step along the damped directions helps: a (local) optimum
        return params, (residual, jac, attained)

    pairs = search(params, margin)
    # Pairs beyond the search's cap (its margin narrowed) counted as growing with the margin.
    held = len(pairs.pts) * margin / pairs.margin
    if held > CROWDED * len(points) and held > THIN:
        # Nearly every primitive within every sample's band (a sphere-like shape): a
        # regular selection of the samples (and inner points) tells the fit as much, for
        # `THIN` pairs (see the module's notes).
        keep = np.unique((np.arange(int(len(points) * THIN / held))
                          * (held / THIN)).astype(np.int64))
        points, targets = points[keep], targets[keep]
        contain_weight = np.sqrt(0.1 * len(points) / n)
        pairs = search(params, margin)
    params, fitted = descend(params, pairs, evaluate(params, pairs), iterations, margin, False)
    # Then rounds of steps twice as long, centres kept inside, each kept only if it brings
    # the worst sample (or sphere past the surface) nearer (see the module's notes).
    for _ in range(0, extra, ROUND):
        trial, t_fitted = descend(params, None, fitted, ROUND, 2 * margin, True)
        if worst(t_fitted[0]) >= worst(fitted[0]):
            break
        params, fitted = trial, t_fitted
    if surface is not None:
        # The samples' distances at the end (those on the surface: target 0).
        outside = fitted[0][: len(points)][targets == 0]
        params = _kept_inside(surface, params, 1e-4 * scale,
                              max(float(outside.max(initial=0.0)), 0.0))
    return params[:, :3], params[:, 3]


def _kept_inside(surface: SurfaceQuery, params, depth: float, allowance: float):
    """Spheres `(n, 4)` whose centres lie inside the surface and which stand out of it by
    at most `allowance` (the farthest that a surface sample lies outside the union).

    - A centre outside is moved to `depth` inside from its closest point: the fit keeps the
      spheres inside by a soft penalty only, which a sphere of radius near 0 barely feels
      (on a plate 0.02 thick, a centre ended 0.03 outside it, issue 30).
    - Inside is told by rays (`surface.ray_inside`), not by the closest point's
      pseudo-normal, which is exact only where the surface does not pass through itself: on
      the quadruped's horn at 4k vertices, a grid cell thick, it called a centre 2.5 % of
      the diagonal beyond the horn inside.
    - A sphere may overhang the surface as much as the union falls short of it elsewhere,
      no more: the penalty let the fit grow a sphere 2.75 % of the diagonal out of that
      horn (envelope → surface 1.05 % after the collapses, 2.75 % after the fit).
    """
    distance, foot, _ = surface.query(params[:, :3])
    inside = ray_inside(params[:, :3], *surface.corners)
    out = np.flatnonzero(~inside & (distance > 0))
    params, distance = params.copy(), distance.copy()
    if len(out):
        inward = (foot[out] - params[out, :3]) / distance[out, None]
        params[out, :3] = foot[out] + depth * inward
        distance[out] = depth
    params[:, 3] = np.minimum(params[:, 3], distance + allowance)
    return params

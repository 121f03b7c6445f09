"""As-rigid-as-possible deformation of a medial mesh by handles (`arap_medial`).

Follows Lan et al. 2017 (appendix, eq. 27) in what it minimises and how: sphere centres
matched in local cells, each cell with its own rotation, rotations and centres updated in
turn, handles (spheres with prescribed centres, optionally rotations) held fixed. Our choices,
where the paper leaves room (see `cells` for the energy):

- **Cells**: one-ring cells around each sphere plus a rotation-smoothness term, instead of
  the paper's cone/slab cells, which leave the twist about a cone and the hinge of a chain of
  cones free. The per-cell rotations are then per-sphere rotations (what `MedialPose` holds).
- **Centre update**: the paper's local update (`solver="local"`: each centre becomes the mean
  over its cells of `t_i + R_i (c⁰_k − t⁰_i)`, centroids of the previous iterate), or the
  exact minimiser of the energy over all centres at fixed rotations (`solver="global"`, the
  default: a linear system with a constant matrix, inverted once per handle set). The exact
  step converges in far fewer iterations. Measured from the same first guess, iterations to
  bring the energy within 1e-4 (relative) of its minimum, global / local: 21 / 87 for a
  20-sphere chain whose last quarter is moved onto a 90° arc, 16 / 140 for 180°, 9 / 22 for a
  6 × 5 sheet bent 90° (1e-6: 47 / 249, 40 / 298, 14 / 34). Alternating minimisation stays
  slow on soft modes: on spot's 200-sphere medial mesh with its head turned 30° (41 handle
  spheres moved, 61 fixed), 20 global iterations leave the centres within 0.5 % of the
  diagonal of the converged pose (50: 0.2 %; the local update: 400 iterations for 2 % of the
  energy). Anderson acceleration would be the next step.
- **Rotation update**: Gauss–Seidel over a colouring of the medial graph (cells of one colour
  share no smoothness term, so each colour's rotations are fitted exactly and the energy
  never increases), with a small proximal term `ε|R − R_old|²` that keeps the fitting matrix
  full rank. The fit maximises `tr(Rᵀ M)` over rotations: the polar factor of `M` by scaled
  Newton iterations, with the reflection fixed when `det M < 0` (as the paper's SVD does), and
  a derivative by the implicit-function rule of the optimality condition (`Rᵀ M` symmetric),
  so that gradients stay finite where `jnp.linalg.svd`'s are not (repeated or zero singular
  values: collinear cells of a straight chain).
- **First guess** (both solvers): the handles' rotations (prescribed, else fitted to the
  handles' own targets, see `_initial_rotations`) interpolated harmonically over the medial
  graph as quaternions (a twist of up to 180° between handles is carried from the start),
  and the exact centres for those rotations.
- **Iterations**: a fixed count (`lax.scan`), differentiated step by step: the returned pose
  is a smooth function of `targets` and `rotations` (away from the measure-zero switches of
  the rotation fit's reflection test and the quaternions' branches), and `jax.grad` of it is
  exact, second derivatives included.
"""

from __future__ import annotations

import functools
import hashlib

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._batching.quick import Program
from .._checks import as_float_array, check_number, is_concrete
from .._medial_axis.medial_mesh import MedialMesh
from .._numerics import safe_divide, safe_sqrt
from .cells import ArapCells, arap_cells
from .pose import ROTATION_TOLERANCE, MedialPose, not_rotations
from .quaternions import matrix_from_quaternion, quaternion_from_matrix

SOLVERS = ("global", "local")
ITERATIONS = 20
SMOOTHNESS = 0.1
# Scaled Newton: quadratic once close. Six steps: on 2,000 random M of each condition number
# 1e1 to 1e14, the polar factor after 6 steps is within 3.3e-16 (float64) / 2.7e-7 (float32)
# of the one after 30, as after 10 (2.8e-16 / 2.4e-7): the last steps only round off.
POLAR_STEPS = 6
LINEAR_WEIGHT = 0.03  # of the linear deformation in the handles' first-guess rotations


# --- the rotation fit: argmax over SO(3) of tr(Rᵀ M) -----------------------------------------


def _fro(x):
    return safe_sqrt(jnp.sum(x * x))


def _cofactors(x):
    """Rows of `det(x) · x⁻ᵀ`, and `det(x)`."""
    c = jnp.stack([jnp.cross(x[1], x[2]), jnp.cross(x[2], x[0]), jnp.cross(x[0], x[1])])
    return c, jnp.sum(x[0] * c[0])


def _polar(m):
    """Orthogonal polar factor of a non-singular `m` (Higham's scaled Newton iteration)."""
    def cross(a, b):  # jnp.cross's arithmetic, on components
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

    def fro(x):  # _fro's sum, in the same order (row-major)
        total = x[0] * x[0]
        for a in x[1:]:
            total = total + a * a
        return safe_sqrt(total)

    def step(_, x):
        rows = x[0:3], x[3:6], x[6:9]
        c = cross(rows[1], rows[2]) + cross(rows[2], rows[0]) + cross(rows[0], rows[1])
        det = rows[0][0] * c[0] + rows[0][1] * c[1] + rows[0][2] * c[2]
        inv_t = [a / det for a in c]
        gamma = jnp.sqrt(fro(inv_t) / fro(x))
        return tuple(0.5 * (gamma * a + b / gamma) for a, b in zip(x, inv_t))

    # On the nine entries as scalars: batched over cells (`vmap`), each a (cells,) vector,
    # so that XLA's CPU backend fuses a step into a few kernels where the (cells, 3, 3)
    # arrays' cross products, sums and broadcasts took nine (and the ten steps run 180 times
    # in a warm 3-iteration ARAP of spot: most of its kernels; see `benchmarks/README.md`).
    # A loop, not unrolled: one step to trace and compile where ten made the rotation fit
    # most of the ARAP solve's program.
    x = jax.lax.fori_loop(0, POLAR_STEPS, step, tuple((m / _fro(m)).reshape(9)))
    return jnp.stack(x).reshape(3, 3)


def _smallest_eigenvector(h):
    """A unit eigenvector of the smallest eigenvalue of a symmetric 3 × 3 `h` (closed form:
    trigonometric eigenvalues, then the largest cross product of two rows of `h − λI`)."""
    eye = jnp.eye(3, dtype=h.dtype)
    q = jnp.trace(h) / 3
    d = h - q * eye
    p = safe_sqrt(jnp.sum(d * d) / 6)
    b = safe_divide(d, p)
    r = _cofactors(b)[1] / 2
    inside = jnp.abs(r) < 1
    phi = jnp.where(inside, jnp.arccos(jnp.where(inside, r, 0)), jnp.where(r > 0, 0, jnp.pi)) / 3
    smallest = q + 2 * p * jnp.cos(phi + 2 * jnp.pi / 3)
    a = h - smallest * eye
    crosses = jnp.stack([jnp.cross(a[0], a[1]), jnp.cross(a[0], a[2]), jnp.cross(a[1], a[2])])
    sizes = jnp.sum(crosses**2, axis=1)
    best = crosses[jnp.argmax(sizes)]
    # A double smallest eigenvalue: `a` has rank ≤ 1, any vector orthogonal to its row does.
    row = a[jnp.argmax(jnp.sum(a * a, axis=1))]
    fallback = jnp.cross(row, eye[jnp.argmin(jnp.abs(row))])
    eps = jnp.finfo(h.dtype).eps
    use_cross = jnp.max(sizes) > jnp.sqrt(eps) * jnp.sum(a * a) ** 2
    v = jnp.where(use_cross, best, fallback)
    size = _fro(v)
    return jnp.where(size > 0, v / jnp.where(size > 0, size, 1), eye[0])


def _polar_part(m):
    """The first part of `fit_rotation`: `(polar factor, m as fitted, usable)`, where a zero
    `m` is not usable and is fitted as the identity."""
    # Written with finite derivatives everywhere: reverse-over-reverse through `lax.scan`
    # differentiates this primal computation instead of the rule below (the rule gives every
    # first derivative; second ones inside the solver's scan come from here, exact once the
    # Newton iteration has converged).
    usable = jnp.sum(m * m) > 0
    m = jnp.where(usable, m, jnp.eye(3, dtype=m.dtype))
    return _polar(m), m, usable


def _finish(q, m, usable, reflections):
    """The rest of `fit_rotation` from `_polar_part`'s: the reflection fixed (if
    `reflections`), the identity where `m` was not usable or the fit is not finite."""
    r = q
    if reflections:
        h = q.T @ m
        v = _smallest_eigenvector(0.5 * (h + h.T))
        # det M < 0: the best rotation flips the direction of M's smallest singular value
        # (the paper's SVD with the reflection fixed, U diag(1, 1, −1) Vᵀ = Q (I − 2 v vᵀ)).
        flipped = q - 2 * jnp.outer(q @ v, v)
        r = jnp.where(_cofactors(m)[1] < 0, flipped, q)
    good = usable & jnp.all(jnp.isfinite(r))
    return jnp.where(good, r, jnp.eye(3, dtype=m.dtype))


@functools.partial(jax.custom_jvp, nondiff_argnums=(1,))
def fit_rotation(m: Float[Array, "3 3"], reflections: bool = True) -> Float[Array, "3 3"]:
    """The rotation `R` maximising `tr(Rᵀ m)` (the closest rotation to `m`).

    The polar factor of `m` when `det m > 0`, with the reflection fixed otherwise; identity for
    a zero or singular `m`. Its derivative comes from the optimality condition `Rᵀ m`
    symmetric: with `S = sym(Rᵀ m)` and `dR = R [ω]×`, `((tr S) I − S) ω = vee(Rᵀ dm − dmᵀ R)`,
    finite wherever the maximiser is unique (no SVD derivative, whose `1/(σᵢ² − σⱼ²)` terms
    are infinite at repeated singular values); the system gets a relative `10 eps` shift so it
    stays finite where the maximiser is not unique. Composes for higher derivatives.
    `reflections=False`: the polar factor alone, for an `m` known to have `det m ≥ 0`.
    """
    return _finish(*_polar_part(m), reflections)


@jax.custom_jvp
def fit_rotations(m: Float[Array, "k 3 3"]) -> Float[Array, "k 3 3"]:
    """`fit_rotation` of each of `m`, the reflection's fix (an eigenvector of each matrix)
    computed only when one of them has `det m < 0` (one test per batch, `lax.cond`): the same
    rotations, bit for bit. On spot's poses no cell needs it, and its warm ARAP (3 iterations,
    `benchmarks/medial_deform.py`) took 0.72–0.78 instead of 0.86–1.02 ms of CPU. The polar
    factors are computed before the test, outside its branches: one copy of their loop in
    the program rather than one per branch (compiled once)."""
    parts = jax.vmap(_polar_part)(m)
    reflected = jnp.any(jax.vmap(lambda a: _cofactors(a)[1])(m) < 0)
    return jax.lax.cond(reflected, jax.vmap(lambda *a: _finish(*a, True)),
                        jax.vmap(lambda *a: _finish(*a, False)), *parts)


def _tangent(r, m, dm):
    """The derivative of `fit_rotation` at `m` (whose rotation is `r`) along `dm`."""
    s = r.T @ m
    s = 0.5 * (s + s.T)
    eye = jnp.eye(3, dtype=m.dtype)
    shift = 10 * jnp.finfo(m.dtype).eps * (_fro(s) + jnp.finfo(m.dtype).tiny)
    k = (jnp.trace(s) + shift) * eye - s
    g = r.T @ dm
    rhs = jnp.stack([g[2, 1] - g[1, 2], g[0, 2] - g[2, 0], g[1, 0] - g[0, 1]])
    c, det = _cofactors(k)  # k is symmetric, so its cofactor matrix is too
    omega = (c @ rhs) / det
    hat = jnp.array([[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]],
                     [-omega[1], omega[0], 0]], dtype=m.dtype)
    return r @ hat


@fit_rotation.defjvp
def _fit_rotation_jvp(reflections, primals, tangents):
    (m,), (dm,) = primals, tangents
    r = fit_rotation(m, reflections)
    return r, _tangent(r, m, dm)


@fit_rotations.defjvp
def _fit_rotations_jvp(primals, tangents):
    (m,), (dm,) = primals, tangents
    r = fit_rotations(m)
    return r, jax.vmap(_tangent)(r, m, dm)


# --- the alternating minimisation ------------------------------------------------------------


def _centroids(cells: ArapCells, c):
    return jnp.sum(cells.mask[..., None] * c[cells.members], 1) / jnp.sum(cells.mask, 1)[:, None]


def energy(cells: ArapCells, c: Array, r: Array) -> Array:
    """The energy of centres `c (n, 3)` and per-sphere rotations `r (n, 3, 3)` (see `cells`)."""
    points = c[cells.members] - _centroids(cells, c)[:, None]
    residual = points - jnp.einsum("nab,nkb->nka", r, cells.offsets)
    match = jnp.sum(cells.mask * jnp.sum(residual**2, -1))
    smooth = jnp.sum(cells.weights * jnp.sum((r[:, None] - r[cells.neighbours]) ** 2, (-2, -1)))
    return match + 0.5 * smooth  # each edge is in both of its spheres' neighbour lists


def _rotation_step(cells: ArapCells, c, r, prescribed):
    """Fits every cell's rotation to centres `c`, one colour at a time (Gauss–Seidel)."""
    # Σ_k (c_k − t_i) x⁰ᵀ = Σ_k (c_k − c_i) x⁰ᵀ, as the offsets x⁰ sum to zero; differences
    # of neighbouring centres keep float32 accurate far from the origin.
    d = c[cells.members] - c[:, None]
    a = jnp.einsum("nka,nkb->nab", d, cells.offsets)

    def colour(k, r):
        idx = cells.colours[k]
        m = (a[idx] + jnp.einsum("nd,ndab->nab", cells.weights[idx], r[cells.neighbours[idx]])
             + cells.proximal[idx, None, None] * r[idx])
        r = r.at[idx].set(fit_rotations(m))
        if prescribed is not None:
            r = r.at[cells.handles].set(prescribed)
        return r

    # A loop over the colours (rows of one padded table), not unrolled: the rotation fit is
    # traced and compiled once rather than once per colour.
    return jax.lax.fori_loop(0, cells.colours.shape[0], colour, r)


def _global_centres(cells: ArapCells, r, shift):
    """The centres minimising the energy at rotations `r`, handles displaced by `shift`
    `(h, 3)`: `L_ff u_f = b_f − L_fh u_h`, solved for the displacement `u = c − c⁰` (zero
    right-hand side at rest, so the identity pose is exact in any precision)."""
    eye = jnp.eye(3, dtype=r.dtype)
    # Products, then explicit sums over the short axes: the einsum's dot took a transposed
    # copy of the gathered rotations per call, a reduction over them is slower still.
    p = (r[cells.owners] - eye) * cells.owner_offsets[:, :, None, :]
    p = p[..., 0] + p[..., 1] + p[..., 2]
    b = sum((p[:, k] for k in range(1, p.shape[1])), p[:, 0])
    u = jnp.zeros_like(cells.rest).at[cells.handles].set(shift)
    if cells.free.shape[0]:
        u = u.at[cells.free].set(cells.inverse @ b[cells.free] - cells.coupling @ shift)
    return cells.rest + u


def _local_centres(cells: ArapCells, c, r, targets):
    """Lan et al.'s update: each centre becomes the mean over its cells of `t_i + R_i x⁰`."""
    t = _centroids(cells, c)
    p = t[cells.owners] + jnp.einsum("nkab,nkb->nka", r[cells.owners], cells.owner_offsets)
    new = jnp.sum(cells.mask[..., None] * p, 1) / jnp.sum(cells.mask, 1)[:, None]
    return new.at[cells.handles].set(targets)


def _initial_rotations(cells: ArapCells, prescribed, targets):
    """The first guess of the rotations.

    At the handles: the prescribed rotations, else each handle's rotation fitted to the
    handles of its cell, completed, in the directions they leave free (collinear handles), by
    the rest of its cell in the linear deformation `argmin_c E(c, I)` with a small weight
    (`LINEAR_WEIGHT`, measured: 0.03 converges fastest of 0–1 on bends of a chain and a rigid
    motion of a sheet). Elsewhere: those rotations interpolated harmonically over the medial
    graph as quaternions, with the smoothness weights.
    """
    n = cells.rest.shape[0]
    eye = jnp.eye(3, dtype=cells.rest.dtype)
    if prescribed is None:
        ring = cells.members[cells.handles]
        held = cells.rest.at[cells.handles].set(targets)[ring] - targets[:, None]
        linear = _global_centres(cells, jnp.broadcast_to(eye, (n, 3, 3)),
                                 targets - cells.rest[cells.handles])[ring] - targets[:, None]
        m = (jnp.einsum("hka,hkb->hab", held, cells.handle_offsets)
             + LINEAR_WEIGHT * jnp.einsum("hka,hkb->hab", linear, cells.offsets[cells.handles])
             + cells.proximal[cells.handles, None, None] * eye)
        at_handles = fit_rotations(m)
    else:
        at_handles = prescribed
    q = jax.vmap(quaternion_from_matrix)(at_handles)
    q = q * jnp.where(q @ q[0] >= 0, 1, -1)[:, None]  # one hemisphere: the shorter arcs
    field = jnp.zeros((n, 4), q.dtype).at[cells.handles].set(q)
    if cells.free.shape[0]:
        field = field.at[cells.free].set(-cells.q_coupling @ q)
    return jax.vmap(matrix_from_quaternion)(field).at[cells.handles].set(at_handles)


def _arap_solve(cells: ArapCells, targets, prescribed, iterations: int, solver: str, start=None):
    """Runs `iterations` (centre step, rotation step) pairs from the first guess, or from the
    rotations of an earlier pose `start = (centres (n, 3), rotations (n, 3, 3))` (a warm
    start: the previous frame's), each turned by the change of the first guess from the
    start's handles to this call's (`R_guess R_guess,startᵀ R_start`: prescribed handles
    start at theirs, and what the start had converged beyond its first guess is kept).

    **Returns:** `(centres (n, 3), rotations (n, 3, 3), energies (iterations,))`, the energy
    after each iteration.
    """
    cells = jax.tree.map(jnp.asarray, cells)
    shift = targets - cells.rest[cells.handles]
    r = _initial_rotations(cells, prescribed, targets)
    if start is not None:
        # The start's rotations, carried by the change of the first guess since: the first
        # guess of the start's own handles (its handles' centres are its targets), turned
        # into this one's. At the start's targets, the start itself.
        centres, rotations = start
        before = _initial_rotations(
            cells, None if prescribed is None else rotations[cells.handles],
            centres[cells.handles])
        r = jnp.einsum("nab,ncb,ncd->nad", r, before, rotations)
    # The local solver starts from the same first guess as the global one (the exact
    # centres of the first-guess rotations), so that the two differ only in their updates.
    # The global one's first step computes those centres itself: computed here, they would
    # only be read without an iteration.
    c = (_global_centres(cells, r, shift) if solver == "local" or iterations == 0
         else cells.rest)

    def step(state, _):
        c, r = state
        if solver == "global":
            c = _global_centres(cells, r, shift)
        else:
            c = _local_centres(cells, c, r, targets)
        r = _rotation_step(cells, c, r, prescribed)
        return (c, r), energy(cells, c, r)

    (c, r), energies = jax.lax.scan(step, (c, r), None, length=iterations)
    return c, r, energies


# Compiled the optimised way (`solve`: per-frame poses), or quickly for `deform_medial`'s one
# call on a small mesh (`posed(…, quick=True)`, `_batching.quick`).
_solve = Program(_arap_solve, kept=True)
solve = _solve.optimised


# --- the public function: checks, cached preprocessing -----------------------------------------

_CACHE: dict = {}
_CACHE_SIZE = 16


def _cells(medial: MedialMesh, handles: np.ndarray, smoothness: float, dtype) -> ArapCells:
    """The `ArapCells` of a mesh and handle set, cached (per-frame calls reuse them)."""
    rest, _, edges, _ = medial.numpy()
    digest = hashlib.blake2b(digest_size=16)
    for array in (rest, edges, handles):
        digest.update(np.ascontiguousarray(array).tobytes())
        digest.update(str(array.shape).encode())
    key = (digest.hexdigest(), float(smoothness), jnp.dtype(dtype).name)
    if key not in _CACHE:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = arap_cells(rest, edges, handles, smoothness, dtype)
    return _CACHE[key]


def check_handles(handles, n: int) -> np.ndarray:
    """`handles` as a NumPy int array, else `ValueError`: concrete, 1-D, non-empty, integer,
    in `[0, n)`, without repeats."""
    if not is_concrete(handles):
        raise ValueError("`handles` must be concrete sphere indices (not traced): close over "
                         "them, e.g. jax.jit(lambda t: arap_medial(medial, handles, t)).")
    array = np.asarray(handles)
    if array.ndim != 1 or array.size == 0:
        raise ValueError(f"`handles` must be a non-empty 1-D array of sphere indices, got shape "
                         f"{array.shape}.")
    if not np.issubdtype(array.dtype, np.integer):
        raise ValueError(f"`handles` must be integer sphere indices, got dtype {array.dtype}.")
    out = array[(array < 0) | (array >= n)]
    if out.size:
        raise ValueError(f"`handles` must index spheres in [0, {n}), got {out.tolist()[:10]}.")
    values, counts = np.unique(array, return_counts=True)
    if (counts > 1).any():
        repeated = values[counts > 1].tolist()[:10]
        raise ValueError(f"`handles` must not repeat a sphere, got {repeated} more than once.")
    return array.astype(np.int64)


def _check_rotations(rotations, h: int, dtype):
    if rotations is None:
        return None
    rotations = as_float_array(rotations, "rotations")
    if rotations.shape != (h, 3, 3):
        raise ValueError(f"`rotations` must have shape (h, 3, 3) = ({h}, 3, 3), one per handle, "
                         f"got shape {rotations.shape}.")
    if is_concrete(rotations):
        if not np.isfinite(np.asarray(rotations)).all():
            raise ValueError("`rotations` must be finite (found NaN or inf).")
        bad = not_rotations(rotations)
        if bad.size:
            raise ValueError(f"`rotations` must be rotation matrices (orthonormal, det +1, to "
                             f"{ROTATION_TOLERANCE}); handles at positions {bad.tolist()[:10]} "
                             "are not.")
    return rotations.astype(dtype)


MAXIMUM_ITERATIONS = 100_000  # a scan: time grows linearly, memory does not
MAXIMUM_SMOOTHNESS = 1e6


def _check_options(iterations, solver, smoothness):
    if solver not in SOLVERS:
        raise ValueError(f"`solver` must be one of {SOLVERS}, got {solver!r}.")
    iterations = check_number(iterations, "iterations", 1, MAXIMUM_ITERATIONS, integer=True)
    smoothness = check_number(smoothness, "smoothness", 0, MAXIMUM_SMOOTHNESS, above=True)
    return iterations, smoothness


def _check_targets(targets, h: int):
    """`targets` as a float array of shape `(h, 3)`, finite where concrete; a value finite as
    given but beyond the range of the dtype it is cast to is named as such."""
    given = None  # a host array of what was given (JAX arrays are cast already)
    if not isinstance(targets, jax.Array | str | bytes | None):
        try:
            given = np.asarray(targets)
        except (TypeError, ValueError):
            pass  # refused by `as_float_array` below, with the reason
    if given is not None and given.dtype.kind == "f" and np.isfinite(given).all():
        limit = float(jnp.finfo(jnp.result_type(float)).max)  # what a float64 array becomes
        if given.dtype.itemsize == 8 and np.abs(given).max(initial=0) > limit:
            raise ValueError(f"`targets` must be representable in {jnp.result_type(float)}: "
                             f"they reach {np.abs(given).max():.3g}, beyond its range (enable "
                             "float64 or move them closer).")
    targets = as_float_array(targets, "targets")
    if jnp.finfo(targets.dtype).bits < 32:
        raise TypeError(f"`targets` must be float32 or float64, got {targets.dtype}.")
    if targets.shape != (h, 3):
        raise ValueError(f"`targets` must have shape (h, 3) = ({h}, 3), one centre "
                         f"per handle, got shape {targets.shape}.")
    if is_concrete(targets) and not np.isfinite(np.asarray(targets)).all():
        raise ValueError("`targets` must be finite (found NaN or inf).")
    return targets


def _prepare(medial, handles, targets, rotations, iterations, solver, smoothness):
    if not isinstance(medial, MedialMesh):
        raise TypeError(f"`medial` must be a MedialMesh, got {type(medial)}.")
    if not is_concrete(medial):
        raise ValueError("`medial` must be concrete (not traced): close over it, e.g. "
                         "jax.jit(lambda t: arap_medial(medial, handles, t)).")
    iterations, smoothness = _check_options(iterations, solver, smoothness)
    n = medial.centers.shape[0]
    handles = check_handles(handles, n)
    targets = _check_targets(targets, len(handles))
    dtype = targets.dtype
    rotations = _check_rotations(rotations, len(handles), dtype)
    cells = _cells(medial, handles, smoothness, dtype)
    return cells, targets, rotations, iterations


def _check_start(start, medial: MedialMesh, dtype):
    """`(centres (n, 3), rotations (n, 3, 3))` of a warm-start pose, in `dtype`, or None."""
    if start is None:
        return None
    if not isinstance(start, MedialPose):
        raise TypeError(f"`start` must be a MedialPose (e.g. the previous frame's), got "
                        f"{type(start).__name__}.")
    if start.rotations.shape[0] != medial.centers.shape[0]:
        raise ValueError(f"`start` must be a pose of `medial` ({medial.centers.shape[0]} "
                         f"spheres), got one of {start.rotations.shape[0]}.")
    if is_concrete(start.medial) and start.medial.fingerprint() != medial.fingerprint():
        raise ValueError("`start` must be a pose of `medial`; it is a pose of another medial "
                         "mesh (other spheres or topology).")
    return start.centers.astype(dtype), start.rotations.astype(dtype)


def arap_medial(
    medial: MedialMesh,
    handles: ArrayLike,
    targets: ArrayLike,
    *,
    rotations: ArrayLike | None = None,
    iterations: int = ITERATIONS,
    solver: str = "global",
    smoothness: float = SMOOTHNESS,
    start: MedialPose | None = None,
) -> MedialPose:
    """Deforms a medial mesh as rigidly as possible so that the handle spheres reach `targets`.

    Minimises the ARAP energy of Lan et al. 2017 (eq. 27) over sphere centres and per-cell
    rotations, on one-ring cells with a rotation-smoothness term (our choice: the paper's
    cone/slab cells leave twist and hinges free; see `fleshing_jax._medial_deform.cells`), by
    `iterations` alternations of a centre step and a rotation step (see
    `fleshing_jax._medial_deform.arap`). Radii are kept.

    Works under `jax.jit` and `jax.grad` with `targets` and `rotations` traced (the pose is a
    smooth function of them; the medial mesh and `handles` must be concrete: close over them).
    Preprocessing (cells, colouring, the systems' inverses) is NumPy, cached per mesh and
    handle set.

    **Arguments:**

    - `medial`: the rest `MedialMesh`; every sphere must be in an edge, and every connected
      component must hold a handle. At most 4096 spheres (dense inverses).
    - `handles`: `(h,)` int sphere indices (concrete, distinct, at least one).
    - `targets`: `(h, 3)` new centres of the handles; the pose has their dtype (float32 in,
      float32 out).
    - `rotations`: optional `(h, 3, 3)` prescribed rotations of the handles (a twist moves no
      centre but twists what lies between handles). Without them, the handles' rotations
      are fitted like every other sphere's.
    - `iterations`: number of (centre step, rotation step) pairs, fixed (no early stop, so the
      derivative is that of the function computed). Default 20: with the global step, the
      bends above are then within 1.1e-4 (90°) and 4e-5 (180°) of their minimum energy,
      centres within 3.3e-4 of the chain's length of the converged ones; on 300 spheres in
      float32, 20 iterations take 3.2 ms (chain) to 4.4 ms (sheet) after compilation on an
      idle 2-core machine.
    - `solver`: `"global"` (default: the exact centre step, a product with the system's
      inverse, computed once per handle set) or `"local"` (Lan et al.'s per-sphere
      averaging, from the same first guess; converges 2.5–9× more slowly, see the module
      docstring).
    - `smoothness`: weight of the rotation-smoothness term relative to the cells' term (> 0).
    - `start`: optional `MedialPose` of `medial` to start from (a warm start: the previous
      frame's pose in an animation). Its rotations, each turned by how the first guess
      changed between its handles' rotations and these, and their exact centres start the
      iterations: a few then get as near the converged pose as 20 from the first guess.
      Measured on spot (200 spheres, head turned 0 → 30° about the neck, rump held, the
      body free, float32), the largest centre distance to the converged pose at 30° as % of
      the diagonal: 20 iterations from the first guess 1.31; warm, 1° a frame, 2 / 3 / 5
      iterations a frame 1.11 / 0.86 / 0.62; 3° a frame 1.67 / 1.47 / 1.17. The pose then
      depends on `start` (traced or not) as well.

    **Returns:** a `MedialPose`: the rest mesh, posed `centers (n, 3)` (handles exactly at
    `targets`) and per-sphere `rotations (n, 3, 3)` (the prescribed ones at the handles).

    Raises `ValueError` naming the argument for bad handles (out of range, repeated, empty,
    traced), `targets` or `rotations` of the wrong shape, non-finite or (rotations) not
    rotations when concrete, an unknown `solver`, and a medial mesh with isolated spheres or
    a component without a handle (naming the spheres).
    """
    prepared = _prepare(medial, handles, targets, rotations, iterations, solver, smoothness)
    start = _check_start(start, medial, prepared[1].dtype)
    return posed(medial, *prepared, solver, start)[0]


def posed(medial, cells, targets, rotations, iterations, solver, start=None, quick=False):
    """`(pose, energies)` of inputs checked by `_prepare` (the pose checks its values);
    `start`: rotations to start from (`_check_start`); `quick`: the solve compiled quickly
    (`_batching.quick`: a single call)."""
    centers, rots, energies = _solve(cells, targets, rotations, iterations, solver, start,
                                     quick=quick)
    return MedialPose(medial, centers, rots), energies


def arap_energies(medial, handles, targets, *, rotations=None, iterations=ITERATIONS,
                  solver="global", smoothness=SMOOTHNESS, start=None):
    """`arap_medial`'s pose and the energy after each iteration `(iterations,)` (for
    convergence measurements and tests)."""
    prepared = _prepare(medial, handles, targets, rotations, iterations, solver, smoothness)
    return posed(medial, *prepared, solver, _check_start(start, medial, prepared[1].dtype))

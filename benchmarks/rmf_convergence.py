"""Convergence of the discrete rotation-minimising frames on a helix (prints a Markdown table).

Double reflection (Wang, Jüttler, Zheng & Liu 2008) against the paper's projection rule: both
propagate the first normal along a 12-unit helix (radius 1, pitch 1) in `n` equal steps; the
error is the max-norm distance of the final frame from the closed form. The measured order is
`log2(e(n) / e(2n))`. Also prints the free-form spines' accuracy: max |speed − 1|, length error,
max |det J − 1| on a B-spline pair, and the polyline's det J error against its step.

    python benchmarks/rmf_convergence.py
"""

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import fleshing_jax as fj  # noqa: E402
from fleshing_jax._spines.parametric import RMF_NODES_PER_RADIAN  # noqa: E402


def frame_errors():
    helix = fj.Helix(1.0, 1.0, 12.0)
    exact = fj.rotation_minimizing_frame(helix, 12.0)
    print("| steps | double reflection | order | projection | order |")
    print("|---:|---:|---:|---:|---:|")
    previous = None
    for n in (32, 64, 128, 256, 512, 1024):
        errors = [
            float(jnp.max(jnp.abs(fj.rotation_minimizing_frame(helix, 12.0, method=m, steps=n)
                                  - exact)))
            for m in ("double_reflection", "projection")
        ]  # fmt: skip
        orders = [f"{np.log2(p / e):.2f}" for p, e in zip(previous or errors, errors)]
        orders = orders if previous else ["", ""]
        print(f"| {n} | {errors[0]:.2e} | {orders[0]} | {errors[1]:.2e} | {orders[1]} |")
        previous = errors
    kappa = 1 / (1 + (1 / (2 * np.pi)) ** 2)
    n = int(np.ceil(RMF_NODES_PER_RADIAN * kappa * 12))
    error = float(jnp.max(jnp.abs(fj.rotation_minimizing_frame(helix, 12.0, steps=n) - exact)))
    print(f"\nDefault node density ({RMF_NODES_PER_RADIAN}/radian, {n} steps): error {error:.2e}")


def spine_accuracy():
    control = np.array([[0, 0, 0], [1, 0.2, 0.1], [2, 0.5, 0.4], [3, 0.3, 0.9], [4, -0.2, 1.0],
                        [5, 0, 0.8], [6, 0.3, 0.5]])  # fmt: skip
    inflection = np.array([[0, 0, 0], [1, 0.8, 0.1], [2, 1.0, 0.3], [3, 0, 0.5], [4, -1.0, 0.7],
                           [5, -0.8, 0.9], [6, 0, 1.0]])  # fmt: skip
    source, target = fj.BSpline(control), fj.BSpline(inflection)
    s = jnp.linspace(0, source.length, 401)
    speed = jax.jit(jax.vmap(jax.jacfwd(source)))(s)
    print(f"\nB-spline max |speed − 1| over 401 samples: "
          f"{np.max(np.abs(np.linalg.norm(speed, axis=-1) - 1)):.1e}")  # fmt: skip
    straight = fj.BSpline([[0, 0, 0], [1, 1, 1], [3, 3, 3], [3.5, 3.5, 3.5], [5, 5, 5], [6, 6, 6]])
    print(f"Collinear B-spline length error: {abs(float(straight.length) - 6 * 3**0.5):.1e}")
    rng = np.random.default_rng(0)
    t = jnp.asarray(rng.uniform(0.3, float(source.length) - 0.3, 64))
    (c, _, _), (i, j) = jax.jit(jax.vmap(source.jet_and_normals))(t)
    a, r = rng.uniform(0, 2 * np.pi, (64, 1)), rng.uniform(0.05, 0.3, (64, 1))
    points = c + r * (np.cos(a) * i + np.sin(a) * j)
    for method in ("radial", "normal", "binormal"):
        det = fj.jacobian_determinant(fj.Fleshing(source, target, method=method, twist=0.7), points)
        print(f"B-spline → B-spline (torsion → inflection, twist 0.7), {method}: "
              f"max |det J − 1| = {float(jnp.nanmax(jnp.abs(det - 1))):.1e} "
              f"({int(jnp.sum(jnp.isfinite(det)))}/64 valid)")  # fmt: skip


def polyline_convergence():
    arc0, arc1 = fj.Arc(3.0, 4.0), fj.Arc(2.0, 4.0, normal=(0, 0, 1))
    rng = np.random.default_rng(2)
    t = jnp.asarray(rng.uniform(0.5, 3.5, 32))
    (c, _, _), (i, j) = jax.vmap(arc0.jet_and_normals)(t)
    points = c + 0.2 * i + 0.1 * j
    print("\n| polyline edges | step | max abs(det J - 1) (radial) |")
    print("|---:|---:|---:|")
    for edges in (8, 16, 32, 64, 128):
        grid = jnp.linspace(0, 4.0, edges + 1)
        pair = fj.Polyline(jax.vmap(arc0)(grid)), fj.Polyline(jax.vmap(arc1)(grid))
        det = fj.jacobian_determinant(fj.Fleshing(*pair, check_projection=False), points)
        print(f"| {edges} | {4.0 / edges:.3f} | {float(jnp.max(jnp.abs(det - 1))):.2e} |")


if __name__ == "__main__":
    frame_errors()
    spine_accuracy()
    polyline_convergence()

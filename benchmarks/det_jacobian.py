"""Max |det J − 1| of each fleshing on the analytic spine pairs (float64 and float32).

Run: `python benchmarks/det_jacobian.py`. Points fill a tube of radius 0.5 around the source
spine, 10% past each end included; det J comes from `jax.jacfwd` through the whole pipeline.
"""

import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import fleshing_jax as fj  # noqa: E402

PAIRS = {
    "line → arc": (fj.Line(4.0), fj.Arc(3.0, 4.0)),
    "arc → helix": (
        fj.Arc(2.5, 5.0, origin=(1.0, -1.0, 0.5), tangent=(0, 1, 0), normal=(1, 0, 1)),
        fj.Helix(2.0, 1.5, 5.0),
    ),
    "helix → helix": (fj.Helix(2.0, 3.0, 8.0), fj.Helix(1.5, -2.5, 8.0)),
    "arc → line": (fj.Arc(2.0, 3.0), fj.Line(3.0, origin=(1, 2, 3), tangent=(0, 0, 1))),
    "arc → helix, L1 = 1.5 L0": (fj.Arc(3.0, 4.0), fj.Helix(2.0, 2.0, 6.0)),
}


def tube(spine, n, radius=0.5, seed=0):
    rng = np.random.default_rng(seed)
    length = float(spine.length)
    s = rng.uniform(-0.1 * length, 1.1 * length, n)
    frames = np.asarray(jax.vmap(lambda t: fj.rotation_minimizing_frame(spine, t))(s))
    angle, r = rng.uniform(0, 2 * np.pi, n), radius * np.sqrt(rng.uniform(0, 1, n))
    return (
        np.asarray(jax.vmap(spine)(s))
        + (r * np.cos(angle))[:, None] * frames[:, 1]
        + (r * np.sin(angle))[:, None] * frames[:, 2]
    )


def main(n=2000):
    print(f"max |det J − 1| over {n} points per pair, twist 0.7\n")
    print(f"{'pair':26s} {'method':9s} {'float64':>10s} {'float32':>10s}  valid")
    for name, (source, target) in PAIRS.items():
        points = tube(source, n)
        for method in fj.METHODS:
            fleshing = fj.Fleshing(source, target, method=method, twist=0.7)
            start = time.perf_counter()
            det64 = np.asarray(fj.jacobian_determinant(fleshing, points))
            det32 = np.asarray(fj.jacobian_determinant(fleshing, points.astype(np.float32)))
            valid = np.isfinite(det64)
            err64 = np.max(np.abs(det64[valid] - 1))
            err32 = np.max(np.abs(det32[np.isfinite(det32)] - 1))
            print(
                f"{name:26s} {method:9s} {err64:10.2e} {err32:10.2e}  {valid.mean():.3f}"
                f"  ({time.perf_counter() - start:.1f} s)"
            )


if __name__ == "__main__":
    main()

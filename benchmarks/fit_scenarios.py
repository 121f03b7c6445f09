"""Spine fitting scenarios (GitHub issue 5): steps, time and final rms of each.

    python benchmarks/fit_scenarios.py

float64, 32 points in a tube of radius 0.5 (0.4 for B-splines) around the rest spine, as in
`tests/test_fit.py`. Prints a Markdown table: optimistix steps, wall time of the first call
(compilation included) and of a second identical call (the solve alone), final rms, converged.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fleshing_jax as fj  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from conftest import cloud  # noqa: E402

LINE, TRUTH, NEARLY_STRAIGHT = fj.Line(4.0), fj.Arc(3.0, 4.0), fj.Arc(100.0, 4.0)
STRAIGHT = np.stack([np.linspace(0, 4, 6), np.zeros(6), np.zeros(6)], -1)
BENT = STRAIGHT.copy()
BENT[2:, 1] = [0.3, 0.9, 1.6, 2.4]
BENT[3:, 2] = [0.2, 0.5, 0.9]
ROOT = np.array([True, True, False, False, False, False])


def scenarios():
    """`(name, thunk)` pairs; each thunk runs one fit and returns its `FitResult`."""
    source = cloud(LINE)
    out = []
    for method, twist in [("radial", 0.0), ("normal", 0.0), ("binormal", 0.3)]:
        target, _ = fj.flesh(source, LINE, TRUTH, method=method, twist=twist)
        label = f"arc from nearly straight, {method}" + (", twist fitted" if twist else "")
        out.append((label, lambda t=target, m=method, w=twist: fj.fit_spine(
            LINE, NEARLY_STRAIGHT, source, t, method=m, fit_twist=w != 0)))  # fmt: skip
    target, _ = fj.flesh(source, LINE, TRUTH)
    out.append(("arc, inextensible + smoothness 0.05", lambda: fj.fit_spine(
        LINE, fj.Arc(100.0, 3.0), source, target, length="fixed", smoothness=0.05)))  # fmt: skip
    scan = np.asarray(target)[np.random.default_rng(2).permutation(len(target))]
    out.append(("arc, Chamfer (no correspondences)", lambda: fj.fit_spine_to_points(
        LINE, fj.Arc(6.0, 3.5), source, scan)))  # fmt: skip
    source32 = source.astype(np.float32)
    target32, _ = fj.flesh(source32, LINE, TRUTH)
    out.append(("arc, float32", lambda: fj.fit_spine(LINE, NEARLY_STRAIGHT, source32, target32)))

    rest, truth = fj.BSpline(STRAIGHT, degree=3), fj.BSpline(BENT, degree=3)
    init = fj.BSpline(STRAIGHT, degree=3, subdivisions=truth.subdivisions)
    bsource = cloud(rest, radius=0.4)
    btarget, _ = fj.flesh(bsource, rest, truth)
    noisy = btarget + 0.01 * np.random.default_rng(1).normal(size=btarget.shape)
    out.append(("B-spline from straight, root fixed", lambda: fj.fit_spine(
        rest, init, bsource, btarget, fixed=ROOT)))  # fmt: skip
    out.append(("B-spline, root fixed, noise σ = 0.01", lambda: fj.fit_spine(
        rest, init, bsource, noisy, fixed=ROOT)))  # fmt: skip
    return out


def main():
    print("| scenario | steps | first call s | solve s | rms | converged |")
    print("|---|---:|---:|---:|---:|---|")
    for name, run in scenarios():
        times = []
        for _ in range(2):
            start = time.perf_counter()
            fit = run()
            jax.block_until_ready(fit.rms)
            times.append(time.perf_counter() - start)
        print(
            f"| {name} | {int(fit.num_steps)} | {times[0]:.1f} | {times[1]:.2f} | "
            f"{float(fit.rms):.2e} | {fit.converged} |",
            flush=True,
        )


if __name__ == "__main__":
    main()

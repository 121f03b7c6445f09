"""Spine fitting scenarios (GitHub issue 5): steps, time and final rms of each; free-form
fits from the rest spine onto far bends (issue 48).

    python benchmarks/fit_scenarios.py            # both tables
    python benchmarks/fit_scenarios.py --far      # the far bends only
    python benchmarks/fit_scenarios.py --far --points=200 --shape=tube  # fewer, one shape

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
    out.append(("arc, inextensible + smoothness 0.05 (tolerance None)", lambda: fj.fit_spine(
        LINE, fj.Arc(100.0, 3.0), source, target, length="fixed", smoothness=0.05,
        tolerance=None)))  # fmt: skip
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
    out.append(("B-spline, root fixed, noise σ = 0.01 (tolerance 5e-3)", lambda: fj.fit_spine(
        rest, init, bsource, noisy, fixed=ROOT, tolerance=5e-3)))  # fmt: skip
    return out


def far_bends(points: int = 500, angles=(30, 60, 90), shape: str = ""):
    """`(name, thunk, diagonal)` triples: a free-form rest spine's shape fleshed onto an `Arc`
    of the same length, placed at the rest spine's start along its start tangent and bent
    `angle` degrees, fitted by `fit_spine(C0, C0, source, target)` (every default: the start
    from the targets' shape, the continuation when that fit stops short). Rest spines: a straight 13-control-point
    quintic B-spline in a tube of radius 0.3 (length 4), and the insect's body
    (`characters.insect`, `rest_spine`: a curved quintic of 16 control points, length 1.70;
    `points` of its vertices valid on it, legs included); one case also twisted 0.5 rad
    (`fit_twist=True`)."""
    from fleshing_jax._medial_axis.characters import insect
    from fleshing_jax._skeleton.rest_spine import rest_spine

    rng = np.random.default_rng(0)
    k = 13
    straight = fj.BSpline(np.c_[np.linspace(0, 4, k), np.zeros(k), np.zeros(k)], degree=5)
    mesh = insect()
    body = rest_spine(mesh)
    vertices = np.asarray(mesh.vertices)
    valid = np.flatnonzero(np.asarray(fj.register(vertices, body).valid))
    shapes = [
        ("tube, straight quintic (13)", straight, cloud(straight, n=points, radius=0.3)),
        ("insect body, rest_spine", body, vertices[rng.choice(valid, points, replace=False)]),
    ]
    out = []
    for label, rest, source in [s for s in shapes if shape in s[0]]:
        t0 = np.array(jax.jacfwd(rest)(0.0))
        t0 /= np.linalg.norm(t0)
        normal = np.cross(t0, [0.0, 0.0, 1.0])
        normal = normal if np.linalg.norm(normal) > 1e-3 else np.cross(t0, [0.0, 1.0, 0.0])
        length = float(rest.length)
        cases = [(a, 0.0) for a in angles] + [(angles[-1], 0.5)]
        for angle, twist in cases:
            arc = fj.Arc(length / np.deg2rad(angle), length, origin=np.asarray(rest(0.0)),
                         tangent=t0, normal=normal / np.linalg.norm(normal))
            target, _ = fj.flesh(source, rest, arc, twist=twist)
            name = f"{label} onto {angle}°" + (f", twist {twist}" if twist else "")
            out.append((name, lambda r=rest, x=source, y=target, w=twist: fj.fit_spine(
                r, r, x, y, twist=0.0, fit_twist=w != 0), _diagonal(target)))  # fmt: skip
    return out


def _diagonal(points) -> float:
    points = np.asarray(points)
    return float(np.linalg.norm(points.max(0) - points.min(0)))


def main_far():
    print("| free-form fit from the rest spine | stages | steps | time s | rms / diagonal "
          "| converged |")
    print("|---|---:|---:|---:|---:|---|")
    options = dict(a[2:].split("=") for a in sys.argv[1:] if "=" in a)
    cases = far_bends(int(options.get("points", 500)), shape=options.get("shape", ""))
    for name, run, diagonal in cases:
        start = time.perf_counter()
        fit = run()
        jax.block_until_ready(fit.rms)
        seconds = time.perf_counter() - start
        print(f"| {name} | {fit.stages} | {int(fit.num_steps)} | {seconds:.0f} | "
              f"{float(fit.rms) / diagonal:.1e} | {fit.converged} |", flush=True)
        if not fit.converged:
            print(f"<!-- {fit.message[:160]} -->", flush=True)


def main():
    if "--far" in sys.argv:
        return main_far()
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
    print()
    main_far()


if __name__ == "__main__":
    main()

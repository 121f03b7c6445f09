"""Spine fitting scenarios (GitHub issue 5): steps, time and final rms of each; free-form
fits from the rest spine onto far bends (issue 48).

    python benchmarks/fit_scenarios.py            # both tables
    python benchmarks/fit_scenarios.py --far      # the far bends only
    python benchmarks/fit_scenarios.py --far --points=200 --shape=tube  # fewer, one shape
    python benchmarks/fit_scenarios.py --far --warm --shape=arm  # a second call timed too

float64, 32 points in a tube of radius 0.5 (0.4 for B-splines) around the rest spine, as in
`tests/test_fit.py`. Prints a Markdown table: optimistix steps, wall time of the first call
(compilation included) and of a second identical call (the solve alone), final rms, converged.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fleshing_jax as fj  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from conftest import cloud  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
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


def limb(mesh, spine, reach: float) -> np.ndarray:
    """The vertices (M, 3) of `mesh` that a limb's rest `spine` moves: valid on it, their foot
    inside it (not on a continuation past an end) and nearer to it than `reach`."""
    vertices = np.asarray(mesh.vertices)
    registration = fj.register(vertices, spine)
    s = np.asarray(registration.arc_length)
    near = np.linalg.norm(np.asarray(registration.offset), axis=-1) < reach
    inside = (s > 0) & (s < float(spine.length))
    return vertices[np.asarray(registration.valid) & inside & near]


def shapes() -> dict:
    """Label → thunk returning `(rest spine, its vertices (M, 3))` of each rest shape of
    `far_bends` (built only when asked: a medial mesh takes 20-45 s)."""
    import trimesh

    from fleshing_jax._medial_axis import characters
    from fleshing_jax._skeleton.rest_spine import rest_spine

    def straight(k=13, length=4.0):
        return fj.BSpline(np.c_[np.linspace(0, length, k), np.zeros(k), np.zeros(k)], degree=5)

    def tube():
        return straight(), cloud(straight(), n=2000, radius=0.3)

    def insect():
        mesh = characters.insect()
        body = rest_spine(mesh)
        vertices = np.asarray(mesh.vertices)
        return body, vertices[np.asarray(fj.register(vertices, body).valid)]

    def through(mesh, joints, reach):
        # A limb's rest spine through its medial spheres, from the first joint to the last.
        spine = rest_spine(mesh, ends=np.array([joints[0][:3], joints[-1][:3]], float))
        return spine, limb(mesh, spine, reach)

    def tail():
        # `rest_spine` finds no medial path in spot's tail (a knob that its medial mesh ends
        # with one sphere): a straight quintic from inside the rump to the tail's tip.
        mesh = trimesh.load(DATA / "spot.obj", process=False)
        a, b = np.array([0.0, -0.06, 0.9]), np.array([0.0, -0.08, 1.049])
        spine = fj.BSpline(a + np.linspace(0, 1, 8)[:, None] * (b - a), degree=5)
        return spine, limb(mesh, spine, 0.08)

    return {
        "tube, straight quintic (13)": tube,
        "insect body, rest_spine": insect,
        "quadruped hind leg (jointed_quadruped), rest_spine": lambda: through(
            characters.jointed_quadruped(), characters.QUADRUPED_HIND_LEG, 0.07),
        "human arm (biped), rest_spine": lambda: through(
            characters.biped(), characters.BIPED_ARM, 0.05),
        "spot's tail, straight quintic (8)": tail,
    }


def far_bends(points: int = 500, angles=(30, 60, 90), shape: str = ""):
    """`(name, thunk, diagonal)` triples: a free-form rest spine's shape fleshed onto an `Arc`
    of the same length, placed at the rest spine's start along its start tangent and bent
    `angle` degrees, fitted by `fit_spine(C0, C0, source, target)` (every default: the start
    from the targets' shape, the continuation when that fit stops short). Each source is up
    to `points` of the shape's points valid on both the rest spine and the arc (a bend's
    targets: a point that the bent spine cannot move is no target). Rest shapes (`shapes`):
    a straight 13-control-point quintic B-spline in a tube of radius 0.3 (length 4); the
    insect's body (`characters.insect`, `rest_spine`: a curved quintic of 16 control points,
    length 1.70, legs included); the jointed quadruped's hind leg and the biped's arm (their
    `rest_spine` between their first and last joints, the vertices within 0.07 / 0.05 of
    it); spot's tail (a straight quintic, the vertices within 0.08). There is no human mesh
    in `shared/data`: the arm is the procedural biped's. The largest angle is also fitted
    twisted 0.5 rad (`fit_twist=True`)."""
    rng = np.random.default_rng(0)
    out = []
    for label, build in [(k, v) for k, v in shapes().items() if shape in k]:
        rest, vertices = build()
        t0 = np.array(jax.jacfwd(rest)(0.0))
        t0 /= np.linalg.norm(t0)
        normal = np.cross(t0, [0.0, 0.0, 1.0])
        normal = normal if np.linalg.norm(normal) > 1e-3 else np.cross(t0, [0.0, 1.0, 0.0])
        length = float(rest.length)
        cases = [(a, 0.0) for a in angles] + [(angles[-1], 0.5)]
        for angle, twist in cases:
            arc = fj.Arc(length / np.deg2rad(angle), length, origin=np.asarray(rest(0.0)),
                         tangent=t0, normal=normal / np.linalg.norm(normal))
            target, valid = (np.asarray(a) for a in fj.flesh(vertices, rest, arc, twist=twist))
            chosen = np.flatnonzero(valid)
            chosen = rng.choice(chosen, min(points, len(chosen)), replace=False)
            source, target = vertices[chosen], target[chosen]
            name = f"{label} onto {angle}°" + (f", twist {twist}" if twist else "")
            name += f" ({len(chosen)} points)"
            out.append((name, lambda r=rest, x=source, y=target, w=twist: fj.fit_spine(
                r, r, x, y, twist=0.0, fit_twist=w != 0), _diagonal(target)))  # fmt: skip
    return out


def _diagonal(points) -> float:
    points = np.asarray(points)
    return float(np.linalg.norm(points.max(0) - points.min(0)))


def main_far():
    options = dict(a[2:].split("=") for a in sys.argv[1:] if "=" in a)
    warm = "--warm" in sys.argv
    print(f"load (1, 5, 15 min): {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print("| free-form fit from the rest spine | stages | steps | first call s |"
          + (" warm s |" if warm else "") + " rms / diagonal | converged |")
    print("|---|---:|---:|---:|" + ("---:|" if warm else "") + "---:|---|")
    cases = far_bends(int(options.get("points", 500)), shape=options.get("shape", ""))
    for name, run, diagonal in cases:
        times = []
        for _ in range(2 if warm else 1):
            start = time.perf_counter()
            fit = run()
            jax.block_until_ready(fit.rms)
            times.append(time.perf_counter() - start)
        print(f"| {name} | {fit.stages} | {int(fit.num_steps)} | "
              + " | ".join(f"{t:.1f}" for t in times)
              + f" | {float(fit.rms) / diagonal:.1e} | {fit.converged} |", flush=True)
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

"""Compiled programs and time of eager poses onto many different spines (issue 20).

    python benchmarks/spine_programs.py [--kind bspline|polyline|arc] [--count 20]

One registration (100 points around a line) is posed onto `--count` different spines, each
built anew as a long session or a fitting loop would: B-splines of 6, 7, 8, … control points
bent more and more, polylines of 10, 20, 30, … vertices, or arcs of growing turning. Reports
the wall time of each pose (the first one of a program compiles it), their total, and how
many programs JAX traced (`pose`'s per-batch program, `_pose_certified`, once per program).
Run it with `PYTHONPATH` pointing at another checkout to compare versions.
"""

from __future__ import annotations

import argparse
import collections
import time

import jax
import numpy as np

import fleshing_jax as fj

TRACE_EVENT = "/jax/core/compile/jaxpr_trace_duration"


def spines(kind: str, count: int):
    """`count` different spines of `kind`, all of length about 2 along x."""
    for i in range(count):
        if kind == "bspline":
            t = np.linspace(0.0, 1.0, 6 + i)
            bend = 0.2 + 0.02 * i
            yield fj.BSpline(np.column_stack([2 * t, bend * np.sin(np.pi * t), 0.1 * bend * t]))
        elif kind == "polyline":
            t = np.linspace(0.0, 1.0, 10 * (i + 1))
            yield fj.Polyline(np.column_stack([2 * t, 0.3 * np.sin(np.pi * t), 0.03 * t]))
        else:
            yield fj.Arc(1.0 + 0.1 * i, 2.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=("bspline", "polyline", "arc"), default="bspline")
    parser.add_argument("--count", type=int, default=20)
    parser.add_argument("--float32", action="store_true")
    args = parser.parse_args()
    if not args.float32:
        jax.config.update("jax_enable_x64", True)
    traces = collections.Counter()

    def listener(event, duration, **kwargs):
        if event == TRACE_EVENT:
            traces[kwargs.get("fun_name")] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(0.1, 1.9, 100), rng.uniform(-0.2, 0.2, (100, 2))])
    points = points.astype(np.float32 if args.float32 else np.float64)
    registration = fj.register(points, fj.Line(2.0))
    times = []
    traces.clear()
    for spine in spines(args.kind, args.count):
        started = time.perf_counter()
        jax.block_until_ready(fj.pose(registration, spine))
        times.append(time.perf_counter() - started)
    print(f"{fj.__file__}: {args.kind} ×{args.count}")
    print("pose times (s):", " ".join(f"{t:.2f}" for t in times))
    print(f"total {sum(times):.1f} s, median {np.median(times):.3f} s, "
          f"programs (_pose_certified traces) {traces['_pose_certified']}")


if __name__ == "__main__":
    main()

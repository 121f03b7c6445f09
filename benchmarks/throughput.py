"""Throughput of `register`, `pose` and `flesh` (GitHub issue 6), with a NumPy reference.

    python benchmarks/throughput.py                       # everything, default sizes
    python benchmarks/throughput.py --sizes 1e4,1e5 --dtypes float32 --methods radial
    python benchmarks/throughput.py --resolution --resolution-size 1e5

Prints Markdown tables:

1. Throughput (million points per second, steady-state median of `--repeats` runs) of
   `register`, `pose` with and without `check_projection`, and `flesh`, per pair of spines,
   method, dtype and N; compile time = first call − steady median (caches cleared first).
2. A vectorised NumPy line → arc fleshing (`_numpy_reference.py`), checked against `fj.flesh`
   (1e-5 in float32, 1e-10 in float64, same validity) and timed; ratio = JAX / NumPy speed.
3. Peak memory: one subprocess per (pair, dtype, N), glibc's mmap threshold fixed so freed
   buffers leave the resident set; each call runs once to compile, then the kernel's resident
   high-water mark is reset (`/proc/self/clear_refs`) and the call is run again; reported: the
   high-water mark minus the resident set before the call, as MB and as a multiple of the
   input plus output arrays (`N·3` floats in, `N·3` floats + `N` bools out). Linux only.
   (`tracemalloc` does not see XLA's buffers; `ru_maxrss` cannot be reset, so it would include
   compilation.)
4. With `--resolution`: registration cost against spine resolution (B-spline control points
   8 → 256, polyline vertices 64 → 4096) at a fixed N.
5. With `--tube` (issue 19's per-frame case; `--tube-only` for that table alone): the
   vertices of a closed tube (radius 0.3, length 4, 1,024,258 vertices: 256 around, 4001
   rings and the two cap centres) along a line, bent onto an arc of radius 1.2 of the same
   length, float32, radial, default checks: `pose` and `flesh` (medians of `--repeats`
   runs), against a roofline: the bytes each must move per point (pose: reads the
   registration, 33 B, writes the image and its flag, 13 B; flesh: reads a point, writes an
   image and a flag, 25 B) at the bandwidth of a plain array copy measured in the same run
   (`np.copyto` of 48 MB of float32 into a buffer already touched: 96 MB moved).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _numpy_reference as reference  # noqa: E402
import numpy as np  # noqa: E402

import fleshing_jax as fj  # noqa: E402

PAIRS = ("line-arc", "bspline-bspline")
TUBE = 0.3  # tube radius of the benchmark points around the source spine


# ---------------------------------------------------------------------------------- set-up


def _curve(u):
    """The free-form source shape: a gently wavy curve with torsion, u ∈ [0, 4]."""
    return np.stack([u, 0.3 * np.sin(1.5 * u), 0.2 * np.sin(u)], axis=-1)


def _bend(p, radius=3.0):
    """Wraps points around an arc of `radius` (x → arc length): the bent free-form target."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    r = radius - y
    return np.stack([r * np.sin(x / radius), radius - r * np.cos(x / radius), z], axis=-1)


def spines(pair: str, dtype, control_points: int = 8):
    """`(source, target, dense polyline of the source for sampling)` for a named pair."""
    if pair == "line-arc":
        dense = np.stack([np.linspace(0, 4, 4097), np.zeros(4097), np.zeros(4097)], -1)
        return fj.Line(np.asarray(4.0, dtype)), fj.Arc(np.asarray(3.0, dtype), 4.0), dense
    if pair == "bspline-bspline":
        control = _curve(np.linspace(0, 4, control_points))
        source = fj.BSpline(control.astype(dtype))
        target = fj.BSpline(_bend(control).astype(dtype))
        return source, target, _curve(np.linspace(0, 4, 4097))
    raise ValueError(f"unknown pair {pair!r}; choose from {PAIRS}")


def tube_points(dense: np.ndarray, n: int, dtype, seed: int = 0) -> np.ndarray:
    """`n` random points in a tube of radius `TUBE` around the polyline `dense` (any frame)."""
    rng = np.random.default_rng(seed)
    tangents = np.gradient(dense, axis=0)
    tangents /= np.linalg.norm(tangents, axis=-1, keepdims=True)
    a = np.cross(tangents, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.cross(tangents, a)
    k = rng.integers(0, len(dense), n)
    angle = rng.uniform(0, 2 * np.pi, n)
    r = TUBE * np.sqrt(rng.uniform(0, 1, n))
    out = dense[k] + (r * np.cos(angle))[:, None] * a[k] + (r * np.sin(angle))[:, None] * b[k]
    return out.astype(dtype)


# ---------------------------------------------------------------------------------- timing


def timed(fn, repeats: int, clear: bool = True):
    """`(first, median steady, result)`: wall times in s of a call (first after clearing)."""
    if clear:
        jax.clear_caches()
    start = time.perf_counter()
    result = jax.block_until_ready(fn())
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return first, statistics.median(times), result


def rate(n, seconds):
    return f"{n / seconds / 1e6:.3g}"


def parse_sizes(text: str) -> list[int]:
    return [int(float(x)) for x in text.split(",") if x]


def parse_list(text: str, allowed) -> list[str]:
    items = [x.strip() for x in text.split(",") if x.strip()]
    for item in items:
        if item not in allowed:
            raise SystemExit(f"unknown value {item!r}: choose from {', '.join(allowed)}")
    return items


# ---------------------------------------------------------------------------------- throughput


def throughput(args) -> bool:
    print(f"## Throughput (M points/s, median of {args.repeats} runs; compile s in brackets)\n")
    print(
        "| pair | method | dtype | N | register | pose | pose, no check | flesh |"
        " compile s: register / pose / pose nc / flesh |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---|")
    numpy_rows, ok = [], True
    checks = [True, False] if args.check_projection else [False]
    for pair in args.pairs:
        for dtype in args.dtypes:
            source, target, dense = spines(pair, dtype)
            for n in args.sizes:
                points = jax.device_put(tube_points(dense, n, dtype))
                c_reg, t_reg, registration = timed(
                    lambda: fj.register(points, source), args.repeats
                )
                for method in args.methods:
                    pose_times, compiles = {}, {}
                    for check in checks:

                        def run_pose(check=check):
                            return fj.pose(
                                registration, target, method=method, twist=0.3,
                                check_projection=check,
                            )  # fmt: skip

                        first, steady, _ = timed(run_pose, args.repeats)
                        pose_times[check], compiles[check] = steady, first - steady
                    flesh_check = args.check_projection
                    c_fl, t_fl, (out, valid) = timed(
                        lambda: fj.flesh(
                            points, source, target, method=method, twist=0.3,
                            check_projection=flesh_check,
                        ),
                        args.repeats,
                    )  # fmt: skip
                    pose_c = rate(n, pose_times[True]) if True in pose_times else "–"
                    comp_c = f"{compiles[True]:.2f}" if True in compiles else "–"
                    print(
                        f"| {pair} | {method} | {dtype} | {n:.0e} | {rate(n, t_reg)} | {pose_c} |"
                        f" {rate(n, pose_times[False])} | {rate(n, t_fl)} |"
                        f" {c_reg - t_reg:.2f} / {comp_c} / {compiles[False]:.2f} /"
                        f" {c_fl - t_fl:.2f} |",
                        flush=True,
                    )
                    if pair == "line-arc" and args.numpy:
                        row, good = numpy_row(args, points, out, valid, method, dtype, n)
                        numpy_rows.append(row + (rate(n, t_fl),))
                        ok &= good
    if numpy_rows:
        print("\n## NumPy reference, line → arc (M points/s; ratio = JAX / NumPy)\n")
        print(
            "| method | dtype | N | NumPy register | NumPy pose | NumPy flesh | JAX flesh |"
            " ratio flesh | max abs diff | validity mismatches |"
        )
        print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
        for row in numpy_rows:
            method, dtype, n, reg, pose_, flesh_, diff, bad, good, jax_flesh = row
            ratio = float(jax_flesh) / float(flesh_)
            mark = "" if good else " FAIL"
            print(
                f"| {method} | {dtype} | {n:.0e} | {reg} | {pose_} | {flesh_} | {jax_flesh} |"
                f" {ratio:.2f} | {diff:.1e}{mark} | {bad} |"
            )
    return ok


def numpy_row(args, points, out, valid, method, dtype, n):
    p = np.asarray(points)
    check = args.check_projection
    register = lambda: reference.register_line(p, 4.0, (0, 0, 0), (1, 0, 0))  # noqa: E731
    reg = register()

    def pose():
        return reference.pose_arc(
            p, *reg, 4.0, 3.0, 4.0, method=method, twist=0.3, check_projection=check
        )

    def flesh():
        return reference.flesh_line_arc(
            p, 4.0, 3.0, 4.0, method=method, twist=0.3, check_projection=check
        )

    t = {}
    for name, fn in (("register", register), ("pose", pose), ("flesh", flesh)):
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            result = fn()
            times.append(time.perf_counter() - start)
        t[name] = statistics.median(times)
    image, ok = result
    out, valid = np.asarray(out), np.asarray(valid)
    both = ok & valid
    diff = float(np.max(np.abs(image[both] - out[both]), initial=0.0))
    mismatches = int(np.sum(ok != valid))
    tolerance = 1e-5 if dtype == "float32" else 1e-10
    good = diff <= tolerance and mismatches == 0 and both.any()
    return (
        method, dtype, n, rate(n, t["register"]), rate(n, t["pose"]), rate(n, t["flesh"]),
        diff, mismatches, good,
    ), good  # fmt: skip


# ---------------------------------------------------------------------------------- memory


def _resident():
    fields = {}
    with open("/proc/self/status") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                fields[key] = int(value.split()[0]) * 1024
    return fields


def _peak(fn):
    """Bytes above the current resident set at the peak of `fn()` (run once before)."""
    jax.block_until_ready(fn())
    gc.collect()
    before = _resident()["VmRSS"]
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # resets VmHWM to the current resident set
    result = jax.block_until_ready(fn())
    peak = _resident()["VmHWM"] - before
    del result
    gc.collect()
    return peak


def probe(spec: str) -> None:
    """Subprocess entry: peak memory of one configuration, printed as JSON."""
    pair, dtype, n, method, check = spec.split(",")
    jax.config.update("jax_enable_x64", dtype == "float64")
    n, check = int(n), check == "1"
    source, target, dense = spines(pair, dtype)
    points = jax.device_put(tube_points(dense, n, dtype))
    kwargs = dict(method=method, twist=0.3, check_projection=check)
    peaks = {"register": _peak(lambda: fj.register(points, source))}
    registered = jax.block_until_ready(fj.register(points, source))
    peaks["pose"] = _peak(lambda r=registered: fj.pose(r, target, **kwargs))
    del registered
    gc.collect()
    peaks["flesh"] = _peak(lambda: fj.flesh(points, source, target, **kwargs))
    if pair == "line-arc":
        p = np.asarray(points)
        peaks["numpy flesh"] = _peak(lambda: reference.flesh_line_arc(p, 4.0, 3.0, 4.0, **kwargs))
    print(json.dumps(peaks))


def memory(args) -> None:
    method = args.methods[0]
    print(
        f"\n## Peak memory above the inputs ({method}, check_projection="
        f"{args.check_projection}; MB, and × (input + output arrays))\n"
    )
    print("| pair | dtype | N | in + out MB | register | pose | flesh | NumPy flesh |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    env = dict(os.environ, MALLOC_MMAP_THRESHOLD_="65536")
    for pair in args.pairs:
        for dtype in args.dtypes:
            for n in args.sizes:
                spec = f"{pair},{dtype},{n},{method},{int(args.check_projection)}"
                done = subprocess.run(
                    [sys.executable, __file__, "--_probe", spec],
                    env=env, capture_output=True, text=True,
                )  # fmt: skip
                if done.returncode != 0:
                    print(f"| {pair} | {dtype} | {n:.0e} | probe failed: "
                          f"{done.stderr.strip().splitlines()[-1:]} |||||")  # fmt: skip
                    continue
                peaks = json.loads(done.stdout.strip().splitlines()[-1])
                size = np.dtype(dtype).itemsize
                io = n * (6 * size + 1)
                cells = [
                    f"{peaks[k] / 2**20:.3g} ({peaks[k] / io:.1f}×)" if k in peaks else "–"
                    for k in ("register", "pose", "flesh", "numpy flesh")
                ]
                head = f"| {pair} | {dtype} | {n:.0e} | {io / 2**20:.3g} | "
                print(head + " | ".join(cells) + " |", flush=True)


# ---------------------------------------------------------------------------------- resolution


def resolution(args) -> None:
    """Registration against spine resolution, split into the once-per-spine preparation
    (tables, search samples, reach bounds: linear in the resolution, independent of N) and the
    per-point work with the spine prepared (the coarse-to-fine search: logarithmic)."""
    from fleshing_jax._fleshing.pipeline import _register, _registrar

    n = args.resolution_size
    dtype = args.dtypes[0]
    dense = _curve(np.linspace(0, 4, 8193))
    points = jax.device_put(tube_points(dense, n, dtype))
    print(f"\n## Registration cost against spine resolution (N = {n:.0e}, {dtype})\n")
    print("| spine | resolution | search samples | register M points/s | preparation ms |"
          " prepared: M points/s | prepared time / at lowest | compile s |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    cases = [("BSpline control points", c) for c in (8, 16, 32, 64, 128, 256)]
    cases += [("Polyline vertices", v) for v in (64, 128, 256, 512, 1024, 2048, 4096)]
    base = {}
    for kind, size in cases:
        u = np.linspace(0, 4, size)
        if kind.startswith("BSpline"):
            spine = fj.BSpline(_curve(u).astype(dtype))
        else:
            spine = fj.Polyline(_curve(u).astype(dtype))
        samples = spine.default_samples()
        first, steady, _ = timed(lambda: fj.register(points, spine), args.repeats)
        _, prepare, registrar = timed(lambda: _registrar(spine, samples), args.repeats, False)
        _, per_point, _ = timed(lambda: _register(registrar, points), args.repeats, False)
        base.setdefault(kind, per_point)
        print(
            f"| {kind.split()[0]} | {kind.split(maxsplit=1)[1]}: {size} | {samples} |"
            f" {rate(n, steady)} | {prepare * 1e3:.3g} | {rate(n, per_point)} |"
            f" {per_point / base[kind]:.2f} | {first - steady:.2f} |",
            flush=True,
        )


# ---------------------------------------------------------------------------------- main


# ---------------------------------------------------------------------------------- tube


POSE_BYTES = 12 + 4 + 8 + 8 + 1 + 12 + 1  # points, s, offset, curvature, flag in; image, flag out
FLESH_BYTES = 12 + 12 + 1


def tube(args) -> None:
    """Issue 19's per-frame table: `pose` and `flesh` on a 1M-vertex tube, with a roofline."""
    angle = np.linspace(0.0, 2 * np.pi, 256, endpoint=False)
    contour = 0.3 * np.column_stack([np.cos(angle), np.sin(angle)])
    points = jax.numpy.asarray(np.asarray(fj.extrusion(contour, 4.0, 4000).vertices, np.float32))
    n = points.shape[0]
    source = fj.Line(np.float32(4.0))
    target = fj.Arc(np.float32(1.2), np.float32(4.0))
    registration = fj.register(points, source)
    _, pose_s, (_, valid) = timed(lambda: fj.pose(registration, target), args.repeats)
    _, flesh_s, _ = timed(lambda: fj.flesh(points, source, target), args.repeats)
    block = np.random.default_rng(0).random((n, 12), np.float32)  # 48 MB, pages touched
    copy = np.empty_like(block)
    _, stream_s, _ = timed(lambda: np.copyto(copy, block), max(args.repeats, 10), clear=False)
    bandwidth = 2 * block.nbytes / stream_s
    print(f"\n## Tube: {n} vertices, Line(4) → Arc(1.2, 4), float32, radial "
          f"({int(np.sum(valid))} valid)\n")
    print(f"plain array copy: {bandwidth / 1e9:.1f} GB/s (median of {max(args.repeats, 10)})\n")
    print("| call | median | M points/s | bytes/point | roofline M points/s | fraction |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, seconds, moved in (("pose", pose_s, POSE_BYTES), ("flesh", flesh_s, FLESH_BYTES)):
        limit = bandwidth / moved
        print(f"| {name} | {1e3 * seconds:.1f} ms | {n / seconds / 1e6:.1f} | {moved} | "
              f"{limit / 1e6:.0f} | {n / seconds / limit:.0%} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="1e4,1e5,1e6,4e6", help="comma-separated N")
    parser.add_argument("--dtypes", default="float32,float64")
    parser.add_argument("--methods", default=",".join(fj.METHODS))
    parser.add_argument("--pairs", default=",".join(PAIRS))
    parser.add_argument(
        "--check-projection",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="time pose and flesh with the projection check too (pose is always timed without)",
    )
    parser.add_argument("--repeats", type=int, default=3, help="steady-state runs (median)")
    parser.add_argument("--numpy", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--memory", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--throughput", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--resolution", action="store_true", help="run the resolution study")
    parser.add_argument("--resolution-size", type=lambda x: int(float(x)), default=100_000)
    parser.add_argument("--tube", action="store_true", help="also the 1M-vertex tube table")
    parser.add_argument("--tube-only", action="store_true", help="only the tube table")
    parser.add_argument("--_probe", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args._probe:
        probe(args._probe)
        return 0
    args.sizes = parse_sizes(args.sizes)
    args.dtypes = parse_list(args.dtypes, ("float32", "float64"))
    args.methods = parse_list(args.methods, fj.METHODS)
    args.pairs = parse_list(args.pairs, PAIRS)
    args.repeats = max(3, args.repeats)
    # float64 needs x64; float32-only runs leave it off, as a float32 user would.
    jax.config.update("jax_enable_x64", "float64" in args.dtypes)
    print(f"jax {jax.__version__}, {jax.devices()[0].platform}, {os.cpu_count()} cores\n")
    ok = True
    if args.tube_only:
        tube(args)
        return 0
    if args.throughput:
        ok = throughput(args)
    if args.memory and sys.platform.startswith("linux"):
        memory(args)
    if args.resolution:
        resolution(args)
    if args.tube:
        tube(args)
    if not ok:
        print("\nNumPy reference and fj.flesh disagree (see the table).", file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

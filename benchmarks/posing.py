"""Posing spot limb by limb (issue 33): the targets of speed and volume.

    python benchmarks/posing.py                   # all three tables and the figure
    python benchmarks/posing.py --skip-skeleton   # spot's saved skeleton, not built again
    python benchmarks/posing.py --only-frames     # the per-frame tables only (2, 2b below)
    python benchmarks/posing.py --skip-skeleton --spot-frames   # spot's own frames only (2b)
    python benchmarks/posing.py --skip-skeleton --only-volumes  # the volume table only (3)
    python benchmarks/posing.py --skip-skeleton --only-fit      # the fit table only (4)
    python benchmarks/posing.py --quadruped --figure F.png     # the quadruped's table (5)

Prints Markdown tables:

1. The skeleton of spot (2,930 vertices) with its medial mesh (200 spheres), wall time.
2. A new pose of spot subdivided to about 100k vertices (trimesh's `subdivide` keeps the old
   vertices first; a new vertex takes the region of its nearest old one), registered once in
   float32; `jax.jit(lambda poses: fj.pose_skeleton(...).vertices)` per frame, medians.
   2b. (`--spot-frames`: this one only) spot itself (2,930 vertices) registered in float32
   (1, 3 and all 9 limbs posed) and float64 (`--float64-limbs`, default 1 and 3), a new bend
   every frame: per-frame medians and the programs compiled after the first frame
   (`frame_table`).
3. A hind leg and the head posed together on spot in float64, the bends' directions turned by
   0, 90, 180 and 270°: whole-mesh volume change of ours
   against medial deformation, LBS and DQS given the same intent (every sphere of the medial
   mesh a handle: those of a posed limb's region sent where our map sends their centres,
   those of the limbs below it by its end motion, the others held), max
   |det J − 1| in the posed regions, the largest stretch of an edge crossing a region border,
   whether the body is bit for bit still. `--figure PATH` writes the before/after picture.
4. `fj.fit_skeleton_pose` on spot: the leg, then the leg and the head, brought back to their
   valid poses of 2 from every 40th vertex of their regions, starting at rest, in float64 and
   float32: the first call (its compilation included, none cached) and the second, wall time.
5. With `--quadruped`: a four-legged animal with separate thin legs (`quadruped(32)`, 4,256
   vertices) posed on its own skeleton in float64: a front leg lifted 60°, then with a hind
   leg and the tail: volume change, invalid vertices, max |det J − 1| in the posed regions,
   the largest stretch of an edge crossing a region border, the rest bit for bit still.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np
import trimesh

import fleshing_jax as fj
from fleshing_jax._skeleton.posing import end_motion  # a posed limb's motion of its children
from fleshing_jax._skeleton.skeleton import descendants

SAVED_SKELETON = Path(__file__).resolve().parents[1] / "notebooks" / "data" / "spot-skeleton.json"
HEAD, LEG = 0, 8  # spot's head/neck and a hind leg (every limb is valid at rest)
POSES = {HEAD: (10.0, 90.0), LEG: (30.0, 0.0)}  # bend, direction (degrees): all valid


def _median_ms(fn, arg, frames):
    """`(wall, CPU)` medians (ms) of `frames` calls `fn(arg)`, after one (the CPU time of all
    threads: steadier than the wall time on a loaded machine)."""
    fn(arg).block_until_ready()
    times, cpu = [], []
    for _ in range(frames):
        start, used = time.perf_counter(), time.process_time()
        fn(arg).block_until_ready()
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - used)
    return 1e3 * float(np.median(times)), 1e3 * float(np.median(cpu))


def skeleton_time(spot):
    start = time.perf_counter()
    skeleton = fj.skeleton(spot)
    return skeleton, time.perf_counter() - start


def subdivided(spot, skeleton, count=100_000):
    """spot subdivided to about `count` vertices (twice whole, then the first faces once more:
    the mesh is for timing, its T-junctions do not matter), regions carried to the new
    vertices."""
    vertices, faces = np.asarray(spot.vertices), np.asarray(spot.faces)
    for _ in range(2):
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
    # A subdivided face adds its three edge midpoints, each shared with a neighbour.
    more = int((count - len(vertices)) / 1.5)
    vertices, faces = trimesh.remesh.subdivide(vertices, faces, face_index=np.arange(more))
    from scipy.spatial import cKDTree

    old = np.asarray(spot.vertices)
    nearest = cKDTree(old).query(vertices)[1]
    region = np.asarray(skeleton.region)[nearest]
    region[: len(old)] = np.asarray(skeleton.region)  # subdivide keeps the old vertices first
    return trimesh.Trimesh(vertices, faces, process=False), region


def pose_speed(spot, skeleton, frames=50):
    import equinox as eqx
    import jax.numpy as jnp

    big, region = subdivided(spot, skeleton)
    big_skeleton = eqx.tree_at(lambda s: s.region, skeleton, jnp.asarray(region))
    start = time.perf_counter()
    registration = fj.register_skeleton(big, big_skeleton, dtype=jnp.float32)
    registered = time.perf_counter() - start
    frame = jax.jit(lambda poses: fj.pose_skeleton(registration, big_skeleton, poses).vertices)
    rows = []
    for name, limbs in (("leg", [LEG]), ("head", [HEAD]), ("leg + head", [LEG, HEAD])):
        poses = {k: fj.LimbPose(*POSES[k]) for k in limbs}
        start = time.perf_counter()
        frame(poses).block_until_ready()
        first = time.perf_counter() - start
        rows.append((name, first, *_median_ms(frame, poses, frames)))
    return len(big.vertices), registered, rows


SPOT_LIMBS = (LEG, HEAD, 5, 6, 7, 1, 2, 3, 4)  # posed in this order: 1, 3 or all 9 of them


def frame_table(mesh, skeleton, dtype, counts=(1, 3, 9), frames=50, order=SPOT_LIMBS):
    """Rows `(dtype, limbs posed, first call (s), per frame (ms, median), its CPU time (ms,
    median: all threads; steadier than the wall time on a loaded machine), recompilations)`:
    `mesh` registered once in `dtype`, then `jax.jit(lambda poses: fj.pose_skeleton(...))`
    a frame, each frame a new bend (10° + 0.2° a frame, the direction and twist fixed) of the
    first `count` limbs of `order`; recompilations: the programs the jitted frame gained
    after its first call (0: one program for every angle)."""
    registration = fj.register_skeleton(mesh, skeleton, dtype=dtype)
    frame = jax.jit(lambda poses: fj.pose_skeleton(registration, skeleton, poses).vertices)
    rows = []
    for count in counts:
        limbs = order[:count]

        def poses(i):
            return {k: fj.LimbPose(10.0 + 0.2 * i, 30.0, 5.0) for k in limbs}

        start = time.perf_counter()
        frame(poses(0)).block_until_ready()
        first, programs = time.perf_counter() - start, frame._cache_size()
        times, cpu = [], []
        for i in range(1, frames + 1):
            start, used = time.perf_counter(), time.process_time()
            frame(poses(i)).block_until_ready()
            times.append(time.perf_counter() - start)
            cpu.append(time.process_time() - used)
        rows.append((np.dtype(dtype).name, count, first, 1e3 * float(np.median(times)),
                     1e3 * float(np.median(cpu)), frame._cache_size() - programs))
    return rows


def fit_time(spot, skeleton):
    """Rows `(limbs, dtype, vertices, first call (s), second call (s), rms, steps)`."""
    rows = []
    for dtype in (np.float64, np.float32):
        registration = fj.register_skeleton(spot, skeleton, dtype=dtype)
        region = np.asarray(skeleton.region)
        for limbs in ((LEG,), (LEG, HEAD)):
            poses = {k: fj.LimbPose(*POSES[k]) for k in limbs}
            ids = np.concatenate([np.flatnonzero(region == k)[::40] for k in limbs])
            targets = np.asarray(fj.pose_skeleton(registration, skeleton, poses).vertices)[ids]
            seconds = []
            for _ in range(2):
                start = time.perf_counter()
                fit = fj.fit_skeleton_pose(registration, skeleton, ids, targets)
                fit.rms.block_until_ready()
                seconds.append(time.perf_counter() - start)
            assert fit.converged, fit.message
            names = " + ".join("leg" if k == LEG else "head" for k in limbs)
            rows.append((names, np.dtype(dtype).name, len(ids), *seconds, float(fit.rms),
                         int(fit.num_steps)))
    return rows


def _sphere_regions(medial, vertices, region):
    """The region of the vertex nearest each sphere's centre."""
    from scipy.spatial import cKDTree

    return region[cKDTree(vertices).query(np.asarray(medial.centers))[1]]


def posed_measures(mesh, skeleton, poses):
    """`mesh` posed by `poses` (float64): `(vertices, valid, ΔV/V, max |det J − 1| in the posed
    regions, the largest stretch of an edge crossing a region border, whether the vertices
    of the regions neither posed nor below a posed limb are bit for bit still, {limb: (rest
    spine, bent spine)})`."""
    registration = fj.register_skeleton(mesh, skeleton)
    out = fj.pose_skeleton(registration, skeleton, poses)
    vertices, valid = np.asarray(out.vertices), np.asarray(out.valid)
    rest = np.asarray(mesh.vertices)
    region = np.asarray(skeleton.region)
    change = float(fj.volume(vertices, mesh.faces) / fj.volume(rest, mesh.faces)) - 1
    det, bents = [], {}
    for k in poses:
        spine = registration.rests[k]
        bent = poses[k].spine(spine, registration.joints[k], registration.stops[k])
        bents[k] = (spine, bent)
        ids = np.flatnonzero(region == k)
        d = np.asarray(fj.jacobian_determinant(
            fj.Fleshing(spine, bent, beyond="rigid"), rest[ids]))  # fmt: skip
        det.append(np.nanmax(np.abs(d - 1)))
    edges = mesh.edges_unique
    crossing = region[edges[:, 0]] != region[edges[:, 1]]
    length = lambda v: np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)  # noqa: E731
    stretch = float(np.max(length(vertices)[crossing] / length(rest)[crossing]))
    below = descendants(skeleton.limbs)
    moving = np.isin(region, [*poses, *(d for k in poses for d in below[k])])
    still = bool(np.array_equal(vertices[~moving], rest[~moving]))
    return vertices, valid, change, max(det), stretch, still, bents


QUADRUPED_POSES = (  # (name, {leg or tail: (bend, direction)}) on `quadruped`'s skeleton
    ("front leg 60°", {"front": (60.0, 0.0)}),
    ("front leg 60°, hind leg 45°, tail 40°",
     {"front": (60.0, 0.0), "hind": (45.0, 180.0), "tail": (40.0, 90.0)}),
)


def quadruped_table(figure=None):
    """Rows `(pose, vertices, ΔV/V, invalid, max |det J − 1|, border stretch, still)` of
    `quadruped(32)` (`fleshing_jax._medial_axis.animal`: four separate thin legs, a tail,
    horns) posed on its skeleton (200 spheres): a front leg, then a hind leg and the tail."""
    from fleshing_jax._medial_axis.animal import quadruped

    mesh = quadruped(32)
    skeleton = fj.skeleton(mesh)
    tips = np.array([np.asarray(limb.spine(limb.spine.length)) for limb in skeleton.limbs])
    top = [k for k, limb in enumerate(skeleton.limbs) if limb.parent == -1]
    limbs = {  # z up, the head towards +x
        "front": next(k for k in top if tips[k, 2] < 0 and tips[k, 0] > 0.5 and tips[k, 1] > 0),
        "hind": next(k for k in top if tips[k, 2] < 0 and tips[k, 0] < 0.5 and tips[k, 1] < 0),
        "tail": next(k for k in top if tips[k, 0] < 0),
    }
    rows = []
    for name, wanted in QUADRUPED_POSES:
        poses = {limbs[part]: fj.LimbPose(*angles) for part, angles in wanted.items()}
        vertices, valid, change, det, stretch, still, _ = posed_measures(mesh, skeleton, poses)
        rows.append((name, len(vertices), change, int((~valid).sum()), det, stretch, still))
    if figure is not None:
        region = np.asarray(skeleton.region)
        _picture(figure, mesh, np.asarray(mesh.vertices), vertices, None, region,
                 (f"quadruped, {len(vertices):,} vertices", rows[-1][0]), view=(12, -60))
    return rows


def volume_table(spot, skeleton, medial, figure=None, turn=0.0):
    """The volume table for `POSES`, each bend's direction turned by `turn` degrees."""
    import jax.numpy as jnp

    poses = {k: fj.LimbPose(bend, direction + turn) for k, (bend, direction) in POSES.items()}
    vertices, valid, ours, det, stretch, still, bents = posed_measures(spot, skeleton, poses)
    rest = np.asarray(spot.vertices)
    region = np.asarray(skeleton.region)
    v0 = fj.volume(rest, spot.faces)
    # The same intent for the medial mesh, every sphere a handle: a posed limb's spheres
    # carried by our map, those of the limbs below it (the head's ears and horns) by its end
    # motion, the others (the body, the legs not posed) held where they are.
    centers = np.asarray(medial.centers)
    owner = _sphere_regions(medial, rest, region)
    targets = centers.copy()
    for k in POSES:
        moved = owner == k
        targets[moved] = np.asarray(fj.flesh(jnp.asarray(centers[moved]), *bents[k],
                                             beyond="rigid")[0])
        below = np.isin(owner, descendants(skeleton.limbs)[k])
        targets[below] = np.asarray(end_motion(*bents[k])(jnp.asarray(centers[below])))
    handles = np.arange(len(centers))
    rows = [("Fleshing (ours)", ours, int((~valid).sum()))]
    deformed = {}
    for method, implicit in (("medial", True), ("lbs", False), ("dqs", False)):
        result = fj.deform_medial(spot, medial, handles, targets, method, implicit=implicit)
        deformed[method] = np.asarray(result.vertices)
        rows.append(
            (
                method,
                fj.volume(deformed[method], spot.faces) / v0 - 1,
                int((~np.asarray(result.vertex_attributes["valid"])).sum()),
            )
        )
    if figure is not None:
        _picture(figure, spot, rest, vertices, deformed["medial"], region)
    return rows, det, stretch, still


def _picture(path, spot, rest, ours, medial, region, titles=None, view=(10, -70)):
    """Rest, ours and medial deformation (when given), rendered as shaded triangles (side
    view; spot's y up, a mesh with z up when `titles`, its titles, are given)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    colours = plt.get_cmap("tab10")(np.arange(10))
    face_region = region[spot.faces].max(axis=1)
    shown = [("rest", rest), ("Fleshing: leg 30°, head 10°", ours)]
    if titles is not None:
        shown = [(titles[0] + ", rest", rest), (titles[1], ours)]
    if medial is not None:
        shown.append(("medial deformation, same intent", medial))
    fig = plt.figure(figsize=(13 * len(shown) / 3, 4.6))
    for i, (title, v) in enumerate(shown):
        ax = fig.add_subplot(1, len(shown), i + 1, projection="3d")
        axes = [2, 0, 1] if titles is None else [0, 1, 2]  # spot: z across, x deep, y up
        triangles = v[spot.faces][:, :, axes]
        normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
        shade = 0.45 + 0.55 * np.clip(normal @ np.array([0.3, -0.5, 0.8]), 0, 1)
        base = np.where(face_region[:, None] < 0, 0.8, colours[face_region % 10, :3])
        ax.add_collection3d(Poly3DCollection(triangles, facecolors=base * shade[:, None],
                                             edgecolor="none"))  # fmt: skip
        low, high = rest[:, axes].min(axis=0), rest[:, axes].max(axis=0)
        half = 0.55 * float(np.max(high - low))
        for centre, limits in zip((low + high) / 2, (ax.set_xlim, ax.set_ylim, ax.set_zlim)):
            limits(centre - half, centre + half)
        ax.view_init(*view)
        ax.set_axis_off()
        ax.set_title(title)
    fig.tight_layout()
    partial = Path(str(path) + ".partial.png")
    fig.savefig(partial, dpi=80)
    partial.replace(path)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--skip-skeleton", action="store_true")
    parser.add_argument("--figure", type=Path, default=None)
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--only-frames", action="store_true", help="the per-frame tables only")
    parser.add_argument("--spot-frames", action="store_true",
                        help="the per-frame table of spot itself only (2b)")
    parser.add_argument("--float64-limbs", type=lambda v: tuple(int(c) for c in v.split(",")),
                        default=(1, 3), help="limb counts of the float64 rows (default 1,3: "
                        "all 9 compile for minutes)")
    parser.add_argument("--only-volumes", action="store_true", help="the volume table only")
    parser.add_argument("--only-fit", action="store_true", help="the fit table only")
    parser.add_argument("--quadruped", action="store_true", help="the quadruped's table only")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)  # float64 for the volumes; the pose is float32
    for name, value in fj.compilation_cache_settings().items():  # compiled programs on disk
        jax.config.update(name, value)
    if args.quadruped:
        print("| pose | vertices | ΔV/V | invalid | max abs(det J − 1) | border stretch | "
              "the rest still |\n|---|---:|---:|---:|---:|---:|---|")
        for name, n, change, invalid, det, stretch, still in quadruped_table(args.figure):
            print(f"| {name} | {n} | {100 * change:+.4f} % | {invalid} | {det:.2e} | "
                  f"{stretch:.3f} | {still} |")
        return
    spot = fj.data.spot()
    if args.skip_skeleton:  # the skeleton the notebooks load (the same build, saved)
        skeleton = fj.load_skeleton(SAVED_SKELETON)
    else:
        skeleton, seconds = skeleton_time(spot)
        print(
            f"| mesh | vertices | limbs | skeleton incl. medial mesh (s) |\n|---|---:|---:|---:|\n"
            f"| spot | {len(spot.vertices)} | {len(skeleton.limbs)} | {seconds:.1f} |\n"
        )
    if args.only_fit:
        print("| fitted | dtype | vertices | first call (s) | second (s) | rms | steps |\n"
              "|---|---|---:|---:|---:|---:|---:|")
        for names, dtype, k, first, second, rms, steps in fit_time(spot, skeleton):
            print(f"| {names} | {dtype} | {k} | {first:.1f} | {second:.2f} | {rms:.1e} | {steps} |")
        return
    if not (args.only_volumes or args.spot_frames):
        n, registered, rows = pose_speed(spot, skeleton, args.frames)
        print(f"{n} vertices, float32, registered once in {registered:.1f} s\n")
        print("| posed | first frame (s) | per frame (ms, median) | CPU (ms) |\n"
              "|---|---:|---:|---:|")
        for name, first, ms, cpu in rows:
            print(f"| {name} | {first:.1f} | {ms:.2f} | {cpu:.2f} |")
    if args.only_frames or args.spot_frames:
        print(f"\nspot, {len(spot.vertices):,} vertices, jitted frames\n")
        print("| dtype | limbs posed | first call (s) | per frame (ms, median) | CPU (ms) | "
              "recompilations |\n|---|---:|---:|---:|---:|---:|")
        for dtype, counts in ((np.float32, (1, 3, 9)), (np.float64, args.float64_limbs)):
            for name, count, first, ms, cpu, again in frame_table(spot, skeleton, dtype, counts,
                                                                  args.frames):
                print(f"| {name} | {count} | {first:.1f} | {ms:.2f} | {cpu:.2f} | {again} |",
                      flush=True)
        return
    medial = fj.medial_mesh(spot, 200, progress=False)
    turns = (0.0, 90.0, 180.0, 270.0)  # the bends' directions turned: the same angles
    tables = [volume_table(spot, skeleton, medial, args.figure if not t else None, t)
              for t in turns]  # fmt: skip
    print("\n| method | " + " | ".join(f"ΔV/V, turned {t:.0f}°" for t in turns) + " |")
    print("|---|" + "---:|" * len(turns))
    for i, (name, *_) in enumerate(tables[0][0]):
        cells = [f"{100 * rows[i][1]:+.4f} % ({rows[i][2]})" for rows, *_ in tables]
        print(f"| {name} | " + " | ".join(cells) + " |")
    for t, (_, det, stretch, still) in zip(turns, tables):
        print(
            f"turned {t:.0f}°: max |det J − 1| in the posed regions {det:.2e}; largest stretch "
            f"of an edge crossing a region border {stretch:.3f}; the rest (neither posed nor "
            f"below a posed limb) bit for bit still: {still}"
        )


if __name__ == "__main__":
    main()

"""Medial-axis-driven deformation (Lan et al. 2017) against the targets of issue 18.

    python benchmarks/medial_deform.py            # volumes, then speed
    python benchmarks/medial_deform.py --quick    # the capsule only, no speed table

Prints Markdown tables:

1. Volumes: a capsule (radius 0.5, axis 4, medial mesh from `fj.medial_mesh`) bent 90° and
   180° by moving its spheres of the first and last quarter onto an arc of the axis' length
   (the others free), and twisted 180° by rotating its last quarter's spheres about the axis
   (rotations prescribed, no centre moved); spot (`fj.data.spot()`: y up, its head towards
   −z) with its head turned 30° about the vertical through the neck, its rump (with the hind
   legs and tail) turned 30° the same way, and its right hind leg (+x) swung by 30°, each
   about a pivot, its body's core held; each case's picture (`--figures DIR`: the moved
   spheres in red, the rest pose in grey) is shown in benchmarks/README.md. For each:
   `|ΔV/V|` of `medial` (with the implicit
   correction), LBS and DQS (without it, as baselines), and Fleshing's radial map on the
   bent capsule (rest spine: its axis through the caps; target: an arc of the same
   curvature; Fleshing's twist is a rigid rotation, so there is no twist to compare). Total
   volume hides redistribution (DQS keeps it by bulging), so the capsule rows also give the **radius
   error**: over the vertices of the capsule's cylinder, the largest `|d/0.5 − 1|` of their
   distance `d` to the bent (or twisted) axis.
2. Speed (`--speed`: this table only): binding a capsule of about 30k vertices to medial
   meshes of 200 and 300 spheres; one frame (ARAP on about 300 spheres +
   skin of about 100k vertices, float32, one compiled program) and its parts; one frame of
   spot (2,930 vertices, 200 spheres), ARAP from its first guess or warm from the previous
   frame; medians of 20 after compilation.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import trimesh

import fleshing_jax as fj

METHODS = (("medial", True), ("lbs", False), ("dqs", False))


def capsule(sections: int, edge: float) -> trimesh.Trimesh:
    """A closed capsule along z (radius 0.5, cylinder length 4) with edges at most `edge`
    long (trimesh's own capsule spans its cylinder with single long triangles)."""
    mesh = trimesh.creation.capsule(height=4.0, radius=0.5, count=[sections, sections])
    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, edge)
    return trimesh.Trimesh(vertices, faces, process=False)


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _on_arc(points, radius):
    """Points near the z axis (z in [−2, 2]) carried onto an arc of radius `radius` in the
    x–z plane, tangent to the axis at z = −2: the bend the handles are given."""
    s = points[:, 2] + 2.0
    t = s / radius
    centre = np.column_stack([radius * (1 - np.cos(t)), np.zeros_like(t), radius * np.sin(t) - 2])
    normal = np.column_stack([-np.cos(t), np.zeros_like(t), np.sin(t)])  # towards the outside
    return centre - points[:, :1] * normal + points[:, 1:2] * np.array([0.0, 1.0, 0.0])


def _capsule_case(name, mesh, medial, degrees=None, twist=None):
    centers = np.asarray(medial.centers)
    z = centers[:, 2]
    first, last = np.flatnonzero(z < -1.0), np.flatnonzero(z > 1.0)
    handles = np.r_[first, last]
    rotations = None
    if degrees is not None:
        radius = 4.0 / np.radians(degrees)
        targets = _on_arc(centers[handles], radius)
    else:
        targets = centers[handles]
        rotations = np.stack([np.eye(3)] * len(first) + [_rotation([0, 0, 1], twist)] * len(last))
    row = {"case": name}
    cylinder = np.abs(np.asarray(mesh.vertices)[:, 2]) < 2.0
    v0 = fj.volume(mesh.vertices, mesh.faces)
    for method, implicit in METHODS:
        out = fj.deform_medial(mesh, medial, handles, targets, method, rotations=rotations,
                               implicit=implicit)
        row[method] = (float(fj.volume(out.vertices, out.faces) / v0 - 1),
                       _radius_error(np.asarray(out.vertices)[cylinder], degrees))
    row["fleshing"] = None  # Fleshing's twist is global (rigid): no graded twist to compare
    if degrees is not None:  # the same curvature along the rest spine through the caps
        source = fj.Line(5.0, origin=(0, 0, -2.5), tangent=(0, 0, 1))
        target = fj.Arc(4.0 / np.radians(degrees), 5.0, origin=(0, 0, -2.5), tangent=(0, 0, 1),
                        normal=(1, 0, 0))
        out = fj.deform_mesh(mesh, source, target, method="radial")
        row["fleshing"] = (float(fj.volume(out.vertices, out.faces) / v0 - 1), None)
    return row


def _radius_error(vertices, degrees):
    """Largest `|d/0.5 − 1|` of the distance of cylinder vertices to the bent axis (the arc
    of radius 4/angle through the handles' targets), or to the straight axis."""
    if degrees is None:
        d = np.linalg.norm(vertices[:, :2], axis=1)
    else:
        radius = 4.0 / np.radians(degrees)
        centre = np.array([radius, 0.0, -2.0])  # the arc's centre, in the x–z plane
        in_plane = np.linalg.norm((vertices - centre)[:, [0, 2]], axis=1)
        d = np.hypot(in_plane - radius, vertices[:, 1])
    return float(np.max(np.abs(d / 0.5 - 1)))


def _spot_case(name, mesh, medial, moved, pivot, axis, angle, figures=None):
    centers = np.asarray(medial.centers)
    core = np.flatnonzero((np.abs(centers[:, 2] + 0.1) < 0.25) & (centers[:, 1] > -0.1))
    handles = np.r_[moved, np.setdiff1d(core, moved)]
    rotation = _rotation(axis, angle)
    targets = centers[handles].copy()
    targets[: len(moved)] = (centers[moved] - pivot) @ rotation.T + pivot
    rotations = np.stack([rotation] * len(moved) + [np.eye(3)] * (len(handles) - len(moved)))
    v0 = fj.volume(mesh.vertices, mesh.faces)
    row = {"case": name}
    for method, implicit in METHODS:
        out = fj.deform_medial(mesh, medial, handles, targets, method, rotations=rotations,
                               implicit=implicit)
        row[method] = (float(fj.volume(out.vertices, out.faces) / v0 - 1), None)
        if figures is not None and method == "medial":
            _picture(figures, name, mesh, out, centers[moved])
    row["fleshing"] = None
    return row


def _picture(folder: Path, name: str, mesh, posed, moved) -> None:
    """Side and top views of the rest (grey) and posed (blue) vertices, the moved spheres'
    centres in red: spot's y is up (side view: z across, y up; top view: z across, x up)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rest, bent = np.asarray(mesh.vertices), np.asarray(posed.vertices)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for ax, (down, title) in zip(axes, ((1, "side (y up)"), (0, "top (x up)"))):
        ax.scatter(rest[:, 2], rest[:, down], s=0.4, c="0.75")
        ax.scatter(bent[:, 2], bent[:, down], s=0.4, c="tab:blue")
        ax.scatter(moved[:, 2], moved[:, down], s=12, c="tab:red")
        ax.set_aspect("equal")
        ax.set_xlabel("z (head at −z)")
        ax.set_title(title)
    fig.suptitle(name)
    fig.tight_layout()
    slug = "-".join("".join(ch if ch.isalnum() else " " for ch in name.lower()).split())
    fig.savefig(folder / f"medial-deform-{slug}.png", dpi=80)
    plt.close(fig)


def volumes(quick: bool, figures: Path | None = None):
    tube = capsule(24, 0.2)
    medial = fj.medial_mesh(tube, 60, progress=False)
    rows = [
        _capsule_case("capsule bent 90°", tube, medial, degrees=90),
        _capsule_case("capsule bent 180°", tube, medial, degrees=180),
        _capsule_case("capsule twisted 180°", tube, medial, twist=np.pi),
    ]
    if not quick:
        spot = fj.data.spot()  # y up, head towards −z
        spot_medial = fj.medial_mesh(spot, 200, progress=False)
        c = np.asarray(spot_medial.centers)
        # The head: in front of the neck (z < −0.35), above the front legs.
        head = np.flatnonzero((c[:, 2] < -0.35) & (c[:, 1] > 0.0))
        # The rump: behind z = 0.6, with the hind legs and the tail. (Before issue 31 this
        # case was named "head", and a "front leg" case moved the lower spheres of both
        # right legs, z > 0.)
        rump = np.flatnonzero(c[:, 2] > 0.6)
        hind_leg = np.flatnonzero((c[:, 1] < -0.45) & (c[:, 0] > 0) & (c[:, 2] > 0.4))
        rows.append(_spot_case("spot: head turned 30°", spot, spot_medial, head,
                               np.array([0.0, 0.3, -0.3]), [0, 1, 0], np.radians(30),
                               figures))  # fmt: skip
        rows.append(_spot_case("spot: rump turned 30°", spot, spot_medial, rump,
                               np.array([0.0, 0.2, 0.55]), [0, 1, 0], np.radians(30),
                               figures))  # fmt: skip
        rows.append(_spot_case("spot: right hind leg swung 30°", spot, spot_medial, hind_leg,
                               np.array([0.2, -0.2, 0.75]), [1, 0, 0], np.radians(-30),
                               figures))  # fmt: skip
    print("| case | medial ΔV/V | LBS ΔV/V | DQS ΔV/V | Fleshing (radial) ΔV/V "
          "| radius error medial / LBS / DQS |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for row in rows:
        cells = [f"{100 * row[m][0]:+.2f} %" for m, _ in METHODS]
        cells.append("—" if row["fleshing"] is None else f"{100 * row['fleshing'][0]:+.3f} %")
        radius = [row[m][1] for m, _ in METHODS]
        cells.append("—" if radius[0] is None else " / ".join(f"{100 * r:.1f} %" for r in radius))
        print(f"| {row['case']} | " + " | ".join(cells) + " |", flush=True)


def speed():
    mesh = capsule(40, 0.1)
    bindings = []
    for spheres in (200, 300):
        medial = fj.medial_mesh(mesh, spheres, progress=False)
        start = time.perf_counter()
        fj.MedialRig(mesh.vertices, medial, faces=mesh.faces)
        bindings.append((medial, time.perf_counter() - start))
    big = capsule(36, 0.06)
    rig = fj.MedialRig(big.vertices, medial, faces=big.faces)
    centers = np.asarray(medial.centers)
    handles = np.r_[np.flatnonzero(centers[:, 2] < -1.0), np.flatnonzero(centers[:, 2] > 1.0)]
    targets = jnp.asarray(_on_arc(centers[handles], 4.0 / np.radians(90)), jnp.float32)

    posed = fj.arap_medial(medial, handles, targets)
    calls = {  # name: (compiled call, its argument)
        "frame: ARAP + skin (medial, implicit)": (jax.jit(
            lambda t: rig.pose(fj.arap_medial(medial, handles, t), "medial")), targets),
        "frame: ARAP (warm, 3 iterations) + skin (medial, implicit)": (jax.jit(
            lambda t: rig.pose(fj.arap_medial(medial, handles, t, start=posed, iterations=3),
                               "medial")), targets),
        "ARAP alone": (jax.jit(lambda t: fj.arap_medial(medial, handles, t).centers), targets),
        "skin alone (medial, implicit)": (jax.jit(lambda p: rig.pose(p, "medial")), posed),
        "skin alone (medial, no implicit)": (jax.jit(
            lambda p: rig.pose(p, "medial", implicit=False)), posed),
        "skin alone (DQS, no implicit)": (jax.jit(lambda p: rig.pose(p, "dqs",
                                                                     implicit=False)), posed),
    }
    print("\n| task | size | median |\n| --- | --- | ---: |")
    for m, seconds in bindings:
        print(f"| binding (`MedialRig`) | {len(mesh.vertices)} vertices, {m.centers.shape[0]} "
              f"spheres, {m.faces.shape[0]} slabs | {seconds:.2f} s |")
    size = f"{len(centers)} spheres, {len(big.vertices)} vertices"
    for name, (call, argument) in calls.items():
        _timed(name, size, call, argument)
    spot_frames()


def _timed(name, size, call, *arguments, repeats=20):
    """Prints the median of `repeats` calls after the first (compilation)."""
    jax.block_until_ready(call(*arguments))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(call(*arguments))
        times.append(time.perf_counter() - start)
    print(f"| {name}, float32 | {size} | {1e3 * np.median(times):.2f} ms |", flush=True)


def spot_frames():
    """A frame of spot (2,930 vertices, 200 spheres; its head turned 30° about the neck):
    ARAP from the first guess (20 iterations) or warm from the previous frame (`start`, 3
    iterations), then the skin; with the rump held and the body between free (ARAP moves
    every sphere), and with the core held as in the volume table (the hind quarters keep
    still: the correction skips their groups of vertices)."""
    spot = fj.data.spot()
    medial = fj.medial_mesh(spot, 200, progress=False)
    rig = fj.MedialRig(spot.vertices, medial, faces=spot.faces)
    c = np.asarray(medial.centers)
    head = np.flatnonzero((c[:, 2] < -0.35) & (c[:, 1] > 0.0))
    held = {"rump held": np.flatnonzero(c[:, 2] > 0.6),
            "core held": np.flatnonzero((np.abs(c[:, 2] + 0.1) < 0.25) & (c[:, 1] > -0.1))}
    turn = _rotation([0, 1, 0], np.radians(30))
    pivot = np.array([0.0, 0.3, -0.3])
    for case, still in held.items():
        handles = np.r_[head, np.setdiff1d(still, head)]
        targets = c[handles].copy()
        targets[: len(head)] = (c[head] - pivot) @ turn.T + pivot
        targets = jnp.asarray(targets, jnp.float32)
        rotations = jnp.asarray(np.stack([turn] * len(head)
                                         + [np.eye(3)] * (len(handles) - len(head))), jnp.float32)
        previous = fj.arap_medial(medial, handles, targets, rotations=rotations)
        size = f"spot ({case}), {len(c)} spheres, {len(spot.vertices)} vertices"

        def frame(t, r, start=None, iterations=fj.arap_medial.__kwdefaults__["iterations"],
                  handles=handles):
            return rig.pose(fj.arap_medial(medial, handles, t, rotations=r, start=start,
                                           iterations=iterations), "medial")

        _timed("frame: ARAP (20 iterations) + skin (medial, implicit)", size, jax.jit(frame),
               targets, rotations)
        _timed("frame: ARAP (warm, 3 iterations) + skin (medial, implicit)", size,
               jax.jit(lambda t, r, s, frame=frame: frame(t, r, s, 3)), targets, rotations,
               previous)
        _timed("ARAP alone (warm, 3 iterations)", size, jax.jit(
            lambda t, r, s, handles=handles: fj.arap_medial(
                medial, handles, t, rotations=r, start=s, iterations=3).centers),
            targets, rotations, previous)
        _timed("skin alone (medial, implicit)", size, jax.jit(lambda p: rig.pose(p, "medial")),
               previous)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--speed", action="store_true", help="only the speed table")
    parser.add_argument("--figures", type=Path, metavar="DIR", help="save spot's pictures")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)  # float64 for the volumes; the frame is float32
    for name, value in fj.compilation_cache_settings().items():  # compiled programs on disk
        jax.config.update(name, value)
    if not args.speed:
        volumes(args.quick, args.figures)
    if not args.quick:
        speed()

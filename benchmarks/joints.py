"""One joint posed alone at the angles animators use (issue 46 item 2), on the biped.

    python benchmarks/joints.py [--figure /tmp/joints.png]

On the procedural biped (`characters.biped()`, its own skeleton, float64): its left knee
(the leg chain's middle limb), elbow (the arm's) and shoulder (the arm's top) and its head,
each posed alone both ways (`direction` 0° and 180°), the rest of the chain free (a bend past a
joint's exact range carried on by its free child, `_skeleton.spill`). Prints one Markdown row
per pose: the joint's own exact range that way (`fj.joint_range`), flagged vertices, ΔV/V, the
worst edge stretch, the largest principal stretch of the map at the vertices it places
exactly (`fj.pose_stretch`; "-" where none moves exactly) and whether the body stayed bit for
bit. Then the knee bent 120° back (−x) and the elbow 120° ahead (+x) (`towards`: in the body's
side plane), and the leg lifted 90° as a marching step (hip 90° towards +x, knee 90° towards
−x). With `--figure`, those three poses beside the rest, seen side on.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import fleshing_jax as fj  # noqa: E402
from fleshing_jax._medial_axis.characters import biped  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_armature import biped_poses  # noqa: E402


def _chains(skeleton):
    """The limbs `blender_armature.biped_poses` poses: its leg's and arm's chains (top first)
    and its head (the one bent 30° there)."""
    poses = biped_poses(fj, skeleton)(None)
    head = next(k for k, pose in poses.items() if float(pose.bend) == 30.0)
    chains = {}
    for k in sorted(poses):
        if k != head:
            chains.setdefault(skeleton.chain(k)[0], []).append(k)

    def height(chain):
        spine = skeleton.limbs[chain[-1]].spine
        return float(spine(spine.length)[2])

    leg, arm = sorted(chains.values(), key=height)
    return leg, arm, head


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figure", type=Path)
    args = parser.parse_args()
    mesh = biped()
    skeleton = fj.skeleton(mesh)
    registration = fj.register_skeleton(mesh, skeleton)
    rest, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    edges = np.asarray(mesh.edges_unique)
    lengths = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    body = np.asarray(skeleton.region) == -1
    leg, arm, head = _chains(skeleton)
    joints = [(leg[1], 120.0, "knee"), (arm[1], 120.0, "elbow"), (arm[0], 90.0, "shoulder"),
              (leg[1], 70.0, "knee"), (arm[1], 70.0, "elbow"), (head, 45.0, "head")]
    print("| joint (limb) | bend | its own exact range that way | flagged | dV/V (%) | worst edge "
          "| principal stretch | body still |")
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    def row(label, pose_text, own_text, poses):
        """Prints one table row for `poses` and returns the posed vertices."""
        posed = fj.pose_skeleton(registration, skeleton, poses)
        moved = np.asarray(posed.vertices)
        stretch = np.linalg.norm(moved[edges[:, 0]] - moved[edges[:, 1]], axis=1) / lengths
        change = float(fj.volume(moved, faces) / fj.volume(rest, faces)) - 1
        principal = np.asarray(fj.pose_stretch(registration, skeleton, poses))
        principal = principal[np.isfinite(principal) & (principal > 1 + 1e-9)]
        print(f"| {label} | {pose_text} | {own_text} | "
              f"{int(np.sum(~np.asarray(posed.valid)))} | {100 * change:+.4f} | "
              f"{stretch.max():.2f} | "
              f"{f'{principal.max():.2f}' if principal.size else '-'} | "
              f"{'yes' if np.array_equal(moved[body], rest[body]) else 'no'} |", flush=True)
        return moved

    shown = {}
    for k, bend, name in joints:
        for direction in (0.0, 180.0):
            own = float(fj.joint_range(registration, k, direction, children_posed=True))
            shown[(name, bend, direction)] = row(
                f"{name} ({k})", f"{bend:g}° towards {direction:g}°", f"{own:.1f}°",
                {k: fj.LimbPose(bend, direction)})
    # The knee and the elbow bent in the body's side plane (seen side on in the figure).
    for k, name, towards, way in ((leg[1], "knee", (-1.0, 0.0, 0.0), "back (-x)"),
                                  (arm[1], "elbow", (1.0, 0.0, 0.0), "ahead (+x)")):
        own = float(fj.joint_range(registration, k, towards=towards, children_posed=True))
        shown[(name, 120.0, way)] = row(f"{name} ({k})", f"120° {way}", f"{own:.1f}°",
                                        {k: fj.LimbPose(120.0, towards=towards)})
    # The leg lifted 90° as a marching step: the thigh forwards (+x), the shin back down.
    shown[("lifted", 90.0, 0.0)] = row(
        f"leg lifted ({leg[0]}, {leg[1]})", "hip 90° ahead, knee 90° back", "-",
        {leg[0]: fj.LimbPose(90.0, towards=(1.0, 0.0, 0.0)),
         leg[1]: fj.LimbPose(90.0, towards=(-1.0, 0.0, 0.0))})
    if args.figure is not None:
        _figure(args.figure, rest, faces, np.asarray(skeleton.region), leg, arm, shown)


def _figure(path, rest, faces, region, leg, arm, shown):
    """The leg and the arm at rest, with the knee bent 120° back and the elbow 120° ahead, and
    the leg lifted (hip 90° ahead, knee 90° back); seen from the side (along y)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    figure = plt.figure(figsize=(15, 4))
    panels = [(rest, leg, "leg at rest"),
              (shown[("knee", 120.0, "back (-x)")], leg, "knee 120° back"),
              (shown[("lifted", 90.0, 0.0)], leg, "leg lifted: hip 90°, knee 90°"),
              (rest, arm, "arm at rest"),
              (shown[("elbow", 120.0, "ahead (+x)")], arm, "elbow 120° ahead")]
    for i, (points, limbs, title) in enumerate(panels):
        ax = figure.add_subplot(1, len(panels), i + 1, projection="3d")
        keep = np.isin(region[faces], limbs).any(axis=1)
        ax.add_collection3d(Poly3DCollection(points[faces[keep]], facecolor=(0.7, 0.75, 0.9),
                                             edgecolor=(0, 0, 0, 0.15), linewidths=0.2))
        corners = points[np.unique(faces[keep])]
        middle, half = corners.mean(axis=0), np.ptp(corners, axis=0).max() / 2
        for axis, centre in zip("xyz", middle, strict=True):
            getattr(ax, f"set_{axis}lim")(centre - half, centre + half)
        ax.view_init(5, -90)
        ax.set_axis_off()
        ax.set_title(title, fontsize=9)
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)


if __name__ == "__main__":
    main()

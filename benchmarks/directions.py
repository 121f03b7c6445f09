"""Poses given in the world's terms (issue 46 item 4): `fj.turn`, `fj.nod`, `fj.aim`.

    python benchmarks/directions.py [--figure benchmarks/figures/directions-biped.png]

On the procedural biped (`characters.biped()`, z up, facing +x; float64): the head turned 40°
to its left about the world's up, the head nodded 20° down, and the right arm's shoulder bent
so that the arm points at a point 35° forwards of its rest direction. Prints one Markdown row per
pose: how far it is from what was asked (the aim: the chord from the joint to where the
part past the bending zone starts, from the point's direction; a turn or nod: that part's
tangent from the rest one turned by the asked rotation), in degrees, flagged vertices, volume
change, and whether every vertex outside the posed limb and its children stayed bit for bit;
with `--figure`, the rest and the three poses side by side.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import fleshing_jax as fj  # noqa: E402
from fleshing_jax._medial_axis import characters  # noqa: E402
from fleshing_jax._skeleton.posing import limb_target  # noqa: E402

UP = np.array([0.0, 0.0, 1.0])
SIDE = np.array([0.0, -1.0, 0.0])


def _off(registration, k, pose, name, target) -> str:
    """How far the posed limb `k` is from what `name` asked, in degrees: for the aim, its
    chord (joint to where its part past the zone starts, on the bent spine) from the
    direction joint → `target`; for a turn or a nod, the tangent of its part past the zone
    from the rest one turned about the world's up (or the biped's side) by the asked angle."""
    rest_spine, bent = registration.rests[k], limb_target(registration, k, pose)
    joint, stop = registration.joints[k], registration.stops[k]
    origin = np.asarray(rest_spine(joint))
    if "aimed" in name:
        got = _unit(np.asarray(bent(stop)) - origin)
        asked = _unit(target - origin)
    else:
        got = np.asarray(bent._prepare()._jet(stop)[1])
        rest = np.asarray(rest_spine._prepare()._jet(stop)[1])
        angle = np.radians(40.0 if "turned" in name else -20.0)
        axis = UP if "turned" in name else SIDE
        asked = (rest * np.cos(angle) + np.cross(axis, rest) * np.sin(angle)
                 + axis * (axis @ rest) * (1 - np.cos(angle)))
    return f"{np.degrees(np.arccos(np.clip(got @ asked, -1, 1))):.1f}"


def _unit(v):
    return v / np.linalg.norm(v)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figure", type=Path, default=None)
    args = parser.parse_args()
    mesh = characters.biped()
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    skeleton = fj.skeleton(mesh)
    registration = fj.register_skeleton(mesh, skeleton)
    tips = [np.asarray(limb.spine(limb.spine.length)) for limb in skeleton.limbs]
    head = int(np.argmax([t[2] for t in tips]))
    # The right arm's top limb (the shoulder): of the limbs on the body, right of the
    # middle (y < 0), the one whose end is highest (an elbow above a knee).
    right = [k for k in skeleton.children(-1) if k != head and tips[k][1] < 0]
    arm = max(right, key=lambda k: tips[k][2])
    # A point 35° forwards (+x) of the shoulder's rest chord, 0.3 from its joint.
    origin = np.asarray(registration.rests[arm](registration.joints[arm]))
    chord = np.asarray(registration.rests[arm](registration.stops[arm])) - origin
    chord /= np.linalg.norm(chord)
    forwards = np.array([1.0, 0, 0]) - chord[0] * chord
    forwards /= np.linalg.norm(forwards)
    target = origin + 0.3 * (np.cos(np.radians(35)) * chord + np.sin(np.radians(35)) * forwards)
    poses = {
        "head turned 40°": (head, fj.turn(registration, skeleton, head, 40.0, up=UP)),
        # The biped faces +x: its left to right is -y (a head along `up` needs its side).
        "head nodded 20° down": (head, fj.nod(registration, skeleton, head, -20.0, up=UP,
                                              side=SIDE)),
        "right arm aimed 35° forwards": (arm, fj.aim(registration, skeleton, arm, target)),
    }
    print("| pose | limb | bend (°) | off what was asked (°) | flagged | dV/V (%) | "
          "body still |")
    print("|---|---|---|---|---|---|---|")
    posed_points = {}
    for name, (k, pose) in poses.items():
        # (Its children held: `fj.aim` solves on the limb alone, and a free only child would
        # carry a bend past the limb's exact range on.)
        held = {c: fj.LimbPose() for c in skeleton.children(k)}
        posed = fj.pose_skeleton(registration, skeleton, {k: pose, **held})
        points = np.asarray(posed.vertices)
        posed_points[name] = points
        body = np.asarray(skeleton.region) == -1
        still = np.array_equal(points[body], vertices[body])
        change = float(fj.volume(points, faces) / fj.volume(vertices, faces)) - 1
        off = _off(registration, k, pose, name, target)
        print(f"| {name} | {k} | {float(pose.bend):.1f} | {off}"
              f" | {int(np.sum(~np.asarray(posed.valid)))} | {100 * change:+.4f} | "
              f"{'yes' if still else 'no'} |")
    if args.figure is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        figure = plt.figure(figsize=(16, 5))
        panels = [("rest", vertices), *posed_points.items()]
        for i, (title, points) in enumerate(panels):
            ax = figure.add_subplot(1, len(panels), i + 1, projection="3d")
            fj.plot_skeleton((points, faces), fj.Skeleton(skeleton.limbs, skeleton.region,
                                                          points), ax=ax, azim=-65, elev=10)
            for artist in [*ax.lines, *ax.texts, *ax.collections]:
                if not isinstance(artist, Poly3DCollection):
                    artist.remove()  # the rest spines would be drawn on the posed mesh
            if "aimed" in title:
                ax.scatter(*target, color="red", s=30)
            ax.set_title(title)
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        temporary = args.figure.with_suffix(".tmp.png")
        figure.savefig(temporary, dpi=70)
        temporary.replace(args.figure)


if __name__ == "__main__":
    main()

"""How far each tip moves when its chain's top limb bends 30° (issue 45's check).

    python benchmarks/tip_travel.py [--only spot cheburashka biped jointed_quadruped insect]
    python benchmarks/tip_travel.py --only human dog --bpy /path/to/venv-with-bpy/bin/python
    (the horse's faces re-wound by trimesh, with networkx: `pip install -e ".[benchmarks]"`)

Each character's default skeleton (`fj.skeleton`, float64, radial); `human`, `cow`, `insect`,
`horse`, `dog`, `dinosaur`, `bird`, `spider`, `kangaroo` and `hand` are `skin_characters.py`'s,
modelled by Blender (`--bpy` names a Python with `bpy`). For every chain that leaves the
body: its tip (the vertex of the chain's regions farthest along the line from the top limb's
joint to the farthest of its limbs' spine ends), the top limb bent 30° alone towards 0, 90, 180
and 270° (`LimbPose(30, direction=…)`), and how far the tip moves: the least displacement among
the vertices within 1 % of the bounding-box diagonal of it, as % of the diagonal (the issue asks
≥ 4 %). Prints one Markdown row per chain: its limbs, the lever (tip to joint, % of the
diagonal), the bend's zone at 30° beside the limb's room to bend (`JointZone.length`: the whole
room means the limb bends as one arc, its thickness near the joint allowing no shorter zone),
the travel (least and most over the four directions), vertices flagged (most), |ΔV/V| (most)
and whether everything outside the chain stayed bit for bit.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np
import trimesh

jax.config.update("jax_enable_x64", True)

import fleshing_jax as fj  # noqa: E402
from fleshing_jax._medial_axis import characters  # noqa: E402
from fleshing_jax._skeleton.posing import carrying  # noqa: E402
from fleshing_jax._skeleton.skeleton import descendants  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
CHARACTERS = {
    "spot": fj.data.spot,
    "cheburashka": lambda: trimesh.load(DATA / "cheburashka.obj", process=False, force="mesh"),
    "biped": characters.biped,
    "jointed_quadruped": characters.jointed_quadruped,
    "insect": characters.insect,
}
DIRECTIONS = (0.0, 90.0, 180.0, 270.0)


def rows(name: str, bpy: str | None = None):
    """One Markdown row per chain leaving the body of character `name`."""
    if name in CHARACTERS:
        mesh = CHARACTERS[name]()
    elif bpy is None:
        raise SystemExit(f"{name!r} is modelled by Blender: give --bpy")
    else:
        from blender_armature import skin_mesh

        mesh = skin_mesh(bpy, name)
        mesh = mesh if mesh.is_watertight else fj.cap_holes(mesh)  # (the skin's branch holes)
        if not mesh.is_winding_consistent:  # (the horse's 288 faces: its volume signed right)
            trimesh.repair.fix_winding(mesh)
    rest, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    skeleton = fj.skeleton(mesh)
    registration = fj.register_skeleton(mesh, skeleton)
    region = np.asarray(skeleton.region)
    diagonal = np.linalg.norm(np.ptp(rest, axis=0))
    volume = float(fj.volume(rest, faces))
    below = descendants(skeleton.limbs)
    for top, limb in enumerate(skeleton.limbs):
        if limb.parent != -1:
            continue
        chain = np.isin(region, [top, *below[top]])
        joint = np.asarray(limb.spine(limb.joint))
        ends = [np.asarray(skeleton.limbs[k].spine(skeleton.limbs[k].spine.length))
                for k in (top, *below[top])]  # fmt: skip
        end = max(ends, key=lambda e: np.linalg.norm(e - joint))
        along = (rest - joint) @ ((end - joint) / np.linalg.norm(end - joint))
        tip = rest[np.argmax(np.where(chain, along, -np.inf))]
        near = np.linalg.norm(rest - tip, axis=1) < 0.01 * diagonal
        travel, flagged, change, still = [], 0, 0.0, True
        for direction in DIRECTIONS:
            posed = fj.pose_skeleton(registration, skeleton,
                                     {top: fj.LimbPose(30.0, direction=direction)})  # fmt: skip
            moved = np.asarray(posed.vertices)
            travel.append(np.linalg.norm(moved[near] - rest[near], axis=1).min() / diagonal)
            flagged = max(flagged, int(np.sum(~np.asarray(posed.valid))))
            change = max(change, abs(float(fj.volume(moved, faces)) / volume - 1))
            still &= bool(np.array_equal(moved[~chain], rest[~chain]))
        placed = carrying(registration, {top})[0]  # (its children ride on it: `WholeLimb`)
        zone = float(placed.zones[top].length(np.deg2rad(30.0)))
        room = float(placed.stops[top] - placed.joints[top])
        lever = 100 * np.linalg.norm(tip - joint) / diagonal
        yield (f"| {name} | {top} | {1 + len(below[top])} | {lever:.1f} "
               f"| {zone:.3f} / {room:.3f} | {100 * min(travel):.1f}–{100 * max(travel):.1f} "
               f"| {flagged} | {100 * change:.4f} | {'yes' if still else 'no'} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", default=list(CHARACTERS))
    parser.add_argument("--bpy", help="a Python with `bpy` (the characters Blender models)")
    args = parser.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    print("| character | top limb | limbs | lever (%) | zone / room at 30° | tip travel (%) "
          "| flagged | \\|ΔV/V\\| (%) | rest still |")
    print("|---|---:|---:|---:|---|---|---:|---:|---|")
    for name in args.only:
        for row in rows(name, args.bpy):
            print(row, flush=True)


if __name__ == "__main__":
    sys.exit(main())

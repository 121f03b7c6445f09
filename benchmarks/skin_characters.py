"""The rig `fj.skeleton` finds on characters modelled in Blender, not by us (issue 45).

    python benchmarks/skin_characters.py --bpy /path/to/venv-with-bpy/bin/python \
        [--seeds 4] [--spheres 200] [--figures DIR] [--joints] [--only spider hand]

Our procedural characters share one way of building a surface (`_medial_axis.characters`).
Here a human, a horned cow, an insect (its legs bent at rest), a horse, a dog, a dinosaur
(small arms below its neck), a bird (wings spread), a spider (eight legs at a thorax, a large
abdomen), a kangaroo (a thick tail, small arms) and a hand (a palm, four fingers and a
thumb) are modelled as an artist blocks a
character out in Blender: a stick figure of joints with a radius each, its skin
modifier's quad surface, subdivided twice (`pip install bpy` in another
environment: `--bpy` names its Python; the meshes are made there). Each gets `fj.skeleton`
at medial seeds 0 … n−1 (holes from the skin's branch points capped by `fj.cap_holes`, the
faces the skin winds against their neighbours flipped). Prints a Markdown table: limbs,
chains from the body and their lengths, and which of the tips an animator would pose (head,
hands, feet; muzzle, horns, tail, hooves; head, antennae, feet; ears; snout, ears, paws; jaw,
hands; beak, wings; eight feet, abdomen; snout, ears, paws, feet, tail; fingertips, forearm)
lie in a limb of their own, outside the body. `--joints`: issue 46's joint targets on the
human and the cow instead (`--only human cow`; each joint's exact range, alone and with the
chain below it free, then each pose's flagged vertices, volume change and worst edge
stretch, float64).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

# Joints (x, y, z; z up) and their radii; edges between joints. Tips: (name, joint, nudge
# outwards to the surface).
HUMAN = {
    "joints": {
        "pelvis": ((0, 0, 1.0), 0.15), "chest": ((0, 0, 1.35), 0.17),
        "neck": ((0, 0, 1.55), 0.06), "head": ((0, 0.02, 1.75), 0.11),
        **{f"{s}{name}": ((sign * x, 0, z), r) for s, sign in (("l", 1), ("r", -1))
           for name, x, z, r in (("shoulder", 0.2, 1.45, 0.06), ("elbow", 0.45, 1.45, 0.045),
                                 ("wrist", 0.7, 1.45, 0.035), ("hand", 0.8, 1.45, 0.04))},
        **{f"{s}{name}": ((sign * 0.1, y, z), r) for s, sign in (("l", 1), ("r", -1))
           for name, y, z, r in (("hip", 0, 0.95, 0.08), ("knee", 0.02, 0.5, 0.06),
                                 ("ankle", 0, 0.08, 0.045), ("toe", 0.15, 0.04, 0.04))},
    },
    "bones": [("pelvis", "chest"), ("chest", "neck"), ("neck", "head")]
    + [(a if a in ("chest", "pelvis") else s + a, s + b) for s in "lr" for a, b in (
        ("chest", "shoulder"), ("shoulder", "elbow"), ("elbow", "wrist"), ("wrist", "hand"),
        ("pelvis", "hip"), ("hip", "knee"), ("knee", "ankle"), ("ankle", "toe"))],
    "tips": [("head", "head", (0, 0, 0.1)), ("left hand", "lhand", (0.04, 0, 0)),
             ("right hand", "rhand", (-0.04, 0, 0)), ("left foot", "ltoe", (0, 0.04, 0)),
             ("right foot", "rtoe", (0, 0.04, 0))],
}
COW = {
    "joints": {
        "rump": ((-0.5, 0, 1.0), 0.28), "belly": ((0, 0, 1.05), 0.3),
        "chest": ((0.5, 0, 1.05), 0.28), "neck": ((0.75, 0, 1.25), 0.14),
        "head": ((0.95, 0, 1.3), 0.13), "muzzle": ((1.15, 0, 1.15), 0.09),
        "lhorn": ((0.95, 0.15, 1.5), 0.03), "rhorn": ((0.95, -0.15, 1.5), 0.03),
        "tail": ((-0.75, 0, 1.1), 0.04), "tail tip": ((-0.85, 0, 0.7), 0.025),
        **{f"{leg}{name}": ((x + dx, y, z), r) for leg, x, y in (
            ("front left ", 0.45, 0.15), ("front right ", 0.45, -0.15),
            ("hind left ", -0.45, 0.15), ("hind right ", -0.45, -0.15))
           for name, dx, z, r in (("hip", 0, 0.85, 0.1), ("knee", -0.05 * (x < 0), 0.45, 0.06),
                                  ("hoof", 0, 0.05, 0.06))},
    },
    "bones": [("rump", "belly"), ("belly", "chest"), ("chest", "neck"), ("neck", "head"),
              ("head", "muzzle"), ("head", "lhorn"), ("head", "rhorn"), ("rump", "tail"),
              ("tail", "tail tip")]
    + [(top if a == "top" else leg + a, leg + b) for leg, top in (
        ("front left ", "chest"), ("front right ", "chest"), ("hind left ", "rump"),
        ("hind right ", "rump")) for a, b in (("top", "hip"), ("hip", "knee"), ("knee", "hoof"))],
    "tips": [("muzzle", "muzzle", (0, 0, 0)), ("left horn", "lhorn", (0, 0, 0)),
             ("right horn", "rhorn", (0, 0, 0)), ("tail", "tail tip", (0, 0, 0))]
    + [(f"{leg}hoof", f"{leg}hoof", (0, 0, 0)) for leg in (
        "front left ", "front right ", "hind left ", "hind right ")],
}

def _chained(joints: dict, bones: list, chains):
    """Adds each chain `[(existing joint, None), (joint, (point, radius)), ...]` to `joints`
    and `bones`, each joint joined to the one before it (a `None` joint within a chain starts
    a new one from that existing joint)."""
    for chain in chains:
        for (a, _), (b, joint) in zip(chain, chain[1:]):
            if joint is not None:
                joints[b] = joint
                bones.append((a, b))


def _insect() -> dict:
    """Six legs from the thorax, each rising to its knee and down (bent at rest), a waist to
    the abdomen, a neck to the head, two antennae."""
    joints = {"thorax": ((0, 0, 0.5), 0.11), "waist": ((-0.16, 0, 0.5), 0.06),
              "abdomen": ((-0.35, 0, 0.52), 0.14), "abdomen end": ((-0.6, 0, 0.5), 0.1),
              "abdomen tip": ((-0.75, 0, 0.48), 0.04), "neck": ((0.14, 0, 0.52), 0.05),
              "head": ((0.24, 0, 0.55), 0.08)}
    bones = [("thorax", "waist"), ("waist", "abdomen"), ("abdomen", "abdomen end"),
             ("abdomen end", "abdomen tip"), ("thorax", "neck"), ("neck", "head")]
    tips = [("head", "head", (0.08, 0, 0))]
    for s, sign in (("l", 1), ("r", -1)):
        chain = [("head", None), (f"{s}antenna base", ((0.3, sign * 0.04, 0.6), 0.02)),
                 (f"{s}antenna mid", ((0.42, sign * 0.12, 0.78), 0.012)),
                 (f"{s}antenna tip", ((0.55, sign * 0.2, 0.85), 0.008))]
        tips.append((f"{s} antenna", f"{s}antenna tip", (0, 0, 0)))
        for leg, x, dx in (("front", 0.07, 0.12), ("middle", 0.0, 0.0), ("hind", -0.07, -0.12)):
            name = f"{s}{leg} "
            chain += [("thorax", None), (name + "hip", ((x, sign * 0.09, 0.47), 0.035)),
                      (name + "knee", ((x + dx, sign * 0.3, 0.62), 0.03)),
                      (name + "ankle", ((x + 1.6 * dx, sign * 0.45, 0.08), 0.022)),
                      (name + "foot", ((x + 1.9 * dx, sign * 0.5, 0.02), 0.016))]
            tips.append((f"{s} {leg} foot", name + "foot", (0, 0, 0)))
        _chained(joints, bones, [chain])
    return {"joints": joints, "bones": bones, "tips": tips}



def _horse() -> dict:
    """A long neck and head with two ears and a muzzle, four legs of three bones, a tail."""
    joints = {"rump": ((-0.55, 0, 1.25), 0.25), "belly": ((0, 0, 1.28), 0.28),
              "chest": ((0.5, 0, 1.3), 0.26), "neck base": ((0.75, 0, 1.55), 0.16),
              "neck top": ((0.95, 0, 1.95), 0.1), "head": ((1.1, 0, 2.0), 0.1),
              "muzzle": ((1.45, 0, 1.75), 0.07), "tail": ((-0.85, 0, 1.35), 0.05),
              "tail tip": ((-1.0, 0, 0.85), 0.035)}
    bones = [("rump", "belly"), ("belly", "chest"), ("chest", "neck base"),
             ("neck base", "neck top"), ("neck top", "head"), ("head", "muzzle"),
             ("rump", "tail"), ("tail", "tail tip")]
    tips = [("muzzle", "muzzle", (0.05, 0, -0.02)), ("tail", "tail tip", (0, 0, 0))]
    for s, sign in (("left", 1), ("right", -1)):
        joints[f"{s} ear"] = ((1.0, sign * 0.07, 2.25), 0.025)
        bones.append(("head", f"{s} ear"))
        tips.append((f"{s} ear", f"{s} ear", (0, 0, 0.02)))
    for leg, x, top in (("front left ", 0.5, "chest"), ("front right ", 0.5, "chest"),
                        ("hind left ", -0.55, "rump"), ("hind right ", -0.55, "rump")):
        y = 0.15 if "left" in leg else -0.15
        for a, (b, point, radius) in zip(
                [top, leg + "hip", leg + "knee", leg + "fetlock"],
                [("hip", (x, y, 1.05), 0.11), ("knee", (x + (0.05 if x > 0 else -0.1), y, 0.6),
                                               0.06),
                 ("fetlock", (x, y, 0.15), 0.045), ("hoof", (x + 0.05, y, 0.03), 0.055)]):
            joints[leg + b] = (point, radius)
            bones.append((a, leg + b))
        tips.append((leg + "hoof", leg + "hoof", (0, 0, 0)))
    return {"joints": joints, "bones": bones, "tips": tips}


def _dog() -> dict:
    """Four legs of three bones, a neck and head with a snout, two ears of two bones, a tail."""
    joints = {"rump": ((-0.4, 0, 0.6), 0.16), "belly": ((0, 0, 0.62), 0.17),
              "chest": ((0.35, 0, 0.65), 0.17), "neck": ((0.55, 0, 0.85), 0.09),
              "head": ((0.65, 0, 0.95), 0.1), "snout": ((0.85, 0, 0.9), 0.05),
              "tail": ((-0.6, 0, 0.75), 0.03), "tail tip": ((-0.8, 0, 0.95), 0.02)}
    bones = [("rump", "belly"), ("belly", "chest"), ("chest", "neck"), ("neck", "head"),
             ("head", "snout"), ("rump", "tail"), ("tail", "tail tip")]
    tips = [("snout", "snout", (0.04, 0, 0)), ("tail", "tail tip", (0, 0, 0.02))]
    for s, y in (("left", 0.08), ("right", -0.08)):
        joints[f"{s} ear"] = ((0.62, 1.2 * y, 1.12), 0.03)
        joints[f"{s} ear tip"] = ((0.6, 1.6 * y, 1.22), 0.02)
        bones += [("head", f"{s} ear"), (f"{s} ear", f"{s} ear tip")]
        tips.append((f"{s} ear", f"{s} ear tip", (0, 0, 0.01)))
    for leg, x, top in (("front left ", 0.35, "chest"), ("front right ", 0.35, "chest"),
                        ("hind left ", -0.4, "rump"), ("hind right ", -0.4, "rump")):
        y = 0.1 if "left" in leg else -0.1
        for a, (b, point, radius) in zip(
                [top, leg + "hip", leg + "knee"],
                [("hip", (x, y, 0.5), 0.07), ("knee", (x + (0.03 if x > 0 else -0.08), y, 0.3),
                                              0.045), ("paw", (x + 0.04, y, 0.04), 0.04)]):
            joints[leg + b] = (point, radius)
            bones.append((a, leg + b))
        tips.append((leg + "paw", leg + "paw", (0, 0, 0)))
    return {"joints": joints, "bones": bones, "tips": tips}


def _dinosaur() -> dict:
    """Two legs of four bones under the hips, a tail of three, a neck and head with a jaw, two
    small arms of three bones below the neck's base."""
    joints = {"hips": ((0, 0, 1.0), 0.22), "chest": ((0.45, 0, 1.15), 0.2),
              "neck": ((0.75, 0, 1.35), 0.12), "head": ((0.95, 0, 1.45), 0.13),
              "jaw": ((1.25, 0, 1.4), 0.08), "tail 1": ((-0.45, 0, 1.0), 0.15),
              "tail 2": ((-0.9, 0, 0.95), 0.09), "tail 3": ((-1.4, 0, 0.9), 0.04)}
    bones = [("hips", "chest"), ("chest", "neck"), ("neck", "head"), ("head", "jaw"),
             ("hips", "tail 1"), ("tail 1", "tail 2"), ("tail 2", "tail 3")]
    tips = [("jaw", "jaw", (0.06, 0, 0)), ("tail", "tail 3", (-0.03, 0, 0))]
    for s, sign in (("left", 1), ("right", -1)):
        arm = [("chest", None), (f"{s} shoulder", ((0.55, 0.15 * sign, 1.05), 0.05)),
               (f"{s} elbow", ((0.65, 0.2 * sign, 0.9), 0.035)),
               (f"{s} hand", ((0.78, 0.2 * sign, 0.85), 0.03))]
        leg = [("hips", None), (f"{s} hip", ((0.0, 0.16 * sign, 0.8), 0.12)),
               (f"{s} knee", ((0.12, 0.18 * sign, 0.5), 0.08)),
               (f"{s} ankle", ((-0.05, 0.18 * sign, 0.15), 0.05)),
               (f"{s} toe", ((0.15, 0.18 * sign, 0.04), 0.045))]
        _chained(joints, bones, (arm, leg))
        tips += [(f"{s} hand", f"{s} hand", (0.02, 0, 0)), (f"{s} foot", f"{s} toe", (0.03, 0, 0))]
    return {"joints": joints, "bones": bones, "tips": tips}


def _bird() -> dict:
    """A body and breast, a neck and head with a beak, two wings of four bones spread
    sideways, two legs of three bones, a tail."""
    joints = {"body": ((0, 0, 0.5), 0.14), "breast": ((0.15, 0, 0.52), 0.13),
              "neck": ((0.28, 0, 0.65), 0.06), "head": ((0.35, 0, 0.75), 0.07),
              "beak": ((0.5, 0, 0.73), 0.02), "tail": ((-0.25, 0, 0.52), 0.05),
              "tail tip": ((-0.45, 0, 0.55), 0.03)}
    bones = [("body", "breast"), ("breast", "neck"), ("neck", "head"), ("head", "beak"),
             ("body", "tail"), ("tail", "tail tip")]
    tips = [("beak", "beak", (0.02, 0, 0)), ("tail", "tail tip", (-0.02, 0, 0))]
    for s, sign in (("left", 1), ("right", -1)):
        wing = [("breast", None), (f"{s} shoulder", ((0.12, 0.14 * sign, 0.6), 0.04)),
                (f"{s} elbow", ((0.05, 0.4 * sign, 0.62), 0.03)),
                (f"{s} wrist", ((0.1, 0.65 * sign, 0.64), 0.025)),
                (f"{s} wing tip", ((0.0, 0.9 * sign, 0.64), 0.015))]
        leg = [("body", None), (f"{s} hip", ((0.0, 0.07 * sign, 0.38), 0.045)),
               (f"{s} knee", ((0.05, 0.08 * sign, 0.22), 0.025)),
               (f"{s} foot", ((0.1, 0.08 * sign, 0.03), 0.02))]
        _chained(joints, bones, (wing, leg))
        tips += [(f"{s} wing", f"{s} wing tip", (0, 0.015 * sign, 0)),
                 (f"{s} foot", f"{s} foot", (0.02, 0, 0))]
    return {"joints": joints, "bones": bones, "tips": tips}


def _spider() -> dict:
    """Eight legs of four bones from the cephalothorax, each rising to its knee and down, a
    thin waist (pedicel) to a large abdomen, the eyes' bump in front."""
    joints = {"cephalothorax": ((0, 0, 0.3), 0.12), "pedicel": ((-0.15, 0, 0.31), 0.04),
              "abdomen": ((-0.33, 0, 0.35), 0.18), "abdomen tip": ((-0.52, 0, 0.33), 0.06),
              "eyes": ((0.12, 0, 0.33), 0.07)}
    bones = [("cephalothorax", "pedicel"), ("pedicel", "abdomen"), ("abdomen", "abdomen tip"),
             ("cephalothorax", "eyes")]
    tips = [("abdomen", "abdomen tip", (-0.05, 0, 0))]
    chains = []
    for s, sign in (("left", 1), ("right", -1)):
        for i, angle in enumerate(np.radians([50, 20, -15, -50])):
            out = np.array([np.sin(angle), sign * np.cos(angle), 0.0])  # (x ahead, y aside)
            name = f"{s} leg {i} "
            chains.append([("cephalothorax", None)] + [
                (name + joint, (tuple(reach * out + (0, 0, z)), radius))
                for joint, reach, z, radius in (
                    ("hip", 0.08, 0.3, 0.03), ("knee", 0.3, 0.55, 0.025),
                    ("ankle", 0.55, 0.2, 0.018), ("foot", 0.65, 0.02, 0.012))])
            tips.append((f"{s} leg {i}", name + "foot", (0, 0, 0)))
    _chained(joints, bones, chains)
    return {"joints": joints, "bones": bones, "tips": tips}


def _kangaroo() -> dict:
    """Large hind legs of four bones (the long foot on the ground), a thick tail of three, small
    arms of three below the chest, a neck and head with a snout and two upright ears."""
    joints = {"pelvis": ((0, 0, 0.6), 0.2), "chest": ((0.15, 0, 0.95), 0.16),
              "neck": ((0.22, 0, 1.2), 0.08), "head": ((0.28, 0, 1.32), 0.09),
              "snout": ((0.45, 0, 1.28), 0.05), "tail 1": ((-0.3, 0, 0.4), 0.12),
              "tail 2": ((-0.7, 0, 0.15), 0.07), "tail 3": ((-1.1, 0, 0.05), 0.03)}
    bones = [("pelvis", "chest"), ("chest", "neck"), ("neck", "head"), ("head", "snout"),
             ("pelvis", "tail 1"), ("tail 1", "tail 2"), ("tail 2", "tail 3")]
    tips = [("snout", "snout", (0.04, 0, 0)), ("tail", "tail 3", (-0.03, 0, 0))]
    chains = []
    for s, sign in (("left", 1), ("right", -1)):
        chains += [
            [("head", None), (f"{s} ear", ((0.24, 0.05 * sign, 1.45), 0.03)),
             (f"{s} ear tip", ((0.2, 0.07 * sign, 1.58), 0.015))],
            [("chest", None), (f"{s} shoulder", ((0.25, 0.12 * sign, 0.95), 0.04)),
             (f"{s} elbow", ((0.3, 0.14 * sign, 0.8), 0.03)),
             (f"{s} paw", ((0.42, 0.12 * sign, 0.78), 0.025))],
            [("pelvis", None), (f"{s} hip", ((0.05, 0.15 * sign, 0.55), 0.1)),
             (f"{s} knee", ((0.25, 0.17 * sign, 0.35), 0.06)),
             (f"{s} ankle", ((-0.05, 0.17 * sign, 0.08), 0.04)),
             (f"{s} toe", ((0.3, 0.17 * sign, 0.03), 0.035))]]
        tips += [(f"{s} ear", f"{s} ear tip", (0, 0, 0.01)),
                 (f"{s} paw", f"{s} paw", (0.02, 0, 0)), (f"{s} foot", f"{s} toe", (0.03, 0, 0))]
    _chained(joints, bones, chains)
    return {"joints": joints, "bones": bones, "tips": tips}


def _hand() -> dict:
    """A palm on a forearm's stub, four fingers of four bones fanning out a little, a thumb of
    four from the palm's side (a rig's hand: a chain per finger)."""
    joints = {"palm": ((0, 0, 0.1), 0.045), "wrist": ((0, 0, 0.0), 0.03),
              "forearm": ((0, 0, -0.12), 0.032)}
    bones = [("palm", "wrist"), ("wrist", "forearm")]
    tips = [("forearm", "forearm", (0, 0, -0.02))]
    chains = []
    for i, (x, length, r) in enumerate(((-0.042, 0.085, 0.0095), (-0.014, 0.1, 0.01),
                                        (0.014, 0.095, 0.0095), (0.042, 0.075, 0.0085))):
        name = f"finger {i} "
        chains.append([("palm", None)] + [
            (name + joint, ((x * (1 + 0.25 * along * length / 0.1), y, 0.15 + along * length),
                            scale * r))
            for joint, along, y, scale in (("1", 0, 0, 1), ("2", 0.45, 0.005, 0.9),
                                           ("3", 0.75, 0.01, 0.8), ("tip", 1.0, 0.012, 0.7))])
        tips.append((f"finger {i}", name + "tip", (0, 0, 0.005)))
    chains.append([("palm", None)] + [
        (f"thumb {joint}", (point, radius)) for joint, point, radius in (
            ("1", (0.05, 0.01, 0.06), 0.014), ("2", (0.08, 0.02, 0.09), 0.012),
            ("3", (0.1, 0.025, 0.12), 0.011), ("tip", (0.115, 0.03, 0.145), 0.009))])
    tips.append(("thumb", "thumb tip", (0.003, 0, 0.003)))
    _chained(joints, bones, chains)
    return {"joints": joints, "bones": bones, "tips": tips}


CHARACTERS = {"human": HUMAN, "cow": COW, "insect": _insect(), "horse": _horse(), "dog": _dog(),
              "dinosaur": _dinosaur(), "bird": _bird(), "spider": _spider(),
              "kangaroo": _kangaroo(), "hand": _hand()}


def blender_side(out: Path):
    """Runs under Blender's Python: each character's skinned, subdivided, triangulated mesh
    and its tips into `out` (.npz)."""
    import bpy  # noqa: I001 (bmesh is importable once bpy is)
    import bmesh

    arrays = {}
    for name, figure in CHARACTERS.items():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        names = list(figure["joints"])
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata([figure["joints"][n][0] for n in names],
                         [(names.index(a), names.index(b)) for a, b in figure["bones"]], [])
        obj = bpy.data.objects.new(name, mesh)
        bpy.context.scene.collection.objects.link(obj)
        obj.modifiers.new("skin", "SKIN")
        for vertex, n in zip(obj.data.skin_vertices[0].data, names):
            vertex.radius = (figure["joints"][n][1],) * 2
        obj.data.skin_vertices[0].data[0].use_root = True
        obj.modifiers.new("subdivision", "SUBSURF").levels = 2
        evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
        surface = bmesh.new()
        surface.from_mesh(evaluated)
        bmesh.ops.triangulate(surface, faces=surface.faces[:])
        arrays[f"{name}_vertices"] = np.array([v.co[:] for v in surface.verts])
        arrays[f"{name}_faces"] = np.array([[v.index for v in f.verts] for f in surface.faces])
        arrays[f"{name}_tips"] = np.array([np.add(figure["joints"][joint][0], nudge)
                                           for _, joint, nudge in figure["tips"]])
    np.savez(out, **arrays)


def rig_table(data: Path, seeds: int, spheres: int, figures: Path | None, names: list[str]):
    import trimesh

    import fleshing_jax as fj

    arrays = np.load(data)
    print("| character | vertices | seed | limbs | limbs per chain | tips in a limb of their own |")
    print("|---|---:|---:|---:|---|---|")
    for name in names:
        figure = CHARACTERS[name]
        mesh = trimesh.Trimesh(arrays[f"{name}_vertices"], arrays[f"{name}_faces"],
                               process=False)
        mesh = mesh if mesh.is_watertight else fj.cap_holes(mesh)
        vertices = np.asarray(mesh.vertices)
        tips = [int(np.argmin(np.linalg.norm(vertices - p, axis=1)))
                for p in arrays[f"{name}_tips"]]
        for seed in range(seeds):
            skeleton = fj.skeleton(mesh, spheres=spheres, seed=seed)
            at = [int(skeleton.region[v]) for v in tips]
            own = [k != -1 and at.count(k) == 1 for k in at]
            missed = [tip[0] + (" (body)" if k == -1 else f" (limb {k}, shared)")
                      for tip, k, ok in zip(figure["tips"], at, own) if not ok]
            tops = [k for k, limb in enumerate(skeleton.limbs) if limb.parent == -1]
            per_chain = [sum(skeleton.chain(j)[0] == k for j in range(len(skeleton.limbs)))
                         for k in tops]
            print(f"| {name} | {len(vertices):,} | {seed} | {len(skeleton.limbs)} | "
                  f"{'/'.join(map(str, per_chain))} | {sum(own)} of {len(own)}"
                  + (f": not {', '.join(missed)}" if missed else "") + " |", flush=True)
            if figures is not None:
                figures.mkdir(parents=True, exist_ok=True)
                fj.plot_skeleton(mesh, skeleton).savefig(
                    figures / f"skin-{name}-{seed}.png", dpi=80)


def _chains_by_tip(skeleton, pick: dict) -> dict:
    """Name → the longest chain from the body whose last limb's spine ends where
    `pick[name](end point)` holds (z up)."""
    from blender_armature import chain_tips

    chains, tips = chain_tips(skeleton)
    return {name: chains[next(t for t, p in tips.items() if test(p))]
            for name, test in pick.items()}


def _human_targets(fj, skeleton, registration) -> tuple:
    """The human's (z up, +y ahead, +x its left) joints and the poses of issue 46."""
    from blender_armature import human_chains

    leg, arm, head = human_chains(skeleton)
    ahead, up, side = np.eye(3)[[1, 2, 0]]
    ranges = [("hip", leg[0], ahead, "forwards"), ("hip", leg[0], -ahead, "backwards"),
              ("knee", leg[1], -ahead, "backwards"), ("shoulder", arm[0], up, "up"),
              ("shoulder", arm[0], ahead, "forwards"), ("elbow", arm[1], ahead, "forwards"),
              ("neck", head[0], ahead, "forwards"), ("neck", head[0], side, "sideways")]
    poses = {
        "knee 120° backwards": {leg[1]: fj.LimbPose(120.0, towards=-ahead)},
        "elbow 120° forwards": {arm[1]: fj.LimbPose(120.0, towards=ahead)},
        "arm raised 90° at the shoulder": {arm[0]: fj.LimbPose(90.0, towards=up)},
        "leg lifted 90°: hip 45° + knee 45°": {leg[0]: fj.LimbPose(45.0, towards=ahead),
                                                leg[1]: fj.LimbPose(45.0, towards=ahead)},
        "leg lifted 90°: hip 60° + knee 30°": {leg[0]: fj.LimbPose(60.0, towards=ahead),
                                                leg[1]: fj.LimbPose(30.0, towards=ahead)},
        "head turned 45°": {head[0]: fj.turn(registration, skeleton, head[0], 45.0,
                                             up=tuple(up))},
        "head nodded 45°": {head[0]: fj.LimbPose(45.0, towards=ahead)},
    }
    return ranges, poses


def _cow_targets(fj, skeleton, registration) -> tuple:
    """The cow's (z up, +x ahead, +y its left) joints and the poses of issue 46: a front
    leg lifted (hip and knee forwards), a knee bent 120° (the front one back, the hind one
    forwards), the head turned and nodded 45°, the tail raised 60° (at its root, the rest
    free; at two joints)."""
    chains = _chains_by_tip(skeleton, {
        "front": lambda p: p[0] > 0.3 and p[1] > 0 and p[2] < 0.3,
        "hind": lambda p: p[0] < -0.3 and p[1] > 0 and p[2] < 0.3,
        "head": lambda p: p[0] > 0.9, "tail": lambda p: p[0] < -0.7 and p[2] > 0.5})
    front, hind, head, tail = (chains[n] for n in ("front", "hind", "head", "tail"))
    ahead, side, up = np.eye(3)
    ranges = [("front hip", front[0], ahead, "forwards"), ("front knee", front[1], -ahead,
                                                            "backwards"),
              ("hind hip", hind[0], -ahead, "backwards"), ("hind knee", hind[1], ahead,
                                                          "forwards"),
              ("neck", head[0], -up, "down"), ("neck", head[0], side, "sideways"),
              ("tail root", tail[0], up, "up")]
    poses = {
        "front leg lifted 90°: hip 45° + knee 45°": {front[0]: fj.LimbPose(45.0, towards=ahead),
                                                      front[1]: fj.LimbPose(45.0, towards=ahead)},
        "front knee 120° backwards": {front[1]: fj.LimbPose(120.0, towards=-ahead)},
        "hind knee 120° forwards": {hind[1]: fj.LimbPose(120.0, towards=ahead)},
        "head turned 45°": {head[0]: fj.turn(registration, skeleton, head[0], 45.0,
                                             up=tuple(up))},
        "head nodded 45° down": {head[0]: fj.LimbPose(45.0, towards=-up)},
        "tail raised 60° at its root": {tail[0]: fj.LimbPose(60.0, towards=up)},
    }
    if len(tail) > 1:
        poses["tail raised 30° + 30°"] = {tail[0]: fj.LimbPose(30.0, towards=up),
                                         tail[1]: fj.LimbPose(30.0, towards=up)}
    return ranges, poses


def joint_targets(data: Path, names: list[str]):
    """Issue 46's targets on the human and the cow: each joint's exact range
    (`fj.joint_range`) in the direction an animator bends it, alone and with the chain
    below it free (its part counted), then the poses (knees and elbows at 120°, a limb
    raised or lifted 90°, the head turned and nodded 45°, the cow's tail raised 60°)."""
    import trimesh
    from blender_armature import measures

    import fleshing_jax as fj

    arrays = np.load(data)
    for name in names:
        mesh = trimesh.Trimesh(arrays[f"{name}_vertices"], arrays[f"{name}_faces"],
                               process=False)
        mesh = mesh if mesh.is_watertight else fj.cap_holes(mesh)  # (the skin's branch holes)
        skeleton = fj.skeleton(mesh)
        registration = fj.register_skeleton(mesh, skeleton)
        targets = {"human": _human_targets, "cow": _cow_targets}[name]
        ranges, poses = targets(fj, skeleton, registration)
        print(f"\n{name}\n\n| joint | exact to (°), alone | with the chain below free |")
        print("|---|---:|---:|")
        for joint, limb, towards, words in ranges:
            alone, free = (float(fj.joint_range(registration, int(limb), towards=towards,
                                                children_posed=posed))
                           for posed in (True, False))
            print(f"| {joint} {words} | {alone:.1f} | {free:.1f} |")
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        print("\n| pose | flagged | dV/V (%) | worst edge stretch | edges > 2.5x |")
        print("|---|---:|---:|---:|---:|")
        for pose_name, pose in poses.items():
            posed = fj.pose_skeleton(registration, skeleton, pose)
            change, worst, torn, _ = measures(vertices, faces, np.asarray(posed.vertices),
                                              np.asarray(skeleton.region))
            print(f"| {pose_name} | {int(np.sum(~np.asarray(posed.valid)))} | "
                  f"{100 * change:+.4f} | {worst:.2f} | {torn} |", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bpy", help="a Python with `bpy` installed")
    parser.add_argument("--blender-side", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--spheres", type=int, default=200)
    parser.add_argument("--figures", type=Path)
    parser.add_argument("--joints", action="store_true", help="issue 46's joint targets")
    parser.add_argument("--only", nargs="+", choices=list(CHARACTERS), help="these characters")
    args = parser.parse_args()
    if args.blender_side is not None:
        return blender_side(args.blender_side)
    if args.bpy is None:
        parser.error("--bpy is required: the meshes are modelled in Blender")
    with tempfile.TemporaryDirectory() as scratch:
        data = Path(scratch) / "characters.npz"
        subprocess.run([args.bpy, __file__, "--blender-side", str(data)], check=True)
        if args.joints:
            import jax

            jax.config.update("jax_enable_x64", True)
            return joint_targets(data, [n for n in ("human", "cow")
                                         if not args.only or n in args.only])
        rig_table(data, args.seeds, args.spheres, args.figures, args.only or list(CHARACTERS))


if __name__ == "__main__":
    sys.exit(main())

"""Our jointed pose against Blender's armature on the same joint rotations (issues 45/46).

    python benchmarks/blender_armature.py --bpy /path/to/venv-with-bpy/bin/python \
        [--character biped|spot|human|insect|dog|kangaroo|dinosaur|cow|horse] [--own-armature] \
        [--figure benchmarks/figures/skeleton-biped-vs-blender.png]

The procedural biped's skeleton (`fj.skeleton`, 200 spheres): one leg posed at its hip 40°,
knee 70°, ankle 20°, one arm at its shoulder, elbow and wrist alike, the head 30° (float64);
or spot's (`fj.skeleton`): its head turned 45°, a front leg lifted 45°, a hind leg 60°; or
the human modelled in Blender (`skin_characters.py`): a leg, an arm and the head forwards;
or its insect: a front leg raised at hip and knee, a hind leg swung back, the head turned;
or its dog: a front leg stepping (shoulder and next joint), a hind leg back, the head turned,
the tail raised; or its kangaroo: the tail raised, a hind leg forwards, an arm raised, the
head turned.
Blender (`pip install bpy` in another environment: `--bpy` names its Python) gets one bone
per limb (head at the limb's bend start, tail where its bend is complete), a still body
bone, automatic heat weights, and as each bone's rotation the rotation our pose gives that
limb's end (so both pose the same joints by the same angles). `--own-armature` (the human,
the cow, the dinosaur, the insect, the kangaroo, the horse: its only poses): both get the
armature the character is modelled on instead (`skin_characters.py`'s bones: pelvis, spine,
clavicles and hips too), ours through `fj.skeleton(mesh, bones=...)` (the bones inside the
body no limbs), the same poses given by bone name; Blender's bones that are none of our
limbs stay at rest. Prints a Markdown table: volume change, the worst edge stretch and how
many edges stretch past 2.5×, the body's largest drift, flagged vertices (ours) and the time
of a frame (ours: float32, jitted; Blender: its depsgraph's evaluation of the armature
modifier, LBS and DQS).
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

# The characters whose own armature (`--own-armature`) has poses here.
OWN = ("human", "cow", "dinosaur", "insect", "kangaroo", "horse")


def _longest_chains(skeleton) -> dict:
    """Each chain's top limb → the longest chain of limbs from it to an end."""
    chains = {}
    for k in range(len(skeleton.limbs)):
        chain = skeleton.chain(k)
        if len(chain) > len(chains.get(chain[0], ())):
            chains[chain[0]] = chain
    return chains


def chain_tips(skeleton) -> tuple[dict, dict]:
    """`(chains, tips)`: each chain's top limb → its longest chain (`_longest_chains`), and →
    where that chain's last spine ends (3,)."""
    chains = _longest_chains(skeleton)
    return chains, {top: np.asarray(skeleton.limbs[c[-1]].spine(skeleton.limbs[c[-1]].spine.length))
                    for top, c in chains.items()}


def _front_and_hind(chains: dict, tips: dict, below: float) -> tuple:
    """A quadruped's (z up, +x ahead, +y its left) left front and right hind leg chains: of
    the chains ending below height `below`, the farthest ahead and left, and behind and right."""
    feet = {t: p for t, p in tips.items() if p[2] < below}
    return (chains[max(feet, key=lambda t: feet[t][0] + feet[t][1])],
            chains[min(feet, key=lambda t: feet[t][0] + feet[t][1])])


def biped_poses(fj, skeleton):
    """The biped (`characters.biped`, its own skeleton): a leg at hip 40°, knee 70°, ankle
    20°, an arm at shoulder, elbow and wrist alike, the head 30°."""
    chains = _longest_chains(skeleton)

    def tip(chain):
        spine = skeleton.limbs[chain[-1]].spine
        return np.asarray(spine(spine.length))

    leg = next(c for c in chains.values() if tip(c)[2] < 0.1 and tip(c)[1] > 0)
    arm = next(c for c in chains.values() if 0.3 < tip(c)[2] < 0.7 and tip(c)[1] > 0)
    head = next(c for c in chains.values() if tip(c)[2] > 0.9)
    poses = {k: fj.LimbPose(a) for c in (leg, arm) for k, a in zip(c, (40.0, 70.0, 20.0))}
    poses[head[0]] = fj.LimbPose(30.0)
    return lambda registration: poses


def spot_poses(fj, skeleton):
    """Spot (`fj.data.spot()`, y up, head towards −z; its own skeleton): the head turned 45°
    about up (as an animator turns a neck bone), its right front leg lifted 45° forwards, its
    right hind leg 60° backwards."""
    up, ahead = (0.0, 1.0, 0.0), np.array([0.0, 0.0, -1.0])
    tips = np.array([np.asarray(limb.spine(limb.spine.length)) for limb in skeleton.limbs])
    top = [k for k, limb in enumerate(skeleton.limbs) if limb.parent == -1]
    head = max(top, key=lambda k: tips[k, 1])
    legs = [k for k in top if tips[k, 1] < -0.6 and tips[k, 0] < 0]
    front, hind = min(legs, key=lambda k: tips[k, 2]), max(legs, key=lambda k: tips[k, 2])
    return lambda registration: {
        head: fj.turn(registration, skeleton, head, 45.0, up=up),
        front: fj.LimbPose(45.0, towards=ahead), hind: fj.LimbPose(60.0, towards=-ahead)}


def human_chains(skeleton) -> tuple:
    """The human's (z up, +x its left) left leg, left arm and head chains, by their tips."""
    chains, tips = chain_tips(skeleton)
    leg = chains[next(t for t, p in tips.items() if p[2] < 0.3 and p[0] > 0)]
    arm = chains[next(t for t, p in tips.items() if p[0] > 0.5)]
    return leg, arm, chains[max(tips, key=lambda t: tips[t][2])]


def human_poses(fj, skeleton):
    """The human modelled in Blender (`skin_characters.py`, z up, +y ahead; its own skeleton):
    its left leg at hip 40° forwards, knee 70° backwards, ankle 20° forwards, its left arm
    at shoulder, elbow and wrist 40° / 70° / 20° forwards, the head nodded 30° forwards."""
    ahead = np.array([0.0, 1.0, 0.0])
    leg, arm, head = human_chains(skeleton)
    poses = {k: fj.LimbPose(a, towards=sign * ahead)
             for k, a, sign in zip(leg, (40.0, 70.0, 20.0), (1, -1, 1))}
    poses |= {k: fj.LimbPose(a, towards=ahead) for k, a in zip(arm, (40.0, 70.0, 20.0))}
    poses[head[0]] = fj.LimbPose(30.0, towards=ahead)
    return lambda registration: poses


def insect_poses(fj, skeleton):
    """The insect modelled in Blender (`skin_characters.py`, z up, +x ahead; its own
    skeleton): its left front leg raised 30° at the hip and 30° more at the knee, its left
    hind leg swung 30° backwards at the hip (each leg a chain from the hip: thigh, shin,
    foot), its head (with both antennae) turned 20° about up."""
    up, back = np.array([0.0, 0.0, 1.0]), np.array([-1.0, 0.0, 0.0])
    chains, tips = chain_tips(skeleton)
    feet = [t for t, p in tips.items() if p[2] < 0.2 and p[1] > 0.3]
    front = chains[max(feet, key=lambda t: tips[t][0])]
    hind = chains[min(feet, key=lambda t: tips[t][0])]
    poses = {front[0]: fj.LimbPose(30.0, towards=up), front[1]: fj.LimbPose(30.0, towards=up),
             hind[0]: fj.LimbPose(30.0, towards=back)}
    head = max(tips, key=lambda t: tips[t][2])  # (its chain ends at an antenna's tip)
    return lambda registration: poses | {head: fj.turn(registration, skeleton, head, 20.0,
                                                       up=up)}


def dog_poses(fj, skeleton):
    """The dog modelled in Blender (`skin_characters.py`, z up, +x ahead, +y its left; its own
    skeleton): its left front leg lifted 40° forwards at the shoulder and its next joint 60°
    backwards (a step), its right hind leg 30° backwards at the hip, its head (with both ears)
    turned 30° about up, its tail raised 40°."""
    up, ahead = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    chains, tips = chain_tips(skeleton)
    front, hind = _front_and_hind(chains, tips, 0.2)
    high = [t for t, p in tips.items() if p[2] > 0.7]
    head, tail = max(high, key=lambda t: tips[t][0]), min(high, key=lambda t: tips[t][0])
    poses = {front[0]: fj.LimbPose(40.0, towards=ahead), hind[0]: fj.LimbPose(30.0, towards=-ahead),
             tail: fj.LimbPose(40.0, towards=up)}
    if len(front) > 1:
        poses[front[1]] = fj.LimbPose(60.0, towards=-ahead)
    return lambda registration: poses | {head: fj.turn(registration, skeleton, head, 30.0,
                                                       up=up)}


def kangaroo_poses(fj, skeleton):
    """The kangaroo modelled in Blender (`skin_characters.py`, z up, +x ahead; its own
    skeleton): its tail raised 30°, a hind leg swung 30° forwards at the hip, an arm raised
    40° forwards, its head (with its ears) turned 30° about up."""
    up, ahead = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    chains, tips = chain_tips(skeleton)
    tail = min(tips, key=lambda t: tips[t][0])
    head = max(tips, key=lambda t: tips[t][2])
    feet = [t for t, p in tips.items() if p[2] < 0.2 and t != tail]
    arms = [t for t in tips if t not in (tail, head, *feet)]
    poses = {tail: fj.LimbPose(30.0, towards=up),
             chains[feet[0]][0]: fj.LimbPose(30.0, towards=ahead),
             chains[arms[0]][0]: fj.LimbPose(40.0, towards=ahead)}
    return lambda registration: poses | {head: fj.turn(registration, skeleton, head, 30.0,
                                                       up=up)}


def dinosaur_poses(fj, skeleton):
    """The dinosaur modelled in Blender (`skin_characters.py`, z up, +x ahead; its own
    skeleton): its neck raised 30° and its head 20° more (the neck → head chain), its left leg
    swung 30° forwards at the hip and its next joint 40° backwards, its tail raised 30°."""
    up, ahead = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    chains, tips = chain_tips(skeleton)
    neck, tail = max(tips, key=lambda t: tips[t][0]), min(tips, key=lambda t: tips[t][0])
    feet = [t for t, p in tips.items() if p[2] < 0.2]
    leg = chains[max(feet, key=lambda t: tips[t][1])]  # (its left: +y)
    poses = {tail: fj.LimbPose(30.0, towards=up), leg[0]: fj.LimbPose(30.0, towards=ahead)}
    poses |= {k: fj.LimbPose(a, towards=up) for k, a in zip(chains[neck], (30.0, 20.0))}
    if len(leg) > 1:
        poses[leg[1]] = fj.LimbPose(40.0, towards=-ahead)
    return lambda registration: poses


def cow_poses(fj, skeleton):
    """The cow modelled in Blender (`skin_characters.py`, z up, +x ahead, +y its left; its own
    skeleton): its left front leg lifted 45° forwards at the hip and 45° more at the knee,
    its right hind leg 30° backwards at the hip, its head turned 45° about up, its tail
    raised 60° at its root (the rest of the tail free)."""
    up, ahead = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    chains, tips = chain_tips(skeleton)
    front, hind = _front_and_hind(chains, tips, 0.3)
    head = max(tips, key=lambda t: tips[t][0])
    tail = min((t for t, p in tips.items() if p[2] > 0.5), key=lambda t: tips[t][0])
    poses = {front[0]: fj.LimbPose(45.0, towards=ahead), hind[0]: fj.LimbPose(30.0, towards=-ahead),
             tail: fj.LimbPose(60.0, towards=up)}
    if len(front) > 1:
        poses[front[1]] = fj.LimbPose(45.0, towards=ahead)
    return lambda registration: poses | {head: fj.turn(registration, skeleton, head, 45.0,
                                                       up=up)}


def own_bones(character: str) -> tuple:
    """The armature `character` of `skin_characters.py` is modelled on, as Blender exports
    it: `(heads (m, 3), tails (m, 3), parents (m,), names)`, bone `a-b` from joint `a` to
    joint `b`, its parent the bone ending at `a` (−1: none)."""
    from skin_characters import CHARACTERS

    joints, bones = CHARACTERS[character]["joints"], CHARACTERS[character]["bones"]
    parents = [next((i for i, (_, end) in enumerate(bones) if end == a), -1) for a, _ in bones]
    return (np.array([joints[a][0] for a, _ in bones], float),
            np.array([joints[b][0] for _, b in bones], float), np.array(parents),
            [f"{a}-{b}" for a, b in bones])


def human_armature_poses(fj, skeleton):
    """`human_poses` on the human's own armature (`own_bones`), its bones posed by name."""
    ahead = np.array([0.0, 1.0, 0.0])
    poses = {f"l{a}-l{b}": fj.LimbPose(angle, towards=sign * ahead)
             for a, b, angle, sign in (("hip", "knee", 40.0, 1), ("knee", "ankle", 70.0, -1),
                                       ("ankle", "toe", 20.0, 1), ("shoulder", "elbow", 40.0, 1),
                                       ("elbow", "wrist", 70.0, 1), ("wrist", "hand", 20.0, 1))}
    poses["neck-head"] = fj.LimbPose(30.0, towards=ahead)
    return lambda registration: poses


def cow_armature_poses(fj, skeleton):
    """`cow_poses` on the cow's own armature (`own_bones`), its bones posed by name."""
    up, ahead = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    poses = {"front left hip-front left knee": fj.LimbPose(45.0, towards=ahead),
             "front left knee-front left hoof": fj.LimbPose(45.0, towards=ahead),
             "hind right hip-hind right knee": fj.LimbPose(30.0, towards=-ahead),
             "tail-tail tip": fj.LimbPose(60.0, towards=up)}
    return lambda registration: poses | {"neck-head": fj.turn(registration, skeleton,
                                                              "neck-head", 45.0, up=up)}


def dinosaur_armature_poses(fj, skeleton):
    """`dinosaur_poses` on the dinosaur's own armature (`own_bones`), by bone name: the neck
    bone raised 30° and the head's 20° more, the left thigh 30° forwards and the shin 40°
    backwards, the tail's second bone raised 30° (its first runs from the hips' middle)."""
    up, ahead = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    poses = {"chest-neck": fj.LimbPose(30.0, towards=up),
             "neck-head": fj.LimbPose(20.0, towards=up),
             "left hip-left knee": fj.LimbPose(30.0, towards=ahead),
             "left knee-left ankle": fj.LimbPose(40.0, towards=-ahead),
             "tail 1-tail 2": fj.LimbPose(30.0, towards=up)}
    return lambda registration: poses


def insect_armature_poses(fj, skeleton):
    """`insect_poses` on the insect's own armature (`own_bones`), by bone name: the left front
    thigh raised 30° and its shin 30° more, the left hind thigh swung 30° backwards (the head
    is no limb there: its neck and head bones lie in the thorax and head's middle)."""
    up, back = np.array([0.0, 0.0, 1.0]), np.array([-1.0, 0.0, 0.0])
    poses = {"lfront hip-lfront knee": fj.LimbPose(30.0, towards=up),
             "lfront knee-lfront ankle": fj.LimbPose(30.0, towards=up),
             "lhind hip-lhind knee": fj.LimbPose(30.0, towards=back)}
    return lambda registration: poses


def kangaroo_armature_poses(fj, skeleton):
    """`kangaroo_poses` on the kangaroo's own armature (`own_bones`), by bone name: the tail's
    first bone raised 30°, the left thigh swung 30° forwards, the left upper arm 40°
    forwards, the head turned 30° about up (its bone from the neck's top; the snout's bone
    moves with it, the chest and neck bones lie in the body)."""
    up, ahead = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    poses = {"pelvis-tail 1": fj.LimbPose(30.0, towards=up),
             "left hip-left knee": fj.LimbPose(30.0, towards=ahead),
             "left shoulder-left elbow": fj.LimbPose(40.0, towards=ahead)}
    return lambda registration: poses | {"neck-head": fj.turn(registration, skeleton,
                                                              "neck-head", 30.0, up=up)}


def horse_armature_poses(fj, skeleton):
    """The horse's own armature (`own_bones`; its neck and head limbs since `3a7c25d`), by
    bone name: the neck lowered 30° (grazing), the left front leg stepping (thigh 45°
    forwards, the bone below it 45° back), the right hind thigh 30° back, the tail swung 30°
    back."""
    up, ahead = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    poses = {"neck base-neck top": fj.LimbPose(30.0, towards=-up),
             "front left hip-front left knee": fj.LimbPose(45.0, towards=ahead),
             "front left knee-front left fetlock": fj.LimbPose(45.0, towards=-ahead),
             "hind right hip-hind right knee": fj.LimbPose(30.0, towards=-ahead),
             "tail-tail tip": fj.LimbPose(30.0, towards=-ahead)}
    return lambda registration: poses


def skin_mesh(bpy: str, name: str):
    """The character `name` of `skin_characters.py`, modelled by Blender in a subprocess
    (`bpy`)."""
    import trimesh

    with tempfile.TemporaryDirectory() as folder:
        data = Path(folder) / "characters.npz"
        subprocess.run([bpy, str(Path(__file__).with_name("skin_characters.py")),
                        "--blender-side", str(data)], check=True, capture_output=True)
        arrays = np.load(data)
        return trimesh.Trimesh(arrays[f"{name}_vertices"], arrays[f"{name}_faces"],
                               process=False)


def ours(out: Path, character: str, bpy: str, own: bool = False):
    import equinox as eqx
    import jax

    jax.config.update("jax_enable_x64", True)
    import fleshing_jax as fj
    from fleshing_jax._medial_axis.characters import biped
    from fleshing_jax._medial_axis.surface import closed_mesh_arrays
    from fleshing_jax._skeleton.posing import check_poses, placed_poses, posed_limbs

    bones = None
    if own:
        mesh = skin_mesh(bpy, character)
        mesh = mesh if mesh.is_watertight else fj.cap_holes(mesh)
        bones = own_bones(character)
        skeleton = fj.skeleton(mesh, bones=bones)
        poses_of = {"human": human_armature_poses, "cow": cow_armature_poses,
                    "dinosaur": dinosaur_armature_poses, "insect": insect_armature_poses,
                    "kangaroo": kangaroo_armature_poses,
                    "horse": horse_armature_poses}[character](fj, skeleton)
    elif character == "spot":
        mesh = fj.data.spot()
        skeleton = fj.skeleton(mesh)
        poses_of = spot_poses(fj, skeleton)
    elif character in ("human", "insect", "dog", "kangaroo", "dinosaur", "cow"):
        mesh = skin_mesh(bpy, character)
        mesh = mesh if mesh.is_watertight else fj.cap_holes(mesh)  # (the skin's branch holes)
        skeleton = fj.skeleton(mesh)
        poses_of = {"human": human_poses, "insect": insect_poses, "dog": dog_poses,
                    "kangaroo": kangaroo_poses, "dinosaur": dinosaur_poses,
                    "cow": cow_poses}[character](fj, skeleton)
    else:
        mesh = biped()
        skeleton = fj.skeleton(mesh)
        poses_of = biped_poses(fj, skeleton)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    # Faces wound against their neighbours (the horse's 288) turned as `fj.skeleton` turns
    # them: the volumes signed right and Blender's normals consistent.
    closed = closed_mesh_arrays(mesh, ride=True)
    faces = closed[1] if len(closed[0]) == len(vertices) else faces
    registration = fj.register_skeleton(mesh, skeleton)
    count = len(skeleton.limbs)
    poses = poses_of(registration)
    posed = fj.pose_skeleton(registration, skeleton, poses)
    rotations = np.tile(np.eye(3), (count, 1, 1))
    # (As the pose places them: a head's zone running on past its unposed ears, `WholeLimb`.)
    placed, indexed, _ = placed_poses(registration, skeleton, check_poses(poses, skeleton))
    for k, (_, _, motion, _) in posed_limbs(placed, indexed, "radial", True, False).items():
        rotations[k] = np.asarray(motion.rotation)
    if bones is not None:
        # Blender gets the whole armature; a bone that is no limb (inside the body) stays.
        heads, tails, parents = bones[:3]
        rotations = np.array([rotations[skeleton.index(name)] if name in skeleton.names
                              else np.eye(3) for name in bones[3]])
    else:
        # One bone per limb (head at the limb's bend start, tail where its bend is
        # complete) under a still body bone (bone 0) at the body's centre.
        joints, stops, limbs = placed.joints, placed.stops, skeleton.limbs
        centre = vertices[np.asarray(skeleton.region) == -1].mean(axis=0)
        heads = np.array([centre - (0, 0, 0.1)]
                         + [np.asarray(limbs[k].spine(joints[k])) for k in range(count)])
        tails = np.array([centre + (0, 0, 0.15)]
                         + [np.asarray(limbs[k].spine(min(float(stops[k]),
                                                          float(limbs[k].spine.length))))
                            for k in range(count)])  # fmt: skip
        parents = np.array([-1] + [limb.parent + 1 for limb in limbs])
        rotations = np.concatenate([np.eye(3)[None], rotations])
    fast = fj.register_skeleton(mesh, skeleton, dtype=np.float32)
    frame = jax.jit(lambda scale: fj.pose_skeleton(
        fast, skeleton, {k: eqx.tree_at(lambda q: q.bend, p, scale * p.bend)
                         for k, p in poses.items()}).vertices)
    frame(np.float32(1.0)).block_until_ready()
    times = []
    for i in range(20):
        start = time.perf_counter()
        frame(np.float32(1.0 + 1e-4 * i)).block_until_ready()
        times.append(time.perf_counter() - start)
    np.savez(out, vertices=vertices, faces=faces, posed=np.asarray(posed.vertices),
             valid=np.asarray(posed.valid), region=np.asarray(skeleton.region),
             rotations=rotations, heads=heads, tails=tails, parents=parents,
             frame_ms=1e3 * np.median(times))  # fmt: skip


def blender(data: Path, out: Path):
    """Run under bpy's Python: the armature, heat weights, the pose, LBS and DQS."""
    import bpy
    import mathutils

    d = np.load(data)
    vertices, parents = d["vertices"], d["parents"]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new("mesh")
    mesh.from_pydata(vertices.tolist(), [], d["faces"].tolist())
    mesh.update()
    body = bpy.data.objects.new("mesh", mesh)
    armature = bpy.data.objects.new("rig", bpy.data.armatures.new("rig"))
    for thing in (body, armature):
        bpy.context.scene.collection.objects.link(thing)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    bones = armature.data.edit_bones
    made = []
    for k, parent in enumerate(parents):
        bone = bones.new(f"bone{k}")
        bone.head, bone.tail = d["heads"][k], d["tails"][k]
        bone.parent = None if parent < 0 else made[parent]
        made.append(bone)
    bpy.ops.object.mode_set(mode="OBJECT")
    body.select_set(True)
    armature.select_set(True)
    bpy.context.view_layer.objects.active = armature
    start = time.perf_counter()
    bpy.ops.object.parent_set(type="ARMATURE_AUTO")
    result = {"weights_s": time.perf_counter() - start}
    for k in range(len(parents)):
        # Our rotation R of the limb's end, in the armature's space: the bone's own
        # rotation is B^T R B in its rest frame B.
        frame = np.array(armature.data.bones[f"bone{k}"].matrix_local.to_3x3())
        pose = armature.pose.bones[f"bone{k}"]
        pose.rotation_mode = "QUATERNION"
        pose.rotation_quaternion = mathutils.Matrix(
            (frame.T @ d["rotations"][k] @ frame).tolist()).to_quaternion()
    for name, volume_preserving in (("lbs", False), ("dqs", True)):
        body.modifiers[0].use_deform_preserve_volume = volume_preserving
        times = []
        for _ in range(20):
            armature.update_tag()
            start = time.perf_counter()
            graph = bpy.context.evaluated_depsgraph_get()
            graph.update()
            evaluated = body.evaluated_get(graph)
            posed = evaluated.to_mesh()
            times.append(time.perf_counter() - start)
            result[name] = np.array([v.co for v in posed.vertices])
            evaluated.to_mesh_clear()
        result[name + "_ms"] = 1e3 * np.median(times)
    np.savez(out, **result)


def measures(rest, faces, posed, region):
    import trimesh

    import fleshing_jax as fj

    edges = trimesh.Trimesh(rest, faces, process=False).edges_unique
    before = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    after = np.linalg.norm(posed[edges[:, 0]] - posed[edges[:, 1]], axis=1)
    stretch = np.maximum(after / before, before / after)
    change = float(fj.volume(posed, faces) / fj.volume(rest, faces)) - 1
    diagonal = np.linalg.norm(np.ptp(rest, axis=0))
    drift = np.linalg.norm(posed[region == -1] - rest[region == -1], axis=1).max() / diagonal
    return change, stretch.max(), int(np.sum(stretch > 2.5)), drift


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bpy", required=True, help="a Python with `bpy` installed")
    parser.add_argument("--figure", type=Path, default=None)
    parser.add_argument("--character", default="biped",
                        choices=("biped", "spot", "human", "insect", "dog", "kangaroo",
                                 "dinosaur", "cow", "horse"))
    parser.add_argument("--own-armature", action="store_true",
                        help="the character's own armature (`skin_characters.py`'s bones, "
                             "every one to Blender, ours from `fj.skeleton(mesh, bones=...)`), "
                             "not one bone per limb of our found skeleton")
    parser.add_argument("--blender-side", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.blender_side:
        return blender(*map(Path, args.blender_side))
    with tempfile.TemporaryDirectory() as folder:
        mine, theirs = Path(folder) / "ours.npz", Path(folder) / "blender.npz"
        if args.own_armature and args.character not in OWN:
            parser.error(f"--own-armature: --character {', '.join(OWN)}")
        if args.character == "horse" and not args.own_armature:
            parser.error("--character horse: with --own-armature (its poses are by bone name)")
        ours(mine, args.character, args.bpy, args.own_armature)
        subprocess.run([args.bpy, __file__, "--bpy", args.bpy, "--blender-side", str(mine),
                        str(theirs)], check=True, capture_output=True)  # fmt: skip
        o, b = dict(np.load(mine)), dict(np.load(theirs))
    rest, faces, region = o["vertices"], o["faces"], o["region"]
    print(f"Blender's heat weights: {b['weights_s']:.2f} s\n")
    print("| method | flagged | dV/V (%) | worst edge stretch | edges > 2.5x | body drift "
          "(% of diagonal) | frame (ms) |")
    print("|---|---|---|---|---|---|---|")
    rows = [("fleshing_jax (float32, jit)", o["posed"], int(np.sum(~o["valid"])),
             float(o["frame_ms"])),
            ("Blender LBS", b["lbs"], "-", float(b["lbs_ms"])),
            ("Blender DQS", b["dqs"], "-", float(b["dqs_ms"]))]  # fmt: skip
    for name, posed, flagged, ms in rows:
        change, worst, torn, drift = measures(rest, faces, posed, region)
        print(f"| {name} | {flagged} | {100 * change:+.3f} | {worst:.2f} | {torn} | "
              f"{100 * drift:.3f} | {ms:.2f} |")
    if args.figure is not None:
        # Drawn z up (spot's y up becomes the picture's vertical), ahead as the biped's +x
        # (the human's +y, turned about up).
        view = {"spot": lambda p: p[:, [0, 2, 1]],
                "human": lambda p: np.c_[p[:, 1], -p[:, 0], p[:, 2]]}.get(
            args.character, lambda p: p)
        _figure(args.figure, view(rest), faces, [view(p) for p in (o["posed"], b["lbs"], b["dqs"])])


def _figure(path, rest, faces, posed):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    titles = ["rest", "fleshing_jax", "Blender LBS", "Blender DQS"]
    figure = plt.figure(figsize=(16, 4.5))
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    for i, (points, title) in enumerate(zip([rest, *posed], titles)):
        ax = figure.add_subplot(1, 4, i + 1, projection="3d")
        triangles = points[faces]
        normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-300
        shade = 0.3 + 0.7 * np.abs(normals @ light)
        ax.add_collection3d(Poly3DCollection(triangles, facecolors=shade[:, None]
                                             * np.array([0.85, 0.72, 0.6]), edgecolors="none"))
        low, high = rest.min(axis=0), rest.max(axis=0)
        centre, half = (low + high) / 2, (high - low).max() / 2
        for set_limits, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
            set_limits(c - half, c + half)
        ax.view_init(10, -70)
        ax.set_box_aspect(None, zoom=1.5)  # mplot3d's default margin leaves the shape small
        ax.set_axis_off()
        ax.set_title(title)
    figure.tight_layout()
    temporary = Path(path).with_suffix(".tmp.png")
    figure.savefig(temporary, dpi=90)
    temporary.replace(path)
    plt.close(figure)


if __name__ == "__main__":
    main()

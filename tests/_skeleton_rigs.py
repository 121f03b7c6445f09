"""The quadruped rig of the skeleton tests and the skeleton figures' tests, built once per
worker (not once per file): `(mesh, medial, skeleton)`. Trimesh objects are mutable: tests
copy before editing.

`quadruped(32)` (z up; 4,256 vertices, its legs of a pair 0.06 apart) rigged on 56 spheres of
a quick medial mesh: the same limbs as on 60 (four legs of two limbs, the tail, the horns, the
head), its largest region 372 vertices. A posed skeleton's limbs are all padded to the largest
one's bucket (`_batching.buckets`): at 384 the quadruped's registration and pose are the
programs `test_skeleton_given` compiles for the quadruped's given legs (on 60 spheres the head's
413 vertices padded every limb to 512, programs no other test used).
"""

import functools

import fleshing_jax as fj


@functools.cache
def quadruped_rig():
    from fleshing_jax._medial_axis.animal import quadruped

    mesh = quadruped(32)
    medial = fj.medial_mesh(mesh, 56, samples=5000, refine=0, progress=False)
    return mesh, medial, fj.skeleton(mesh, medial=medial)

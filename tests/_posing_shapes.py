"""The posing tests' shape: a tube along x, cut by hand into a body (2 ≤ x ≤ 4), a right limb
with a child at its tip, and a left limb (shared by `test_posing` and `test_fit_pose`, so that
they share their compiled programs through the persistent cache). `tests/conftest.py` makes them
the fixtures `tube`, `skeleton` and `registration`.

Its limbs' spines are built as `fj.skeleton` builds them (8 control points, 32 subdivisions).
"""

import numpy as np

import fleshing_jax as fj

RADIUS = 0.3


def _straight(start, end):
    return fj.BSpline(np.linspace(start, end, 8), subdivisions=32)


def tube_mesh():
    """The tube: radius `RADIUS`, length 6 along x, 60 rings of 16 vertices."""
    angle = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    return fj.extrusion(RADIUS * np.stack([np.cos(angle), np.sin(angle)], 1), 6.0, 60)


def tube_skeleton(mesh):
    """Limb 0: x > 4 (joint at 4); limb 1, its child: x > 5.2; limb 2: x < 2; the body between."""
    x = np.asarray(mesh.vertices)[:, 0]
    region = np.full(len(x), -1)
    region[x > 4.0 + 1e-9] = 0
    region[x > 5.2 + 1e-9] = 1
    region[x < 2.0 - 1e-9] = 2
    limbs = [
        fj.Limb(_straight([3.5, 0, 0], [6, 0, 0]), 0.5, -1),
        fj.Limb(_straight([4.8, 0, 0], [6, 0, 0]), 0.4, 0),
        # (Its joint given short of its region's border, at x = 2.3: the bend must still
        # start past the border, x = 2.)
        fj.Limb(_straight([2.5, 0, 0], [0, 0, 0]), 0.2, -1),
    ]
    return fj.Skeleton(limbs, region, mesh.vertices)


def tube_registration(mesh, skeleton):
    """`register_skeleton` of the tube. (Its cap's fan edges are as long as its radius: half of
    that as the margin would leave no room to bend a tube this thin; the caps are far from the
    bends.)"""
    return fj.register_skeleton(mesh, skeleton, margin=0.06)


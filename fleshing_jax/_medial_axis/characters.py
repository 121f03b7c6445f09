"""Procedural test characters with jointed limbs: shapes closer to real creatures than
`animal.py`'s, whose limbs are single cones.

Each limb here is a chain of spheres, its medial radius narrowing at every joint (a knee,
an elbow, an ankle) and its axis turning a little there: what a skeleton must follow
through a joint without cutting the limb in two, and what posing must bend at. Like
`animal.py`'s shapes each is the envelope of a hand-made medial mesh, closed and manifold
(`MedialMesh.envelope`) with no mesh boolean, and its medial axis is known. All are z up.

- `jointed_quadruped`: a four-legged animal of length 1.43 (body 0.82), legs hip → knee
  → ankle → hoof with a bent knee, a neck narrower than the head, a tapering tail;
- `biped`: a human figure of height 1 (a 1.8 m person scaled), arms held out at ~45°
  (shoulder → elbow → wrist → hand), legs hip → knee → ankle → foot, feet towards +x;
- `insect`: head, thorax and abdomen along x, six three-segment legs from the thorax
  (femur up and out, tibia down, tarsus), two thin antennae: many thin limbs from one
  small body part.

Default resolutions give 3k–9k vertices and one shell: the thinnest parts (the quadruped's
tail tip, the biped's wrists, the insect's antennae and ankles) 1.2–2 grid cells thick
there; a few resolutions lower they fall apart into loose blobs (each function says where).
"""

from __future__ import annotations

import numpy as np
import trimesh

from .medial_mesh import MedialMesh


class _Builder:
    """Spheres, edges and faces of a medial mesh, added one by one."""

    def __init__(self):
        self.spheres, self.edges, self.faces = [], [], []

    def add(self, centre, radius, parent=None):
        """A sphere, joined by a cone to `parent` if given: its index."""
        self.spheres.append((*centre, radius))
        if parent is not None:
            self.edges.append((parent, len(self.spheres) - 1))
        return len(self.spheres) - 1

    def chain(self, parent, points):
        """Spheres `(x, y, z, r)` each joined to the one before (the first to `parent`): the
        last one's index."""
        for *centre, radius in points:
            parent = self.add(centre, radius, parent)
        return parent

    def slab(self, i, j, k):
        """A slab between three spheres (with its edges)."""
        self.edges += [(i, j), (j, k), (i, k)]
        self.faces.append((i, j, k))

    def medial(self) -> MedialMesh:
        spheres = np.array(self.spheres, float)
        edges = np.unique(np.sort(np.array(self.edges), axis=1), axis=0)
        faces = np.array(self.faces, int).reshape(-1, 3)
        return MedialMesh(spheres[:, :3], spheres[:, 3], edges, faces)


# Joint positions of the characters' limbs, exported for tests: (x, y, z, radius) per
# sphere, y for the left side (+y), mirrored for the right.

QUADRUPED_HIND_LEG = (  # hip → thigh → knee → shin → ankle → hoof; the stifle forward
    (0.25, 0.1, 0.5, 0.06),      # thigh (its top inside the body)
    (0.29, 0.1, 0.3, 0.04),      # knee: forwards by 0.04, the axis turning ~20° there
    (0.275, 0.1, 0.21, 0.045),   # shin
    (0.255, 0.1, 0.085, 0.03),   # ankle
    (0.265, 0.1, 0.035, 0.035),  # hoof, its sole at z = 0
)
QUADRUPED_FRONT_LEG = tuple((1 - x, y, z, r)  # mirrored about x = 0.5: the knee backwards
                            for x, y, z, r in QUADRUPED_HIND_LEG)


def jointed_quadruped_medial() -> MedialMesh:
    """A four-legged animal of length 1.43 from tail to snout: a body from x = 0.09 to 0.91
    (radius 0.11–0.13, its top at z = 0.74); legs at y = ±0.1, 0.5 from the thigh's centre
    to the sole (~8 thigh radii), radius 0.06 at the thigh narrowing to 0.04 at the knee,
    0.045 at the shin, 0.03 at the ankle, 0.035 at the hoof, the hind knees 0.04 forwards
    and the front ones backwards (the axis turning 21°), the legs of a pair 0.08 apart at
    the thighs (2.2 grid cells at resolution 40); a neck of radius 0.05 rising to a head
    of 0.075 and a snout of 0.045 at x = 1.18; a tail of four spheres tapering from 0.035
    to 0.022 at x = −0.18."""
    b = _Builder()
    hind = b.add((0.2, 0, 0.59), 0.11)
    front = b.add((0.8, 0, 0.61), 0.11, b.add((0.5, 0, 0.61), 0.13, hind))
    head = b.chain(front, [(0.92, 0, 0.74, 0.05), (0.98, 0, 0.82, 0.05), (1.07, 0, 0.87, 0.075)])
    b.add((1.18, 0, 0.83), 0.045, head)
    b.chain(hind, [(0.06, 0, 0.64, 0.035), (-0.04, 0, 0.62, 0.03), (-0.12, 0, 0.56, 0.026),
                   (-0.18, 0, 0.48, 0.022)])
    for side in (-1, 1):
        for hip, leg in ((hind, QUADRUPED_HIND_LEG), (front, QUADRUPED_FRONT_LEG)):
            b.chain(hip, [(x, y * side, z, r) for x, y, z, r in leg])
    return b.medial()


def jointed_quadruped(resolution: int = 40) -> trimesh.Trimesh:
    """The closed, manifold surface of `jointed_quadruped_medial()` at `resolution`
    (4,654 vertices at the default 40; one shell from 30 up, below which the tail's tip
    comes loose)."""
    return jointed_quadruped_medial().envelope(resolution)


BIPED_ARM = (  # shoulder → upper arm → elbow → forearm → wrist → hand, out at 45°
    (0.0, 0.13, 0.8, 0.045),     # shoulder (inside the chest)
    (0.005, 0.19, 0.74, 0.04),   # upper arm
    (0.02, 0.25, 0.68, 0.028),   # elbow: the forearm turning ~16° to the front there
    (0.047, 0.292, 0.625, 0.032),  # forearm
    (0.075, 0.335, 0.57, 0.021),   # wrist: thinner would come loose below resolution 34
    (0.1, 0.38, 0.515, 0.027),     # hand
)
BIPED_LEG = (  # hip → thigh → knee → calf → ankle → foot, the foot towards +x
    (0.0, 0.08, 0.47, 0.055),    # hip (inside the pelvis)
    (0.01, 0.085, 0.37, 0.05),   # thigh
    (0.02, 0.09, 0.27, 0.033),   # knee, a little forwards
    (0.005, 0.095, 0.18, 0.04),  # calf
    (-0.005, 0.1, 0.05, 0.024),  # ankle
    (0.08, 0.1, 0.024, 0.024),   # foot, its sole at z = 0
)


def biped_medial() -> MedialMesh:
    """A human figure of height 1 (a 1.8 m person scaled): a torso of two slabs between
    pelvis spheres (radius 0.08 at y = ±0.045, z = 0.53) and chest ones (0.08 at y = ±0.06,
    z = 0.71), a neck of 0.035 and a head of 0.065 (its top at z = 1); arms out at 45° from
    shoulders at y = ±0.13, z = 0.8 to hands at y = ±0.38, radius 0.04 at the upper arm,
    0.028 at the elbow, 0.032 at the forearm, 0.021 at the wrist, the elbows bent 16°
    forwards (the arms 0.057 from the torso at the elbows' height, 2.7 grid cells at
    resolution 48); legs from hips at y = ±0.08, radius 0.05 at the thigh (the legs of a
    pair 0.07 apart there), 0.033 at the knee, 0.04 at the calf, 0.024 at the ankle, feet
    along +x to x = 0.1."""
    b = _Builder()
    pelvis = [b.add((0, s * 0.045, 0.53), 0.08) for s in (-1, 1)]
    chest = [b.add((0, s * 0.06, 0.71), 0.08) for s in (-1, 1)]
    b.slab(pelvis[0], pelvis[1], chest[0])
    b.slab(pelvis[1], chest[1], chest[0])
    neck = b.add((0, 0, 0.84), 0.035)
    b.edges += [(chest[0], neck), (chest[1], neck)]
    b.add((0.01, 0, 0.935), 0.065, neck)
    for k, side in enumerate((-1, 1)):
        b.chain(chest[k], [(x, y * side, z, r) for x, y, z, r in BIPED_ARM])
        b.chain(pelvis[k], [(x, y * side, z, r) for x, y, z, r in BIPED_LEG])
    return b.medial()


def biped(resolution: int = 48) -> trimesh.Trimesh:
    """The closed, manifold surface of `biped_medial()` at `resolution` (7,550 vertices at
    the default 48; one shell from 33 up, below which a wrist may come apart)."""
    return biped_medial().envelope(resolution)


INSECT_LEGS = (  # per leg on the left: coxa → femur → knee → tibia → ankle → tarsus tip
    # (x of the coxa, x of the knee, x of the foot): front legs forwards, hind ones back
    (0.66, 0.78, 0.9), (0.6, 0.6, 0.6), (0.54, 0.42, 0.3),
)
INSECT_ANTENNA = ((0.95, 0.05, 0.42, 0.027), (1.05, 0.12, 0.52, 0.024),
                  (1.13, 0.2, 0.58, 0.022))


def insect_leg(coxa_x, knee_x, foot_x):
    """One left leg's spheres `(x, y, z, r)`: out of the thorax's side, the femur up and
    out to the knee, the tibia down to the ankle, the tarsus out along the ground."""
    mid = lambda a, b, t=0.5: a + t * (b - a)  # noqa: E731
    return (
        (coxa_x, 0.08, 0.3, 0.045),                     # coxa, inside the thorax
        (mid(coxa_x, knee_x), 0.19, 0.37, 0.036),       # femur
        (knee_x, 0.3, 0.44, 0.026),                     # knee (the leg's highest point)
        (mid(knee_x, foot_x, 0.3), 0.35, 0.28, 0.032),  # tibia
        (mid(knee_x, foot_x, 0.7), 0.39, 0.07, 0.024),  # ankle
        (foot_x, 0.47, 0.026, 0.026),                   # tarsus tip, on the ground
    )


def insect_medial(head: float = 0.07, thorax: float = 0.11, abdomen: float = 0.095) -> MedialMesh:
    """A six-legged insect along x, 1.17 long: an abdomen from x = −0.02 to 0.45 (radius up
    to 0.095), a thorax at x = 0.6 (0.11, the thickest part), a head at x = 0.8 (0.07) on a
    narrower neck; six legs from inside the thorax's sides (`insect_leg`, `INSECT_LEGS`),
    radius 0.036 at the femur, 0.026 at the knee (z = 0.44, y = ±0.3), 0.032 at the tibia,
    0.024 at the ankle, their tarsi ending at y = ±0.47 on the ground; two antennae from the
    head tapering from 0.027 to 0.022 at x = 1.13 (1.8 grid cells thick at resolution
    48). `head`, `thorax`, `abdomen`: the radii of the head, thorax and abdomen's thickest
    spheres (the neck scaled with the thinner of head and thorax): a head thicker than the
    thorax (0.13 and 0.09) is what real insects have."""
    b = _Builder()
    a = abdomen / 0.095
    middle = b.add((0.6, 0, 0.3), thorax)
    b.chain(middle, [(0.45, 0, 0.31, 0.08 * a), (0.3, 0, 0.33, 0.095 * a),
                     (0.13, 0, 0.34, 0.08 * a), (0.02, 0, 0.33, 0.04 * a)])
    neck = 0.055 * min(head / 0.07, thorax / 0.11)  # narrower than either
    front = b.add((0.8, 0, 0.34), head, b.add((0.72, 0, 0.32), neck, middle))
    for side in (-1, 1):
        b.chain(front, [(x, y * side, z, r) for x, y, z, r in INSECT_ANTENNA])
        for leg in INSECT_LEGS:
            b.chain(middle, [(x, y * side, z, r) for x, y, z, r in insect_leg(*leg)])
    return b.medial()


def insect(resolution: int = 42) -> trimesh.Trimesh:
    """The closed, manifold surface of `insect_medial()` at `resolution` (7,704 vertices at
    the default 42; one shell from 36 up, below which the antennae's and tarsi's tips come
    loose)."""
    return insect_medial().envelope(resolution)

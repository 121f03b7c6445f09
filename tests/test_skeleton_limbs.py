"""The limbs found on a medial graph (`_skeleton.limbs.find_limbs`), on small graphs built by
hand: each rule on the shape that needs it, in milliseconds."""

from pathlib import Path

import numpy as np
import pytest

from fleshing_jax._skeleton.limbs import find_limbs


def _chain(a, b, n, r0, r1):
    t = np.linspace(0, 1, n)[:, None]
    return (1 - t) * np.asarray(a, float) + t * np.asarray(b, float), np.linspace(r0, r1, n)


class _Graph:
    """Spheres and edges added part by part."""

    def __init__(self):
        self.centers, self.radii, self.edges = [], [], []

    def add(self, centers, radii, link_to=None, chain=True):
        start = sum(len(r) for r in self.radii)
        ids = np.arange(start, start + len(radii))
        self.centers.append(centers)
        self.radii.append(radii)
        if chain:
            self.edges += list(zip(ids[:-1], ids[1:]))
        if link_to is not None:
            self.edges.append((int(link_to), int(ids[0])))
        return ids

    def sheet(self, side, base, link_to):
        """A flat ear: a fan of thin spheres out of `base`, joined as a triangulated sheet;
        each of its rim's spheres is a tip of the graph."""
        angles, rings = np.linspace(-0.6, 0.6, 5), np.linspace(0.09, 0.25, 6)
        centers = np.array([[side * r * np.cos(a), base[1] + r * np.sin(a), 0.0]
                            for r in rings for a in angles])
        grid = self.add(centers, np.full(len(centers), 0.012), chain=False).reshape(6, 5)
        for i in range(6):
            for j in range(5):
                if j < 4:
                    self.edges.append((grid[i, j], grid[i, j + 1]))
                if i < 5:
                    self.edges.append((grid[i, j], grid[i + 1, j]))
                if i < 5 and j < 4:
                    self.edges.append((grid[i, j], grid[i + 1, j + 1]))
        self.edges += [(int(link_to), int(g)) for g in grid[0]]
        return grid

    def body(self, radius=0.055, legs=True):
        """A torso of `radius` up y from 0 to 0.3, two arms from its shoulders and (with
        `legs`) two legs below it; the torso's sphere indices."""
        torso = self.add(*_chain([0, 0, 0], [0, 0.3, 0], 7, radius, radius))
        for side in (-1, 1):
            if legs:
                self.add(*_chain([side * 0.03, -0.06, 0], [side * 0.03, -0.2, 0], 6, 0.025,
                                 0.025), link_to=torso[0])  # fmt: skip
            self.add(*_chain([side * 0.07, 0.22, 0], [side * 0.25, 0.22, 0], 8, 0.015, 0.012),
                     link_to=torso[5])
        return torso

    def arrays(self):
        return np.concatenate(self.centers), np.concatenate(self.radii), np.array(self.edges)


def test_a_flat_ear_is_one_limb_not_one_per_tip_of_its_rim():
    """A flat ear's medial axis is a sheet whose rim has a tip per sample: each tip's path
    protrudes, and each was a limb (five per ear, as cheburashka's ears: none of them then
    had a region of its own). The paths joined by the sheet's edges are routes to one limb;
    legs and arms, side by side but not joined along their length, stay apart."""
    g = _Graph()
    torso = g.body()
    neck = g.add(*_chain([0, 0.345, 0], [0, 0.345, 0], 1, 0.045, 0.045), link_to=torso[-1])
    head = g.add(*_chain([0, 0.40, 0], [0, 0.50, 0], 4, 0.07, 0.075), link_to=neck[-1])
    for side in (-1, 1):
        g.sheet(side, [0, 0.5, 0], head[-1])
    centers, radii, edges = g.arrays()
    found = find_limbs(centers, radii, edges)
    tips = np.array([centers[f.path[-1]] for f in found])
    ears = tips[tips[:, 1] > 0.3]
    assert len(found) == 6, tips  # two legs, two arms, two ears
    assert sorted(np.sign(ears[:, 0])) == [-1, 1]
    assert np.sum(tips[:, 1] < -0.1) == 2 and np.sum(np.abs(tips[:, 1] - 0.22) < 1e-9) == 2


def test_two_feet_touching_along_a_crease_are_two_limbs():
    """Two feet side by side whose medial axes are joined by a crease's edges along most of
    their length, their toes free (cheburashka's at 150 and 300 spheres): the second foot
    found was taken as a sheet of the first (`SHEET` of its spheres joined), the two one limb
    whose region held one foot, the other left in the body. A sheet joins the path's tip too
    (a flat ear's rim, above)."""
    g = _Graph()
    torso = g.body(legs=False)
    feet = [g.add(*_chain([side * 0.03, -0.06, 0], [side * 0.03, -0.2, 0.05], 6, 0.025, 0.025),
                  link_to=torso[0]) for side in (-1, 1)]
    g.edges += [(int(a), int(b)) for a, b in zip(feet[0][:4], feet[1][:4])]  # the crease
    centers, radii, edges = g.arrays()
    tips = [int(f.path[-1]) for f in find_limbs(centers, radii, edges)]
    assert len(tips) == 4 and int(feet[0][-1]) in tips and int(feet[1][-1]) in tips, tips


def test_a_head_reached_past_a_thin_neck_by_a_second_strand_is_one_limb():
    """A head of two strands from a thin neck (cheburashka's at 300 spheres, seed 3): the
    strand found first runs to the snout, the second through the head's other thick sphere
    into an ear. The second's own spheres barely narrow before its thickest (0.86 of it),
    and the neck, the last sphere inside the torso, was not counted as its neck: the head
    split lengthwise into two limbs of the body, the ear under one."""
    g = _Graph()
    torso = g.body(radius=0.08)
    neck = g.add(np.array([[0, 0.345, 0]]), np.array([0.02]), link_to=torso[-1])
    snout = g.add(np.array([[0.02, 0.4, 0], [0.03, 0.43, 0], [0.06, 0.47, 0], [0.1, 0.51, 0],
                            [0.15, 0.55, 0], [0.2, 0.58, 0]]),
                  np.array([0.062, 0.068, 0.055, 0.05, 0.045, 0.04]), link_to=neck[0])
    other = g.add(np.array([[-0.02, 0.4, 0], [-0.025, 0.42, 0], [-0.06, 0.44, 0]]),
                  np.array([0.0588, 0.0681, 0.045]), link_to=neck[0])
    ear = g.add(*_chain([-0.09, 0.46, 0], [-0.16, 0.5, 0], 5, 0.013, 0.011), link_to=other[-1])
    g.edges += [(int(a), int(b)) for a, b in zip(snout[:2], other[:2])]
    centers, radii, edges = g.arrays()
    found = find_limbs(centers, radii, edges)
    heads = [k for k, f in enumerate(found) if radii[f.path].max() > 0.06]
    assert len(heads) == 1 and found[heads[0]].parent == -1, [f.path for f in found]
    assert [f.parent for f in found if f.path[-1] == ear[-1]] == [heads[0]]
    assert len(found) == 6  # the head, its ear, two legs, two arms


def test_a_limb_reached_through_a_thicker_limb_is_its_child():
    """A head thicker than the torso, on a thin neck on one side and a thick cheek on the
    other (cheburashka's: no waist on that side): the tree reaches the right ear through the
    cheek, thick all the way, so its path leaves the body's core inside the head, and it was
    a limb of the body beside the head that carries it. Its last sphere inside lies in the
    head's spheres, at least twice as thick as it (`_from_thicker_limbs`): the head's child,
    as the left ear reached through the neck is."""
    g = _Graph()
    torso = g.body()
    head = g.add(*_chain([-0.05, 0.42, 0], [0.05, 0.42, 0], 6, 0.075, 0.075))
    neck = g.add(*_chain([-0.05, 0.35, 0], [-0.05, 0.35, 0], 1, 0.025, 0.025),
                 link_to=torso[-1])
    cheek = g.add(*_chain([0.05, 0.35, 0], [0.05, 0.35, 0], 1, 0.06, 0.06), link_to=torso[-1])
    g.edges += [(int(neck[0]), int(head[0])), (int(cheek[0]), int(head[-1]))]
    for side, end in ((-1, head[0]), (1, head[-1])):
        g.add(*_chain([side * 0.12, 0.5, 0], [side * 0.2, 0.62, 0], 6, 0.013, 0.011),
              link_to=end)
    centers, radii, edges = g.arrays()
    found = find_limbs(centers, radii, edges)
    tips = np.array([centers[f.path[-1]] for f in found])
    parents = np.array([f.parent for f in found])
    heads = [k for k, f in enumerate(found) if radii[f.path].max() >= 0.07]
    assert len(heads) == 1 and parents[heads[0]] == -1
    ears = np.flatnonzero(np.abs(tips[:, 1] - 0.62) < 1e-9)
    assert len(ears) == 2 and np.all(parents[ears] == heads[0]), (tips, parents)
    assert len(found) == 7  # the head, its ears, two legs, two arms


def test_a_limb_entered_through_a_crease_starts_past_it_and_runs_to_its_own_tip():
    """A crease where a leg meets the body holds a medial sphere far thinner than either
    (a cow modelled in Blender: a tenth of its leg), and the shortest-path tree may enter
    the leg through it, and reach part of the body's inside through the leg's top. The leg's
    path starts at its first sphere at least `CREASE` times as thick as the leg, and its
    spine runs to its own tip, not into the body's spheres hanging below its top (it ran
    from the crease into the chest, and the cow's front legs were left in the body)."""
    g = _Graph()
    torso = g.add(*_chain([0, 0, 0], [0.4, 0, 0], 9, 0.08, 0.08))
    crease = g.add(*_chain([0.35, -0.085, 0.03], [0.35, -0.085, 0.03], 1, 0.002, 0.002),
                   link_to=torso[7])
    leg = g.add(*_chain([0.35, -0.1, 0], [0.35, -0.4, 0], 8, 0.025, 0.02), link_to=crease[0])
    g.add(*_chain([0.3, 0, 0.07], [0.05, 0, 0.07], 4, 0.045, 0.045), link_to=leg[0])
    centers, radii, edges = g.arrays()
    (found,) = find_limbs(centers, radii, edges)
    assert found.path[0] == leg[0] and found.path[-1] == leg[-1], found.path


def test_a_slanted_border_with_the_body_is_levelled_across_the_limb():
    """A limb whose border with the body runs at a slant (the body down one side of it, as
    spot's shoulder runs down its front leg's outer side) had its joint past the border's
    lowest vertex: a bend moved only its far part. `levelled` gives the limb the body's
    vertices past the border's top, beside it: the border runs across the spine and the
    joint moves up to the border's top; only body vertices change hands."""
    from _posing_shapes import tube_mesh

    import fleshing_jax as fj
    from fleshing_jax._skeleton.regions import levelled, mesh_adjacency, vertex_normals

    mesh = tube_mesh()  # radius 0.3, along x from 0 to 6
    vertices = np.asarray(mesh.vertices)
    x, y = vertices[:, 0], vertices[:, 1]
    region = np.full(len(vertices), -1)
    region[x > 4.0 + 0.4 * (y > 0)] = 0  # the body reaches 0.4 further along on one side
    region[x > 5.5] = 1  # a child, which the levelling leaves alone
    spine = fj.Line(3.0, origin=(3.0, 0.0, 0.0))
    limbs = [fj.Limb(spine, 1.4 + 1e-9, -1),  # the old border's last vertex, x = 4.4
              fj.Limb(fj.Line(0.8, origin=(5.2, 0.0, 0.0)), 0.35, 0)]
    adjacency = mesh_adjacency(vertices, np.asarray(mesh.faces))
    normals = vertex_normals(vertices, np.asarray(mesh.faces))
    out_limbs, out_region = levelled(limbs, region, vertices, normals, adjacency, [0], 0.05)
    changed = out_region != region
    assert changed.any() and np.all(region[changed] == -1) and np.all(out_region[changed] == 0)
    assert np.array_equal(out_region == 1, region == 1)
    # The border is now across the tube at x = 4 (the old border's top): the joint there.
    body = vertices[out_region == -1]
    assert body[:, 0].max() < 4.0 + 0.11  # (a ring spacing: 0.1)
    # (The border's vertices lie a ring or two past the body's last: rings 0.1 apart.)
    assert float(out_limbs[0].joint) < 1.0 + 0.21 < float(limbs[0].joint) - 0.15
    assert out_limbs[1] is limbs[1]


def test_levelling_passes_over_no_vertex_facing_its_spine_nor_beyond_its_reach():
    """The slanted border above, its body vertices past the border's top facing the spine (a
    flank across a gap from the limb: cheburashka's torso beside its hanging arm), is left
    as it is; so is one whose vertices lie beyond the spine's reach with the margin (a
    nearly straight spine, radius of curvature 20, with a margin of 20: posing would flag
    them, and `register_skeleton` refused the border's meaningless arc lengths)."""
    from _posing_shapes import tube_mesh

    import fleshing_jax as fj
    from fleshing_jax._skeleton.regions import levelled, mesh_adjacency, vertex_normals

    mesh = tube_mesh()  # radius 0.3, along x from 0 to 6
    vertices = np.asarray(mesh.vertices)
    x, y = vertices[:, 0], vertices[:, 1]
    region = np.where(x > 4.0 + 0.4 * (y > 0), 0, -1)
    adjacency = mesh_adjacency(vertices, np.asarray(mesh.faces))
    normals = vertex_normals(vertices, np.asarray(mesh.faces))
    line = [fj.Limb(fj.Line(3.0, origin=(3.0, 0.0, 0.0)), 1.4 + 1e-9, -1)]
    out_limbs, out_region = levelled(line, region, vertices, normals, adjacency, [0], 0.05)
    assert float(out_limbs[0].joint) < 1.3  # (levelled, as above)
    flank = (region == -1) & (x > 4.0 + 1e-9) & (y > 0)
    facing = np.where(flank[:, None], -normals, normals)
    out_limbs, out_region = levelled(line, region, vertices, facing, adjacency, [0], 0.05)
    assert np.array_equal(out_region, region) and out_limbs[0] is line[0]
    arc = [fj.Limb(fj.Arc(20.0, 3.0, origin=(3.0, 0.0, 0.0)), 1.4 + 1e-9, -1)]
    out_limbs, out_region = levelled(arc, region, vertices, normals, adjacency, [0], 0.05)
    assert float(out_limbs[0].joint) < 1.3  # (in reach with a small margin: levelled)
    out_limbs, out_region = levelled(arc, region, vertices, normals, adjacency, [0], 20.0)
    assert np.array_equal(out_region, region) and out_limbs[0] is arc[0]


def test_a_limb_whose_vertices_past_its_joint_barely_move_joins_its_parent():
    """A bend moves only a limb's vertices past its joint (and its descendants'): a limb whose
    region is long but whose joint lies near its end (the bunny's 25-vertex knob beside its
    tail) moves nothing a user sees, and joins its parent; counting its vertices before the
    joint kept it. The same region with its joint near its border stays a limb, and so does
    a limb whose own moved vertices stay near its joint but which carries a child far."""
    import fleshing_jax as fj
    from fleshing_jax._skeleton.visible import VISIBLE, visible

    # A thin rod along x from 0 to 6 (rings 0.1 apart, radius 0.05): diagonal ≈ 6.
    angle = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    mesh = fj.extrusion(0.05 * np.stack([np.cos(angle), np.sin(angle)], 1), 6.0, 60)
    vertices = np.asarray(mesh.vertices)
    x = vertices[:, 0]
    spine = fj.Line(2.5, origin=(3.5, 0.0, 0.0))  # to the rod's end
    region = np.where(x > 4.0 + 1e-9, 0, -1)  # 20 rings and the end's centre
    # Its joint at x = 5.85: the rings at 5.9 and 6 move, within 0.16 of the joint's point,
    # below VISIBLE of the diagonal (0.24); the region reaches 1.85 from it.
    assert 0.16 < VISIBLE * np.linalg.norm(np.ptp(vertices, axis=0))
    limbs, kept = visible([fj.Limb(spine, 2.35, -1)], region, vertices)
    assert limbs == [] and np.all(kept == -1)
    # Its joint at x = 4.1: the limb moves 19 rings, up to 1.9 from the joint: kept.
    limbs, kept = visible([fj.Limb(spine, 0.6, -1)], region, vertices)
    assert len(limbs) == 1 and np.array_equal(kept, region)
    # A parent whose own moved ring (x = 5) lies 0.07 from its joint, carrying a child
    # (x > 5, its joint at 5.5) up to 1 beyond it: both kept.
    region = np.select([x > 5.0 + 1e-9, x > 4.0 + 1e-9], [1, 0], -1)
    family = [fj.Limb(fj.Line(1.5, origin=(3.5, 0.0, 0.0)), 1.45, -1),
              fj.Limb(fj.Line(1.5, origin=(4.5, 0.0, 0.0)), 1.0, 0)]
    limbs, kept = visible(list(family), region, vertices)
    assert len(limbs) == 2 and np.array_equal(kept, region)


def test_a_limb_that_leaves_its_parent_where_its_spine_ends_joins_it():
    """A crease's bump (a cow modelled in Blender, where a hind leg meets the body): a limb
    whose region is wider than its spine is long, its border with the body projecting at
    the spine's end, leaves nothing past its joint to bend; `register_skeleton` refused the
    skeleton `fj.skeleton` returned. It joins its parent; a limb whose border lies well
    before its spine's end stays."""
    import fleshing_jax as fj
    from fleshing_jax._skeleton.build import _room_to_bend
    from fleshing_jax._skeleton.regions import mesh_adjacency

    angle = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    mesh = fj.extrusion(0.05 * np.stack([np.cos(angle), np.sin(angle)], 1), 6.0, 60)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    adjacency = mesh_adjacency(vertices, faces)
    region = np.where(vertices[:, 0] > 4.0 + 1e-9, 0, -1)
    short = fj.Limb(fj.Line(1.0, origin=(3.0, 0.0, 0.0)), 0.5, -1)  # ends at the border
    limbs, kept = _room_to_bend([short], region, vertices, adjacency)
    assert limbs == [] and np.all(kept == -1)
    with pytest.raises(ValueError, match="no room to bend"):
        fj.register_skeleton(mesh, fj.Skeleton([short], region, vertices))
    long = fj.Limb(fj.Line(2.5, origin=(3.5, 0.0, 0.0)), 0.6, -1)
    limbs, kept = _room_to_bend([long], region, vertices, adjacency)
    assert limbs == [long] and np.array_equal(kept, region)


def test_a_slanted_border_with_a_parent_limb_is_levelled_at_a_chain_s_top_only():
    """An ear meeting its head at a slant (spot's at seed 0: its joint at 67 % of its spine,
    the ear's 27 vertices past it too near to move visibly, and it joined the head) is
    levelled as a leg is against the body: it takes its parent's vertices past its border's
    top, and no other region changes. A piece of a chain below its joint (not in `tops`)
    keeps the border its split gave it."""
    from _posing_shapes import tube_mesh

    import fleshing_jax as fj
    from fleshing_jax._skeleton.regions import levelled, mesh_adjacency, vertex_normals

    mesh = tube_mesh()  # radius 0.3, along x from 0 to 6, rings 0.1 apart
    vertices = np.asarray(mesh.vertices)
    x, y = vertices[:, 0], vertices[:, 1]
    region = np.full(len(vertices), -1)
    region[x > 2.0 + 1e-9] = 0  # the head, from the body
    region[x > 4.0 + 0.4 * (y > 0)] = 1  # the ear: the head reaches 0.4 further on one side
    limbs = [fj.Limb(fj.Line(5.0, origin=(1.0, 0.0, 0.0)), 1.0 + 1e-9, -1),
             fj.Limb(fj.Line(3.0, origin=(3.0, 0.0, 0.0)), 1.4 + 1e-9, 0)]
    adjacency = mesh_adjacency(vertices, np.asarray(mesh.faces))
    normals = vertex_normals(vertices, np.asarray(mesh.faces))
    out_limbs, out_region = levelled(limbs, region, vertices, normals, adjacency, [0, 1], 0.05)
    changed = out_region != region
    assert changed.any() and np.all(region[changed] == 0) and np.all(out_region[changed] == 1)
    assert vertices[out_region == 0][:, 0].max() < 4.0 + 0.11  # across the tube at x = 4
    assert float(out_limbs[1].joint) < 1.0 + 0.21 < float(limbs[1].joint) - 0.15
    assert out_limbs[0] is limbs[0]  # (its border with the body was level already)
    # The same limb as a chain's lower piece: left as it is.
    out_limbs, out_region = levelled(limbs, region, vertices, normals, adjacency, [0], 0.05)
    assert np.array_equal(out_region, region) and out_limbs[1] is limbs[1]
    # A sibling in the slanted zone (a horn beside an ear, spot at 60 spheres), which the
    # ear's growth would enclose, bordering the ear alone: the ear is left as it is.
    beside = region.copy()
    beside[(np.abs(x - 4.3) < 1e-9) & (y > 0.29)] = 2  # a vertex ringed by the slant zone
    horn = fj.Limb(fj.Line(1.0, origin=(4.3, 0.0, 0.0)), 0.1, 0)
    out_limbs, out_region = levelled([*limbs, horn], beside, vertices, normals, adjacency,
                                     [0, 1], 0.05)
    assert np.array_equal(out_region, beside) and out_limbs[1] is limbs[1]


def test_within_reach_reads_only_the_samples_that_could_fail_and_agrees_with_in_reach():
    """`regions.within_reach` skips the samples whose curvature no point near them could
    exceed; its verdicts are `in_reach`'s on arcs from straight to curled (every point
    within, some not, none), with margins from 0 up."""
    from fleshing_jax._skeleton.regions import in_reach, within_reach

    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 1.0, 512)
    verdicts = []
    for k in (0.0, 0.5, 2.0, 6.0, 12.0):
        bend = max(k, 1e-12)
        samples = np.c_[np.sin(bend * t) / bend, (1 - np.cos(bend * t)) / bend, 0 * t]
        curvature = k * rng.uniform(0.5, 1.5, len(t))
        for spread in (0.01, 0.1, 0.3):
            points = samples[rng.integers(0, len(t), 500)] + rng.normal(0, spread, (500, 3))
            for margin in (0.0, 0.02):
                expected = in_reach(points, samples, curvature, margin)[0]
                np.testing.assert_array_equal(
                    within_reach(points, samples, curvature, margin, chunk=128), expected)
                verdicts.append(expected.mean())
    assert min(verdicts) < 0.9 and max(verdicts) == 1.0  # cases with points beyond the reach


def test_a_limb_bent_at_rest_is_found_at_its_bend_and_a_straight_one_nowhere():
    """`rest_bend` names the sphere where a path turns by `BENT` degrees or more (an insect's
    knee, the leg rising to it then down), away from the path's ends, and none on a path
    that turns less (a limb one spine follows)."""
    from fleshing_jax._skeleton.rest_bend import BENT, rest_bend

    up = np.stack([np.linspace(0, 0.3, 7), np.zeros(7), np.linspace(0, 0.15, 7)], axis=1)
    down = np.stack([np.full(7, 0.3), np.zeros(7), np.linspace(0.15, -0.45, 7)], axis=1)[1:]
    centers = np.concatenate([up, down])
    radii = np.full(len(centers), 0.02)
    path = np.arange(len(centers))
    assert rest_bend(path, centers, radii) == 6  # the knee: the path turns by 117°
    straight = centers.copy()
    straight[7:, 0] += np.linspace(0.3, 1.8, 6)  # down and on: turns by 45°
    assert rest_bend(path, straight, radii) is None
    assert rest_bend(path, straight, radii, least=BENT / 2) == 6


def test_a_head_of_two_strands_is_one_limb_with_its_antennae_as_children():
    """A head whose medial axis is two strands side by side from the neck on, one into each
    antenna (an insect's, modelled in Blender): each strand was a limb of the body, the head
    split lengthwise, each half with one antenna. The two are one limb (`limbs._forks`),
    its antennae its children however thick (one two thirds of the head's spheres, as on
    that insect); legs side by side touching at the top stay two limbs."""
    g = _Graph()
    torso = g.add(*_chain([0, 0, 0], [0, 0.3, 0], 7, 0.055, 0.055))
    for side in (-1, 1):
        g.add(*_chain([side * 0.02, -0.06, 0], [side * 0.12, -0.25, 0], 7, 0.025, 0.025),
              link_to=torso[0])
    strands = []
    for side, thickness in ((-1, 0.02), (1, 0.014)):
        strand = g.add(*_chain([side * 0.02, 0.36, 0], [side * 0.02, 0.46, 0], 4, 0.03, 0.03),
                       link_to=torso[-1])
        g.add(*_chain([side * 0.04, 0.49, 0], [side * 0.16, 0.7, 0], 8, thickness, 0.01),
              link_to=strand[-1])
        strands.append(strand)
    g.edges += [(int(a), int(b)) for a, b in zip(*strands)]
    centers, radii, edges = g.arrays()
    found = find_limbs(centers, radii, edges)
    tips = np.array([centers[f.path[-1]] for f in found])
    parents = np.array([f.parent for f in found])
    legs = np.flatnonzero(tips[:, 1] < -0.2)
    antennae = np.flatnonzero(tips[:, 1] > 0.65)
    heads = [k for k, f in enumerate(found) if f.parent == -1 and k not in legs]
    assert len(legs) == 2 and np.all(parents[legs] == -1), (tips, parents)
    assert len(heads) == 1 and found[heads[0]].fork, (tips, parents)
    assert len(antennae) == 2 and np.all(parents[antennae] == heads[0]), (tips, parents)
    assert sorted(np.sign(tips[antennae, 0])) == [-1, 1]
    assert len(found) == 5


def test_a_spur_held_by_two_legs_goes_to_the_one_holding_most_of_it():
    """Two legs from one hip, the second's top just inside the first's top sphere and a spur
    off it (the bunny's front paws at seed 0): the spur's path, held by both legs, went to
    the leg found first, which then held half of the second leg's path and took it: one
    limb of two legs. It goes to the leg that holds all of it."""
    g = _Graph()
    torso = g.body(legs=False)
    first = g.add(*_chain([-0.02, -0.06, 0], [-0.02, -0.25, 0], 8, 0.025, 0.025),
                  link_to=torso[0])
    second = g.add(*_chain([0, -0.065, 0], [0.054, -0.104, 0], 4, 0.025, 0.02),
                   link_to=torso[0])
    g.add(np.array([[0.012, -0.058, 0]]), np.array([0.012]), link_to=second[0])  # the spur
    centers, radii, edges = g.arrays()
    tips = [int(f.path[-1]) for f in find_limbs(centers, radii, edges)]
    assert len(tips) == 4 and int(first[-1]) in tips and int(second[-1]) in tips, tips


def test_the_hub_climbs_from_the_median_to_its_parts_core():
    """The body's root is the geodesic median of the limbs' tips, then the thickest sphere
    holding it. Two antennae pulled the median of the Blender insect at seed 1 out of its
    thorax into the neck: the head (0.7 as thick as the thorax) was then the body's core,
    the antennae limbs of the body. From there it climbs to the thorax's thickest sphere."""
    from fleshing_jax._skeleton.fit import medial_graph
    from fleshing_jax._skeleton.limbs import LimbPath, hub

    x = np.linspace(0, 1, 21)  # abdomen (thickest) | waist | thorax | neck | head
    radii = np.interp(x, [0, 0.1, 0.2, 0.4, 0.5, 0.6, 1], [0.06, 0.06, 0.01, 0.035, 0.02,
                                                            0.025, 0.02])  # fmt: skip
    centers = np.c_[x, np.zeros((21, 2))]
    graph = medial_graph(centers, np.c_[np.arange(20), np.arange(1, 21)])
    tips = [6, 10, 10, 20]  # (the median: sphere 10, in the neck)
    limbs = [LimbPath(np.array([t]), t, np.array([t]), np.array([t]), -1) for t in tips]
    assert hub(graph, centers, radii, np.arange(21), 0, limbs) == 8  # the thorax's thickest


def test_a_neck_beside_a_thinner_limb_is_not_a_route_through_it():
    """A path past a neck (its `inside` sphere thinner) whose thickest sphere lies inside a
    limb's is a route through that limb's thick part (a head's second strand, above), when
    the limb is about as thick. A bird's neck starts beside a wing's root, its thickest
    sphere inside the wing's first: the neck and head were taken for a route through the
    wing, and left in the body. A limb thinner than the path is not its route."""
    from fleshing_jax._skeleton.fit import medial_graph
    from fleshing_jax._skeleton.limbs import _same_limb

    wing = [[0, 0, 0], [0.02, 0, 0], [0.04, 0, 0]], [0.015, 0.012, 0.01]
    neck = ([[-0.02, 0, 0], [0.005, 0.005, 0], [0, 0.03, 0], [0, 0.06, 0], [0, 0.09, 0],
             [0, 0.12, 0]], [0.018, 0.022, 0.019, 0.017, 0.016, 0.01])
    inside = [[-0.03, -0.02, 0]], [0.014]
    centers = np.array(wing[0] + neck[0] + inside[0], float)
    graph = medial_graph(centers, np.array([[0, 1], [1, 2], [9, 3]] + [[k, k + 1] for k in
                                                                      range(3, 8)]))  # fmt: skip
    path = np.arange(3, 9)
    for scale, route in ((1.0, None), (1.5, 0)):  # (as thick as the neck: its route)
        radii = np.r_[scale * np.array(wing[1]), neck[1], inside[1]]
        assert _same_limb(centers, radii, path, 9, [[np.arange(3)]], graph) == route


@pytest.mark.parametrize("neck_thickness", [0.03, 0.04])
def test_a_waist_from_which_other_limbs_leave_is_the_body_s(neck_thickness):
    """A limb from the body starts at its waist, where the core tapers to `WAIST` of its
    thickest (a hip). A dinosaur's torso tapers from its hips to its chest, whose small arms
    leave it below the neck's base by routes of their own (a second strand of the chest):
    the neck started at the chest, and the arms were in the neck's limb. Spheres that
    another limb leaves from are the body's: the neck starts past them. A neck thick enough
    to be core (0.04 of a torso's 0.06) starts at its next waist further out, past the arms'
    (it started at the neck's top, the whole neck in the body: the Blender dinosaur's)."""
    g = _Graph()
    x = np.arange(7) * 0.05
    torso = g.add(np.c_[x, np.zeros((7, 2))],
                  np.array([0.06, 0.06, 0.058, 0.055, 0.05, 0.046, 0.044]))
    neck = g.add(*_chain([0.34, 0, 0.03], [0.42, 0, 0.15], 5, neck_thickness, 0.028),
                 link_to=torso[-1])  # fmt: skip
    g.add(*_chain([0.46, 0, 0.17], [0.56, 0, 0.16], 4, 0.035, 0.02), link_to=neck[-1])
    chest = g.add(*_chain([0.05, 0, -0.02], [0.25, 0, -0.02], 5, 0.045, 0.045),
                  link_to=torso[0])  # (the arms' own route from the hips)
    for side in (-1, 1):
        g.add(*_chain([0.25, side * 0.05, -0.03], [0.32, side * 0.09, -0.12], 5, 0.015, 0.012),
              link_to=chest[-1])
        g.add(*_chain([0, side * 0.03, -0.07], [0, side * 0.04, -0.3], 8, 0.03, 0.025),
              link_to=torso[0])
    g.add(*_chain([-0.07, 0, 0], [-0.4, 0, 0.02], 8, 0.035, 0.015), link_to=torso[0])
    centers, radii, edges = g.arrays()
    found = find_limbs(centers, radii, edges)
    assert len(found) == 6  # neck and head, two arms, two legs, the tail
    head = next(f for f in found if f.path[-1] == neck[-1] + 4)
    assert centers[head.path[0], 0] > 0.3  # past the arms' (was 0.25: the chest's)
    assert centers[head.path[0], 0] < 0.36  # in the neck (was 0.40, its top)


def test_a_bird_s_neck_and_wings_leave_its_body_as_limbs_of_their_own():
    """A bird modelled in Blender (`benchmarks/skin_characters.py`), its medial meshes at
    seeds 1 and 2 (200 spheres, unit frame): its neck and a wing leave the body side by side
    from one sphere. At seed 2 a spur at the neck's base, held whole by the neck's paths and
    by the wing's, went to the wing, the neck's thickest sphere with it, and the neck was
    then a route through the wing (the head in the body); at seed 1 the wing and the neck
    were taken for a fork (a stub at the shoulder carrying both), then, the wing apart, the
    neck's level measured by a chest sphere beyond a crease, thicker than the neck, and the
    head went to a spur. Each tip (beak, tail, wings, feet) is now reached by its own limb
    of the body, and each limb on the way runs towards its tip."""
    data = np.load(Path(__file__).parent / "data" / "bird-medial.npz")
    for seed in (1, 2):
        centers, radii = data[f"centers{seed}"], data[f"radii{seed}"]
        limbs = find_limbs(centers, radii, data[f"edges{seed}"])
        tops = []
        for tip in data[f"tips{seed}"]:
            k = max(k for k, limb in enumerate(limbs) if tip in limb.spheres)
            while k != -1:
                first, last = centers[limbs[k].path[[0, -1]]]
                assert np.linalg.norm(last - centers[tip]) < np.linalg.norm(
                    first - centers[tip]), (seed, tip, k)
                top, k = k, limbs[k].parent
            tops.append(top)
        assert len(set(tops)) == 6, (seed, tops)


def test_strands_side_by_side_of_unlike_thickness_are_no_fork():
    """Two strands side by side out of one sphere are one forked limb (an insect's head, a
    strand per antenna) when alike where they meet (`ALIKE`): a bird's wing, two thirds as
    thick as the neck it leaves beside, is a limb of its own, and so is the neck."""
    for thickness, forked in ((0.027, True), (0.02, False)):
        g = _Graph()
        torso = g.add(*_chain([0, 0, 0], [0, 0.3, 0], 7, 0.055, 0.055))
        for side in (-1, 1):  # (legs: the torso their hub)
            g.add(*_chain([side * 0.02, -0.06, 0], [side * 0.12, -0.25, 0], 7, 0.025, 0.025),
                  link_to=torso[0])
        strands = []
        for side, r in ((-1, 0.03), (1, thickness)):
            strand = g.add(*_chain([side * 0.02, 0.36, 0], [side * 0.02, 0.46, 0], 4, r, r),
                           link_to=torso[-1])
            g.add(*_chain([side * 0.04, 0.49, 0], [side * 0.16, 0.7, 0], 8, 0.8 * r, 0.01),
                  link_to=strand[-1])
            strands.append(strand)
        g.edges += [(int(a), int(b)) for a, b in zip(*strands)]
        centers, radii, edges = g.arrays()
        found = find_limbs(centers, radii, edges)
        top = [limb for limb in found if limb.parent == -1 and centers[limb.path[-1], 1] > 0.3]
        assert [limb.fork for limb in top] == ([True] if forked else [False, False]), found


def test_a_parent_s_route_is_judged_by_its_children_s_regions_on_a_tie():
    """A parent whose region leaves a child no room to bend tries other routes
    (`build._unit_limbs`) and keeps the one leaving the fewest children without room, then
    the one whose children hold the most vertices: a dinosaur's chest, from which a small arm
    leaves (the Blender dinosaur at seed 3), took the arm's hand on its first route (the arm
    59 vertices, its hand in the body) and left it on its second (418)."""
    from fleshing_jax._skeleton.build import _Fitted, _lost
    from fleshing_jax._skeleton.limbs import LimbPath

    one = np.array([0])
    found = [LimbPath(one, 0, one, one, -1), LimbPath(one, 0, one, one, 0)]
    region = np.r_[np.zeros(100, int), np.ones(20, int), np.full(10, -1)]
    narrow = _Fitted(region, [None, None], {0: 0, 1: 1}, [], {1})
    region = np.r_[np.zeros(70, int), np.ones(50, int), np.full(10, -1)]
    wide = _Fitted(region, [None, None], {0: 0, 1: 1}, [], {1})
    lost = _Fitted(region, [None], {0: 0}, [], set())  # (the child no region at all)
    assert _lost(found, wide, 0) < _lost(found, narrow, 0) < _lost(found, lost, 0)


def _chain_tops(limbs, spheres) -> set[int]:
    """The limbs leaving the body whose chains hold `spheres` (each in its deepest limb)."""
    tops = set()
    for sphere in spheres:
        k = max(k for k, limb in enumerate(limbs) if sphere in limb.spheres)
        while limbs[k].parent != -1:
            k = limbs[k].parent
        tops.add(k)
    return tops


def _spider():
    """A spider modelled in Blender (`benchmarks/skin_characters.py`): its medial mesh at seed
    1 (200 spheres, unit frame), its limbs, and its legs' ends (the lowest spheres: the feet
    stand on the ground, one per foot, 0.16 apart or more)."""
    data = np.load(Path(__file__).parent / "data" / "spider-medial.npz")
    centers, radii = data["centers"], data["radii"]
    ends = []
    for k in np.argsort(centers[:, 2]):
        if all(np.linalg.norm(centers[k] - centers[e]) > 0.1 for e in ends):
            ends.append(int(k))
        if len(ends) == 8:
            break
    return centers, radii, find_limbs(centers, radii, data["edges"]), ends


def test_a_limb_left_no_spheres_is_none():
    """The spider: within a limb's level, two routes to one leg were found, and every sphere
    went to the other: a limb of no spheres, on which `find_limbs` raised (its thickest
    sphere asked of an empty set). It is none; every limb found has spheres, and the eight
    legs' ends are each in a limb of the body."""
    _, _, limbs, ends = _spider()
    assert all(len(limb.spheres) for limb in limbs)
    assert len(_chain_tops(limbs, ends)) == 8


def test_a_part_thicker_than_the_body_beyond_a_waist_is_a_limb():
    """The spider: its body's root is the thorax, where the eight legs meet, and its abdomen,
    twice as thick, lies beyond a waist. No sphere of the thorax being thick beside the
    abdomen, the body's core ran on from the thorax through the whole abdomen: the limb that
    held the abdomen's spheres ran along a spur at its end (spheres a tenth as thick), and its
    spine left the abdomen in the body (at this seed and one other in four). The abdomen is a
    limb of the body whose path runs through its thickest sphere, and holds no leg's end."""
    _, radii, limbs, ends = _spider()
    holding = [limb for limb in limbs if np.argmax(radii) in limb.spheres]
    assert len(holding) == 1 and holding[0].parent == -1
    assert np.argmax(radii) in holding[0].path
    assert not np.isin(ends, holding[0].spheres).any()


def test_a_hub_that_finds_fewer_limbs_than_the_thickest_sphere_is_not_the_root():
    """A hand modelled in Blender (`benchmarks/skin_characters.py`: a forearm's stub, a flat
    palm, four fingers and a thumb), its medial mesh at seed 0 (200 spheres, unit frame). The
    thickest spheres are the forearm's; the tips' geodesic median (`hub`) lay on the palm's
    edge among the fingers' bases, a sheet a third as thick, and from there three of the
    five fingers were in the body. Each fingertip and the thumb's tip is in a chain of its own
    leaving the body."""
    data = np.load(Path(__file__).parent / "data" / "hand-medial.npz")
    centers = data["centers"]
    limbs = find_limbs(centers, data["radii"], data["edges"])
    tips = []  # the four fingertips (the highest spheres, 0.05 apart), the thumb's (the last)
    for k in np.argsort(-centers[:, 2]):
        if all(np.linalg.norm(centers[k] - centers[t]) > 0.05 for t in tips):
            tips.append(int(k))
        if len(tips) == 4:
            break
    tips.append(int(np.argmax(centers[:, 0])))
    assert len(_chain_tops(limbs, tips)) == 5

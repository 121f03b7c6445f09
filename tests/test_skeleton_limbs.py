"""The limbs found on a medial graph (`_skeleton.limbs.find_limbs`), on small graphs built by
hand: each rule on the shape that needs it, in milliseconds."""

import numpy as np

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

    def arrays(self):
        return np.concatenate(self.centers), np.concatenate(self.radii), np.array(self.edges)


def test_a_flat_ear_is_one_limb_not_one_per_tip_of_its_rim():
    """A flat ear's medial axis is a sheet whose rim has a tip per sample: each tip's path
    protrudes, and each was a limb (five per ear, as cheburashka's ears: none of them then
    had a region of its own). The paths joined by the sheet's edges are routes to one limb;
    legs and arms, side by side but not joined along their length, stay apart."""
    g = _Graph()
    torso = g.add(*_chain([0, 0, 0], [0, 0.3, 0], 7, 0.055, 0.055))
    neck = g.add(*_chain([0, 0.345, 0], [0, 0.345, 0], 1, 0.045, 0.045), link_to=torso[-1])
    head = g.add(*_chain([0, 0.40, 0], [0, 0.50, 0], 4, 0.07, 0.075), link_to=neck[-1])
    for side in (-1, 1):
        g.add(*_chain([side * 0.03, -0.06, 0], [side * 0.03, -0.2, 0], 6, 0.025, 0.025),
              link_to=torso[0])
        g.add(*_chain([side * 0.07, 0.22, 0], [side * 0.25, 0.22, 0], 8, 0.015, 0.012),
              link_to=torso[5])
        g.sheet(side, [0, 0.5, 0], head[-1])
    centers, radii, edges = g.arrays()
    found = find_limbs(centers, radii, edges)
    tips = np.array([centers[f.path[-1]] for f in found])
    ears = tips[tips[:, 1] > 0.3]
    assert len(found) == 6, tips  # two legs, two arms, two ears
    assert sorted(np.sign(ears[:, 0])) == [-1, 1]
    assert np.sum(tips[:, 1] < -0.1) == 2 and np.sum(np.abs(tips[:, 1] - 0.22) < 1e-9) == 2


def test_a_limb_reached_through_a_thicker_limb_is_its_child():
    """A head thicker than the torso, on a thin neck on one side and a thick cheek on the
    other (cheburashka's: no waist on that side): the tree reaches the right ear through the
    cheek, thick all the way, so its path leaves the body's core inside the head, and it was
    a limb of the body beside the head that carries it. Its last sphere inside lies in the
    head's spheres, at least twice as thick as it (`_from_thicker_limbs`): the head's child,
    as the left ear reached through the neck is."""
    g = _Graph()
    torso = g.add(*_chain([0, 0, 0], [0, 0.3, 0], 7, 0.055, 0.055))
    for side in (-1, 1):
        g.add(*_chain([side * 0.03, -0.06, 0], [side * 0.03, -0.2, 0], 6, 0.025, 0.025),
              link_to=torso[0])
        g.add(*_chain([side * 0.07, 0.22, 0], [side * 0.25, 0.22, 0], 8, 0.015, 0.012),
              link_to=torso[5])
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


def test_a_slanted_border_with_the_body_is_levelled_across_the_limb():
    """A limb whose border with the body runs at a slant (the body down one side of it, as
    spot's shoulder runs down its front leg's outer side) had its joint past the border's
    lowest vertex: a bend moved only its far part. `levelled` gives the limb the body's
    vertices past the border's top, beside it: the border runs across the spine and the
    joint moves up to the border's top; only body vertices change hands."""
    from _posing_shapes import tube_mesh

    import fleshing_jax as fj
    from fleshing_jax._skeleton.regions import levelled, mesh_adjacency

    mesh = tube_mesh()  # radius 0.25, along x from 0 to 6
    vertices = np.asarray(mesh.vertices)
    x, y = vertices[:, 0], vertices[:, 1]
    region = np.full(len(vertices), -1)
    region[x > 4.0 + 0.4 * (y > 0)] = 0  # the body reaches 0.4 further along on one side
    region[x > 5.5] = 1  # a child, which the levelling leaves alone
    spine = fj.Line(3.0, origin=(3.0, 0.0, 0.0))
    limbs = [fj.Limb(spine, 1.4 + 1e-9, -1),  # the old border's last vertex, x = 4.4
              fj.Limb(fj.Line(0.8, origin=(5.2, 0.0, 0.0)), 0.35, 0)]
    adjacency = mesh_adjacency(vertices, np.asarray(mesh.faces))
    out_limbs, out_region = levelled(limbs, region, vertices, adjacency)
    changed = out_region != region
    assert changed.any() and np.all(region[changed] == -1) and np.all(out_region[changed] == 0)
    assert np.array_equal(out_region == 1, region == 1)
    # The border is now across the tube at x = 4 (the old border's top): the joint there.
    body = vertices[out_region == -1]
    assert body[:, 0].max() < 4.0 + 0.11  # (a ring spacing: 0.1)
    # (The border's vertices lie a ring or two past the body's last: rings 0.1 apart.)
    assert float(out_limbs[0].joint) < 1.0 + 0.21 < float(limbs[0].joint) - 0.15
    assert out_limbs[1] is limbs[1]

"""Fig. 6: successive bending of a genus-2 quad mesh by two spines.

A slab with two holes (genus 2, quads; in the frontal plane (x, y), thin in z) is bent first
with a vertical spine into the frontal plane, then with a horizontal spine out of it. The
vertical spine lies in the slab's plane of symmetry, so skinning keeps the volume after the
first bend. The horizontal spine lies on the slab's back face (z = −thickness/2) and the second
bend changes skinning's volume. (The paper places both spines on a plane of symmetry; its shape
is not given, so this setting is ours.) Volumes are those of the bilinear quads (`fj.volume`).

    python benchmarks/paper/fig6_genus2.py
"""

from __future__ import annotations

from _common import ALL_METHODS, figure_path, flesh_many, markdown_table, pyplot, render

import fleshing_jax as fj

WIDTH, HEIGHT, THICKNESS = 2.0, 1.0, 0.3


def spines():
    """`((vertical line, arc in the frontal plane), (horizontal line, arc out of it))`."""
    start = (WIDTH / 2, -HEIGHT / 2, 0.0)
    first = (
        fj.Line(HEIGHT, origin=start, tangent=(0.0, 1.0, 0.0)),
        fj.Arc(2.5, HEIGHT, origin=start, tangent=(0.0, 1.0, 0.0), normal=(1.0, 0.0, 0.0)),
    )
    start = (-0.5, 0.0, -THICKNESS / 2)
    second = (
        fj.Line(WIDTH + 1.0, origin=start),
        fj.Arc(2.5, WIDTH + 1.0, origin=start, tangent=(1.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0)),
    )
    return first, second


def run(size: float = 0.05, methods=ALL_METHODS):
    """`volume0`, `{method: (volume after bend 1, volume after bend 2)}`, meshes and poses."""
    vertices, quads = fj.genus2_slab(WIDTH, HEIGHT, THICKNESS, size)
    v0 = float(fj.volume(vertices, quads))
    first, second = spines()
    volumes, poses = {}, {}
    for method in methods:
        bent1, ok1 = flesh_many([vertices], *first, methods=(method,))[method][0]
        bent2, ok2 = flesh_many([bent1], *second, methods=(method,))[method][0]
        assert ok1.all() and ok2.all(), f"{method}: invalid vertices"
        volumes[method] = (float(fj.volume(bent1, quads)), float(fj.volume(bent2, quads)))
        poses[method] = (bent1, bent2)
    return v0, volumes, (vertices, quads), poses


def main():
    v0, volumes, (vertices, quads), poses = run()
    print(f"genus-2 slab: {len(vertices)} vertices, {len(quads)} quads, volume {v0:.6f}")
    rows = [
        (m, f"{a:.6f}", f"{100 * (a - v0) / v0:+.4f}%", f"{b:.6f}", f"{100 * (b - v0) / v0:+.4f}%")
        for m, (a, b) in volumes.items()
    ]
    print(markdown_table(("method", "after bend 1", "change", "after bend 2", "change"), rows))
    plt = pyplot()
    fig = plt.figure(figsize=(14, 6.4))
    panels = [("input", vertices)] + [(f"{m}, bend 1", poses[m][0]) for m in ALL_METHODS]
    panels += [("", None)] + [(f"{m}, bend 2", poses[m][1]) for m in ALL_METHODS]
    for i, (name, points) in enumerate(panels):
        if points is None:
            continue
        ax = fig.add_subplot(2, 5, i + 1, projection="3d")
        colour = (0.85, 0.45, 0.3) if name.startswith("skinning") else (0.3, 0.55, 0.85)
        render(ax, points, quads, colour=colour, view=(20, -60), y_up=True)
        ax.set_title(name, fontsize=9)
    fig.tight_layout()
    fig.savefig(figure_path("fig6_genus2.png"), dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()

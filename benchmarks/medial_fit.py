"""How a change of the medial fit moves the accuracy figures, judged against the fit's own noise.

    python benchmarks/medial_fit.py                            # the null change alone
    python benchmarks/medial_fit.py --kw iterations=16         # any refine_spheres argument
    python benchmarks/medial_fit.py --set refine.ROUND=1       # any module constant
    python benchmarks/medial_fit.py --meshes spot --seeds 0 1

For each mesh (spot, cheburashka and the capped bunny of `../shared/data`) and construction
seed (0-7: 24 runs), `medial_mesh(mesh, 200)` is built up to its fit (`refine.refine_spheres`),
whose arguments are kept; the fit then runs on them as it is, with the change, and with the
null change (the margin 1 % longer, 0.0101: as good a fit, other round-off), and each result
is measured as `medial.py` measures (`point_distances`, samples of seed 1): the one-sided
Hausdorff distances surface → envelope and envelope → surface (the largest), and the mean
distances, as % of the bounding-box diagonal, with the fit's CPU time. (In the unit frame
that `medial_mesh` computes in: the same fractions up to round-off.)

A Hausdorff distance moves by ±20 % a mesh and seed under the null change alone, so a change
is judged over all the runs, beside the null measured the same way: (a) the median and the
mean over runs of the Hausdorff ratio new / old (both directions) within 3 %, and its spread
(standard deviation, and the 10th to 90th percentile) no wider than the null's; (b) the mean
distances within 2 % on average; (c) every medial mesh connected. Prints a Markdown row per
mesh, seed and change, then these figures for each change.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.csgraph as csgraph
import trimesh

from fleshing_jax import cap_holes
from fleshing_jax._medial_axis import construct
from fleshing_jax._medial_axis.distance import point_distances
from fleshing_jax._medial_axis.medial_mesh import MedialMesh

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

MESHES = {"spot": "spot.obj", "cheburashka": "cheburashka.obj", "bunny": "stanford-bunny.obj"}


class _Recorded(Exception):
    """Raised by the recorder in place of the fit: its arguments are in `args`."""


def fit_arguments(mesh, seed: int):
    """The arguments `(args, kwargs)` that `medial_mesh(mesh, 200, seed=seed)` gives its fit."""

    def record(*args, **kwargs):
        raise _Recorded(args, kwargs)

    fit, construct.refine_spheres = construct.refine_spheres, record
    try:
        construct.medial_mesh(mesh, 200, seed=seed, progress=False)
    except _Recorded as recorded:
        return recorded.args
    finally:
        construct.refine_spheres = fit
    raise RuntimeError("medial_mesh did not reach its fit")


def measured(args, kwargs):
    """The fit's CPU time (s) and `(Hausdorff ×2, mean ×2)` figures (% of the diagonal)."""
    start = time.process_time()
    centers, radii = construct.refine_spheres(*args, **kwargs)
    cpu = time.process_time() - start
    surface = kwargs["surface"]
    medial = MedialMesh(centers, radii, args[4], args[5])
    to_envelope, to_surface = point_distances(medial, (surface.vertices, surface.faces), seed=1)
    figures = [to_envelope.max(), to_surface.max(), to_envelope.mean(), to_surface.mean()]
    return cpu, 100 * np.array(figures)


class _Setting:
    """Module constants (`module.NAME=value`, modules of `fleshing_jax._medial_axis`) set
    within a `with` block, restored after."""

    def __init__(self, assignments):
        self.changes = []
        for assignment in assignments:
            name, value = assignment.split("=", 1)
            module, attribute = name.rsplit(".", 1)
            module = importlib.import_module(f"fleshing_jax._medial_axis.{module}")
            self.changes.append((module, attribute, ast.literal_eval(value)))

    def __enter__(self):
        self.saved = [getattr(module, name) for module, name, _ in self.changes]
        for module, name, value in self.changes:
            setattr(module, name, value)

    def __exit__(self, *_):
        for (module, name, _), value in zip(self.changes, self.saved):
            setattr(module, name, value)


NULL = {"margin": 0.0101}  # the default 0.01, 1 % longer: the fit's noise


def connected(edges, count: int) -> bool:
    """Whether the `count` spheres and their `edges (e, 2)` form one piece."""
    graph = sparse.coo_matrix(
        (np.ones(len(edges)), tuple(np.asarray(edges).reshape(-1, 2).T)), shape=(count, count)
    )
    return csgraph.connected_components(graph, directed=False)[0] == 1


def verdict(name, rows, null=None):
    """Prints the figures of one change over its `rows` (`(mesh, ratios (4,), cpu old, cpu
    new, connected)`: the Hausdorff distances' and means' ratios new / old), against the null
    change's (`verdict`'s return of the null), and returns its `(sd, p10-90)` spread."""
    ratio = np.array([row[1] for row in rows])
    hausdorff, means = ratio[:, :2].ravel(), ratio[:, 2:]
    spread = (hausdorff.std(), np.subtract(*np.percentile(hausdorff, [90, 10])))
    cpu = sum(row[2] for row in rows), sum(row[3] for row in rows)
    centre = (np.median(hausdorff) - 1, hausdorff.mean() - 1)
    print(
        f"\n{name} ({len(rows)} runs): fit CPU {cpu[0]:.1f} → {cpu[1]:.1f} s "
        f"({100 * (cpu[1] / cpu[0] - 1):+.0f} %)"
    )
    print(
        f"- Hausdorff new / old: median {100 * centre[0]:+.1f} %, mean {100 * centre[1]:+.1f} %, "
        f"spread: sd {100 * spread[0]:.1f} %, 10th-90th percentile {100 * spread[1]:.1f} %, "
        f"range {100 * (hausdorff.min() - 1):+.0f} to {100 * (hausdorff.max() - 1):+.0f} %"
    )
    print(
        f"- means: {100 * (means.mean() - 1):+.2f} % on average; "
        f"{sum(not row[4] for row in rows)} medial meshes not connected"
    )
    for mesh in dict.fromkeys(row[0] for row in rows):
        own = np.array([row[1] for row in rows if row[0] == mesh])
        print(
            f"  - {mesh}: Hausdorff median {100 * (np.median(own[:, :2]) - 1):+.1f} %, "
            f"mean {100 * (own[:, :2].mean() - 1):+.1f} %; "
            f"means {100 * (own[:, 2:].mean() - 1):+.2f} %"
        )
    if null is not None:
        ok = (
            max(abs(x) for x in centre) <= 0.03
            and all(a <= b for a, b in zip(spread, null))
            and abs(means.mean() - 1) <= 0.02
            and all(row[4] for row in rows)
        )
        print(
            f"- within the null's noise: {'yes' if ok else 'no'} (spread of the null: sd "
            f"{100 * null[0]:.1f} %, 10th-90th percentile {100 * null[1]:.1f} %)"
        )
    return spread


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--kw", nargs="*", default=[], help="refine_spheres NAME=value")
    parser.add_argument("--set", nargs="*", default=[], help="module.NAME=value")
    parser.add_argument("--meshes", nargs="*", default=list(MESHES), choices=list(MESHES))
    parser.add_argument("--seeds", nargs="*", type=int, default=list(range(8)))
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the meshes")
    options = parser.parse_args()
    changed = {
        name: ast.literal_eval(value) for name, value in (kw.split("=", 1) for kw in options.kw)
    }
    changes = {"null": (NULL, _Setting([]))}
    if changed or options.set:
        changes["change"] = (changed, _Setting(options.set))
    print(f"Change: {changed or ''} {' '.join(options.set)}; null: {NULL}\n")
    print("| mesh | seed | change | surface → envelope | envelope → surface | means | fit CPU |")
    print("|---|---:|---|---:|---:|---:|---:|")
    rows = {name: [] for name in changes}
    for name in options.meshes:
        mesh = trimesh.load(str(options.data / MESHES[name]), process=False)
        mesh = cap_holes(mesh) if name == "bunny" else mesh
        for seed in options.seeds:
            args, kwargs = fit_arguments(mesh, seed)
            cpu, before = measured(args, kwargs)
            for label, (kw, setting) in changes.items():
                with setting:
                    new_cpu, after = measured(args, {**kwargs, **kw})
                one = connected(args[4], len(args[2]))  # (the fit keeps the connectivity)
                rows[label].append((name, after / before, cpu, new_cpu, one))
                print(
                    f"| {name} | {seed} | {label} | {before[0]:.3f} → {after[0]:.3f} % | "
                    f"{before[1]:.3f} → {after[1]:.3f} % | {before[2]:.4f} / {before[3]:.4f} → "
                    f"{after[2]:.4f} / {after[3]:.4f} % | {cpu:.2f} → {new_cpu:.2f} |",
                    flush=True,
                )
    null = verdict("null change (margin 0.0101)", rows["null"])
    if "change" in rows:
        verdict("change", rows["change"], null)


if __name__ == "__main__":
    main()

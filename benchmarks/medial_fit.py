"""How a change of the medial fit moves the accuracy figures, beside the fit's own noise.

    python benchmarks/medial_fit.py                            # margin +1 %: the noise
    python benchmarks/medial_fit.py --kw iterations=16         # any refine_spheres argument
    python benchmarks/medial_fit.py --set refine.ROUND=1       # any module constant
    python benchmarks/medial_fit.py --meshes spot --seeds 0 1

For each mesh (spot, cheburashka and the capped bunny of `../shared/data`) and construction
seed, `medial_mesh(mesh, 200)` is built up to its fit (`refine.refine_spheres`), whose
arguments are kept; the fit then runs twice on them, as it is and changed, and each result
is measured as `medial.py` measures (`point_distances`, samples of seed 1): the one-sided
Hausdorff distances surface → envelope and envelope → surface (the largest), and the mean
distances, as % of the bounding-box diagonal, with the fit's CPU time. (In the unit frame
that `medial_mesh` computes in: the same fractions up to round-off.)

Prints a Markdown row per mesh and seed, then the largest relative increase of a Hausdorff
distance, and the average relative change of the Hausdorff distances and of the means.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import time
from pathlib import Path

import numpy as np
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--kw", nargs="*", default=[], help="refine_spheres NAME=value")
    parser.add_argument("--set", nargs="*", default=[], help="module.NAME=value")
    parser.add_argument("--meshes", nargs="*", default=list(MESHES), choices=list(MESHES))
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2, 3])
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the meshes")
    options = parser.parse_args()
    changed = {
        name: ast.literal_eval(value) for name, value in (kw.split("=", 1) for kw in options.kw)
    }
    if not changed and not options.set:
        changed = {"margin": 0.0101}  # the default 0.01, 1 % longer: the fit's noise
    setting = _Setting(options.set)
    print(f"Changed: {changed or ''} {' '.join(options.set)}\n")
    print("| mesh | seed | surface → envelope | envelope → surface | means | fit CPU (s) |")
    print("|---|---:|---:|---:|---:|---:|")
    rows = []
    for name in options.meshes:
        mesh = trimesh.load(str(options.data / MESHES[name]), process=False)
        mesh = cap_holes(mesh) if name == "bunny" else mesh
        for seed in options.seeds:
            args, kwargs = fit_arguments(mesh, seed)
            cpu, before = measured(args, kwargs)
            with setting:
                new_cpu, after = measured(args, {**kwargs, **changed})
            rows.append((name, after / before - 1))
            print(
                f"| {name} | {seed} | {before[0]:.3f} → {after[0]:.3f} % | "
                f"{before[1]:.3f} → {after[1]:.3f} % | {before[2]:.4f} / {before[3]:.4f} → "
                f"{after[2]:.4f} / {after[3]:.4f} % | {cpu:.2f} → {new_cpu:.2f} |",
                flush=True,
            )
    change = 100 * np.array([row for _, row in rows])
    print(
        f"\nLargest increase of a Hausdorff distance: {change[:, :2].max():+.1f} %; average "
        f"change of the Hausdorff distances {change[:, :2].mean():+.1f} %, of the means "
        f"{change[:, 2:].mean():+.1f} %"
    )
    for name in options.meshes:
        own = change[[mesh == name for mesh, _ in rows]]
        print(
            f"- {name}: Hausdorff {own[:, :2].min():+.1f} to {own[:, :2].max():+.1f} %, means "
            f"{own[:, 2:].min():+.1f} to {own[:, 2:].max():+.1f} %"
        )


if __name__ == "__main__":
    main()

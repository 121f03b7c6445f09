"""The README's picture of a medial mesh: spot's, with 200 spheres (issue 17).

    python benchmarks/medial_figure.py   # writes benchmarks/figures/medial-spot.png
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import fleshing_jax as fj  # noqa: E402

OUT = Path(__file__).resolve().parent / "figures" / "medial-spot.png"


def main() -> None:
    spot = fj.data.spot()
    medial = fj.medial_mesh(spot, spheres=200, progress=False)
    to_envelope, to_surface = fj.medial_distance(medial, spot)
    fig = plt.figure(figsize=(10, 4.6))
    for i, (elev, azim) in enumerate(((15, -50), (5, 0))):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        fj.plot_medial(medial, spot, ax=ax, elev=elev, azim=azim)  # an OBJ: y up
    fig.suptitle(
        f"Medial mesh of spot: {len(medial.radii)} spheres, {len(medial.edges)} cones, "
        f"{len(medial.faces)} slabs (distances {100 * to_envelope:.2f} % / "
        f"{100 * to_surface:.2f} % of the diagonal)"
    )
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.92, wspace=0)
    OUT.parent.mkdir(exist_ok=True)
    fig.savefig(OUT, dpi=100, bbox_inches="tight")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()

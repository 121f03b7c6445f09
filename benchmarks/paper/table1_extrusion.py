"""Table 1 (paper §5.1): an off-centre planar cross-section extruded along circular arcs.

Both arcs start at Q = 0 with tangent x, with different radii and osculating planes. The
cross-section R lies in the plane x = 0. Unbending maps it to the straight spine (ρ = 1) and
bending to the second arc. The solid swept by a region R along an arc of length l has the exact
Pappus–Foote volume `area(R) · ρ · l`, `ρ = OW·OQ/|OQ|² = 1 − k·w` (W the centroid of R, w = W − Q,
k the curvature vector). Areas and centroids of the mapped regions are contour integrals of the
mapped boundary, which is a smooth periodic curve: the trapezoidal rule with spectral
(FFT) derivatives is exact to round-off, so every number below is exact up to round-off.

    python benchmarks/paper/table1_extrusion.py
"""

from __future__ import annotations

import numpy as np
from _common import FLESHINGS, figure_path, flesh_many, markdown_table, pyplot

import fleshing_jax as fj

LENGTH = 2.0


def contour(samples: int) -> np.ndarray:
    """The cross-section's boundary in the plane x = 0: a three-lobed blob, off-centre.

    (samples, 3) points, counter-clockwise about +x.
    """
    t = 2 * np.pi * np.arange(samples) / samples
    r = 0.25 * (1 + 0.25 * np.cos(3 * t) + 0.1 * np.sin(2 * t))
    y, z = -0.06 + r * np.cos(t), 0.02 + r * np.sin(t)
    return np.column_stack([np.zeros(samples), y, z])


def spines(length: float = LENGTH):
    source = fj.Arc(1.25, length, normal=(0.0, 1.0, 0.0))
    angle = np.deg2rad(60.0)  # the second osculating plane is turned 60° about the tangent
    target = fj.Arc(1.0, length, normal=(0.0, np.cos(angle), np.sin(angle)))
    return source, fj.Line(length), target


def region_moments(points: np.ndarray) -> tuple[float, np.ndarray]:
    """Area and centroid (y, z) of the region bounded by a smooth closed curve in x = 0."""
    u, v = points[:, 1], points[:, 2]
    n = len(u)
    freq = 1j * np.fft.fftfreq(n, d=1.0 / n)  # d/dt for t ∈ [0, 2π)
    du, dv = np.real(np.fft.ifft(freq * np.fft.fft(u))), np.real(np.fft.ifft(freq * np.fft.fft(v)))
    dt = 2 * np.pi / n
    area = 0.5 * np.sum(u * dv - v * du) * dt
    mu = 0.5 * np.sum(u**2 * dv) * dt  # ∫∫ u dA
    mv = -0.5 * np.sum(v**2 * du) * dt  # ∫∫ v dA
    return area, np.array([mu, mv]) / area


def pappus(area: float, centroid: np.ndarray, spine) -> tuple[float, float]:
    """`(ρ, volume)` of the region swept along `spine` (curvature vector at s = 0)."""
    k = np.asarray(spine.curvature_vector(0.0))[1:]
    rho = 1.0 - float(k @ centroid)
    return rho, area * rho * float(spine.length)


def run(samples: int = 512, length: float = LENGTH, methods=("skinning", *FLESHINGS)):
    """The rows of Table 1: `(name, area, ρ, volume, ε)`, and the mapped contours."""
    source, line, target = spines(length)
    r0 = contour(samples)
    unbent = flesh_many([r0], source, line, methods=methods)
    rows, contours = [], {"original": r0}
    area0, w0 = region_moments(r0)
    rho0, vol0 = pappus(area0, w0, source)
    rows.append(("Original", area0, rho0, vol0, 0.0))
    for method in methods:
        straight, ok0 = unbent[method][0]
        bent, ok1 = flesh_many([straight], line, target, methods=(method,))[method][0]
        if not (ok0.all() and ok1.all()):
            raise RuntimeError(f"{method}: cross-section outside the valid space")
        direct, _ = flesh_many([r0], source, target, methods=(method,))[method][0]
        assert np.allclose(direct, bent, atol=1e-12), "unbend∘bend differs from the direct map"
        label = "" if method == "skinning" else method.capitalize() + " "
        for step, points, spine in (("Unbend", straight, line), ("Bend", bent, target)):
            area, w = region_moments(points)
            rho, vol = pappus(area, w, spine)
            rows.append((label + step, area, rho, vol, (vol - vol0) / vol0))
            contours[f"{method} {step.lower()}"] = points
    return rows, contours


def format_rows(rows):
    return [
        (name, f"{a:.6f}", f"{rho:.6f}", f"{v:.6f}", f"{e:+.2e}") for name, a, rho, v, e in rows
    ]


def plot(contours, path):
    plt = pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.6), sharex=True, sharey=True)
    for ax, method in zip(axes, ("skinning", *FLESHINGS)):
        for key, colour in (("original", "tab:blue"), ("unbend", "tab:green"), ("bend", "tab:red")):
            pts = contours["original" if key == "original" else f"{method} {key}"]
            closed = np.vstack([pts, pts[:1]])
            ax.plot(closed[:, 1], closed[:, 2], color=colour, label=key)
        ax.plot([0], [0], "k+")
        ax.set_title(method)
        ax.set_aspect("equal")
    axes[0].legend(loc="lower left", fontsize=8)
    fig.suptitle("Table 1: cross-sections (y, z) — original (blue), unbent (green), bent (red)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    rows, contours = run()
    coarse, _ = run(samples=256)
    quadrature = max(abs(a[3] - b[3]) / a[3] for a, b in zip(rows, coarse))
    print(markdown_table(("", "area(R)", "ρ", "vol(S)", "ε"), format_rows(rows)))
    print(f"\nquadrature check (512 vs 256 samples): max relative difference {quadrature:.1e}")
    plot(contours, figure_path("table1_cross_sections.png"))


if __name__ == "__main__":
    main()

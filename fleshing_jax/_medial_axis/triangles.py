"""The closest points of triangles to points (Ericson's region tests), in one compiled loop.

`SurfaceQuery`'s exact tests: the initial axis tests every medial pole against the faces
around its contact samples (spot: 2.4M (pole, face) pairs), and the fit and its last pass
test sphere centres. Ericson ("Real-Time Collision Detection", 5.1.5) tells from six dot
products which feature of the triangle (face, vertex, edge) holds the closest point; in
NumPy that was a dozen passes over the pairs and three `np.select`s over six conditions,
here one numba loop (division by zero as NumPy's: infinities and NaN, replaced as
`np.nan_to_num` does): spot's 120k poles, 0.29 → 0.12 s with the rest of the query.
"""

from __future__ import annotations

import numba
import numpy as np

_BIG = np.finfo(np.float64).max


@numba.njit(cache=True, error_model="numpy")
def _finite(x):
    """`np.nan_to_num(x)` of one float."""
    if x != x:
        return 0.0
    if x == np.inf:
        return _BIG
    if x == -np.inf:
        return -_BIG
    return x


@numba.njit(cache=True, error_model="numpy")
def closest_on_faces(points, faces, a, b, c):
    """For `points (M, 3)` and face indices `faces (M,)` into the corners `a, b, c (F, 3)`:
    the distances `(M,)`, closest points `(M, 3)` and the features they lie on `(M,)` (0
    face, 1/2/3 vertex a/b/c, 4/5/6 edge ab/bc/ca)."""
    m = len(faces)
    distance, closest, feature = np.empty(m), np.empty((m, 3)), np.empty(m, np.int64)
    for k in range(m):
        f = faces[k]
        ax, ay, az = a[f, 0], a[f, 1], a[f, 2]
        abx, aby, abz = b[f, 0] - ax, b[f, 1] - ay, b[f, 2] - az
        acx, acy, acz = c[f, 0] - ax, c[f, 1] - ay, c[f, 2] - az
        px, py, pz = points[k, 0], points[k, 1], points[k, 2]
        apx, apy, apz = px - ax, py - ay, pz - az
        d1 = (abx * apx + abz * apz) + aby * apy
        d2 = (acx * apx + acz * apz) + acy * apy
        bpx, bpy, bpz = px - b[f, 0], py - b[f, 1], pz - b[f, 2]
        d3 = (abx * bpx + abz * bpz) + aby * bpy
        d4 = (acx * bpx + acz * bpz) + acy * bpy
        cpx, cpy, cpz = px - c[f, 0], py - c[f, 1], pz - c[f, 2]
        d5 = (abx * cpx + abz * cpz) + aby * cpy
        d6 = (acx * cpx + acz * cpz) + acy * cpy
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        # The first condition that holds, as `np.select`.
        if d1 <= 0 and d2 <= 0:
            feat, wb, wc = 1, 0.0, 0.0
        elif d3 >= 0 and d4 <= d3:
            feat, wb, wc = 2, 1.0, 0.0
        elif vc <= 0 and d1 >= 0 and d3 <= 0:
            feat, wb, wc = 4, d1 / (d1 - d3), 0.0
        elif d6 >= 0 and d5 <= d6:
            feat, wb, wc = 3, 0.0, 1.0
        elif vb <= 0 and d2 >= 0 and d6 <= 0:
            feat, wb, wc = 6, 0.0, d2 / (d2 - d6)
        elif va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
            t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            feat, wb, wc = 5, 1 - t, t
        else:
            denom = 1.0 / (va + vb + vc)
            feat, wb, wc = 0, vb * denom, vc * denom
        wb, wc = _finite(wb), _finite(wc)
        qx = ax + wb * abx + wc * acx
        qy = ay + wb * aby + wc * acy
        qz = az + wb * abz + wc * acz
        closest[k, 0], closest[k, 1], closest[k, 2] = qx, qy, qz
        x, y, z = px - qx, py - qy, pz - qz
        distance[k] = np.sqrt((x * x + y * y) + z * z)
        feature[k] = feat
    return distance, closest, feature

"""`MedialMesh`: medial spheres joined by cones (edges) and slabs (triangles)."""

from __future__ import annotations

import hashlib

import equinox as eqx
import jax
import numpy as np
import trimesh
from jaxtyping import ArrayLike
from scipy.spatial import cKDTree

from .._checks import check_finite_points, is_concrete
from .envelope import envelope_arrays, mesh_volume


def face_edges(faces) -> np.ndarray:
    """The three edges of every face, sorted within each row: `(3F, 2)` int array."""
    faces = np.asarray(faces).reshape(-1, 3)
    return np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [0, 2]]]), axis=1)


def _float32_precision(x: np.ndarray) -> np.ndarray:
    """`x` rounded to a 24-bit significand, as (significand, exponent) integer pairs: equal for
    a float64 array and its float32 cast, at any magnitude (a float32 cast overflows)."""
    significand, exponent = np.frexp(x)
    return np.stack([np.round(significand * 2.0**24).astype(np.int64), exponent], -1)


def _rows(indices: np.ndarray) -> np.ndarray:
    """Index tuples in a canonical order (sorted rows, duplicates dropped)."""
    return np.unique(indices, axis=0) if len(indices) else indices


def _check(centers, radii, edges, faces):
    n = len(centers)
    if not np.isfinite(centers).all():
        raise ValueError("MedialMesh centers must be finite")
    if not np.isfinite(radii).all():
        raise ValueError("MedialMesh radii must be finite")
    if (radii < 0).any():
        raise ValueError(f"MedialMesh radii must be >= 0, got {radii.min():.3g}")
    for name, idx in (("edges", edges), ("faces", faces)):
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            raise ValueError(f"MedialMesh {name} index spheres in [0, {n}), got "
                             f"[{idx.min()}, {idx.max()}]")
    if (edges[:, 0] == edges[:, 1]).any():
        raise ValueError("MedialMesh edges must join two different spheres")
    if len(faces) and ((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2])
                       | (faces[:, 0] == faces[:, 2])).any():
        raise ValueError("MedialMesh faces must join three different spheres")
    if len(faces):
        have = np.unique(np.sort(edges, axis=1) @ np.array([n, 1]))
        need = face_edges(faces) @ np.array([n, 1])
        missing = ~np.isin(need, have)
        if missing.any():
            i, j = divmod(int(need[missing][0]), n)
            raise ValueError(f"MedialMesh faces need their edges in `edges`: {missing.sum()} "
                             f"missing, e.g. ({i}, {j})")


class MedialMesh(eqx.Module):
    """A medial mesh (Sun et al. 2013; Q-MAT, Li et al. 2015): spheres `(centers[i],
    radii[i])`, *cones* (the convex hull of the two spheres of each edge) and *slabs* (the
    convex hull of the three spheres of each face). Its volume is the union of all three.

    **Arguments/fields:**

    - `centers`: `(n, 3)` float array of sphere centres.
    - `radii`: `(n,)` float array, `>= 0`.
    - `edges`: `(e, 2)` int array of sphere indices (default: none).
    - `faces`: `(f, 3)` int array of sphere indices; each face's three edges must also be in
      `edges` (default: none).

    Arrays are kept as given (NumPy or JAX, dtype of the input; indices as int); concrete
    values are validated and a `ValueError` names the problem (shapes, indices out of range,
    faces whose edges are missing, non-finite values, negative radii).
    """

    centers: np.ndarray
    radii: np.ndarray
    edges: np.ndarray
    faces: np.ndarray

    def __init__(self, centers, radii, edges=None, faces=None):
        def arr(x, kind):
            if isinstance(x, jax.Array):
                return x
            try:
                x = np.asarray(x)
            except (TypeError, ValueError) as error:
                raise TypeError(f"MedialMesh arrays must be numbers, got {error}") from None
            if x.dtype.kind not in "iuf" and not (kind == "int" and x.size == 0):
                # Complex numbers would lose their imaginary part, strings be parsed.
                raise TypeError(f"MedialMesh arrays must be real numbers, got dtype {x.dtype}")
            if kind == "int":
                if x.size == 0:
                    return x.astype(np.int64)
                if not np.issubdtype(x.dtype, np.integer):
                    raise ValueError(f"MedialMesh indices must be integers, got {x.dtype}")
                return x.astype(np.int64)
            return x if np.issubdtype(x.dtype, np.floating) else x.astype(np.float64)

        self.centers = arr(centers, "float")
        self.radii = arr(radii, "float")
        self.edges = arr(np.zeros((0, 2), np.int64) if edges is None else edges, "int")
        self.faces = arr(np.zeros((0, 3), np.int64) if faces is None else faces, "int")
        if self.edges.size == 0:
            self.edges = self.edges.reshape(0, 2)
        if self.faces.size == 0:
            self.faces = self.faces.reshape(0, 3)

    def __check_init__(self):
        n = self.centers.shape[0] if self.centers.ndim == 2 else -1
        if self.centers.ndim != 2 or self.centers.shape[1] != 3:
            raise ValueError(f"MedialMesh centers must have shape (n, 3), got "
                             f"{self.centers.shape}")
        if self.radii.shape != (n,):
            raise ValueError(f"MedialMesh radii must have shape ({n},), got {self.radii.shape}")
        if self.edges.ndim != 2 or self.edges.shape[1] != 2:
            raise ValueError(f"MedialMesh edges must have shape (e, 2), got {self.edges.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ValueError(f"MedialMesh faces must have shape (f, 3), got {self.faces.shape}")
        if is_concrete(self.centers, self.radii, self.edges, self.faces):
            _check(*(np.asarray(x) for x in (self.centers, self.radii, self.edges, self.faces)))

    def numpy(self):
        """`(centers, radii, edges, faces)` as NumPy arrays (float64 and int64)."""
        return (np.asarray(self.centers, np.float64), np.asarray(self.radii, np.float64),
                np.asarray(self.edges, np.int64), np.asarray(self.faces, np.int64))

    def envelope(self, resolution: int = 128) -> trimesh.Trimesh:
        """A closed triangle mesh of the union of the spheres, cones and slabs.

        Marching tetrahedra on the union's exact signed distance (closed and manifold),
        vertices projected onto the surface (see `fleshing_jax._medial_axis.envelope`).
        `resolution`: grid cells along the longest side of the union's bounding box; the
        volume's error is second order in the cell size (about 0.1 % at the default 128 on a
        capsule).

        **Returns:** a `trimesh.Trimesh` (built with `process=False`), faces outward.
        """
        vertices, faces = envelope_arrays(*self.numpy(), resolution=resolution)
        return trimesh.Trimesh(vertices, faces, process=False)

    def volume(self, resolution: int = 160) -> float:
        """Volume of the union of the spheres, cones and slabs: the volume of its envelope
        at `resolution` (within 0.2 % at the default; see `envelope`)."""
        vertices, faces = envelope_arrays(*self.numpy(), resolution=resolution)
        return mesh_volume(vertices, faces)

    def fingerprint(self) -> str:
        """A digest of the spheres and of the topology (edges and faces as sets of sphere
        index tuples, so their order and orientation do not matter): what a `MedialPose` and
        a `MedialRig` compare to tell whether they belong to the same medial mesh. Values are
        hashed to float32's 24-bit precision (without its range), so that one mesh in float32
        and in float64 is one mesh."""
        centers, radii, edges, faces = self.numpy()
        centers, radii = (_float32_precision(x) for x in (centers, radii))
        digest = hashlib.blake2b(digest_size=16)
        for array in (centers, radii, _rows(np.sort(edges, axis=1)),
                      _rows(np.sort(faces, axis=1))):
            digest.update(str(array.shape).encode())
            digest.update(np.ascontiguousarray(array).tobytes())
        return digest.hexdigest()

    def nearest(self, points: ArrayLike) -> np.ndarray:
        """The index of the sphere whose centre is nearest to each point (e.g. to choose
        handles by position).

        **Arguments:** `points`: `(k, 3)` points, or one point `(3,)`; finite real numbers.

        **Returns:** `(k,)` int64 sphere indices (a 0-d array for one point); ties go to the
        lowest index.
        """
        p = np.asarray(check_finite_points(points, "points"))
        centers = np.asarray(self.centers, np.float64)
        if len(centers) == 0:
            raise ValueError("the medial mesh has no sphere to be nearest to")
        single = p.ndim == 1
        _, index = cKDTree(centers).query(p.reshape(-1, 3))
        index = np.asarray(index, np.int64)
        return index.reshape(()) if single else index

    def __repr__(self):
        return (f"MedialMesh(spheres={self.centers.shape[0]}, edges={self.edges.shape[0]}, "
                f"faces={self.faces.shape[0]})")

"""Q-MAT's `.ma` files: `nv ne nf`, then `v x y z r`, `e i j` and `f i j k` lines.

The format is the one Q-MAT (Li et al. 2015) writes and Coverage Axis and MATFP read; indices
are 0-based. Blank lines and lines starting with `#` are skipped on reading (our leniency).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from .medial_mesh import MedialMesh, face_edges


def _records(lines):
    """(line number, fields) of the meaningful lines."""
    for number, line in enumerate(lines, start=1):
        fields = line.split()
        if fields and not fields[0].startswith("#"):
            yield number, fields


def load_medial(path) -> MedialMesh:
    """Reads a medial mesh from a Q-MAT `.ma` file.

    A face whose edges are not all listed gets them added (some writers list only the
    edges that belong to no face).

    **Raises:** `ValueError` naming the line: a header that is not three counts, a record of
    the wrong kind or length, non-numeric values, fewer or more records than the header
    says, indices out of range, negative or non-finite radii.
    """
    path = Path(path)
    records = list(_records(path.read_text().splitlines()))
    if not records:
        raise ValueError(f"{path}: empty file, expected a header line 'nv ne nf'")
    number, header = records[0]
    try:
        nv, ne, nf = (int(x) for x in header)
    except ValueError:
        raise ValueError(f"{path}:{number}: header must be three counts 'nv ne nf', got "
                         f"{' '.join(header)!r}") from None
    if min(nv, ne, nf) < 0:
        raise ValueError(f"{path}:{number}: counts must be >= 0, got {nv} {ne} {nf}")
    body = records[1:]
    if len(body) != nv + ne + nf:
        raise ValueError(f"{path}: the header (line {number}) announces {nv} + {ne} + {nf} = "
                         f"{nv + ne + nf} records, the file has {len(body)}")
    parts = {"v": (body[:nv], 4, float), "e": (body[nv:nv + ne], 2, int),
             "f": (body[nv + ne:], 3, int)}
    arrays = {}
    for tag, (rows, width, kind) in parts.items():
        values = np.zeros((len(rows), width), dtype=np.float64 if kind is float else np.int64)
        for row, (number, fields) in enumerate(rows):
            if fields[0] != tag or len(fields) != width + 1:
                raise ValueError(f"{path}:{number}: expected a {tag!r} record with {width} "
                                 f"values, got {' '.join(fields)!r}")
            try:
                values[row] = [kind(x) for x in fields[1:]]
            except ValueError:
                raise ValueError(f"{path}:{number}: non-numeric value in "
                                 f"{' '.join(fields)!r}") from None
            if tag == "v" and not (np.isfinite(values[row]).all() and values[row, 3] >= 0):
                raise ValueError(f"{path}:{number}: a sphere needs a finite centre and a "
                                 f"finite radius >= 0, got {' '.join(fields[1:])!r}")
            if tag != "v" and (values[row].min() < 0 or values[row].max() >= nv):
                raise ValueError(f"{path}:{number}: sphere index out of range [0, {nv}) in "
                                 f"{' '.join(fields)!r}")
        arrays[tag] = values
    edges, faces = arrays["e"], arrays["f"]
    if len(faces):
        edges = np.unique(np.concatenate([np.sort(edges, axis=1), face_edges(faces)]), axis=0)
    return MedialMesh(arrays["v"][:, :3], arrays["v"][:, 3], edges, faces)


def save_medial(medial: MedialMesh, path) -> None:
    """Writes `medial` to a Q-MAT `.ma` file, atomically.

    The text goes to a temporary file in the same folder, which then replaces `path`
    (`os.replace`), so readers see the old file or the whole new one, never a part. The file
    gets the permissions a plain `open` would give (`0o666` less the umask).
    """
    path = Path(path)
    centers, radii, edges, faces = medial.numpy()
    lines = [f"{len(centers)} {len(edges)} {len(faces)}"]
    lines += [f"v {x!r} {y!r} {z!r} {r!r}" for (x, y, z), r in zip(centers.tolist(),
                                                                     radii.tolist())]
    lines += [f"e {i} {j}" for i, j in edges.tolist()]
    lines += [f"f {i} {j} {k}" for i, j, k in faces.tolist()]
    text = "\n".join(lines) + "\n"
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "w") as file:
            file.write(text)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temporary, 0o666 & ~umask)
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise

"""Q-MAT's `.ma` files: `nv ne nf`, then `v x y z r`, `e i j` and `f i j k` lines.

The format is the one Q-MAT (Li et al. 2015) writes and Coverage Axis and MATFP read; indices
are 0-based. Blank lines and lines starting with `#` are skipped on reading (our leniency).
"""

from __future__ import annotations

import glob
import os
import tempfile
from pathlib import Path

import numpy as np

from .._checks import check_readable_file
from .medial_mesh import MedialMesh, face_edges


def _records(lines):
    """(line number, fields) of the meaningful lines."""
    for number, line in enumerate(lines, start=1):
        fields = line.split()
        if fields and not fields[0].startswith("#"):
            yield number, fields


MAX_FILE_BYTES = 32 * 2**20  # a bound on untrusted files: 191 MB took 61 s and 2.6 GB


def _text(path: Path) -> str:
    """The text of a medial file, after the checks that need no reading."""
    check_readable_file(path, "a medial mesh file", MAX_FILE_BYTES)
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not a text .ma file ({error})") from None


def load_medial(path) -> MedialMesh:
    """Reads a medial mesh from a Q-MAT `.ma` file.

    A face whose edges are not all listed gets them added (some writers list only the
    edges that belong to no face).

    **Raises:** `FileNotFoundError` when `path` is not a file; `ValueError` naming the file
    (and the line): a folder, a file over `MAX_FILE_BYTES` or not UTF-8 text, a header that is
    not three counts, a record of the wrong kind or length, non-numeric values, fewer or more
    records than the header says, indices out of range, negative or non-finite radii.
    """
    path = Path(path)
    records = list(_records(_text(path).splitlines()))
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
            except OverflowError:  # an index beyond int64
                raise ValueError(f"{path}:{number}: sphere index out of range [0, {nv}) in "
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
    gets the permissions a plain `open` would give (`0o666` less the umask). A `path` that is a
    symbolic link keeps it: the file it points to is replaced. Temporary files that a killed
    writer left beside the file (their process is gone) are removed.

    **Raises:** `TypeError` when `medial` is not a `MedialMesh`; `ValueError` naming `path`
    when its folder does not exist or is not writable, or it is a folder.
    """
    if not isinstance(medial, MedialMesh):
        raise TypeError(f"`medial` must be a MedialMesh, got {type(medial).__name__}")
    target = check_medial_path(path)
    centers, radii, edges, faces = medial.numpy()
    lines = [f"{len(centers)} {len(edges)} {len(faces)}"]
    lines += [f"v {x!r} {y!r} {z!r} {r!r}" for (x, y, z), r in zip(centers.tolist(),
                                                                     radii.tolist())]
    lines += [f"e {i} {j}" for i, j in edges.tolist()]
    lines += [f"f {i} {j} {k}" for i, j, k in faces.tolist()]
    write_atomic(target, "\n".join(lines) + "\n")


def write_atomic(target: Path, text: str) -> None:
    """Writes `text` to a temporary file beside `target` (checked by `check_medial_path`),
    which then replaces it, with a plain `open`'s permissions; removes the temporary files
    that killed writers left there."""
    _remove_stale(target)
    # The writer's process id in the name tells a later writer whether the file is stale.
    handle, temporary = tempfile.mkstemp(dir=target.parent,
                                         prefix=f".{target.name}.{os.getpid()}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "w") as file:
            file.write(text)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temporary, 0o666 & ~umask)
        os.replace(temporary, target)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise


def check_medial_path(path) -> Path:
    """Checks, before any work, that a medial mesh can be written at `path` (a name in an
    existing, writable folder, not a folder); returns the file to replace (the target of a
    symbolic link). Raises `ValueError` naming `path`."""
    path = Path(path)
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    folder = target.parent
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a file name")
    if not folder.is_dir():
        raise ValueError(f"{path}: the output folder {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"{path}: the output folder {folder} is not writable")
    return target


def _remove_stale(target: Path) -> None:
    """Removes `.NAME.PID.*.tmp` files beside `target` whose writer `PID` is no longer running
    (a writer killed mid-write leaves its whole temporary file)."""
    for temporary in target.parent.glob(f".{glob.escape(target.name)}.*.tmp"):
        pid = temporary.name[len(target.name) + 2:].split(".", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _running(int(pid)):
            temporary.unlink(missing_ok=True)


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # someone else's process, or not a process id: leave its file alone
    return True

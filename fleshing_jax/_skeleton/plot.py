"""`plot_skeleton`: a picture of a `Skeleton` on its mesh, for a person to check it.

The mesh's faces coloured by limb region (the body grey), each limb's rest spine drawn over
it, its joint a dot and its index written at its tip, the model's up axis vertical. `save_png`
writes that picture to a PNG file atomically (the command line's `skeleton --png`).
"""

from __future__ import annotations

import io
import numbers
import os
import tempfile
from pathlib import Path

import numpy as np

from .._medial_axis.figure import default_up, upright
from .regions import spine_samples
from .skeleton import Skeleton

BODY = (0.62, 0.62, 0.62)  # the body's grey
GROUND = 0.05  # a limb end this close to a face of the bounding box (of its extent) stands on it
# The limbs' colours: matplotlib's qualitative tab10, its grey (index 7) left out so that no
# limb looks like the body; past 9 limbs tab20 (its two greys left out), past 18 hues evenly
# spaced.
_TAB10 = [0, 1, 2, 3, 4, 5, 6, 8, 9]
_TAB20 = [0, 2, 4, 6, 8, 10, 12, 16, 18, 1, 3, 5, 7, 9, 11, 13, 17, 19]
_AXES = {"x": 0, "y": 1, "z": 2}


def limb_colours(count: int) -> np.ndarray:
    """`(count, 3)` RGB: distinct colours for `count` limbs, none of them grey."""
    import matplotlib

    if count <= len(_TAB10):
        return np.asarray(matplotlib.colormaps["tab10"].colors)[_TAB10[:count]]
    if count <= len(_TAB20):
        return np.asarray(matplotlib.colormaps["tab20"].colors)[_TAB20[:count]]
    hues = np.arange(count) / count
    hsv = np.stack([hues, np.full(count, 0.75), np.where(np.arange(count) % 2, 0.7, 0.95)], 1)
    return matplotlib.colors.hsv_to_rgb(hsv)


def face_regions(region: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """`(f,)` the region of each face: the one at least two of its vertices share, else its
    first vertex's."""
    r = region[faces]
    return np.where(r[:, 1] == r[:, 2], r[:, 1], r[:, 0])


def limb_points(skeleton: Skeleton) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per limb `(spine (k, 3), joint (3,))`, float64: its rest spine sampled evenly from
    `s = 0` to its tip (`spine_samples`, the compiled program `fj.skeleton` ran already), and
    its joint `limb.spine(limb.joint)`, interpolated between those samples (within far less
    than a dot's size of it)."""
    found = []
    for limb in skeleton.limbs:
        s, points, _ = map(np.asarray, spine_samples(limb.spine))
        points = points.astype(np.float64)
        joint = [np.interp(float(limb.joint), s, points[:, i]) for i in range(3)]
        found.append((points, np.array(joint)))
    return found


def guess_up(mesh, skeleton: Skeleton, points=None) -> str:
    """The model's up axis, guessed: a character stands on its feet. `up` is the signed
    coordinate axis pointing away from the face of the mesh's bounding box that the most
    limb ends (the tips of limbs without children) lie on, within `GROUND` of its extent,
    when at least two do and no other face holds as many (cheburashka's two feet below its
    head, arms and ears: its limbs' directions, summed, pointed along its forward feet).
    Else it is the one nearest to minus the sum of the body's limbs' (parent −1) unit
    directions, from joint to tip, when that sum is at least two limbs long (legs agreeing;
    the bunny's head and haunch, 1.6 long, pointed sideways); else (no limbs, or limbs
    that do not agree) `default_up(mesh)` of `plot_medial`: `"y"` for a mesh read from an
    OBJ file, else `"z"`. `points`: the skeleton's `limb_points`, when computed already."""
    points = limb_points(skeleton) if points is None else points
    ends = np.array([spine[-1] for k, (spine, _) in enumerate(points)
                     if not skeleton.children(k)]).reshape(-1, 3)
    vertices = np.asarray(skeleton.vertices, np.float64)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    near = GROUND * (high - low)
    # Per face (rows: the low faces, then the high ones): the limb ends lying on it.
    counts = np.stack([np.sum(ends - low < near, axis=0), np.sum(high - ends < near, axis=0)])
    side, axis = np.unravel_index(np.argmax(counts), counts.shape)
    if counts[side, axis] >= 2 and np.sum(counts == counts[side, axis]) == 1:
        return ("+" if side == 0 else "-") + "xyz"[axis]
    total = np.zeros(3)
    for limb, (spine, joint) in zip(skeleton.limbs, points):
        if limb.parent == -1:
            direction = spine[-1] - joint
            total += direction / max(float(np.linalg.norm(direction)), 1e-300)
    if np.linalg.norm(total) < 2.0:
        return default_up(mesh)
    axis = int(np.argmax(np.abs(total)))
    return ("-" if total[axis] > 0 else "+") + "xyz"[axis]


def up_rotation(up) -> np.ndarray:
    """`(3, 3)` the proper rotation `R` that turns `up` to the picture's vertical:
    `R @ up ∝ (0, 0, 1)`. `up`: `"x"`, `"y"`, `"z"`, each optionally signed (`"-y"`), or a
    (3,) nonzero finite vector. The positive axes turn as `plot_medial` turns them; a
    negative one turns as the positive one, then half a turn about the picture's x; another
    vector by the smallest rotation. Raises `ValueError`/`TypeError` naming `up`."""
    if isinstance(up, str):
        name = up.strip().lower()
        sign = -1.0 if name.startswith("-") else 1.0
        name = name.lstrip("+-")
        if name not in _AXES or len(up.strip()) > 2:
            raise ValueError(
                f"`up` must be 'x', 'y' or 'z' (optionally signed, e.g. '-y') or a (3,) "
                f"vector, got {up!r}."
            )
        turn = upright(np.eye(3), name).T  # rows: the picture's x, y, z in the model's axes
        return turn if sign > 0 else np.diag([1.0, -1.0, -1.0]) @ turn
    try:
        vector = np.asarray(up, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(
            f"`up` must be None, an axis name such as 'y' or '-z', or a (3,) vector, got "
            f"{type(up).__name__}."
        ) from None
    if vector.shape != (3,) or not np.isfinite(vector).all() or not np.any(vector):
        raise ValueError(
            f"`up` must be a finite, nonzero (3,) vector (or an axis name), got {up!r}."
        )
    vector = vector / np.linalg.norm(vector)
    for axis, i in _AXES.items():
        if abs(vector[i]) == 1.0:
            return up_rotation(("-" if vector[i] < 0 else "") + axis)
    # The smallest rotation taking `vector` to z (Rodrigues; `vector` is not ±z here).
    axis = np.cross(vector, [0.0, 0.0, 1.0])
    sine, cosine = np.linalg.norm(axis), vector[2]
    k = axis / sine
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + sine * cross + (1 - cosine) * cross @ cross


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


def _name(up) -> str:
    """`up` as the title says it: an axis name, or a vector's components."""
    if isinstance(up, str):
        return up.strip().lower()
    return "(" + ", ".join(f"{float(c):.3g}" for c in np.asarray(up, np.float64)) + ")"


def _mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """`(vertices (n, 3) float64, faces (f, 3) int)` of a `trimesh.Trimesh` or a pair."""
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        vertices, faces = mesh.vertices, mesh.faces
    else:
        try:
            vertices, faces = mesh
        except (TypeError, ValueError):
            raise TypeError(
                f"`mesh` must be a trimesh.Trimesh or a pair (vertices, faces), got "
                f"{type(mesh).__name__}."
            ) from None
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not len(vertices):
        raise ValueError(f"`mesh` vertices must have shape (n, 3), got {vertices.shape}.")
    if not np.isfinite(vertices).all():
        raise ValueError("`mesh` vertices must be finite.")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"`mesh` faces must be (f, 3) integers, got {faces.shape} "
                         f"{faces.dtype}.")  # fmt: skip
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"`mesh` faces must index its {len(vertices)} vertices.")
    return vertices, faces


def _shade(triangles: np.ndarray, light: np.ndarray) -> np.ndarray:
    """`(f,)` the brightness of each face, between 0.55 and 1, lit from `light` (either
    side of a face lit alike: the mesh is see-through)."""
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-300
    return 0.55 + 0.45 * np.abs(normals @ light)


def plot_skeleton(mesh, skeleton: Skeleton, *, ax=None, up=None, elev: float = 15.0,
                  azim: float | None = None, alpha: float = 0.5):  # fmt: skip
    """Draws `skeleton` on `mesh` for a person to check it: each face coloured by its limb
    region (the body grey, each limb a distinct colour of matplotlib's qualitative `tab10`,
    `tab20` past 9 limbs; lit from the viewer's side), then over it, visible through the
    translucent mesh, each limb's rest spine (a black line from `s = 0`, inside its parent,
    to its tip), its joint `limb.spine(limb.joint)` (a dot in the limb's colour) and its index
    (written just beyond its tip `limb.spine(limb.spine.length)`, framed in the limb's
    colour). The model's up axis is the picture's vertical, the axes have the data's
    proportions, and the title gives the limb count and the up axis.

    **Arguments:**

    - `mesh`: the mesh `skeleton` was built on, at rest (the spines drawn are the rest
      spines): a `trimesh.Trimesh` or `(vertices (n, 3), faces (f, 3))`.
    - `skeleton`: an `fj.Skeleton` of that mesh (`fj.skeleton`, `fj.load_skeleton`); its
      `region` is `(n,)`.
    - `ax`: a matplotlib 3D axis to draw on (default: a new figure's). Its artists are drawn
      in the order they were added (`ax.computed_zorder = False`).
    - `up`: the model's vertical axis: `"x"`, `"y"`, `"z"`, optionally signed (`"-y"`: the
      model is upside down), or a `(3,)` vector. Default (`None`): guessed from the skeleton,
      as a character stands on its feet (`guess_up`): away from the bounding box's face
      that the most limb ends lie on, at least two (spot's hooves, cheburashka's feet:
      `"+y"`; the procedural quadruped: `"+z"`); else the signed axis nearest to minus the
      sum of the body's limbs' unit directions (each from joint to tip), when that sum is
      at least two limbs long; else `"y"` for a mesh read from an OBJ file and `"z"` for
      any other, as `fj.plot_medial` guesses. (The box's extents alone say nothing: spot's are
      about (0.94, 1.69, 1.72), its up axis y neither the smallest nor the largest.)
    - `elev`, `azim`: the view in degrees (matplotlib's). `azim` default: the side view,
      turned 30° towards the front, across the longer horizontal extent.
    - `alpha`: the mesh's opacity in (0, 1].

    **Returns:** the matplotlib `Figure` (`ax`'s when given).

    **Raises:** `TypeError` for a `skeleton` that is not an `fj.Skeleton`, an `ax` that is
    not a 3D axis, a `mesh` that is no mesh, an `up` of another type; `ValueError` for a
    skeleton built on another mesh (its vertex count differs), malformed mesh arrays, an `up`
    not understood, an `alpha` outside (0, 1], a non-finite `elev` or `azim`.
    """
    if not isinstance(skeleton, Skeleton):
        raise TypeError(f"`skeleton` must be an fj.Skeleton, got {type(skeleton).__name__}.")
    vertices, faces = _mesh_arrays(mesh)
    region = np.asarray(skeleton.region)
    if len(region) != len(vertices):
        raise ValueError(
            f"`skeleton` was built on a mesh of {len(region)} vertices, but `mesh` has "
            f"{len(vertices)}: pass the mesh it was built on."
        )
    if not (_is_number(alpha) and 0 < alpha <= 1):
        raise ValueError(f"`alpha` must be a number in (0, 1], got {alpha!r}.")
    for name, value in (("elev", elev), ("azim", azim)):
        if value is not None and not (_is_number(value) and np.isfinite(value)):
            raise ValueError(f"`{name}` must be a finite number of degrees, got {value!r}.")
    if ax is not None:
        from mpl_toolkits.mplot3d import Axes3D

        if not isinstance(ax, Axes3D):
            raise TypeError(
                f"`ax` must be a matplotlib 3D axis (projection='3d'), got {type(ax).__name__}."
            )
    found = limb_points(skeleton)
    guessed = guess_up(mesh, skeleton, found) if up is None else None
    turn = up_rotation(guessed or up)
    spines = [spine @ turn.T for spine, _ in found]
    joints = [joint @ turn.T for _, joint in found]
    limbs = skeleton.limbs
    points = vertices @ turn.T
    everything = np.concatenate([points, *spines]) if spines else points
    lo, hi = everything.min(axis=0), everything.max(axis=0)
    extent = np.maximum(hi - lo, 1e-3 * max(float((hi - lo).max()), 1e-300))
    if azim is None:
        azim = -60.0 if extent[0] >= extent[1] else 30.0
    view = np.radians([elev, azim])
    eye = np.array([np.cos(view[0]) * np.cos(view[1]), np.cos(view[0]) * np.sin(view[1]),
                    np.sin(view[0])])  # fmt: skip
    light = eye + np.array([0.0, 0.0, 0.6]) + 0.4 * np.cross([0.0, 0.0, 1.0], eye)
    light /= np.linalg.norm(light)

    import matplotlib.patheffects as effects
    import matplotlib.pyplot as plt
    from matplotlib.transforms import ScaledTranslation
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if ax is None:
        ax = plt.figure(figsize=(8, 7)).add_subplot(projection="3d")
    ax.computed_zorder = False  # the spines over the mesh, whatever their depth
    colours = np.concatenate([[BODY], limb_colours(len(limbs))])
    triangles = points[faces]
    shade = _shade(triangles, light)[:, None]
    rgba = np.concatenate([shade * colours[face_regions(region, faces) + 1],
                           np.full((len(faces), 1), float(alpha))], axis=1)  # fmt: skip
    ax.add_collection3d(Poly3DCollection(triangles, facecolors=rgba, linewidths=0, zorder=1))
    halo = [effects.withStroke(linewidth=4.5, foreground="white")]
    for i, (spine, joint) in enumerate(zip(spines, joints)):
        ax.plot(*spine.T, color="black", linewidth=2.0, zorder=3, path_effects=halo)
        ax.scatter(*joint, s=45, color=colours[i + 1], edgecolors="black", linewidths=1.0,
                   depthshade=False, zorder=4)  # fmt: skip
    for setter, low, high in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), lo, hi):
        setter(low, high)
    ax.set_box_aspect(tuple(extent), zoom=1.1)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    if spines:
        tips = np.array([spine[-1] for spine in spines])
        offsets = _label_offsets(ax, tips, np.array([spine[-2] for spine in spines]))
        for i, (tip, offset) in enumerate(zip(tips, offsets)):
            shift = ScaledTranslation(*(offset / 72), ax.get_figure().dpi_scale_trans)
            ax.text(*tip, str(i), color="black", fontsize=10, fontweight="bold", ha="center",
                    va="center", zorder=5, transform=ax.transData + shift,
                    bbox=dict(boxstyle="round,pad=0.2", facecolor="white", alpha=0.85,
                              edgecolor=colours[i + 1], linewidth=1.5))  # fmt: skip
    shown = _name(up) if guessed is None else f"{guessed} (guessed)"
    ax.set_title(f"{len(limbs)} limbs, numbered at their tips; body grey; up {shown}")
    return ax.get_figure()


def _label_offsets(ax, tips: np.ndarray, before: np.ndarray) -> np.ndarray:
    """`(k, 2)` offsets in points, on the screen, of the labels of limbs ending at `tips`
    `(k, 3)` (in `ax`'s data, `before`: a point on each spine just before its tip): just
    beyond each tip, along its spine as the view shows it, or, where an earlier label or
    another tip is there already (a limb's tip beside its child's), the nearest free place
    around it."""
    from mpl_toolkits.mplot3d import proj3d

    ax.apply_aspect()  # the axis's final place in the figure, as when drawn
    projection = ax.get_proj()
    scale = 72.0 / ax.get_figure().dpi
    at, back = (ax.transData.transform(np.column_stack(proj3d.proj_transform(*p.T, projection)[:2]))
                * scale for p in (tips, before))  # fmt: skip
    ahead = at - back
    ahead /= np.linalg.norm(ahead, axis=1, keepdims=True) + 1e-9
    size = np.array([22.0, 18.0])  # a label's box, in points, and a little room
    angles = np.radians(np.arange(0, 360, 45))
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    placed, offsets = [], []
    for k in range(len(tips)):
        wanted = 14.0 * ahead[k]
        others = np.delete(at, k, axis=0)
        # Beyond the tip first, else the free place nearest to the tip (not on it), the more
        # ahead first among equals.
        around = wanted + np.concatenate([r * ring for r in (18.0, 36.0, 54.0)])
        around = around[np.linalg.norm(around, axis=1) >= 12.0]
        order = np.lexsort((-(around @ ahead[k]), np.round(np.linalg.norm(around, axis=1))))
        candidates = [wanted, *around[order]]
        for offset in candidates:
            centre = at[k] + offset
            # Clear of the labels placed and of the other limbs' tips.
            free = all(np.any(np.abs(centre - other) >= size) for other in placed)
            if free and np.all(np.any(np.abs(centre - others) >= size / 2, axis=1)):
                break
        else:
            offset = wanted
        placed.append(at[k] + offset)
        offsets.append(offset)
    return np.array(offsets)


def save_png(mesh, skeleton: Skeleton, path: str | os.PathLike, *, up=None, dpi: int = 130) -> None:
    """Draws `plot_skeleton(mesh, skeleton, up=up)` on a figure of its own, rendered by Agg
    (no screen, pyplot untouched), and writes it as a PNG at `path`, atomically: to a
    temporary file in the same folder, then renamed over `path` (`os.replace`), with a plain
    `open`'s permissions; a failure leaves `path` as it was."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(8, 7))
    FigureCanvasAgg(figure)
    plot_skeleton(mesh, skeleton, ax=figure.add_subplot(projection="3d"), up=up)
    image = io.BytesIO()
    figure.savefig(image, format="png", dpi=dpi, bbox_inches="tight", pad_inches=0.1)
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(handle, "wb") as file:
            file.write(image.getvalue())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temporary, 0o666 & ~umask)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise

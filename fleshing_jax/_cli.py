"""The `fleshing-jax` command line.

    fleshing-jax deform IN OUT [--from A.json | --ends X,Y,Z X,Y,Z] [--medial IN.ma]
                               (--to B.json | --bend-angle DEG) [--method M] [--twist RAD]
                               [--beyond MODE] [--max-stretch X] [--allow-invalid]
                               [--save-spine FILE] [--cap-holes]
    fleshing-jax medial IN OUT.ma [--spheres N] [--envelope ENV.obj] [--list]
    fleshing-jax medial-deform IN OUT --medial IN.ma --handles H.json [--method M]
                                      [--no-implicit]
    fleshing-jax skeleton IN OUT.json [--spheres N] [--seed S] [--png FILE]
    fleshing-jax pose IN OUT [--skeleton S.json] ((--limb K | --at X,Y,Z) --bend DEG
                             [--direction DEG] [--twist DEG])... | --poses P.json)
                             [--method M] [--max-stretch X] [--allow-inexact] [--spheres N]
    fleshing-jax demo [--out DIR]
    fleshing-jax --version

Expected failures (missing file, malformed spine, unreadable mesh, unwritable output) print one
line `fleshing-jax: error: …` on stderr and exit with status 2; outputs are checked before any
work and written atomically. JAX is imported only once a command runs (`--help` stays fast),
and compiled programs are kept in the user's cache folder (`_cache`).
"""

from __future__ import annotations

import argparse
import re
import sys
import time

from . import __version__
from ._fleshing.methods import METHODS

PROG = "fleshing-jax"
# `pose`'s default largest change of an edge's length: spot's leg bent 60° stretches one 2.2×
# (radial), its head bent 15° with the binormal method 7.5× (a spike), both with no vertex
# invalid.
MAX_STRETCH = 3.0

SPINE_FORMAT = """\
spine files (JSON), e.g.
  {"type": "line", "length": 4.0, "origin": [0, 0, 0], "tangent": [1, 0, 0]}
  {"type": "arc", "radius": 2.0, "length": 4.0, "origin": [0, 0, 0],
   "tangent": [1, 0, 0], "normal": [0, 1, 0]}
  {"type": "bspline", "control_points": [[0, 0, 0], [1, 0, 0], ...], "degree": 5}
types: line, arc, helix, bspline, interpolatingpolynomial, polyline (see the README).

Without --from, the rest spine is found on the medial axis of IN (IN must be closed; see
--cap-holes), between the points --ends names (else along the medial axis's longest path), on
the medial mesh --medial reads (from `fleshing-jax medial`; else computed), and printed as
JSON; --save-spine FILE writes it, to reuse with --from."""


POSES_FORMAT = """\
poses files (JSON): a list of limbs, each named by its index (or its name) or a point, e.g.
  [{"limb": 7, "bend": 30, "direction": 90},
   {"at": [0.1, 0.9, -0.3], "bend": 20, "twist": 10}]
angles in degrees; "direction" and "twist" default to 0."""


def _limb_key(text: str) -> int | str:
    """`--limb`'s value: a limb index, or a limb's name (`Limb.name`)."""
    try:
        return int(text)
    except ValueError:
        return text


class _LimbGroup(argparse.Action):
    """Collects `--limb`/`--at` and the angles after it into one group per limb (`args.limbs`:
    a list of dicts); an angle before any `--limb`/`--at` is a usage error."""

    def __call__(self, parser, namespace, value, option_string=None):
        groups = getattr(namespace, "limbs", None) or []
        if self.dest in ("limb", "at"):
            groups.append({self.dest: value})
        elif not groups:
            parser.error(f"{option_string} must follow --limb K or --at X,Y,Z")
        elif self.dest in groups[-1]:
            parser.error(f"{option_string} given twice for one limb")
        else:
            groups[-1][self.dest] = value
        namespace.limbs = groups


def _point(text: str) -> tuple[float, float, float]:
    """`X,Y,Z` → three finite floats (argparse reports a ValueError as a usage error)."""
    values = tuple(float(v) for v in text.split(","))
    if len(values) != 3 or not all(abs(v) < float("inf") for v in values):
        raise ValueError(text)
    return values


_point.__name__ = "point X,Y,Z"  # argparse names the expected type after it


def _factor(text: str) -> float:
    """A finite float ≥ 1: a factor by which a length may change."""
    value = float(text)
    if not 1.0 <= value < float("inf"):
        raise ValueError(text)
    return value


_factor.__name__ = "factor ≥ 1"


def _command(commands, name: str, summary: str, description: str, source: str, *,
             output=("OUT", "output file; its extension sets the format"), epilog=None,
             raw=False):
    """A subcommand reading IN and writing OUT: its parser, with the two positional arguments
    (`source`: IN's help; `output`: OUT's metavar and help; `raw`: the epilog is laid out
    already, and printed as it is)."""
    formatter = argparse.RawDescriptionHelpFormatter if raw else argparse.HelpFormatter
    parser = commands.add_parser(name, help=summary, description=description, epilog=epilog,
                                 formatter_class=formatter)
    parser.add_argument("input", metavar="IN", help=source)
    parser.add_argument("output", metavar=output[0], help=output[1])
    return parser


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Spine-driven bending of 3D shapes with local volume preservation.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    deform = _command(
        commands, "deform", "bend a mesh or point cloud from one spine to another",
        "Bend IN (any format trimesh reads) from the rest spine (--from, or found on the medial "
        "axis) to a bent spine (--to, or an arc turning by --bend-angle) and write OUT in the "
        "format of its extension.",
        "input mesh or point cloud", epilog=SPINE_FORMAT, raw=True,
    )
    rest = deform.add_mutually_exclusive_group()
    rest.add_argument(
        "--from", dest="source", metavar="A.json", help="rest spine (default: from the medial axis)"
    )
    rest.add_argument(
        "--ends",
        nargs=2,
        type=_point,
        metavar="X,Y,Z",
        help="without --from: the rest spine runs between the medial spheres nearest to these "
        "two points (default: the medial axis's longest path)",
    )
    deform.add_argument(
        "--medial",
        metavar="IN.ma",
        help="without --from: find the rest spine on this medial mesh of IN (from `medial`) "
        "instead of computing one",
    )
    deform.add_argument(
        "--save-spine", metavar="FILE", help="write the rest spine used to FILE (JSON, atomically)"
    )
    bend = deform.add_mutually_exclusive_group(required=True)
    bend.add_argument("--to", dest="target", metavar="B.json", help="bent spine (JSON)")
    bend.add_argument(
        "--bend-angle",
        type=float,
        metavar="DEG",
        help="bend the rest spine into an arc of the same length turning by DEG degrees "
        "towards its initial normal (negative: the other way)",
    )
    deform.add_argument(
        "--method",
        choices=METHODS,
        default="radial",
        help="fleshing method (default: radial; skinning is the baseline)",
    )
    deform.add_argument(
        "--twist", type=float, default=0.0, metavar="RAD", help="global twist in radians"
    )
    deform.add_argument(
        "--cap-holes",
        action="store_true",
        help="close the holes of an open mesh first (fj.cap_holes): exact volumes, and a "
        "medial axis to find the rest spine on",
    )
    deform.add_argument(
        "--beyond",
        choices=("continue", "rigid"),
        default="continue",
        help="vertices that project before the rest spine's start or past its end: fleshed "
        "along the spines' continuations (default), or moved rigidly with the end frames "
        "(rigid: the rest of a body stays where it is when only a tail or a limb is bent)",
    )
    _max_stretch_argument(deform, "bend")
    deform.add_argument(
        "--allow-invalid",
        action="store_true",
        help="write OUT even when vertices are invalid (left where they were, so that the "
        "mesh may be torn between them and their neighbours); without it such a bend is not "
        "written and the exit status is 3",
    )
    medial = _command(
        commands, "medial", "compute the medial mesh of a closed mesh (Q-MAT .ma file)",
        "Compute the medial mesh of IN (a closed mesh) and write it to OUT in Q-MAT's .ma "
        "format; print its size, its two one-sided Hausdorff distances to IN (as fractions of "
        "the bounding-box diagonal) and the time taken.",
        "input mesh (closed)", output=("OUT.ma", "output medial mesh (.ma)"),
    )
    medial.add_argument("--spheres", type=int, default=200, metavar="N", help="default: 200")
    medial.add_argument("--seed", type=int, default=0, help="seed of the surface samples")
    medial.add_argument(
        "--envelope", metavar="ENV.obj", help="also write the medial mesh's envelope (a mesh)"
    )
    medial.add_argument("--cap-holes", action="store_true", help="close IN's holes first")
    medial.add_argument(
        "--list",
        action="store_true",
        help="print every sphere: index, centre and radius (to choose handles)",
    )
    medial_deform = _command(
        commands, "medial-deform",
        "deform a mesh by moving spheres of its medial mesh (Lan et al. 2017)",
        "Bind IN to its medial mesh (--medial, from `medial`), move the handle spheres to their "
        "targets (--handles) as rigidly as possible, skin IN from the deformed medial mesh and "
        "write OUT in the format of its extension; print the volumes before and after.",
        "input mesh", epilog="handle files (JSON): " + _handles_format(),
    )
    medial_deform.add_argument("--medial", required=True, metavar="IN.ma", help="medial mesh")
    medial_deform.add_argument(
        "--handles", required=True, metavar="H.json", help="handle spheres and their targets"
    )
    medial_deform.add_argument(
        "--method", choices=("medial", "lbs", "dqs"), default="medial", help="default: medial"
    )
    medial_deform.add_argument(
        "--no-implicit", action="store_true", help="skip the implicit-skinning correction"
    )
    medial_deform.add_argument("--cap-holes", action="store_true", help="close IN's holes first")
    skeleton = _command(
        commands, "skeleton", "find the limbs of a closed mesh on its medial mesh (JSON skeleton)",
        "Find the limbs of IN (a closed mesh) on its medial mesh, each with its rest spine, its "
        "parent and the vertices it moves; print them (index, parent, spine length, joint, "
        "region size, the spine's end point) and write the skeleton to OUT.json "
        "(fj.load_skeleton reads it).",
        "input mesh (closed)", output=("OUT.json", "output skeleton (JSON)"),
    )
    skeleton.add_argument(
        "--spheres", type=int, default=200, metavar="N", help="spheres of the medial mesh (200)"
    )
    skeleton.add_argument("--seed", type=int, default=0, help="seed of the surface samples")
    skeleton.add_argument("--png", metavar="FILE", help="also draw the skeleton on IN to this "
                          "PNG file: limb regions coloured, spines, joints, limb numbers")
    skeleton.add_argument("--cap-holes", action="store_true", help="close IN's holes first (the "
                          "skeleton is then the capped mesh's: pose it with --cap-holes too)")
    pose = _command(
        commands, "pose",
        "pose a closed mesh limb by limb on its skeleton (each limb bent, the rest still)",
        "Bend limbs of IN, each along its own spine from its joint (its child limbs "
        "follow; the body and the other limbs stay exactly still), and write OUT in the format "
        "of its extension. Each limb is named by --limb K (its index in the skeleton, or its "
        "name: a skeleton from an armature's bones) or --at "
        "X,Y,Z (the limb holding the vertex nearest to that point), followed by its --bend "
        "(and optionally --direction and --twist), in degrees; or all of them in --poses.",
        "input mesh (closed)", epilog=POSES_FORMAT, raw=True,
    )
    pose.add_argument("--skeleton", metavar="S.json",
                      help="skeleton (from `skeleton`; default: found on IN's medial mesh)")
    pose.add_argument("--spheres", type=int, default=200, metavar="N",
                      help="without --skeleton: spheres of the medial mesh (200)")
    group = pose.add_argument_group("limbs (repeat the group for each limb)")
    group.add_argument("--limb", type=_limb_key, metavar="K", action=_LimbGroup,
                       help="limb index, or the limb's name (a skeleton from an armature's bones)")
    group.add_argument("--at", type=_point, metavar="X,Y,Z", action=_LimbGroup,
                       help="the limb holding the vertex nearest to this point")
    for name, what in (("bend", "the bend from the joint"), ("direction", "the direction of the "
                       "bend about the limb's tangent at its joint (default 0)"),
                       ("twist", "the twist about that tangent (default 0)")):
        group.add_argument(f"--{name}", type=float, metavar="DEG", action=_LimbGroup,
                           help=f"{what}, in degrees")
    pose.add_argument("--poses", metavar="P.json", help="the limbs' poses in a file (below)")
    pose.add_argument("--cap-holes", action="store_true", help="close IN's holes first, pose "
                      "the closed mesh and write IN's own faces (the caps dropped)")
    pose.add_argument("--method", choices=METHODS[:3], default="radial",
                      help="fleshing method (default: radial)")
    _max_stretch_argument(pose, "pose")
    pose.add_argument(
        "--allow-inexact",
        "--allow-invalid",
        dest="allow_invalid",
        action="store_true",
        help="write OUT even when vertices are posed inexactly (past a joint's range: placed "
        "continuously, the volume not kept there); without it such a pose is not written and "
        "the status is 3",
    )
    demo = commands.add_parser(
        "demo",
        help="bend a built-in creature with the four methods; write meshes, a figure, a table",
    )
    demo.add_argument(
        "--out", default="fleshing-demo", metavar="DIR", help="output folder (./fleshing-demo)"
    )
    return parser


class _Progress:
    """A one-line progress bar on stderr, shown only for work split in several chunks."""

    def __init__(self, label: str, stream=None):
        self.label, self.stream, self.shown = label, stream or sys.stderr, False

    def __call__(self, done: int, total: int) -> None:
        if done == total and not self.shown:
            return
        self.shown = True
        width = 30
        filled = int(width * done / max(total, 1))
        bar = "#" * filled + "-" * (width - filled)
        end = "\n" if done == total else ""
        self.stream.write(f"\r{self.label} [{bar}] {done}/{total}{end}")
        self.stream.flush()


def _max_stretch_argument(parser, what: str) -> None:
    """`--max-stretch`, one rule for `deform` and `pose` (`_refused_stretch`)."""
    parser.add_argument(
        "--max-stretch", type=_factor, default=MAX_STRETCH, metavar="X",
        help="the largest factor by which an edge between valid vertices may change length, "
        f"and the map stretch or squeeze a direction at a vertex (default {MAX_STRETCH:g}: a "
        f"valid {what} near the edge of its range keeps volume but can draw a part out into a "
        "spike or press it into a blade); beyond it the result is not written and the status "
        "is 3",
    )


def _refused_stretch(args, factors) -> bool:
    """Whether one of `factors` (`(what, factor)` pairs) is beyond `--max-stretch`; then
    says so on stderr."""
    for what, factor in factors:
        if factor > args.max_stretch:
            print(f"not written: {what} {factor:.3g}× (more than --max-stretch "
                  f"{args.max_stretch:g}): it distorts the mesh there; bend less, or pass "
                  "a larger --max-stretch", file=sys.stderr)
            return True
    return False


def _load_input(path, cap: bool):
    """The input mesh, finite, with its holes closed when asked."""
    import numpy as np
    import trimesh

    from ._mesh.files import load_mesh
    from ._mesh.holes import cap_holes

    mesh = load_mesh(path)
    if not np.all(np.isfinite(np.asarray(mesh.vertices))):
        raise ValueError(f"{path}: has non-finite vertex coordinates (NaN or inf)")
    if cap and isinstance(mesh, trimesh.Trimesh):
        mesh = cap_holes(mesh)
    return mesh


def _deform(args) -> int:
    import jax.numpy as jnp
    import numpy as np
    import trimesh

    from ._fleshing.diagnose import diagnose, largest_valid_bend, planar_bend
    from ._fleshing.pipeline import register
    from ._mesh.deform import deform_mesh, longest_edge
    from ._mesh.files import MESH_WRITABLE, check_output_path, write_mesh_atomic
    from ._mesh.volume import volume
    from ._spines.files import load_spine, save_spine, spine_json

    check_output_path(args.output)
    if args.bend_angle is not None and not abs(args.bend_angle) < 360:
        raise ValueError(
            f"--bend-angle {args.bend_angle:g}: an arc turning by 360 degrees or more comes "
            "back on itself, where no vertex can stay valid; give an angle in (-360, 360)"
        )
    if args.save_spine is not None:
        check_output_path(args.save_spine, extensions=("json",))
    if args.source is not None and args.medial is not None:
        raise ValueError("--medial finds the rest spine: it goes without --from")
    mesh = _load_input(args.input, args.cap_holes)
    is_mesh = isinstance(mesh, trimesh.Trimesh) and len(mesh.faces) > 0
    if is_mesh:
        check_output_path(args.output, extensions=MESH_WRITABLE)  # (before the work)
    started = time.perf_counter()
    if args.source is not None:
        source = load_spine(args.source)
    else:
        source = _found_rest_spine(mesh, args)
        print(f"rest spine (medial axis): {spine_json(source)}")
    if args.save_spine is not None:
        save_spine(source, args.save_spine)
        print(f"wrote {args.save_spine} (rest spine)")
    if args.target is not None:
        target = load_spine(args.target)
    else:
        target = planar_bend(source, float(np.radians(args.bend_angle)))
    margin = 0.5 * longest_edge(mesh.vertices, mesh.faces) if is_mesh else 0.0
    bent = deform_mesh(
        mesh,
        source,
        target,
        method=args.method,
        twist=args.twist,
        progress=_Progress(f"{args.method}: vertices"),
        margin=margin,
        beyond=args.beyond,
        stretch=is_mesh,  # measured as it is bent (`_bend_stretch`)
    )
    if isinstance(bent, trimesh.Trimesh):
        valid = np.asarray(bent.vertex_attributes["valid"], dtype=bool)
    else:
        valid = np.asarray(bent.metadata["valid"], dtype=bool)
    if is_mesh:
        _print_volumes(mesh, bent, volume)
    print(f"invalid vertices: {int(np.sum(~valid))} of {len(valid)}")
    if args.bend_angle is not None or not valid.all():
        registration = register(jnp.asarray(np.asarray(mesh.vertices)), source, margin=margin)
        options = dict(method=args.method, twist=args.twist, margin=margin, beyond=args.beyond)
        if not valid.all():
            _print_causes(diagnose(registration, target, **options),
                          "bend less (the largest valid bend is below), or try another --method")
        sign = -1.0 if args.bend_angle is not None and args.bend_angle < 0 else 1.0
        angle = largest_valid_bend(registration, source, sign=sign, **options)
        radius = float(source.length) / angle if angle > 0 else float("inf")
        degrees = np.floor(100 * np.degrees(angle)) / 100  # rounded down: still valid
        # (Counted over the vertices a bend can keep valid: say which it cannot.)
        stuck = int(np.sum(~np.asarray(registration.valid)))
        print(
            f"largest bend of the rest spine keeping every vertex valid ({args.method}): "
            f"{degrees:.2f} degrees (arc radius {radius:.6g})"
            + (f", but the {stuck} outside the rest spine's reach, invalid at any bend"
               if stuck else "")
        )
    if not valid.all() and not args.allow_invalid:
        print(
            f"not written: {int(np.sum(~valid))} vertices are invalid and would be left in "
            "place, tearing the mesh around them; bend less, or pass --allow-invalid to write "
            "it anyway",
            file=sys.stderr,
        )
        return 3
    if is_mesh and _refused_stretch(args, _bend_stretch(mesh, bent, valid)):
        return 3
    write_mesh_atomic(bent, args.output)
    print(f"wrote {args.output} ({args.method}, {time.perf_counter() - started:.1f} s)")
    return 0


def _bend_stretch(mesh, bent, valid) -> list:
    """Prints and returns (`_refused_stretch`'s pairs) the largest change of length of an edge
    between two valid vertices of `bent`, and the largest principal stretch of the map at a
    valid vertex (`deform_mesh`'s `stretch`): the same rule as `pose`'s."""
    import numpy as np

    from ._mesh.stretch import edge_stretch

    edges = np.asarray(edge_stretch(mesh, np.asarray(bent.vertices), valid=valid))
    principal = np.asarray(bent.vertex_attributes["stretch"])
    principal = np.where(valid & np.isfinite(principal), principal, 1.0)
    worst_edge, worst_map = int(edges.argmax()), int(principal.argmax())
    print(f"largest edge stretch between valid vertices: {edges[worst_edge]:.3g}× (vertex "
          f"{worst_edge}); largest principal stretch of the map: {principal[worst_map]:.3g}× "
          f"(vertex {worst_map})")
    return [("an edge between valid vertices changes length", edges[worst_edge]),
            ("the bend stretches or squeezes the shape", principal[worst_map])]


def _found_rest_spine(mesh, args):
    import trimesh

    from ._skeleton.rest_spine import rest_spine

    if not (isinstance(mesh, trimesh.Trimesh) and mesh.is_watertight):
        raise ValueError(
            f"{args.input}: finding the rest spine needs a closed mesh; pass --cap-holes to "
            "close its holes, or give the rest spine with --from"
        )
    if args.medial is None:
        return rest_spine(mesh, ends=args.ends)
    from ._medial_axis.files import load_medial

    return rest_spine(load_medial(args.medial), ends=args.ends, surface=mesh)


def _print_volumes(mesh, bent, volume) -> None:
    import numpy as np

    closed = "" if mesh.is_watertight else " (mesh not closed: volumes approximate)"
    v0 = float(volume(np.asarray(mesh.vertices), mesh.faces))
    v1 = float(volume(np.asarray(bent.vertices), bent.faces))
    change = (v1 - v0) / v0 if v0 != 0 else float("nan")
    print(f"volume before: {v0:.9g}{closed}")
    print(f"volume after:  {v1:.9g} ({100 * change:+.4f}%)")
    if not mesh.is_watertight:
        print("advice: the mesh has holes; pass --cap-holes to close them (exact volumes)")


def _print_causes(causes, advice: str) -> None:
    """Prints `causes` (`fj.diagnose`'s counts), and `advice` where a smaller bend helps."""
    print(f"  outside the rest spine's reach: {causes.outside_source}")
    print(f"  beyond the rest spine's reach (the map is discontinuous there): "
          f"{causes.beyond_reach}")
    print(f"  beyond the method's bending limit: {causes.beyond_limit}")
    print(f"  outside the bent spine's reach: {causes.outside_target}")
    if causes.outside_source or causes.beyond_reach:
        print(
            "advice: vertices outside the rest spine's reach stay invalid for any bend: move "
            "the rest spine closer to them or make it straighter (its stretches that come "
            "close to each other, or bend tightly, tear the shape between them)"
        )
    if causes.beyond_limit or causes.outside_target:
        print(f"advice: {advice}")


def _medial(args) -> int:

    from ._medial_axis.construct import medial_mesh
    from ._medial_axis.distance import medial_distance
    from ._medial_axis.files import check_medial_path, save_medial
    from ._mesh.files import MESH_WRITABLE, check_output_path, write_mesh_atomic

    if not str(args.output).lower().endswith(".ma"):
        raise ValueError(f"{args.output}: the medial mesh is written in .ma format (OUT.ma)")
    check_medial_path(args.output)
    if args.envelope is not None:
        check_output_path(args.envelope, extensions=MESH_WRITABLE)
    if args.spheres < 2:
        raise ValueError(f"--spheres must be an integer >= 2, got {args.spheres}")
    if args.seed < 0:
        raise ValueError(f"--seed must be an integer >= 0, got {args.seed}")
    mesh = _welded_input(args.input, args.cap_holes)
    started = time.perf_counter()
    medial = medial_mesh(mesh, spheres=args.spheres, seed=args.seed)
    elapsed = time.perf_counter() - started
    to_envelope, to_surface = medial_distance(medial, mesh)
    save_medial(medial, args.output)
    centers, radii, edges, faces = medial.numpy()
    print(f"spheres: {len(radii)}, edges: {len(edges)}, faces: {len(faces)}")
    print(
        "one-sided Hausdorff distances (fraction of the diagonal): surface to envelope "
        f"{to_envelope:.4f}, envelope to surface {to_surface:.4f}"
    )
    if args.list:
        print(f"{'sphere':>6}  {'x':>10} {'y':>10} {'z':>10}  {'radius':>10}")
        for i, ((x, y, z), r) in enumerate(zip(centers, radii)):
            print(f"{i:>6}  {x:>10.5g} {y:>10.5g} {z:>10.5g}  {r:>10.5g}")
    print(f"wrote {args.output} in {elapsed:.1f} s")
    if args.envelope is not None:
        write_mesh_atomic(medial.envelope(), args.envelope)
        print(f"wrote {args.envelope}")
    return 0


def _welded_input(path, cap: bool):
    """The input mesh of the medial commands: an unwelded mesh (copies of vertices at seams,
    an STL's corners) is said so and welded first (its holes, if any, are closed after)."""
    import trimesh

    from ._mesh.holes import cap_holes

    mesh = _load_input(path, False)
    if not isinstance(mesh, trimesh.Trimesh) or not len(mesh.faces):
        return mesh
    welded = mesh.copy()
    welded.merge_vertices(merge_tex=True, merge_norm=True)
    copies = len(mesh.vertices) - len(welded.vertices)
    if copies:
        print(f"note: {path} is unwelded: {copies} vertices are copies of others (seams); "
              "welded by position")
        mesh = welded
    return cap_holes(mesh) if cap else mesh
def _handles_format() -> str:
    from ._medial_deform.handle_files import HANDLES_FORMAT

    return HANDLES_FORMAT


def _medial_deform(args) -> int:
    import numpy as np
    import trimesh

    from ._medial_axis.files import load_medial
    from ._medial_deform.deform import deform_medial
    from ._medial_deform.handle_files import load_handles
    from ._mesh.files import MESH_WRITABLE, check_output_path, write_mesh_atomic
    from ._mesh.volume import volume

    check_output_path(args.output, extensions=MESH_WRITABLE)
    medial = load_medial(args.medial)
    handles, targets, rotations = load_handles(args.handles, medial)
    mesh = _load_input(args.input, False)
    if not (isinstance(mesh, trimesh.Trimesh) and len(mesh.faces)):
        raise ValueError(f"{args.input}: medial-deform needs a mesh with faces")
    # The output keeps IN's vertices (seams included: the rig poses copies as one); the
    # volumes are measured on the welded mesh, closed when only the welding was missing.
    welded = mesh.copy()
    welded.merge_vertices(merge_tex=True, merge_norm=True)
    if len(welded.vertices) < len(mesh.vertices):
        print(f"note: {args.input} is unwelded: {len(mesh.vertices) - len(welded.vertices)} "
              "vertices are copies of others (seams); they move as one")
    if args.cap_holes and not welded.is_watertight:
        from ._mesh.holes import cap_holes

        mesh = welded = cap_holes(welded)  # welded first: its seams are no holes
    started = time.perf_counter()
    try:
        bent = deform_medial(mesh, medial, handles, targets, args.method, rotations=rotations,
                             implicit=not args.no_implicit)
    except ValueError as error:
        raise ValueError(f"{args.handles} with {args.medial}: {error}") from None
    valid = np.asarray(bent.vertex_attributes["valid"], dtype=bool)
    if not np.isfinite(np.asarray(bent.vertices)).all():  # never written, whatever happened
        raise ValueError(f"{args.input}: the deformed mesh is not finite; nothing written")
    _print_volumes(welded if welded.is_watertight else mesh, bent, volume)
    print(f"invalid vertices: {int(np.sum(~valid))} of {len(valid)}")
    write_mesh_atomic(bent, args.output)
    print(f"wrote {args.output} ({args.method}, {time.perf_counter() - started:.1f} s)")
    return 0


def _skeleton(args) -> int:
    import numpy as np

    from ._mesh.files import check_output_path
    from ._skeleton.build import skeleton
    from ._skeleton.files import save_skeleton
    from ._skeleton.regions import spine_samples

    check_output_path(args.output, extensions=("json",))
    if args.png is not None:
        if not args.png.lower().endswith(".png"):
            raise ValueError(f"--png {args.png}: the picture is written as PNG (FILE.png)")
        check_output_path(args.png, extensions=("png",))
    if args.spheres < 2:
        raise ValueError(f"--spheres must be an integer >= 2, got {args.spheres}")
    if args.seed < 0:
        raise ValueError(f"--seed must be an integer >= 0, got {args.seed}")
    mesh = _load_input(args.input, args.cap_holes)
    started = time.perf_counter()
    try:
        found = skeleton(mesh, spheres=args.spheres, seed=args.seed)
    except (ValueError, TypeError) as error:
        raise ValueError(f"{args.input}: {_with_cap_advice(error)}") from None
    elapsed = time.perf_counter() - started
    region = np.asarray(found.region)
    print(f"{'limb':>4} {'parent':>6} {'length':>10} {'joint':>10} {'vertices':>8}  end point")
    for i, limb in enumerate(found.limbs):
        end = np.asarray(spine_samples(limb.spine, 2)[1])[-1]
        print(f"{i:>4} {limb.parent:>6} {float(limb.spine.length):>10.5g} "
              f"{float(limb.joint):>10.5g} {int(np.sum(region == i)):>8}  "
              f"{end[0]:.5g},{end[1]:.5g},{end[2]:.5g}")  # fmt: skip
    print(f"body: {int(np.sum(region == -1))} vertices")
    save_skeleton(found, args.output)
    print(f"wrote {args.output} ({len(found.limbs)} limbs, {elapsed:.1f} s)")
    if args.png is not None:
        from ._skeleton.plot import save_png

        save_png(mesh, found, args.png)  # Agg, atomically
        print(f"wrote {args.png}")
    return 0


def _with_cap_advice(error: Exception) -> str:
    """The library's message, with the option that closes holes where it says to close them."""
    text = str(error)
    return text + " (here: pass --cap-holes)" if "fj.cap_holes" in text else text


POSES_LIMIT = 1 << 20  # bytes of a poses file
POSE_KEYS = {"limb", "at", "bend", "direction", "twist"}


def _read_poses(path) -> list[dict]:
    """The limbs' groups of a poses file (`POSES_FORMAT`), checked."""
    import json
    from pathlib import Path

    from ._checks import check_readable_file

    path = Path(path)
    check_readable_file(path, "poses file", POSES_LIMIT)
    try:
        groups = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not a JSON poses file ({error})") from None
    if not isinstance(groups, list) or not all(isinstance(g, dict) for g in groups):
        raise ValueError(f"{path}: a poses file is a list of objects (see --help)")
    if not groups:
        raise ValueError(f"{path}: the poses file lists no pose (nothing to write)")
    for g in groups:
        unknown = set(g) - POSE_KEYS
        if unknown or ("limb" in g) == ("at" in g) or "bend" not in g:
            raise ValueError(f"{path}: each pose names its limb by \"limb\" or \"at\" and has "
                             f"a \"bend\"; got {json.dumps(g)}")
    return groups


def _limb_poses(groups: list[dict], skeleton, source: str) -> dict:
    """`{limb: LimbPose}` from the groups (a limb named by index or by a point)."""
    from ._skeleton.limb_pose import LimbPose

    poses = {}
    for g in groups:
        if "bend" not in g:
            raise ValueError(f"{source}: limb {g.get('limb', g.get('at'))} has no --bend")
        if "at" in g:
            at = g["at"]
            limb = skeleton.limb_at(at)
            if limb < 0:
                raise ValueError(f"{source}: the point {at} lies on the body, not on a limb")
        else:
            limb, names = g["limb"], skeleton.names
            if isinstance(limb, str) and limb and limb in names:
                limb = names.index(limb)
            elif isinstance(limb, bool) or not isinstance(limb, int) or not (
                0 <= limb < len(skeleton.limbs)
            ):
                named = [name for name in names if name]
                raise ValueError(f"{source}: no limb {limb!r}; the skeleton has limbs 0 to "
                                 f"{len(skeleton.limbs) - 1}"
                                 + (f", named {', '.join(named)}" if named else ""))
        if limb in poses:
            raise ValueError(f"{source}: limb {limb} is posed twice")
        angles = [g.get(name, 0.0) for name in ("bend", "direction", "twist")]
        if not all(isinstance(a, int | float) and abs(a) < float("inf") for a in angles):
            raise ValueError(f"{source}: limb {limb}'s angles must be finite numbers of degrees")
        poses[limb] = LimbPose(*(float(a) for a in angles))
    return poses


def _pose(args) -> int:
    import numpy as np
    import trimesh

    from ._mesh.files import MESH_WRITABLE, check_output_path, write_mesh_atomic
    from ._mesh.holes import cap_holes
    from ._mesh.stretch import edge_stretch
    from ._mesh.volume import volume
    from ._skeleton.joint_zone import joint_range
    from ._skeleton.posing import limb_causes, placed_poses, pose_skeleton, register_skeleton
    from ._skeleton.stretch import pose_stretch

    check_output_path(args.output, extensions=MESH_WRITABLE)
    groups = getattr(args, "limbs", None) or []
    if bool(groups) == (args.poses is not None):
        raise ValueError("give the limbs' poses with --limb/--at groups or with --poses (one)")
    if args.poses is not None:
        groups = _read_poses(args.poses)
    given = _load_input(args.input, False)
    if not (isinstance(given, trimesh.Trimesh) and len(given.faces)):
        raise ValueError(f"{args.input}: posing needs a triangle mesh")
    # Capped, the input's vertices come first: posed, they are written with its own faces.
    mesh = cap_holes(given) if args.cap_holes else given
    started = time.perf_counter()
    if args.skeleton is not None:
        from ._skeleton.files import load_skeleton

        skeleton = load_skeleton(args.skeleton)
    else:
        from ._skeleton.build import skeleton as find_skeleton

        try:
            skeleton = find_skeleton(mesh, spheres=args.spheres)
        except (ValueError, TypeError) as error:
            raise ValueError(f"{args.input}: {_with_cap_advice(error)}") from None
        print(f"skeleton (medial axis): {len(skeleton.limbs)} limbs")
    rest = np.asarray(skeleton.vertices)
    if len(rest) > len(mesh.vertices) and np.allclose(  # (to the file's rounding)
            rest[: len(mesh.vertices)], mesh.vertices, rtol=0, atol=1e-6 * mesh.scale):
        raise ValueError(f"{args.skeleton}: the skeleton is {args.input}'s with its holes "
                         "closed (`skeleton --cap-holes`): pass --cap-holes")
    poses = _limb_poses(groups, skeleton, args.poses or "--limb/--at")
    registration = register_skeleton(mesh, skeleton)
    posed = pose_skeleton(registration, skeleton, poses, method=args.method)
    bent = mesh.copy()
    bent.vertices = np.asarray(posed.vertices)
    valid = np.asarray(posed.valid)
    _print_volumes(mesh, bent, volume)
    for limb, pose in poses.items():
        print(f"limb {limb}: bend {float(pose.bend):g}, direction {float(pose.direction):g}, "
              f"twist {float(pose.twist):g} degrees")
    print(f"invalid vertices: {int(np.sum(~valid))} of {len(valid)}")
    stretch = np.asarray(edge_stretch(mesh, posed.vertices))
    worst = _print_largest("edge stretch", stretch, skeleton)
    # The map's own stretch catches a cross-section pressed flat whose edges barely change.
    principal = np.nan_to_num(np.asarray(pose_stretch(registration, skeleton, poses,
                                                      method=args.method)), nan=1.0)
    squeezed = _print_largest("principal stretch of the map", principal, skeleton)
    if not valid.all():
        # (With the bends a free child carries on past its parent's range: `spill`.)
        _, carried, _ = placed_poses(registration, skeleton, poses)
        for limb, causes in limb_causes(registration, skeleton, poses, args.method).items():
            if causes.invalid:
                print(f" limb {limb}:")
                pose = carried[limb]  # (a bend the other way: towards the opposite direction)
                towards = float(pose.direction) + (180.0 if float(pose.bend) < 0 else 0.0)
                # (Its children ride on its bend, or a free only child carries it on, unless
                # posed.)
                whole = registration.wholes[limb]
                children = whole.below if whole is not None else registration.children[limb]
                largest = np.floor(100 * float(joint_range(
                    registration, limb, towards, twist=float(pose.twist),
                    children_posed=bool(set(children) & set(poses))))) / 100
                bend = (f"bend limb {limb}" if limb in poses else
                        f"limb {limb} carries its parent's bend on past the parent's range: "
                        f"it takes")
                free = whole is None and not set(children) & set(poses) and len(children) == 1
                carried_on = f", limb {children[0]} carrying the rest on" if free else ""
                _print_causes(causes, f"{bend} at most {largest:.2f} degrees (its exact "
                                      f"range at its joint in this direction{carried_on}), or "
                                      "try another --method")
        if not args.allow_invalid:
            print(f"not written: {int(np.sum(~valid))} vertices are posed inexactly (past "
                  "their joint's range: placed continuously, the volume not kept there); bend "
                  "less, or pass --allow-inexact to write it anyway", file=sys.stderr)
            return 3
    if _refused_stretch(args, (("the pose stretches or squeezes the shape",
                                principal[squeezed]),
                               ("an edge changes length", stretch[worst]))):
        return 3
    if bent.vertices.shape != given.vertices.shape:  # (capped: the caps dropped)
        bent = trimesh.Trimesh(bent.vertices[: len(given.vertices)], given.faces, process=False)
    write_mesh_atomic(bent, args.output)
    print(f"wrote {args.output} ({args.method}, {time.perf_counter() - started:.1f} s)")
    return 0


def _print_largest(what: str, factor, skeleton) -> int:
    """Prints the largest of `factor` (n,) per vertex, with its limb; returns its vertex."""
    worst = int(factor.argmax())
    where = int(skeleton.region[worst])
    print(f"largest {what}: {factor[worst]:.3g}× "
          f"({f'limb {where}' if where >= 0 else 'body'}, vertex {worst})")
    return worst


def _demo(args) -> int:
    from ._demo import format_table, run_demo

    started = time.perf_counter()
    rows = run_demo(args.out, log=lambda message: print(message, file=sys.stderr))
    print(format_table(rows))
    print(f"wrote meshes and demo.png to {args.out}/ in {time.perf_counter() - started:.1f} s")
    return 0


COMMANDS = {
    "deform": _deform,
    "medial": _medial,
    "medial-deform": _medial_deform,
    "skeleton": _skeleton,
    "pose": _pose,
    "demo": _demo,
}


def _values_attached(argv: list[str]) -> list[str]:
    """`argv` with the point after each `--at` attached to it (`--at=-2.9,0,0`): argparse
    would take a point starting with a minus for an option."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--at" and i + 1 < len(argv) and re.match(r"-[\d.]", argv[i + 1]):
            out.append(f"--at={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    """Runs the command line with `argv` (default: `sys.argv[1:]`); returns the exit status."""
    parser = _parser()
    try:
        args = parser.parse_args(_values_attached(sys.argv[1:] if argv is None else argv))
    except SystemExit as exit_:  # argparse has printed its usage or version message
        return int(exit_.code or 0)
    try:
        from ._cache import enable_compilation_cache

        enable_compilation_cache()
        return COMMANDS[args.command](args)
    except (FileNotFoundError, ValueError, TypeError, OSError) as error:
        message = " ".join(str(error).split()) or type(error).__name__
        print(f"{PROG}: error: {message}", file=sys.stderr)
        return 2
    except (ArithmeticError, RecursionError, MemoryError) as error:
        # Unexpected, but still one line and status 2, never a traceback: inputs so large
        # that a computation overflows, or that do not fit in memory.
        what = {MemoryError: "out of memory"}.get(type(error), type(error).__name__)
        message = " ".join(str(error).split())
        print(f"{PROG}: error: {args.command} {getattr(args, 'input', '')}: {what}"
              + (f" ({message})" if message else "") + "; inputs too large?", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""The `fleshing-jax` command line.

    fleshing-jax deform IN OUT --from A.json --to B.json [--method radial] [--twist RAD]
    fleshing-jax demo [--out DIR]

Expected failures (missing file, malformed spine, unreadable mesh, unwritable output) print one
line `fleshing-jax: error: …` on stderr and exit with status 2; OUT is written atomically.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ._fleshing.methods import METHODS

PROG = "fleshing-jax"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Spine-driven bending of 3D shapes with local volume preservation.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    deform = commands.add_parser(
        "deform",
        help="bend a mesh or point cloud from one spine to another",
        description="Bend IN (any format trimesh reads) from the spine --from to the spine "
        "--to and write OUT in the format of its extension.",
    )
    deform.add_argument("input", metavar="IN", help="input mesh or point cloud")
    deform.add_argument("output", metavar="OUT", help="output file; its extension sets the format")
    deform.add_argument(
        "--from", dest="source", required=True, metavar="A.json", help="source spine (JSON)"
    )
    deform.add_argument(
        "--to", dest="target", required=True, metavar="B.json", help="target spine (JSON)"
    )
    deform.add_argument(
        "--method",
        choices=METHODS,
        default="radial",
        help="fleshing method (default: radial; skinning is the baseline)",
    )
    deform.add_argument(
        "--twist",
        type=float,
        default=0.0,
        metavar="RAD",
        help="global twist in radians (default: 0)",
    )
    demo = commands.add_parser(
        "demo",
        help="bend a built-in creature with the four methods; write meshes, a figure, a table",
    )
    demo.add_argument(
        "--out",
        default="fleshing-demo",
        metavar="DIR",
        help="output folder (default: ./fleshing-demo)",
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


def _deform(args) -> int:
    import trimesh

    from ._mesh.deform import deform_mesh
    from ._mesh.files import load_mesh, write_mesh_atomic
    from ._mesh.volume import volume
    from ._spines.files import load_spine

    source, target = load_spine(args.source), load_spine(args.target)
    mesh = load_mesh(args.input)
    started = time.perf_counter()
    bent = deform_mesh(
        mesh,
        source,
        target,
        method=args.method,
        twist=args.twist,
        progress=_Progress(f"{args.method}: vertices"),
    )
    if isinstance(bent, trimesh.Trimesh):
        valid = bent.vertex_attributes["valid"]
        if len(bent.faces):
            closed = "" if mesh.is_watertight else " (mesh not closed: volumes approximate)"
            v0 = float(volume(np.asarray(mesh.vertices), mesh.faces))
            v1 = float(volume(np.asarray(bent.vertices), bent.faces))
            change = (v1 - v0) / v0 if v0 != 0 else float("nan")
            print(f"volume before: {v0:.9g}{closed}")
            print(f"volume after:  {v1:.9g} ({100 * change:+.4f}%)")
    else:
        valid = bent.metadata["valid"]
    write_mesh_atomic(bent, args.output)
    print(f"invalid vertices: {int(np.sum(~valid))} of {len(valid)}")
    print(f"wrote {args.output} ({args.method}, {time.perf_counter() - started:.1f} s)")
    return 0


def _demo(args) -> int:
    from ._demo import format_table, run_demo

    started = time.perf_counter()
    rows = run_demo(args.out, log=lambda message: print(message, file=sys.stderr))
    print(format_table(rows))
    print(f"wrote meshes and demo.png to {args.out}/ in {time.perf_counter() - started:.1f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Runs the command line with `argv` (default: `sys.argv[1:]`); returns the exit status."""
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # argparse has printed its usage message
        return int(exit_.code or 0)
    try:
        return _deform(args) if args.command == "deform" else _demo(args)
    except (FileNotFoundError, ValueError, TypeError, OSError) as error:
        message = " ".join(str(error).split()) or type(error).__name__
        print(f"{PROG}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

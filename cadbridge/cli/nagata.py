"""`cadbridge nagata`: Nagata tool file and report from a mesh (and the CAD's normals)."""

from __future__ import annotations

import argparse

from cadbridge.cli.options import add_edge_rule_option, add_normal_options, edge_rule
from cadbridge.common.errors import EXIT_OK, UsageError
from cadbridge.common.progress import Progress, say


def cmd_nagata(args: argparse.Namespace) -> int:
    from cadbridge.tool.pipeline import nagata_from_mesh

    rule = edge_rule(args)
    if args.method == "cad" and not args.cad:
        raise UsageError("--method cad (the default) needs --cad FILE.igs; or pick an estimator, e.g. --method mwe")
    with Progress("cadbridge nagata") as progress:
        result = nagata_from_mesh(
            args.mesh, cad=args.cad, output=args.output, method=args.method, name=args.name,
            report=not args.no_report, tolerance=args.tolerance, flip=args.flip, allow_far=args.allow_far,
            grid=args.grid, progress=progress, orient=args.orient, allow_worse=args.allow_worse, edge_rule=rule,
        )
    say(result.summary())
    return EXIT_OK


def register(sub, fmt) -> None:
    p = sub.add_parser("nagata", help="Nagata tool file and report from a mesh (+ CAD normals)", formatter_class=fmt,
                       epilog="example:\n  cadbridge nagata die.msh --cad die.igs -o die_tool/")
    p.add_argument("mesh", help="mesh file readable by meshio")
    p.add_argument("--cad", help="IGES or STEP file (exact normals and shape errors)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--name", help="tool name (default from the CAD names or the mesh file name)")
    p.add_argument("--grid", type=int, default=10, help="grid divisions per patch for errors and viewing")
    p.add_argument("--allow-worse", action="store_true",
                   help="write a tool even if its Nagata surface is worse than its flat mesh (for inspection)")
    p.add_argument("--no-report", action="store_true", help="only the tool file")
    add_normal_options(p)
    add_edge_rule_option(p)
    p.set_defaults(func=cmd_nagata)

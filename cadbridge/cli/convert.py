"""`cadbridge convert`: mesh + normals + Nagata + report in one go."""

from __future__ import annotations

import argparse

from cadbridge.cli.options import add_edge_rule_option, add_mesh_options, add_normal_options, edge_rule, no_qit_refinement
from cadbridge.common.errors import EXIT_OK
from cadbridge.common.progress import Progress, say


def cmd_convert(args: argparse.Namespace) -> int:
    from cadbridge.tool.pipeline import convert

    no_qit_refinement(args)
    rule = edge_rule(args)
    with Progress("cadbridge convert") as progress:
        result = convert(
            args.cad, args.output, element=args.element, size=args.size, structured=args.structured,
            radius_divisions=args.radius_divisions, length_divisions=args.length_divisions,
            curvature_elements=args.curvature_elements, method=args.method, grid=args.grid, flip=args.flip, tolerance=args.tolerance, progress=progress,
            allow_worse=args.allow_worse, shape_tolerance=args.shape_tolerance, min_size=args.min_size,
            mesher=args.mesher, full_report=args.full_report, edge_rule=rule,
        )
    if getattr(result, "adaptive", None) is not None:
        say(result.adaptive.summary())
    say(result.summary())
    return EXIT_OK


def register(sub, fmt) -> None:
    p = sub.add_parser("convert", help="mesh + normals + Nagata + report in one go", formatter_class=fmt,
                       epilog="example:\n  cadbridge convert die.igs -o die_out/ --element quad --size 5")
    p.add_argument("cad", help="IGES or STEP file")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--grid", type=int, default=10, help="grid divisions per patch for errors and viewing")
    p.add_argument("--allow-worse", action="store_true",
                   help="write a tool even if its Nagata surface is worse than its flat mesh (for inspection)")
    p.add_argument("--full-report", action="store_true",
                   help="also the per-patch listings (grid CSV, coefficient listing, Nagata IGES) of tools above "
                        "50 000 elements (default: only up to that size)")
    add_mesh_options(p)
    add_normal_options(p)
    add_edge_rule_option(p)
    p.set_defaults(func=cmd_convert)

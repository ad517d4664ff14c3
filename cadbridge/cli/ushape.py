"""`cadbridge ushape`: the NUMISHEET'93 U-shape benchmark (thesis §5.2, Fig. 49)."""

from __future__ import annotations

import argparse

from cadbridge.cli.options import add_edge_rule_option, add_mesher_option, edge_rule
from cadbridge.common.errors import EXIT_OK
from cadbridge.common.progress import Progress, say


def cmd_ushape(args: argparse.Namespace) -> int:
    from cadbridge.ushape.benchmark import run_ushape

    rule = edge_rule(args)
    with Progress("cadbridge ushape") as progress:
        summary = run_ushape(args.output, grid=args.grid, fine_size=args.fine_size, progress=progress,
                             mesher=args.mesher, edge_rule=rule)
    say(summary.table())
    say("")
    say("\n".join(summary.findings("die")))
    say(f"wrote {len(summary.run['files'])} files to {args.output} in {summary.run['seconds']:.1f} s")
    return EXIT_OK


def register(sub, fmt) -> None:
    p = sub.add_parser("ushape", help="the NUMISHEET'93 U-shape benchmark (thesis §5.2, Fig. 49)", formatter_class=fmt,
                       epilog="example:\n  cadbridge ushape -o out/")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--grid", type=int, default=20, help="grid divisions per patch")
    p.add_argument("--fine-size", type=float, default=4.0, help="element size of the unstructured triangle variant (mm)")
    add_mesher_option(p, "the unstructured triangle variant")
    add_edge_rule_option(p)
    p.set_defaults(func=cmd_ushape)

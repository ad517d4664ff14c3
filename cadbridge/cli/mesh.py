"""`cadbridge mesh`: the mesh stage of `convert`, written to a mesh file."""

from __future__ import annotations

import argparse

from cadbridge.cli.options import add_mesh_options, no_qit_refinement
from cadbridge.common.errors import EXIT_OK
from cadbridge.common.progress import Progress, say


def cmd_mesh(args: argparse.Namespace) -> int:
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.io import write_mesh

    from cadbridge.heal.creases import crease_lines
    from cadbridge.iges import read_iges

    no_qit_refinement(args)
    if getattr(args, "shape_tolerance", None) is not None:  # sized and refined for a Nagata tolerance
        from cadbridge.tool.refine import mesh_command

        with Progress("cadbridge mesh") as progress:
            return mesh_command(args, progress, say)
    from cadbridge.heal.mesh_source import mesh_source

    model = read_iges(args.cad)
    creases = crease_lines(model)  # C0 knot lines inside faces become mesh edges
    with mesh_source(args.cad, model) as source:  # faces the reader re-read: meshed as it read them
        mesh = mesh_cad(
            source,
            element=args.element,
            size=args.size,
            structured=args.structured,
            radius_divisions=args.radius_divisions,
            length_divisions=args.length_divisions,
            curvature_elements=args.curvature_elements,
            embed_curves=[c.curve for c in creases],
            mesher=args.mesher,
        )
    write_mesh(mesh, args.output)
    n_el = sum(len(b.data) for b in mesh.cells)
    say(f"wrote {args.output}: {len(mesh.nodes)} nodes, {n_el} elements")
    return EXIT_OK


def register(sub, fmt) -> None:
    p = sub.add_parser("mesh", help="mesh the CAD with gmsh", formatter_class=fmt,
                       epilog="example:\n  cadbridge mesh die.igs -o die.msh --element quad --structured --radius-divisions 3")
    p.add_argument("cad", help="IGES file")
    p.add_argument("-o", "--output", required=True, help="mesh file (.msh, .vtu, .inp, .bdf, .stl, .obj, GiD .msh via --gid)")
    add_mesh_options(p)
    p.set_defaults(func=cmd_mesh)

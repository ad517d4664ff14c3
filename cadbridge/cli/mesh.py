"""`cadbridge mesh`: the mesh stage of `convert`, written to a mesh file."""

from __future__ import annotations

import argparse

from cadbridge.cli.options import add_mesh_options, no_qit_refinement
from cadbridge.common.errors import EXIT_OK
from cadbridge.common.progress import Progress, say


def cmd_mesh(args: argparse.Namespace) -> int:
    no_qit_refinement(args)
    if getattr(args, "shape_tolerance", None) is not None:  # sized and refined for a Nagata tolerance
        from cadbridge.tool.refine import mesh_command

        with Progress("cadbridge mesh") as progress:
            return mesh_command(args, progress, say)
    from cadbridge.mesh.io import write_mesh
    from cadbridge.tool.build import tools_from_mesh
    from cadbridge.tool.meshing import read_healed
    from cadbridge.tool.pipeline import guarded_mesh

    with Progress("cadbridge mesh") as progress:  # the mesh `convert` builds its tools on
        model, excursions = read_healed(args.cad, progress)
        guarded = guarded_mesh(
            args.cad, model, excursions=excursions, progress=progress, unchecked_ok=True,
            build=lambda m: tools_from_mesh(m, model, progress=progress, orient=True, meshed_per_face=True,
                                            measure=False),  # the guards of convert, without its error measures
            element=args.element, size=args.size, structured=args.structured,
            radius_divisions=args.radius_divisions, length_divisions=args.length_divisions,
            curvature_elements=args.curvature_elements, mesher=args.mesher,
        )
        mesh, notes = guarded.mesh, guarded.mesh_notes + guarded.notes
        write_mesh(mesh, args.output)
    say(f"wrote {args.output}: {len(mesh.nodes)} nodes, {mesh.n_elements} elements")
    for n in notes:
        say(f"  {n}")
    return EXIT_OK


def register(sub, fmt) -> None:
    p = sub.add_parser("mesh", help="mesh the CAD with gmsh (the mesh stage of convert)", formatter_class=fmt,
                       epilog="example:\n  cadbridge mesh die.igs -o die.msh --element quad --structured --radius-divisions 3\n"
                       "  cadbridge nagata die.msh --cad die.igs -o die_tool/   # the tools convert makes")
    p.add_argument("cad", help="IGES or STEP file")
    p.add_argument("-o", "--output", required=True, help="mesh file (.msh, .vtu, .inp, .bdf, .stl, .obj, GiD .msh via --gid)")
    add_mesh_options(p)
    p.set_defaults(func=cmd_mesh)

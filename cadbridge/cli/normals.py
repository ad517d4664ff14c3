"""`cadbridge normals`: node normals of a mesh, exact from the CAD or estimated, as VTU."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from cadbridge.cli.options import add_normal_options
from cadbridge.common.errors import EXIT_OK, UsageError
from cadbridge.common.progress import say


def cmd_normals(args: argparse.Namespace) -> int:
    from cadbridge.io.vtu import write_mesh_vtu
    from cadbridge.mesh.io import read_mesh

    if args.method == "cad" and not args.cad:
        raise UsageError("--method cad (the default) needs --cad FILE.igs; or pick an estimator, e.g. --method mwe")
    from cadbridge.tool.build import consistently_oriented, tool_normals
    from cadbridge.tool.meshing import read_healed

    mesh = consistently_oriented(read_mesh(args.mesh), args.orient)
    model = read_healed(args.cad)[0] if args.cad else None  # as convert and nagata read it
    # the normals stage of convert and nagata (the fold rule applied to CAD normals)
    normals, _, _, _, _, cn = tool_normals(mesh, model, args.method, tolerance=args.tolerance, flip=args.flip,
                                           allow_far=args.allow_far)
    source = args.method
    point_data = {"normal": normals}
    if cn is not None:
        point_data.update(face_id=cn.face, distance=cn.distance, status=cn.status, crease=cn.crease.astype(np.int32))
    out = args.output or str(Path(args.mesh).with_suffix(".normals.vtu"))
    write_mesh_vtu(
        out,
        mesh.nodes,
        [(b.type, np.asarray(b.data)) for b in mesh.cells],
        point_data=point_data,
        field_data={"normal_source": source},
    )
    msg = f"wrote {out}: {len(mesh.nodes)} node normals from {source}"
    if cn is not None:
        msg += f"; max node-to-CAD distance {np.nanmax(cn.distance):.3g}, {int(cn.crease.sum())} crease nodes"
        far = cn.far_nodes()
        if len(far):
            msg += f"; {len(far)} nodes beyond tolerance (allowed by --allow-far)"
    say(msg)
    return EXIT_OK


def register(sub, fmt) -> None:
    p = sub.add_parser("normals", help="node normals of a mesh: exact from CAD or estimated", formatter_class=fmt,
                       epilog="example:\n  cadbridge normals die.msh --cad die.igs -o die_normals.vtu\n"
                       "  cadbridge normals die.msh --method mwselr")
    p.add_argument("mesh", help="mesh file readable by meshio")
    p.add_argument("--cad", help="IGES or STEP file (needed for --method cad)")
    p.add_argument("-o", "--output", help="output VTU (default MESH.normals.vtu)")
    add_normal_options(p)
    p.set_defaults(func=cmd_normals)

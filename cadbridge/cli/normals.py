"""`cadbridge normals`: node normals of a mesh, exact from the CAD or estimated, as VTU."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from cadbridge.cli.options import add_normal_options
from cadbridge.common.errors import EXIT_OK, UsageError
from cadbridge.common.progress import say


def _normals_for(mesh, args, model=None):
    """(node normals (N,3), corner normals per block, source label, CadNormals|None)."""
    from cadbridge.normals.cad import cad_normals
    from cadbridge.normals.estimators import estimate_normals

    if args.method == "cad":
        cn = cad_normals(mesh, model, tolerance=args.tolerance, flip=args.flip, allow_far=args.allow_far,
                         orient=getattr(args, "orient", False))
        return cn.normals, cn.corner_normals, "cad", cn
    blocks = [np.asarray(b.data) for b in mesh.cells]
    n = estimate_normals(mesh.nodes, blocks, method=args.method)
    if args.flip:
        n = -n
    return n, [n[b] for b in blocks], args.method, None


def cmd_normals(args: argparse.Namespace) -> int:
    from cadbridge.io.vtu import write_mesh_vtu
    from cadbridge.mesh.io import read_mesh

    if args.method == "cad" and not args.cad:
        raise UsageError("--method cad (the default) needs --cad FILE.igs; or pick an estimator, e.g. --method mwe")
    from cadbridge.tool.build import consistently_oriented

    mesh = consistently_oriented(read_mesh(args.mesh), args.orient)
    model = None
    if args.cad:
        from cadbridge.iges import read_iges

        model = read_iges(args.cad)
    normals, corners, source, cn = _normals_for(mesh, args, model)
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
    p.add_argument("--cad", help="IGES file (needed for --method cad)")
    p.add_argument("-o", "--output", help="output VTU (default MESH.normals.vtu)")
    add_normal_options(p)
    p.set_defaults(func=cmd_normals)

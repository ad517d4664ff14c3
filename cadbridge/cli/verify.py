"""`cadbridge verify`: cadbridge's reading of a CAD file against OpenCASCADE's, face by face."""

from __future__ import annotations

import argparse

from cadbridge.common.errors import EXIT_CHECK_FAILED, EXIT_OK
from cadbridge.common.progress import say


def cmd_verify(args: argparse.Namespace) -> int:
    from cadbridge.verify.faces import verify

    report = verify(args.cad, n_samples=args.samples, tol_pos=args.tol_pos, tol_der=args.tol_der, tol_ang=args.tol_ang)
    say(report.format())
    return EXIT_OK if report.ok else EXIT_CHECK_FAILED


def register(sub, fmt) -> None:
    p = sub.add_parser("verify", help="compare our reading of an IGES or STEP file with OpenCASCADE", formatter_class=fmt,
                       epilog="example:\n  cadbridge verify iges_samples/ushape_die_nurbs.igs   # exit 1 if any face deviates")
    p.add_argument("cad", help="IGES or STEP file")
    p.add_argument("--samples", type=int, default=200, help="random (u, v) per face (default 200)")
    p.add_argument("--tol-pos", type=float, default=1e-9, help="position tolerance, relative to model size")
    p.add_argument("--tol-der", type=float, default=1e-8, help="derivative tolerance, relative")
    p.add_argument("--tol-ang", type=float, default=1e-9, help="normal angle tolerance, radians")
    p.set_defaults(func=cmd_verify)

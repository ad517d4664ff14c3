"""`cadbridge fit`: a NURBS surface fitted to points (scan, FE nodes, Nagata tool), written as IGES.

    cadbridge fit POINTS -o surface.igs [--degree 3] [--tolerance 0.01]
                  [--base CAD.igs | --base-curves CURVES.igs | --plane]
                  [--smoothing W] [--max-ctrl 60x60] [--trim]

Prints the report (max / RMS deviation, which stop criterion, control net, outliers) and writes,
beside the IGES, STEM_report.txt/.json, STEM_deviation.vtu/.png and STEM_beyond.csv (atomically).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

__all__ = ["cmd_fit", "register"]


def _net(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*(?:[xX*,]\s*(\d+))?\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"expected NUxNV, e.g. 60x60, got {text!r}")
    a = int(m.group(1))
    b = int(m.group(2) or a)
    return a, b


def cmd_fit(args: argparse.Namespace) -> int:
    from cadbridge.common.errors import CheckFailed, UsageError
    from cadbridge.common.progress import Progress, say
    from cadbridge.fitting.surface_fit import FitInputError, fit_points, read_points, write_fit_outputs
    from cadbridge.nurbs.fit import FitError

    if not args.tolerance > 0:
        raise UsageError(f"--tolerance must be > 0, got {args.tolerance}")
    if args.smoothing < 0:
        raise UsageError(f"--smoothing must be >= 0, got {args.smoothing}")
    if not 1 <= args.degree <= 9:
        raise UsageError(f"--degree must be 1..9, got {args.degree}")
    if args.max_distance is not None and not args.max_distance > 0:
        raise UsageError(f"--max-distance must be > 0, got {args.max_distance}")
    if args.noise is not None and args.noise < 0:
        raise UsageError(f"--noise must be >= 0, got {args.noise}")
    p = args.degree
    if min(args.max_ctrl) < p + 1:
        raise UsageError(f"--max-ctrl {args.max_ctrl[0]}x{args.max_ctrl[1]} is below degree + 1 = {p + 1}")
    out = Path(args.output)
    if not out.parent.is_dir() and str(out.parent):
        raise UsageError(f"{out}: directory {out.parent} does not exist")
    if args.rational and not args.base:
        raise UsageError("--rational takes its weights from the base surface: give --base CAD.igs")
    try:
        with Progress("cadbridge fit") as progress:
            progress.stage(f"reading {args.points}")
            pts, kind = read_points(args.points, nagata_samples=args.nagata_samples)
            base = "plane"
            units = None
            base_name = "given base surface"
            if args.base:
                from cadbridge.formats import read_cad

                progress.stage(f"reading the base {args.base}")
                base = read_cad(args.base)
                units = base.units
            elif args.base_curves:
                from cadbridge.fitting.boundary_curves import coons_base, read_boundary_curves

                progress.stage(f"reading the boundary curves {args.base_curves}")
                base = coons_base(read_boundary_curves(args.base_curves))
                base_name = f"Coons patch of the 4 boundary curves of {Path(args.base_curves).name}"
            noise = args.noise
            if noise is None and kind in ("tool nodes", "Nagata samples"):
                noise = 0.0  # computed points are exact
            report = fit_points(pts, base=base, face=args.face, degree=p, tolerance=args.tolerance,
                                smoothing=args.smoothing, max_ctrl=tuple(args.max_ctrl), trim=args.trim,
                                rational=args.rational, noise=noise, robust=None if args.no_robust else "tukey",
                                max_distance=args.max_distance,
                                source=f"{kind} of {Path(args.points).name}", name=args.name, base_name=base_name,
                                progress=progress)
            progress.stage("writing")
            written = write_fit_outputs(report, out, units=units, extras=not args.no_report)
    except (FitInputError, FitError) as exc:
        raise UsageError(str(exc)) from None
    say(report.format())
    say("wrote " + ", ".join(str(w) for w in written))
    if args.strict and (report.fit.stop != "tolerance"):
        raise CheckFailed(f"tolerance {args.tolerance:g} not reached ({report.fit.stop}); the surface is written")
    return 0


def register(sub, fmt) -> None:
    """Add the `fit` subcommand to the cadbridge parser."""
    p = sub.add_parser(
        "fit", help="fit a NURBS surface to points (scan, FE nodes, Nagata tool) and write IGES 128/144",
        formatter_class=fmt,
        epilog="examples:\n"
        "  cadbridge fit scan.xyz -o die_scan.igs --base die.igs --tolerance 0.01 --trim\n"
        "  cadbridge fit nodes.csv -o moved.igs --plane --max-ctrl 40x40\n"
        "  cadbridge fit die.nagata -o die_fit.igs --nagata-samples 4 --base die.igs\n"
        "  cadbridge fit scan.xyz -o panel.igs --base-curves panel_edges.igs\n"
        "exit codes: 0 written, 1 --strict and the tolerance was not reached, 2 bad input",
    )
    p.add_argument("points", help="points: .xyz/.csv/.txt (x y z per line), STL/PLY/OBJ or any meshio mesh, "
                                  "or a cadbridge tool file (.nagata)")
    p.add_argument("-o", "--output", required=True, help="output IGES file")
    p.add_argument("--degree", type=int, default=3, help="degree in u and v (default 3)")
    p.add_argument("--tolerance", type=float, default=0.01, help="max deviation wanted, model units (default 0.01)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--base", help="IGES or STEP file whose face (or faces joined edge to edge) parametrises the points")
    g.add_argument("--base-curves", metavar="CURVES.igs",
                   help="IGES file with exactly 4 standalone boundary curves (126, 110, ...; polynomial) meeting "
                        "at 4 corners: parametrise on the Coons patch they span")
    g.add_argument("--plane", action="store_true", help="parametrise on the best-fit plane (default; height fields)")
    p.add_argument("--face", type=int, default=None, help="with --base: use only this face (0-based)")
    p.add_argument("--smoothing", type=float, default=1e-6,
                   help="thin-plate (bending) energy weight, relative to the data term (default 1e-6; 0 = none)")
    p.add_argument("--max-ctrl", type=_net, default=(60, 60), help="control net limit NUxNV (default 60x60)")
    p.add_argument("--trim", action="store_true", help="trim the surface by the outline of the data (IGES 144)")
    p.add_argument("--rational", action="store_true",
                   help="take degrees, knots and weights from the --base surface (conics, fillets)")
    p.add_argument("--noise", type=float, default=None,
                   help="noise sigma of the points (default: estimated; 0 for tool files)")
    p.add_argument("--max-distance", type=float, default=None,
                   help="points farther than this from the base are stray and left out "
                        "(default 1%% of the base CAD's size with --base; no limit with --plane)")
    p.add_argument("--nagata-samples", type=int, default=0,
                   help="tool file input: sample each Nagata patch with N points per edge (default 0: nodes)")
    p.add_argument("--no-robust", action="store_true", help="plain least squares (no Huber/Tukey reweighting)")
    p.add_argument("--name", default="FIT", help="face name written to the IGES (default FIT)")
    p.add_argument("--no-report", action="store_true", help="only the IGES file")
    p.add_argument("--strict", action="store_true", help="exit 1 when the tolerance was not reached")
    p.set_defaults(func=cmd_fit)

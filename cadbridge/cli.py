"""The `cadbridge` command: CAD in, exact normals, Nagata tool files and reports out.

Each subcommand is a thin layer over the library: parse arguments, call, print, and turn
the library's errors into one clear line and an exit code:

    0  success          1  checks failed (verify deviations, nodes off the CAD, a tool worse
                           than its flat mesh or straddling a crease)
    2  bad input (unreadable IGES/mesh, wrong arguments, or input the library could not
       handle: one line naming the error and where; CADBRIDGE_DEBUG=1 shows the traceback)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

EXIT_OK, EXIT_CHECK_FAILED, EXIT_BAD_INPUT = 0, 1, 2


PROGRESS_LINE = r"^cadbridge \w+( \[\s*\d+\] |: done in )"  # how `Progress` lines begin (for filters)


class Progress:
    """Stage-level progress on stderr. On a terminal, one line rewritten in place::

        cadbridge convert [ 4] die: errors vs CAD (8484 patch points)  [######........]  43%  3.1 s

    Elsewhere (a log file, a pipe, CI), plain lines: one per stage, one every
    ``log_every`` seconds within a long stage, and the closing ``done in`` line, so a log
    says where long work is as a terminal does. ``cadbridge --quiet`` (``Progress.quiet``)
    silences both. `stage(text)` starts a new stage, `update(done, total)` moves the bar
    within it (chunked projection), `close()` ends the output. ``enabled`` forces the
    terminal form (True) or silence (False). The pipeline calls it duck-typed (see
    `cadbridge.pipeline.NoProgress`).
    """

    width = 20
    log_every = 10.0  # seconds between the lines of one stage off a terminal
    quiet = False  # set by `cadbridge --quiet`

    def __init__(self, label: str, enabled: bool | None = None, stream=None) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.mode = ("off" if self.quiet else "tty" if tty else "lines") if enabled is None else \
            ("tty" if enabled else "off")
        self.enabled = self.mode != "off"
        self.t0 = time.perf_counter()
        self.stages = 0
        self.text = ""
        self._last = 0.0
        self._logged = 0.0

    def _line(self, frac: float | None) -> str:
        bar = "" if frac is None else f"  [{'#' * int(self.width * frac):.<{self.width}}] {100 * frac:3.0f}%"
        return f"{self.label} [{self.stages:>2}] {self.text[:60]}{bar}  {time.perf_counter() - self.t0:.1f} s"

    def _draw(self, frac: float | None) -> None:
        if self.mode == "tty":
            self.stream.write("\r" + self._line(frac).ljust(110)[:110])
        elif self.mode == "lines":
            self._logged = time.perf_counter()
            self.stream.write(self._line(frac) + "\n")
        else:
            return
        self.stream.flush()

    def stage(self, text: str) -> None:
        self.stages += 1
        self.text = text
        self._draw(None)

    def update(self, done: int, total: int) -> None:
        now = time.perf_counter()
        if self.mode == "lines":
            if now - self._logged >= self.log_every:
                self._draw(min(done / max(total, 1), 1.0))
        elif now - self._last > 0.1 or done >= total:  # at most ten redraws a second
            self._last = now
            self._draw(min(done / max(total, 1), 1.0))

    def close(self) -> None:
        if self.enabled:
            done = f"{self.label}: done in {time.perf_counter() - self.t0:.1f} s"
            self.stream.write(("\r" + done.ljust(110) if self.mode == "tty" else done) + "\n")
            self.stream.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        if self.mode == "tty" and exc[0] is not None:
            self.stream.write("\n")  # keep the error message on its own line
            self.stream.flush()
        elif exc[0] is None:
            self.close()


class UsageError(Exception):
    """Wrong combination of arguments or unusable input (exit code 2, like argparse's own errors)."""


class CheckFailed(Exception):
    """A check the user asked for did not hold (exit code 1): the message says which."""


# Subcommands that live in their own module (one module per job). Each module defines
# ``register(sub, fmt) -> None`` that adds its parser with ``set_defaults(func=...)``; its
# command functions raise `UsageError` (exit 2) or `CheckFailed` (exit 1) with one line.
COMMAND_MODULES: tuple[str, ...] = ("cadbridge.results.command", "cadbridge.fit_command", "cadbridge.mesh.quality_command")


def _say(msg: str) -> None:
    print(msg, flush=True)


# ----------------------------------------------------------------------------- inspect
def cmd_inspect(args: argparse.Namespace) -> int:
    from cadbridge.iges import read_iges

    model = read_iges(args.cad)
    _say(format_inspect(model))
    return EXIT_OK


#: IGES 5.3 entity type names, for `cadbridge inspect`.
ENTITY_NAMES = {
    100: "circular arc", 102: "composite curve", 104: "conic arc", 106: "copious data",
    108: "plane", 110: "line", 112: "parametric spline curve", 114: "parametric spline surface",
    116: "point", 118: "ruled surface", 120: "surface of revolution", 122: "tabulated cylinder",
    123: "direction", 124: "transformation matrix", 126: "rational B-spline curve",
    128: "rational B-spline surface", 130: "offset curve", 140: "offset surface", 141: "boundary",
    142: "curve on a parametric surface", 143: "bounded surface", 144: "trimmed surface",
    186: "manifold solid B-rep object", 190: "plane surface", 192: "right circular cylindrical surface",
    194: "right circular conical surface", 196: "spherical surface", 198: "toroidal surface",
    212: "general note", 308: "subfigure definition", 314: "colour definition",
    402: "associativity instance", 406: "property", 408: "singular subfigure instance",
    502: "vertex list", 504: "edge list", 508: "loop", 510: "face", 514: "shell",
}


def format_inspect(model) -> str:
    """Human-readable summary of a Model: header, entity counts, faces, box, names."""
    lines = [f"{'file':<14}{model.filename}"]
    for label, val in (
        ("system", model.system),
        ("preprocessor", model.preprocessor),
        ("author", model.author),
        ("organization", model.organization),
        ("product", model.product_id),
    ):
        if val:
            lines.append(f"{label:<14}{val}")
    lines.append(f"{'units':<14}{model.units.name} (flag {model.units.flag}, 1 unit = {model.units.to_mm:g} mm)")
    if model.resolution is not None:
        lines.append(f"{'resolution':<14}{model.resolution:g}")
    lines.append("entities")
    for et in sorted(model.entity_counts):
        lines.append(f"  {et:>4}  {ENTITY_NAMES.get(et, 'other'):<36}{model.entity_counts[et]:>6}")
    lines.append(f"{'faces':<14}{len(model.faces)}")
    if model.faces:
        b = model.bbox()
        lines.append(
            "bounding box  min ({:.6g}, {:.6g}, {:.6g})  max ({:.6g}, {:.6g}, {:.6g})".format(*b[0], *b[1])
        )
        deltas = [f.trim_delta for f in model.faces]  # file's 2D/3D trim disagreement (all faces in one pass)
        have = [i for i, d in enumerate(deltas) if d is not None]
        if have:
            w = max(have, key=lambda i: deltas[i])
            lines.append(f"{'trim delta':<14}max {deltas[w]:.3g} {model.units.name} ({deltas[w] / model.size():.3g} x size) "
                         f"on face {w} (DE {model.faces[w].de}); {len(have)} of {len(deltas)} faces have 2D and 3D trims")
        from cadbridge.loop_excursions import find_excursions

        for e in find_excursions(model):  # trim loops that run back beside themselves (convert cuts them out)
            lines.append(f"{'trim defect':<14}{e} by convert")
        lines.append(f"  {'#':>4} {'DE':>6} {'type':>5} {'surf':>5} {'degree':>7} {'ctrl':>9} {'trim':>5} {'delta':>9}  name")
        for i, f in enumerate(model.faces):
            s = f.surface
            nu, nv = s.shape
            trim = "-" if f.trims is None else f"{(1 if f.trims.outer is not None else 0)}+{len(f.trims.inner)}"
            dl = "-" if deltas[i] is None else f"{deltas[i]:.2e}"
            lines.append(
                f"  {i:>4} {f.de:>6} {f.entity_type:>5} {f.surface_type:>5} "
                f"{f'{s.degree_u}x{s.degree_v}':>7} {f'{nu}x{nv}':>9} {trim:>5} {dl:>9}  {f.name or ''}"
            )
    names = sorted({f.name for f in model.faces if f.name})
    if names:
        lines.append(f"{'names':<14}" + ", ".join(names))
    if model.diagnostics:
        lines.append(f"{'diagnostics':<14}{len(model.diagnostics)}")
        for d in model.diagnostics[:20]:
            lines.append(f"  {d}")
        if len(model.diagnostics) > 20:
            lines.append(f"  ... {len(model.diagnostics) - 20} more")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- verify
def cmd_verify(args: argparse.Namespace) -> int:
    from cadbridge.occ.verify import verify

    report = verify(args.cad, n_samples=args.samples, tol_pos=args.tol_pos, tol_der=args.tol_der, tol_ang=args.tol_ang)
    _say(report.format())
    return EXIT_OK if report.ok else EXIT_CHECK_FAILED


# ----------------------------------------------------------------------------- mesh
def _no_qit_refinement(args: argparse.Namespace) -> None:
    if getattr(args, "mesher", "gmsh") == "qit" and getattr(args, "shape_tolerance", None) is not None:
        raise UsageError("--shape-tolerance refines with gmsh; it cannot be combined with --mesher qit")


def cmd_mesh(args: argparse.Namespace) -> int:
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.io import write_mesh

    from cadbridge.creases import crease_lines
    from cadbridge.iges import read_iges

    _no_qit_refinement(args)
    if getattr(args, "shape_tolerance", None) is not None:  # sized and refined for a Nagata tolerance
        from cadbridge.refine import mesh_command

        with Progress("cadbridge mesh") as progress:
            return mesh_command(args, progress, _say)
    from cadbridge.mesh_source import mesh_source

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
    _say(f"wrote {args.output}: {len(mesh.nodes)} nodes, {n_el} elements")
    return EXIT_OK


# ----------------------------------------------------------------------------- normals
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
    from cadbridge.pipeline import _consistently_oriented

    mesh = _consistently_oriented(read_mesh(args.mesh), args.orient)
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
    _say(msg)
    return EXIT_OK


# ----------------------------------------------------------------------------- nagata / convert
def cmd_nagata(args: argparse.Namespace) -> int:
    from cadbridge.pipeline import nagata_from_mesh

    if args.method == "cad" and not args.cad:
        raise UsageError("--method cad (the default) needs --cad FILE.igs; or pick an estimator, e.g. --method mwe")
    with Progress("cadbridge nagata") as progress:
        result = nagata_from_mesh(
            args.mesh, cad=args.cad, output=args.output, method=args.method, name=args.name,
            report=not args.no_report, tolerance=args.tolerance, flip=args.flip, allow_far=args.allow_far,
            grid=args.grid, progress=progress, orient=args.orient, allow_worse=args.allow_worse,
        )
    _say(result.summary())
    return EXIT_OK


def cmd_convert(args: argparse.Namespace) -> int:
    from cadbridge.pipeline import convert

    _no_qit_refinement(args)
    with Progress("cadbridge convert") as progress:
        result = convert(
            args.cad, args.output, element=args.element, size=args.size, structured=args.structured,
            radius_divisions=args.radius_divisions, length_divisions=args.length_divisions,
            curvature_elements=args.curvature_elements, method=args.method, grid=args.grid, flip=args.flip, tolerance=args.tolerance, progress=progress,
            allow_worse=args.allow_worse, shape_tolerance=args.shape_tolerance, min_size=args.min_size,
            mesher=args.mesher, full_report=args.full_report,
        )
    if getattr(result, "adaptive", None) is not None:
        _say(result.adaptive.summary())
    _say(result.summary())
    return EXIT_OK


# ----------------------------------------------------------------------------- ushape
def cmd_ushape(args: argparse.Namespace) -> int:
    from cadbridge.ushape.benchmark import run_ushape

    with Progress("cadbridge ushape") as progress:
        summary = run_ushape(args.output, grid=args.grid, fine_size=args.fine_size, progress=progress,
                             mesher=args.mesher)
    _say(summary.table())
    _say("")
    _say("\n".join(summary.findings("die")))
    _say(f"wrote {len(summary.run['files'])} files to {args.output} in {summary.run['seconds']:.1f} s")
    return EXIT_OK


# ----------------------------------------------------------------------------- parser
def _add_mesher_option(p: argparse.ArgumentParser, what: str = "the mesh") -> None:
    p.add_argument("--mesher", choices=["gmsh", "qit"], default="gmsh",
                   help=f"mesher of {what}: gmsh (default) or qit, the quasi-isotropic triangulation directly on "
                        "the NURBS faces (triangles, --size = target edge length; docs/qit.md)")


def _add_mesh_options(p: argparse.ArgumentParser) -> None:
    _add_mesher_option(p)
    p.add_argument("--element", choices=["tri", "quad"], default="quad", help="element type (default quad)")
    p.add_argument("--size", type=float, default=None, help="target element size in model units")
    p.add_argument("--structured", action="store_true", help="structured (transfinite) mesh on four-sided faces")
    p.add_argument("--radius-divisions", type=int, default=3, help="elements across fillet radii (structured)")
    p.add_argument("--length-divisions", type=int, default=None, help="elements along fillets (structured)")
    p.add_argument("--curvature-elements", type=int, default=12,
                   help="elements per full turn of the surface normal, from the CAD curvature (default 12: "
                        "30 degrees per element, 3 across a quarter fillet as in the thesis; 0 = off)")
    p.add_argument("--shape-tolerance", type=float, default=None, metavar="T",
                   help="size and refine the mesh until the Nagata surface (exact normals) is within T of the CAD "
                        "(model units; --size is then the largest element; docs/adaptive_meshing.md)")
    p.add_argument("--min-size", type=float, default=None,
                   help="size floor of --shape-tolerance refinement (default model size / 1000, or a quarter "
                        "of the smallest size the error law asks on the CAD where that is less)")


def _add_normal_options(p: argparse.ArgumentParser, default: str = "cad") -> None:
    p.add_argument(
        "--method",
        choices=["cad", "mwe", "mwa", "mwselr", "mwaat", "mwelr", "mwrelr"],
        default=default,
        help="normal source: exact CAD normals (default) or a polyhedral estimator",
    )
    p.add_argument("--tolerance", type=float, default=None, help="max node-to-CAD distance (default 1e-4 x model size)")
    p.add_argument("--flip", action="store_true", help="reverse the normals (other side of the tool)")
    p.add_argument("--allow-far", action="store_true", help="keep going when nodes are beyond the tolerance")
    p.add_argument("--orient", action="store_true",
                   help="re-orient inconsistently wound elements (default: stop and name them)")


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(
        prog="cadbridge",
        formatter_class=fmt,
        description="Turn die and punch CAD (IGES/NURBS) into Nagata-patch tool files.",
        epilog="example:\n  cadbridge ushape -o out/            # the NUMISHEET'93 U-shape benchmark\n"
        "  cadbridge convert die.igs -o die/   # mesh + normals + Nagata + report",
    )
    parser.add_argument("--version", action="version", version="cadbridge 0.1.0")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress lines (errors and the summary are still printed)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("inspect", help="entities, faces, names, units, bounding box of an IGES file", formatter_class=fmt,
                       epilog="example:\n  cadbridge inspect iges_samples/ushape_die_nurbs.igs")
    p.add_argument("cad", help="IGES file")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("verify", help="compare our reading of an IGES file with OpenCASCADE", formatter_class=fmt,
                       epilog="example:\n  cadbridge verify iges_samples/ushape_die_nurbs.igs   # exit 1 if any face deviates")
    p.add_argument("cad", help="IGES file")
    p.add_argument("--samples", type=int, default=200, help="random (u, v) per face (default 200)")
    p.add_argument("--tol-pos", type=float, default=1e-9, help="position tolerance, relative to model size")
    p.add_argument("--tol-der", type=float, default=1e-8, help="derivative tolerance, relative")
    p.add_argument("--tol-ang", type=float, default=1e-9, help="normal angle tolerance, radians")
    p.set_defaults(func=cmd_verify)

    p = sub.add_parser("mesh", help="mesh the CAD with gmsh", formatter_class=fmt,
                       epilog="example:\n  cadbridge mesh die.igs -o die.msh --element quad --structured --radius-divisions 3")
    p.add_argument("cad", help="IGES file")
    p.add_argument("-o", "--output", required=True, help="mesh file (.msh, .vtu, .inp, .bdf, .stl, .obj, GiD .msh via --gid)")
    _add_mesh_options(p)
    p.set_defaults(func=cmd_mesh)

    p = sub.add_parser("normals", help="node normals of a mesh: exact from CAD or estimated", formatter_class=fmt,
                       epilog="example:\n  cadbridge normals die.msh --cad die.igs -o die_normals.vtu\n"
                       "  cadbridge normals die.msh --method mwselr")
    p.add_argument("mesh", help="mesh file readable by meshio")
    p.add_argument("--cad", help="IGES file (needed for --method cad)")
    p.add_argument("-o", "--output", help="output VTU (default MESH.normals.vtu)")
    _add_normal_options(p)
    p.set_defaults(func=cmd_normals)

    p = sub.add_parser("nagata", help="Nagata tool file and report from a mesh (+ CAD normals)", formatter_class=fmt,
                       epilog="example:\n  cadbridge nagata die.msh --cad die.igs -o die_tool/")
    p.add_argument("mesh", help="mesh file readable by meshio")
    p.add_argument("--cad", help="IGES file (exact normals and shape errors)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--name", help="tool name (default from the CAD names or the mesh file name)")
    p.add_argument("--grid", type=int, default=10, help="grid divisions per patch for errors and viewing")
    p.add_argument("--allow-worse", action="store_true",
                   help="write a tool even if its Nagata surface is worse than its flat mesh (for inspection)")
    p.add_argument("--no-report", action="store_true", help="only the tool file")
    _add_normal_options(p)
    p.set_defaults(func=cmd_nagata)

    p = sub.add_parser("convert", help="mesh + normals + Nagata + report in one go", formatter_class=fmt,
                       epilog="example:\n  cadbridge convert die.igs -o die_out/ --element quad --size 5")
    p.add_argument("cad", help="IGES file")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--grid", type=int, default=10, help="grid divisions per patch for errors and viewing")
    p.add_argument("--allow-worse", action="store_true",
                   help="write a tool even if its Nagata surface is worse than its flat mesh (for inspection)")
    p.add_argument("--full-report", action="store_true",
                   help="also the per-patch listings (grid CSV, coefficient listing, Nagata IGES) of tools above "
                        "50 000 elements (default: only up to that size)")
    _add_mesh_options(p)
    _add_normal_options(p)
    p.set_defaults(func=cmd_convert)

    p = sub.add_parser("ushape", help="the NUMISHEET'93 U-shape benchmark (thesis §5.2, Fig. 49)", formatter_class=fmt,
                       epilog="example:\n  cadbridge ushape -o out/")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--grid", type=int, default=20, help="grid divisions per patch")
    p.add_argument("--fine-size", type=float, default=4.0, help="element size of the unstructured triangle variant (mm)")
    _add_mesher_option(p, "the unstructured triangle variant")
    p.set_defaults(func=cmd_ushape)

    import importlib

    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub, fmt)
    return parser


def _known_errors() -> tuple[type[BaseException], ...]:
    errs: list[type[BaseException]] = [UsageError, CheckFailed, FileNotFoundError, IsADirectoryError, PermissionError,
                                       NotADirectoryError]
    for mod, name in (
        ("cadbridge.iges", "IgesError"),
        ("cadbridge.mesh.mesh", "MeshError"),
        ("cadbridge.normals.cad", "ProjectionError"),
        ("cadbridge.io.toolfile", "ToolFileError"),
        ("cadbridge.occ.reference", "OccReadError"),
        ("cadbridge.pipeline", "ToolQualityError"),
    ):
        try:
            module = __import__(mod, fromlist=[name])
            errs.append(getattr(module, name))
        except (ImportError, AttributeError):
            pass
    return tuple(errs)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    Progress.quiet = bool(getattr(args, "quiet", False))
    from cadbridge._jit import announce_compilation

    # one line on the then-current stderr if numba has to compile (cold cache), not with --quiet
    announce_compilation(quiet=Progress.quiet)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("cadbridge: interrupted", file=sys.stderr)
        return 130
    except _known_errors() as exc:
        from cadbridge.normals.cad import ProjectionError
        from cadbridge.pipeline import ToolQualityError

        print(f"cadbridge {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_CHECK_FAILED if isinstance(exc, (ProjectionError, ToolQualityError, CheckFailed)) else EXIT_BAD_INPUT
    except (ValueError, ArithmeticError, MemoryError, OSError, RuntimeError, LookupError, TypeError) as exc:
        # anything the library did not anticipate: still one line (the input it could not
        # handle); CADBRIDGE_DEBUG=1 shows the traceback for a bug report
        import os
        import traceback

        if os.environ.get("CADBRIDGE_DEBUG"):
            traceback.print_exc()
        where = traceback.extract_tb(exc.__traceback__)[-1]
        print(f"cadbridge {args.command}: error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''} "
              f"(at {Path(where.filename).name}:{where.lineno}; CADBRIDGE_DEBUG=1 shows the traceback)",
              file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())

"""Argument groups and checks that several subcommands share (mesh, normals, mesher, edge rule)."""

from __future__ import annotations

import argparse

from cadbridge.common.errors import UsageError
from cadbridge.nagata.edge import EDGE_RULES


def add_mesher_option(p: argparse.ArgumentParser, what: str = "the mesh") -> None:
    p.add_argument("--mesher", choices=["gmsh", "qit"], default="gmsh",
                   help=f"mesher of {what}: gmsh (default) or qit, the quasi-isotropic triangulation directly on "
                        "the NURBS faces (triangles, --size = target edge length; docs/qit.md)")


def add_mesh_options(p: argparse.ArgumentParser) -> None:
    add_mesher_option(p)
    p.add_argument("--element", choices=["tri", "quad"], default=None,
                   help="element type (default quad; tri with --mesher qit, which makes triangles only)")
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


def add_normal_options(p: argparse.ArgumentParser, default: str = "cad") -> None:
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


def add_edge_rule_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--edge-rule", default=EDGE_RULES[0], metavar="{" + ",".join(EDGE_RULES) + "}",
                   help="rule of the Nagata edge coefficients: bounded (default: eq. 15 with the bounded cases, "
                        "conormals on curved boundary edges) or published (Nagata 2005 exactly); the tool file "
                        "states it (docs/toolfile.md, README)")


def edge_rule(args: argparse.Namespace) -> str:
    """``args.edge_rule`` checked: one of `EDGE_RULES`, else a one-line `UsageError` (exit 2)."""
    rule = getattr(args, "edge_rule", EDGE_RULES[0])
    if rule not in EDGE_RULES:
        raise UsageError(f"--edge-rule must be one of {', '.join(EDGE_RULES)}, got {rule!r}")
    return rule


def no_qit_refinement(args: argparse.Namespace) -> None:
    """Usage checks of --mesher qit; also sets the default --element (quad, tri with qit)."""
    qit = getattr(args, "mesher", "gmsh") == "qit"
    if hasattr(args, "element"):
        if args.element is None:
            args.element = "tri" if qit else "quad"
        elif qit and args.element == "quad":
            raise UsageError("QIT makes triangles only: --element quad needs --mesher gmsh")
    if getattr(args, "mesher", "gmsh") == "qit" and getattr(args, "shape_tolerance", None) is not None:
        raise UsageError("--shape-tolerance refines with gmsh; it cannot be combined with --mesher qit")

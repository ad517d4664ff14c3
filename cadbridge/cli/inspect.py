"""`cadbridge inspect`: entities, faces, names, units and bounding box of a CAD file."""

from __future__ import annotations

import argparse

from cadbridge.common.errors import EXIT_OK
from cadbridge.common.progress import say


def cmd_inspect(args: argparse.Namespace) -> int:
    from cadbridge.formats import read_cad

    model = read_cad(args.cad)
    say(format_inspect(model))
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
    step = (model.preprocessor or "").startswith("STEP")
    if not step:
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
            if step:  # a STEP face's trim delta is its largest edge tolerance (`cadbridge.step.reader`)
                lines.append(f"{'trim delta':<14}max {deltas[w]:.3g} {model.units.name} ({deltas[w] / model.size():.3g} x "
                             f"size) on face {w}: the largest edge tolerance OCC's reading gives")
            else:
                lines.append(f"{'trim delta':<14}max {deltas[w]:.3g} {model.units.name} ({deltas[w] / model.size():.3g} x "
                             f"size) on face {w} (DE {model.faces[w].de}); {len(have)} of {len(deltas)} faces have 2D and 3D "
                             f"trims")
        from cadbridge.heal.loop_excursions import find_excursions

        crossings: list[str] = []
        for e in find_excursions(model, crossings=crossings):  # trim loops that run back beside themselves
            lines.append(f"{'trim defect':<14}{e} by convert")  # or cross themselves in a tiny lobe: cut out
        for c in crossings:  # trim loops that really cross themselves
            lines.append(f"{'trim defect':<14}{c}: convert refuses this face")
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


def register(sub, fmt) -> None:
    p = sub.add_parser("inspect", help="entities, faces, names, units, bounding box of an IGES or STEP file", formatter_class=fmt,
                       epilog="example:\n  cadbridge inspect iges_samples/ushape_die_nurbs.igs")
    p.add_argument("cad", help="IGES or STEP file")
    p.set_defaults(func=cmd_inspect)

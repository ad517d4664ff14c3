"""Tool surfaces of the NUMISHEET'93 U-shape (2D draw bending) benchmark, built with OCP.

Coordinates (mm): x across the tools (along the 350 mm strip), y along the tool depth (the
35 mm strip width), z vertical. The die sits below the blank, the punch and the blank holder
above it; the punch moves in -z. In the initial position the blank's lower surface lies on
the die land (z = 0), its mid-surface at z = t/2, and the punch bottom and the blank holder
touch its upper surface (z = t).

Symmetry: the benchmark is plane strain with two symmetry planes. With ``symmetry_x`` the
model keeps x >= 0 (one punch corner, one die shoulder: the plane x = 0 is the punch centre);
with ``symmetry_y`` it keeps y >= 0, i.e. the "half width" model of Neto's thesis (§5.2).
Both default to True (a quarter of the physical tools, the usual FE set-up).

Only the surfaces the sheet touches are built (not solids), one face per geometric piece:
planes for lands, walls and bottoms, a separate quarter cylinder for every radius. Every face
is oriented so that its normal (as OCC writes it to IGES: Su x Sv of the written surface)
points out of the tool material, towards the sheet.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from OCP.BRep import BRep_Builder
from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_NurbsConvert, BRepBuilderAPI_Sewing
from OCP.Geom import Geom_CylindricalSurface, Geom_Plane
from OCP.gp import gp_Ax3, gp_Dir, gp_Pnt
from OCP.IGESBasic import IGESBasic_Name
from OCP.IGESControl import IGESControl_Writer
from OCP.IGESData import IGESData_IGESWriter
from OCP.IGESGraph import IGESGraph_Color
from OCP.Interface import Interface_Static
from OCP.TCollection import TCollection_HAsciiString
from OCP.TopAbs import TopAbs_SHELL
from OCP.TopExp import TopExp_Explorer
from OCP.TopoDS import TopoDS, TopoDS_Face, TopoDS_Shape, TopoDS_Shell

from cadbridge.common.atomic import atomic_write

__all__ = ["FACE_LABELS", "UShapeParams", "blank_mesh", "build_tools", "export_iges", "tool_faces"]

#: IGES names of the faces (DE labels, so at most 8 characters), per tool, in
#: the order `tool_faces` returns them for the default (quarter) model.
FACE_LABELS: dict[str, tuple[str, ...]] = {
    "die": ("DIEWALL", "DIERAD", "DIELAND"),
    "punch": ("PCHWALL", "PCHRAD", "PCHBOT"),
    "blankholder": ("BHOLDER",),
}

#: Colours written with the tools (IGES 314), so a viewer tells them apart.
TOOL_COLORS: dict[str, tuple[float, float, float]] = {
    "die": (0.25, 0.45, 0.85),
    "punch": (0.85, 0.30, 0.25),
    "blankholder": (0.30, 0.70, 0.35),
}

_FIXED_DATE = "20100101.000000"  # Global fields 18 and 25: fixed so files are reproducible


@dataclass(frozen=True)
class UShapeParams:
    """Dimensions and process data of the NUMISHEET'93 2D draw bending benchmark (mm, kN).

    Sources: [N93] Makinouchi et al. (eds.), NUMISHEET'93 proceedings, benchmark "2D draw
    bending" (as used throughout the springback literature); [T] Neto 2010, thesis §5.2 and
    Fig. 48 (../shared/refs/neto2010-nagata-patches-thesis.txt). Values marked *choice* are
    not fixed by either source and were chosen here; change them freely.
    """

    punch_width: float = 70.0  # [N93] punch width 70 mm (half 35 mm)
    punch_radius: float = 5.0  # [N93] punch profile radius R5; [T] "same corner radius"
    die_radius: float = 5.0  # [N93] die shoulder radius R5; [T] §5.2
    # *choice*: radial clearance per side between punch wall and die wall. The benchmark's
    # fixed tool set was run with 0.74 (HSS), 0.78 (mild steel) and 0.81 mm (Al) blanks, so
    # the gap must exceed 0.81 mm; 1.0 mm per side (die opening 72 mm) is the value we use,
    # not verified against the original drawing.
    clearance: float = 1.0
    blank_length: float = 350.0  # [N93] blank 350 mm long (across the tools, x)
    blank_width: float = 35.0  # [N93] blank 35 mm wide (along the tools, y)
    thickness: float = 0.78  # [N93] mild steel sheet, t = 0.78 mm
    blankholder_force: float = 2.45  # [N93] blank-holder force 2.45 kN on the full strip
    friction: float = 0.144  # [N93] Coulomb friction coefficient 0.144 (all tools)
    punch_stroke: float = 70.0  # [N93] punch travel 70 mm
    tool_half_width: float = 20.5  # [T] §5.2: die modelled over "half width, i.e. 20.5 mm"
    land_end_x: float = 190.0  # *choice*: die land / blank holder reach x = 190 (> 175 = L/2)
    die_depth: float = 80.0  # *choice*: die wall runs to z = -80 (stroke 70 + 10 mm)
    punch_height: float = 80.0  # *choice*: punch wall rises to z = t + 80
    symmetry_x: bool = True  # keep x >= 0 only (symmetry plane at the punch centre)
    symmetry_y: bool = True  # keep y >= 0 only (half width, as in [T])

    def __post_init__(self) -> None:
        if min(self.punch_radius, self.die_radius, self.thickness, self.clearance) <= 0:
            raise ValueError("radii, thickness and clearance must be positive")
        if self.punch_radius >= self.punch_width / 2:
            raise ValueError("punch radius must be smaller than half the punch width")
        if self.land_end_x <= self.die_half_opening + self.die_radius:
            raise ValueError("land_end_x must lie beyond the die shoulder")
        if self.die_depth <= self.die_radius or self.punch_height <= self.punch_radius:
            raise ValueError("die_depth / punch_height must exceed the radii")

    @property
    def punch_half_width(self) -> float:
        """Half of the punch width (35 mm)."""
        return self.punch_width / 2.0

    @property
    def die_half_opening(self) -> float:
        """Half of the die opening: punch half width + clearance (36 mm by default)."""
        return self.punch_half_width + self.clearance

    @property
    def model_blankholder_force(self) -> float:
        """Blank-holder force acting on the modelled part (kN), scaled by the symmetries."""
        return self.blankholder_force / (2 if self.symmetry_x else 1) / (2 if self.symmetry_y else 1)

    @property
    def y_range(self) -> tuple[float, float]:
        """Extent of the tools along y."""
        w = self.tool_half_width
        return (0.0, w) if self.symmetry_y else (-w, w)


# ---------------------------------------------------------------------- profile -> faces
# A tool is a profile in the xz plane swept along y. Each piece is a straight segment
# (a plane face) or a convex circular arc (a cylinder face). Pieces are listed in the
# direction t for which n = t x (+y) = (-t_z, 0, t_x) points towards the sheet; for a convex
# arc (tool material inside the circle) that direction is the sense of increasing angle of
# a direct gp_Ax3 with main direction +y, whose Su x Sv is the outward normal.


def _line_face(p0: tuple[float, float], p1: tuple[float, float], y0: float, y1: float) -> TopoDS_Face:
    """Plane face over the segment p0 -> p1 (xz), u along the segment (0..length), v = y."""
    tx, tz = p1[0] - p0[0], p1[1] - p0[1]
    length = math.hypot(tx, tz)
    tx, tz = tx / length, tz / length
    ax = gp_Ax3(gp_Pnt(p0[0], 0.0, p0[1]), gp_Dir(-tz, 0.0, tx), gp_Dir(tx, 0.0, tz))
    face = BRepBuilderAPI_MakeFace(Geom_Plane(ax), 0.0, length, y0, y1, 1e-7).Face()
    return face


def _arc_face(center: tuple[float, float], radius: float, start: tuple[float, float], sweep: float, y0: float, y1: float) -> TopoDS_Face:
    """Convex cylinder face: axis +y through center, angle 0 at direction ``start`` (xz), u in [0, sweep]."""
    ax = gp_Ax3(gp_Pnt(center[0], 0.0, center[1]), gp_Dir(0.0, 1.0, 0.0), gp_Dir(start[0], 0.0, start[1]))
    return BRepBuilderAPI_MakeFace(Geom_CylindricalSurface(ax, radius), 0.0, sweep, y0, y1, 1e-7).Face()


def tool_faces(params: UShapeParams = UShapeParams()) -> dict[str, dict[str, TopoDS_Face]]:
    """The contact faces of each tool, labelled: {"die": {"DIEWALL": face, ...}, ...}.

    Labels are IGES DE labels (<= 8 characters); a second copy mirrored for the full model
    (``symmetry_x=False``) carries the suffix "2".
    """
    p = params
    y0, y1 = p.y_range
    t = p.thickness
    a_d, r_d = p.die_half_opening, p.die_radius
    a_p, r_p = p.punch_half_width, p.punch_radius
    h = math.pi / 2
    die: dict[str, TopoDS_Face] = {}
    punch: dict[str, TopoDS_Face] = {}
    holder: dict[str, TopoDS_Face] = {}

    # Right half (x >= 0). Die: wall bottom -> up the wall -> shoulder -> out along the land.
    die["DIEWALL"] = _line_face((a_d, -p.die_depth), (a_d, -r_d), y0, y1)
    die["DIERAD"] = _arc_face((a_d + r_d, -r_d), r_d, (-1.0, 0.0), h, y0, y1)
    die["DIELAND"] = _line_face((a_d + r_d, 0.0), (p.land_end_x, 0.0), y0, y1)
    # Punch: down the wall -> corner -> along the bottom towards the centre.
    punch["PCHWALL"] = _line_face((a_p, t + p.punch_height), (a_p, t + r_p), y0, y1)
    punch["PCHRAD"] = _arc_face((a_p - r_p, t + r_p), r_p, (1.0, 0.0), h, y0, y1)
    bottom_end = 0.0 if p.symmetry_x else -(a_p - r_p)
    punch["PCHBOT"] = _line_face((a_p - r_p, t), (bottom_end, t), y0, y1)
    # Blank holder: plate on the blank over the die land, normal -z.
    holder["BHOLDER"] = _line_face((p.land_end_x, t), (a_d + r_d, t), y0, y1)

    if not p.symmetry_x:  # left half, traversed so that normals still face the sheet
        die["DIELAND2"] = _line_face((-p.land_end_x, 0.0), (-(a_d + r_d), 0.0), y0, y1)
        die["DIERAD2"] = _arc_face((-(a_d + r_d), -r_d), r_d, (0.0, 1.0), h, y0, y1)
        die["DIEWALL2"] = _line_face((-a_d, -r_d), (-a_d, -p.die_depth), y0, y1)
        punch["PCHRAD2"] = _arc_face((-(a_p - r_p), t + r_p), r_p, (0.0, -1.0), h, y0, y1)
        punch["PCHWALL2"] = _line_face((-a_p, t + r_p), (-a_p, t + p.punch_height), y0, y1)
        holder["BHOLDER2"] = _line_face((-(a_d + r_d), t), (-p.land_end_x, t), y0, y1)
    return {"die": die, "punch": punch, "blankholder": holder}


def _sew(faces: list[TopoDS_Face], tol: float = 1e-6) -> TopoDS_Shell:
    """Sew faces sharing edges into one shell (a single face is wrapped in a shell)."""
    if len(faces) > 1:
        sewing = BRepBuilderAPI_Sewing(tol)
        for f in faces:
            sewing.Add(f)
        sewing.Perform()
        shape = sewing.SewedShape()
        if shape.ShapeType() == TopAbs_SHELL:
            return TopoDS.Shell_s(shape)
        exp = TopExp_Explorer(shape, TopAbs_SHELL)
        if exp.More():
            shell = TopoDS.Shell_s(exp.Current())
            exp.Next()
            if not exp.More():
                return shell
        raise RuntimeError("sewing the tool faces did not give a single shell")
    shell = TopoDS_Shell()
    builder = BRep_Builder()
    builder.MakeShell(shell)
    for f in faces:
        builder.Add(shell, f)
    return shell


def build_tools(params: UShapeParams = UShapeParams()) -> dict[str, TopoDS_Shell]:
    """The tools as OCP shells of faces: {"die": shell, "punch": shell, "blankholder": shell}."""
    return {name: _sew(list(faces.values())) for name, faces in tool_faces(params).items()}


def blank_mesh(params: UShapeParams = UShapeParams(), element_size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Structured quad mesh of the blank mid-surface (z = t/2) over the modelled part.

    Returns nodes (N, 3) float and quads (M, 4) int (0-based, counter-clockwise seen from
    +z, so element normals point up towards the punch). Element size is at most
    ``element_size`` in both directions.
    """
    if element_size <= 0:
        raise ValueError("element_size must be positive")
    p = params
    x0, x1 = (0.0, p.blank_length / 2) if p.symmetry_x else (-p.blank_length / 2, p.blank_length / 2)
    y0, y1 = (0.0, p.blank_width / 2) if p.symmetry_y else (-p.blank_width / 2, p.blank_width / 2)
    nx = max(1, math.ceil((x1 - x0) / element_size - 1e-9))
    ny = max(1, math.ceil((y1 - y0) / element_size - 1e-9))
    xs = np.linspace(x0, x1, nx + 1)
    ys = np.linspace(y0, y1, ny + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")  # node (i, j) -> index i * (ny + 1) + j
    nodes = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, p.thickness / 2)])
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    n00 = (i * (ny + 1) + j).ravel()
    quads = np.column_stack([n00, n00 + ny + 1, n00 + ny + 2, n00 + 1]).astype(np.int64)
    return nodes, quads


# ---------------------------------------------------------------------- IGES export
def export_iges(
    shapes: TopoDS_Shape | Mapping[str, TopoDS_Shape],
    path: str | os.PathLike,
    mode: str = "nurbs",
    names: Mapping[str, str] | None = None,
    *,
    colors: Mapping[str, tuple[float, float, float]] | None = None,
    brep: bool = False,
    description: str = "",
    author: str = "cadbridge",
    organization: str = "cadbridge",
    date: str = _FIXED_DATE,
) -> None:
    """Write shapes to an IGES 5.3 file (mm) with OCC's IGES writer, at round-trip precision.

    shapes       one shape, or {key: shape}; each key (or ``names[key]``) names the entity
                 written for that shape (the 144 / 402 / 510 / 514 on top): its first 8
                 characters go to the DE label (field 18), the whole name to a 406 form 15
                 name property.
    mode         "nurbs": every face converted with BRepBuilderAPI_NurbsConvert first, so
                 each surface is a 128 (rational where exact conics need it) under a 144;
                 "analytic": faces written as OCC holds them (planes 108, cylinders 120
                 surfaces of revolution in faces mode; 190/192 in B-rep mode).
    brep         False: "faces" mode (144 trimmed surfaces); True: B-rep mode (MSBO
                 186/514/510; write.iges.brep.mode = 1).
    colors       {key: (r, g, b)} in 0..1, written as 314 colour entities (one per colour).
    description  text for the Start section.
    date         Global fields 18 and 25 (fixed by default so output is reproducible).

    The real format is switched from OCC's default (10 significant digits, lossy) to
    "%#.17g" (round-trip, always with a decimal point). The write is atomic.
    """
    if mode not in ("nurbs", "analytic"):
        raise ValueError(f"mode must be 'nurbs' or 'analytic', got {mode!r}")
    items = list(shapes.items()) if isinstance(shapes, Mapping) else [(None, shapes)]
    old_mode = Interface_Static.IVal_s("write.iges.brep.mode")
    try:
        Interface_Static.SetIVal_s("write.iges.brep.mode", 1 if brep else 0)
        writer = IGESControl_Writer("MM", 1 if brep else 0)
        model = writer.Model()
        colour_entities: dict[tuple[float, float, float], IGESGraph_Color] = {}
        for key, shape in items:
            if mode == "nurbs":
                shape = BRepBuilderAPI_NurbsConvert(shape, True).Shape()
            first = model.NbEntities() + 1
            if not writer.AddShape(shape) or model.NbEntities() < first:
                raise RuntimeError(f"OCC could not transfer shape {key!r} for {path}")
            root = model.Value(first)  # AddShape appends the shape's top entity first
            if key is None:
                continue
            name = (names or {}).get(key, key)
            prop = IGESBasic_Name()
            prop.Init(1, TCollection_HAsciiString(name))
            root.AddProperty(prop)
            root.SetLabel(TCollection_HAsciiString(name[:8]))
            model.AddWithRefs(prop)
            if colors and key in colors:
                rgb = tuple(float(c) for c in colors[key])
                if rgb not in colour_entities:
                    col = IGESGraph_Color()
                    col.Init(100.0 * rgb[0], 100.0 * rgb[1], 100.0 * rgb[2], TCollection_HAsciiString())
                    model.AddWithRefs(col)
                    colour_entities[rgb] = col
                root.InitColor(colour_entities[rgb], 0)
        writer.ComputeModel()
    finally:
        Interface_Static.SetIVal_s("write.iges.brep.mode", old_mode)

    gs = model.GlobalSection()
    gs.SetFileName(TCollection_HAsciiString(os.path.basename(os.fspath(path))))
    gs.SetAuthorName(TCollection_HAsciiString(author))
    gs.SetCompanyName(TCollection_HAsciiString(organization))
    gs.SetDate(TCollection_HAsciiString(date))
    gs.SetLastChangeDate(TCollection_HAsciiString(date))
    model.SetGlobalSection(gs)

    iw = IGESData_IGESWriter(model)
    iw.FloatWriter().SetFormat("%#.17g", True)
    for line in _start_lines(description):
        iw.SendStartLine(line)
    iw.SendModel(model.Protocol())
    buf = io.BytesIO()
    if not iw.Print(buf):
        raise RuntimeError(f"OCC could not write {path}")
    _atomic_write(path, buf.getvalue())


def _start_lines(text: str, width: int = 72) -> list[str]:
    """Split a description into Start-section lines of at most ``width`` characters."""
    lines: list[str] = []
    for para in text.splitlines():
        words, cur = para.split(), ""
        for w in words:
            if cur and len(cur) + 1 + len(w) > width:
                lines.append(cur)
                cur = w
            else:
                cur = f"{cur} {w}" if cur else w[:width]
        lines.append(cur)
    return lines


def _atomic_write(path: str | os.PathLike, data: bytes) -> None:
    with atomic_write(path, "wb") as fh:
        fh.write(data)

"""Regenerate every sample IGES file in this folder (deterministic: same bytes on every run).

    /work/venv/bin/python iges_samples/make_samples.py [--production] [OUT_DIR]

Files made by OpenCASCADE go through `cadbridge.ushape.export_iges` (OCC's IGES writer in
"faces" mode, reals at round-trip precision, fixed dates). Two files are written by hand
here, entity by entity, because OCC cannot produce them: the thesis' appendix A surface and
the surfaces placed by 124 transformation matrices (OCC bakes locations into the geometry).
The entity-count table of README.md is rewritten between its markers on every run.
``--production`` also writes the production-size draw die (issue #8, 1 102 trimmed faces,
NURBS and analytic modes, about 25 MB each); see `production_die`.
"""

from __future__ import annotations

import collections
import functools
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import cadquery as cq
from OCP.BRep import BRep_Tool
from OCP.BRepAlgoAPI import BRepAlgoAPI_BooleanOperation, BRepAlgoAPI_Common, BRepAlgoAPI_Cut, BRepAlgoAPI_Fuse
from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeWire
from OCP.BRepCheck import BRepCheck_Analyzer
from OCP.BRepFilletAPI import BRepFilletAPI_MakeFillet
from OCP.BRepLib import BRepLib
from OCP.BRepPrimAPI import BRepPrimAPI_MakePrism, BRepPrimAPI_MakeSphere, BRepPrimAPI_MakeTorus
from OCP.BRepTools import BRepTools
from OCP.Geom import (
    Geom_BSplineCurve,
    Geom_BSplineSurface,
    Geom_ConicalSurface,
    Geom_CylindricalSurface,
    Geom_Plane,
    Geom_RectangularTrimmedSurface,
    Geom_SphericalSurface,
    Geom_Surface,
    Geom_SurfaceOfRevolution,
    Geom_ToroidalSurface,
)
from OCP.GeomAbs import GeomAbs_C0, GeomAbs_C2
from OCP.GeomAPI import GeomAPI_PointsToBSplineSurface
from OCP.GeomConvert import GeomConvert
from OCP.gp import gp_Ax1, gp_Ax2, gp_Ax3, gp_Circ, gp_Dir, gp_Pnt, gp_Vec
from OCP.TColgp import TColgp_Array1OfPnt, TColgp_Array2OfPnt
from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal, TColStd_Array2OfReal
from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE, TopAbs_WIRE
from OCP.TopExp import TopExp, TopExp_Explorer
from OCP.TopoDS import TopoDS, TopoDS_Shape
from OCP.TopTools import TopTools_IndexedDataMapOfShapeListOfShape, TopTools_IndexedMapOfShape, TopTools_ListOfShape

from cadbridge.ushape import UShapeParams, export_iges, tool_faces
from cadbridge.ushape.geometry import TOOL_COLORS

HERE = Path(__file__).resolve().parent
README = HERE / "README.md"
_DATE = "20100101.000000"


# ---------------------------------------------------------------------- reading back
def entity_counts(path: str | os.PathLike) -> dict[int, int]:
    """{entity type: number of directory entries} of an IGES file (from its D section)."""
    d_lines = [ln for ln in Path(path).read_text(encoding="latin-1").splitlines() if len(ln) >= 73 and ln[72] == "D"]
    return dict(sorted(collections.Counter(int(d_lines[i][:8]) for i in range(0, len(d_lines), 2)).items()))


# ---------------------------------------------------------------------- a tiny IGES writer
class _Entity:
    """One entity for the hand-written files: type, form, parameters (after the type), DE fields."""

    def __init__(self, etype: int, params: Sequence, form: int = 0, transform: int = 0, label: str = "", subscript: int = 0, status: str = "00000000") -> None:
        self.etype, self.params, self.form = etype, list(params), form
        self.transform, self.label, self.subscript, self.status = transform, label, subscript, status


def _fmt(x) -> str:
    if isinstance(x, str):  # already formatted (keeps the thesis' own spelling of numbers)
        return x
    if isinstance(x, int):
        return str(x)
    r = repr(float(x)).upper()  # IGES exponents: E (or D)
    return r if ("." in r or "E" in r) else r + "."


def _pack(tokens: list[str], width: int) -> list[str]:
    """Lay out delimited tokens on lines of at most ``width`` characters, breaking after delimiters."""
    lines, cur = [], ""
    for tok in tokens:
        if len(cur) + len(tok) > width:
            lines.append(cur)
            cur = ""
        cur += tok
    if cur:
        lines.append(cur)
    return lines


def _hollerith(s: str) -> str:
    return f"{len(s)}H{s}" if s else ""


def write_iges_by_hand(path: Path, entities: list[_Entity], start: list[str], *, product: str, system: str, author: str, organization: str, resolution: float = 1e-7, max_coord: float = 100.0) -> None:
    """Write entities as an IGES 5.3 fixed-format file (S, G, D, P, T sections)."""
    glob = [",", ";", _hollerith(product), _hollerith(path.name), _hollerith(system), _hollerith(system),
            "32", "38", "6", "308", "15", _hollerith(product), "1.0", "2", "2HMM", "1", "0.01",
            _hollerith(_DATE), _fmt(resolution), _fmt(max_coord), _hollerith(author), _hollerith(organization),
            "11", "0", _hollerith(_DATE)]
    glob = [f"1H{g}" if g in (",", ";") else g for g in glob]
    g_tokens = [g + "," for g in glob[:-1]] + [glob[-1] + ";"]
    g_lines = _pack(g_tokens, 72)

    d_lines: list[str] = []
    p_lines: list[str] = []
    for k, ent in enumerate(entities):
        de = 2 * k + 1  # DE numbers are odd and 1-based (the first line of the pair)
        toks = [str(ent.etype)] + [_fmt(x) for x in ent.params]
        toks = [t + "," for t in toks[:-1]] + [toks[-1] + ";"]
        body = _pack(toks, 64)
        first_p = len(p_lines) + 1
        for line in body:
            p_lines.append(f"{line:<64} {de:>7d}P{len(p_lines) + 1:07d}")
        f = lambda v: f"{v:>8}"  # noqa: E731
        d_lines.append(f(ent.etype) + f(first_p) + f(0) + f(0) + f(0) + f(0) + f(ent.transform) + f(0) + ent.status + f"D{len(d_lines) + 1:07d}")
        d_lines.append(f(ent.etype) + f(0) + f(0) + f(len(body)) + f(ent.form) + f("") + f("") + f(ent.label[:8]) + f(ent.subscript) + f"D{len(d_lines) + 1:07d}")
    out = [f"{s:<72}S{i + 1:07d}" for i, s in enumerate(start)]
    out += [f"{g:<72}G{i + 1:07d}" for i, g in enumerate(g_lines)]
    out += d_lines + p_lines
    out.append(f"S{len(start):7d}G{len(g_lines):7d}D{len(d_lines):7d}P{len(p_lines):7d}".ljust(72) + "T0000001")
    path.write_text("\n".join(out) + "\n", encoding="ascii")


def bspline_128_params(bs: Geom_BSplineSurface) -> list:
    """IGES 128 parameters (after the type number) of an OCC B-spline surface."""
    nu, nv = bs.NbUPoles(), bs.NbVPoles()

    def flat(n: int, knot, mult) -> list[float]:
        return [knot(i) for i in range(1, n + 1) for _ in range(mult(i))]

    su = flat(bs.NbUKnots(), bs.UKnot, bs.UMultiplicity)
    sv = flat(bs.NbVKnots(), bs.VKnot, bs.VMultiplicity)
    rational = bs.IsURational() or bs.IsVRational()
    # IGES order: first index (u) varies fastest; OCC poles are 1-based (i, j)
    w = [bs.Weight(i, j) for j in range(1, nv + 1) for i in range(1, nu + 1)]
    pts = [c for j in range(1, nv + 1) for i in range(1, nu + 1) for c in bs.Pole(i, j).Coord()]
    u0, u1, v0, v1 = bs.Bounds()
    return [nu - 1, nv - 1, bs.UDegree(), bs.VDegree(), 0, 0, 0 if rational else 1, 0, 0, *su, *sv, *w, *pts, u0, u1, v0, v1]


# ---------------------------------------------------------------------- geometry helpers
def _ax3(origin=(0.0, 0.0, 0.0), z=(0.0, 0.0, 1.0), x=(1.0, 0.0, 0.0)) -> gp_Ax3:
    return gp_Ax3(gp_Pnt(*origin), gp_Dir(*z), gp_Dir(*x))


def _exact_bspline(surf: Geom_Surface, u0: float, u1: float, v0: float, v1: float) -> Geom_BSplineSurface:
    """Exact rational B-spline of an analytic surface restricted to [u0, u1] x [v0, v1]."""
    return GeomConvert.SurfaceToBSplineSurface_s(Geom_RectangularTrimmedSurface(surf, u0, u1, v0, v1))


def _face(surf: Geom_Surface):
    return BRepBuilderAPI_MakeFace(surf, 1e-7).Face()


def quarter_cylinder() -> Geom_BSplineSurface:
    """R 5 quarter cylinder (the U-shape die shoulder, axis +y), v over the 20.5 mm tool half width."""
    return _exact_bspline(Geom_CylindricalSurface(_ax3((41.0, 0.0, -5.0), (0, 1, 0), (-1, 0, 0)), 5.0), 0.0, math.pi / 2, 0.0, 20.5)


def sphere_patch() -> Geom_BSplineSurface:
    """Sphere R 10: longitude 0..90 deg, latitude 0..60 deg (no pole)."""
    return _exact_bspline(Geom_SphericalSurface(_ax3(), 10.0), 0.0, math.pi / 2, 0.0, math.pi / 3)


def torus_patch() -> Geom_BSplineSurface:
    """Torus R 20, r 5: a quarter turn around the axis, the outer half of the tube."""
    return _exact_bspline(Geom_ToroidalSurface(_ax3(), 20.0, 5.0), 0.0, math.pi / 2, -math.pi / 2, math.pi / 2)


def multiple_knots_surface() -> Geom_BSplineSurface:
    """Bicubic, rational, u knots 0 0 0 0 | 1 1 (C1) | 2 2 2 (C0) | 3 3 3 3, v knots 0^4 0.5 1^4."""
    uk, um = [0.0, 1.0, 2.0, 3.0], [4, 2, 3, 4]
    vk, vm = [0.0, 0.5, 1.0], [4, 1, 4]
    nu = sum(um) - 4  # 9 poles along u
    nv = sum(vm) - 4  # 5 poles along v
    poles = TColgp_Array2OfPnt(1, nu, 1, nv)
    weights = TColStd_Array2OfReal(1, nu, 1, nv)
    for i in range(1, nu + 1):
        for j in range(1, nv + 1):
            x, y = 10.0 * (i - 1), 8.0 * (j - 1)
            z = 6.0 * math.sin(0.7 * i) * math.cos(0.9 * j) + (5.0 if i >= 7 else 0.0)  # a step after the C0 knot
            poles.SetValue(i, j, gp_Pnt(x, y, z))
            weights.SetValue(i, j, 1.0 + 0.25 * ((i + 2 * j) % 3))
    arr = lambda vals, cls: _fill(cls(1, len(vals)), vals)  # noqa: E731
    return Geom_BSplineSurface(poles, weights, arr(uk, TColStd_Array1OfReal), arr(vk, TColStd_Array1OfReal),
                               arr(um, TColStd_Array1OfInteger), arr(vm, TColStd_Array1OfInteger), 3, 3, False, False)


# singular points (issue 32, point 5): a whole iso-line of the surface collapses onto one
# point, where Su x Sv = 0 and the normal is a limit
CONE_HALF_ANGLE = 30.0  # deg, cone_apex.igs
REVOLVED_APEX_ANGLE = 50.0  # deg between the profile's tangent and the axis at the apex, revolved_apex.igs


def full_cone() -> Geom_BSplineSurface:
    """Full cone, half angle 30 deg, apex (0, 0, 20) on top, axis -z, 20 mm tall (base R 11.55 at
    z = 0): u the angle (0..2 pi, periodic), v along the generatrix from the apex, so the edge
    v = 0 collapses onto the apex."""
    a = math.radians(CONE_HALF_ANGLE)
    return _exact_bspline(Geom_ConicalSurface(_ax3((0.0, 0.0, 20.0), (0, 0, -1)), a, 0.0), 0.0, 2 * math.pi, 0.0, 20.0 / math.cos(a))


def hemisphere() -> Geom_BSplineSurface:
    """Hemisphere R 10 about +z: u the longitude (0..2 pi), v the latitude 0..90 deg, so the edge
    v = 90 deg collapses onto the pole (0, 0, 10)."""
    return _exact_bspline(Geom_SphericalSurface(_ax3(), 10.0), 0.0, 2 * math.pi, 0.0, math.pi / 2)


def revolved_profile() -> Geom_BSplineCurve:
    """Cubic B-spline profile in the xz plane from (0, 0, 15) on the z axis, leaving it at
    `REVOLVED_APEX_ANGLE` to the axis (downwards), to (18, 0, -1)."""
    b = math.radians(REVOLVED_APEX_ANGLE)
    pts = [(0.0, 0.0, 15.0), (5.0 * math.sin(b), 0.0, 15.0 - 5.0 * math.cos(b)), (9.0, 0.0, 6.0), (14.0, 0.0, 1.0), (18.0, 0.0, -1.0)]
    poles = TColgp_Array1OfPnt(1, len(pts))
    for k, p in enumerate(pts, start=1):
        poles.SetValue(k, gp_Pnt(*p))
    knots = _fill(TColStd_Array1OfReal(1, 3), [0.0, 0.5, 1.0])
    mults = _fill(TColStd_Array1OfInteger(1, 3), [4, 1, 4])
    return Geom_BSplineCurve(poles, knots, mults, 3)


def revolved_apex() -> Geom_BSplineSurface:
    """The profile of `revolved_profile` revolved a full turn about z: u the angle, v the profile
    parameter; the edge v = 0 collapses onto the apex (0, 0, 15), where the limit normal depends
    on u (a cone of directions at 90 - 50 = 40 deg to the axis)."""
    rev = Geom_SurfaceOfRevolution(revolved_profile(), gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1)))
    return _exact_bspline(rev, 0.0, 2 * math.pi, 0.0, 1.0)


def _fill(array, values):
    for k, v in enumerate(values, start=1):
        array.SetValue(k, v)
    return array


def plate_with_hole():
    """Plane plate 100 x 60 mm with a circular hole of radius 10 mm centred at (30, 25)."""
    plane = Geom_Plane(_ax3())
    pts = [gp_Pnt(0, 0, 0), gp_Pnt(100, 0, 0), gp_Pnt(100, 60, 0), gp_Pnt(0, 60, 0)]
    outer = BRepBuilderAPI_MakeWire()
    for a, b in zip(pts, pts[1:] + pts[:1]):
        outer.Add(BRepBuilderAPI_MakeEdge(a, b).Edge())
    circ = gp_Circ(gp_Ax2(gp_Pnt(30, 25, 0), gp_Dir(0, 0, -1)), 10.0)  # clockwise seen from +z: a hole
    hole = BRepBuilderAPI_MakeWire(BRepBuilderAPI_MakeEdge(circ).Edge()).Wire()
    maker = BRepBuilderAPI_MakeFace(plane, outer.Wire(), True)
    maker.Add(hole)
    return maker.Face()


# ---------------------------------------------------------------------- production-size draw die
# A sheet-metal draw die of production size, modelled with cadquery (tool solids) and OCP
# (booleans and fillets, whose modification history names every face by its role): a
# 1200 x 800 mm block whose top, the binder, is a crowned cylinder R 5000 (axis along y); a
# drawn pocket (rounded rectangle 760 x 440, corner R 90, 10 deg draft, punch-entry radius
# R 20) down to a double-curved B-spline panel floor (floor radius R 12); the blank-holder
# land carries double draw beads along the long sides (half-round R 6 following the crown,
# spherical ends), single straight beads along the short sides and eight pilot holes, all
# filleted R 3; the panel floor carries 18 embossings and 18 pockets (rounded rectangles
# 44 x 34, corner R 8, 15 deg draft, R 4 / R 3 end radii) in a checkerboard and 24 round
# bosses R 8, all filleted R 4 to the floor. Only the working (top) side is written.

class DieParams(NamedTuple):  # a NamedTuple, not a dataclass: tests load this file without sys.modules
    """Main dimensions of the production die [mm, deg]."""

    length: float = 1200.0  # block along x
    width: float = 800.0  # block along y
    height: float = 300.0  # block below the crown's top
    crown_radius: float = 5000.0  # binder: cylinder about an axis parallel to y
    pocket: tuple[float, float, float] = (760.0, 440.0, 90.0)  # at the binder: x, y, corner radius
    pocket_draft: float = 10.0
    punch_radius: float = 20.0  # punch-entry (die shoulder) radius
    floor_radius: float = 12.0
    bead_radius: float = 6.0
    land_fillet: float = 3.0  # bead feet and pilot-hole edges
    feature: tuple[float, float, float] = (44.0, 34.0, 8.0)  # embossing/pocket outline: x, y, corner radius
    feature_draft: float = 15.0
    feature_fillet: float = 4.0  # feature feet on the floor, pocket entries


def crown_z(x: float, p: DieParams = DieParams()) -> float:
    """Height of the binder (crown cylinder) above x."""
    return math.sqrt(p.crown_radius ** 2 - x * x) - p.crown_radius


def floor_z(x: float, y: float) -> float:
    """Pocket floor: a gently double-curved panel, 90..105 mm below the crown's top."""
    return -105.0 + 15.0 * math.cos(math.pi * x / 1200.0) * math.cos(math.pi * y / 800.0)


def _subshapes(shape: TopoDS_Shape, kind) -> list:
    cast = TopoDS.Face_s if kind == TopAbs_FACE else TopoDS.Edge_s
    out, exp = [], TopExp_Explorer(shape, kind)
    while exp.More():
        out.append(cast(exp.Current()))
        exp.Next()
    return out


class _TrackedSolid:
    """A solid whose faces carry a role, kept through OCC's modification history."""

    def __init__(self, shape: TopoDS_Shape, role: str) -> None:
        self.shape = shape
        self.roles: dict[str, list] = {role: _subshapes(shape, TopAbs_FACE)}

    def _update(self, op, new_role: str) -> None:
        for role, faces in self.roles.items():
            new = []
            for f in faces:
                mod = op.Modified(f)
                if mod.Size():
                    new += [TopoDS.Face_s(s) for s in mod]
                elif not op.IsDeleted(f):
                    new.append(f)
            self.roles[role] = new
        self.shape = op.Shape()
        known = TopTools_IndexedMapOfShape()
        for faces in self.roles.values():
            for f in faces:
                known.Add(f)
        fresh = [f for f in _subshapes(self.shape, TopAbs_FACE) if not known.Contains(f)]
        self.roles.setdefault(new_role, []).extend(fresh)

    def boolean(self, kind: str, tools: Sequence[TopoDS_Shape], role: str) -> None:
        """Fuse or cut all tools at once; the tools' faces take ``role``."""
        op: BRepAlgoAPI_BooleanOperation = {"fuse": BRepAlgoAPI_Fuse, "cut": BRepAlgoAPI_Cut}[kind]()
        args, tl = TopTools_ListOfShape(), TopTools_ListOfShape()
        args.Append(self.shape)
        for t in tools:
            tl.Append(t)
        self.roles.setdefault(role, []).extend(f for t in tools for f in _subshapes(t, TopAbs_FACE))
        op.SetArguments(args)
        op.SetTools(tl)
        op.Build()
        if not op.IsDone():
            raise RuntimeError(f"die: {kind} of {len(tools)} {role} tools failed")
        self._update(op, role)

    def fillet(self, edges: Sequence, radius: float, role: str) -> None:
        mk = BRepFilletAPI_MakeFillet(self.shape)
        for e in edges:
            mk.Add(radius, e)
        mk.Build()
        if not mk.IsDone():
            raise RuntimeError(f"die: fillet R {radius} of {len(edges)} {role} edges failed")
        self._update(mk, role)

    def sharp_edges(self, role: str, inner_only: bool = True) -> list:
        """Sharp (C0) edges bounding the faces of ``role`` (of their inner wires only, if asked)."""
        BRepLib.EncodeRegularity_s(self.shape, 1e-3)
        ancestors = TopTools_IndexedDataMapOfShapeListOfShape()
        TopExp.MapShapesAndAncestors_s(self.shape, TopAbs_EDGE, TopAbs_FACE, ancestors)
        picked = TopTools_IndexedMapOfShape()
        for f in self.roles[role]:
            outer = BRepTools.OuterWire_s(f)
            exp = TopExp_Explorer(f, TopAbs_WIRE)
            while exp.More():
                if not (inner_only and exp.Current().IsSame(outer)):
                    for e in _subshapes(exp.Current(), TopAbs_EDGE):
                        faces = list(ancestors.FindFromKey(e))
                        if len(faces) == 2 and BRep_Tool.Continuity_s(e, TopoDS.Face_s(faces[0]), TopoDS.Face_s(faces[1])) == GeomAbs_C0:
                            picked.Add(e)
                exp.Next()
        return [TopoDS.Edge_s(picked.FindKey(i)) for i in range(1, picked.Size() + 1)]


def _floor_surface() -> Geom_BSplineSurface:
    """Bicubic B-spline through floor_z on a 13 x 9 grid (reaching past the pocket floor)."""
    nx, ny = 13, 9
    pts = TColgp_Array2OfPnt(1, nx, 1, ny)
    for i in range(nx):
        for j in range(ny):
            x, y = -480.0 + 960.0 * i / (nx - 1), -300.0 + 600.0 * j / (ny - 1)
            pts.SetValue(i + 1, j + 1, gp_Pnt(x, y, floor_z(x, y)))
    return GeomAPI_PointsToBSplineSurface(pts, 3, 3, GeomAbs_C2, 1e-6).Surface()


def _prism(x: float, y: float, z0: float, h: float, sketch: Callable[[cq.Sketch], cq.Sketch], *, taper: float = 0.0, down: bool = False, end_fillet: float = 0.0) -> TopoDS_Shape:
    """A drafted prism from the plane z = z0 up (or down) by h, its far end filleted."""
    plane = cq.Plane(origin=(x, y, z0), xDir=(1, 0, 0), normal=(0, 0, -1 if down else 1))
    wp = cq.Workplane(plane).placeSketch(sketch(cq.Sketch())).extrude(h, taper=taper)
    if end_fillet:
        wp = wp.faces("<Z" if down else ">Z").edges().fillet(end_fillet)
    return wp.val().wrapped


def _rounded_rect(w: float, d: float, r: float) -> Callable[[cq.Sketch], cq.Sketch]:
    return lambda s: s.rect(w, d).vertices().fillet(r)


def _circle(r: float) -> Callable[[cq.Sketch], cq.Sketch]:
    return lambda s: s.circle(r)


def production_die(p: DieParams = DieParams()) -> tuple[TopoDS_Shape, dict[str, list]]:
    """The die solid and its faces by role (every top-side face has exactly one role)."""
    L, W, H, R = p.length, p.width, p.height, p.crown_radius
    block = (cq.Workplane("XZ").moveTo(-L / 2, -H).lineTo(L / 2, -H).lineTo(L / 2, crown_z(L / 2, p))
             .threePointArc((0.0, 0.0), (-L / 2, crown_z(-L / 2, p))).close().extrude(W / 2, both=True))
    die = _TrackedSolid(block.val().wrapped, "block")
    die.roles["binder"] = [f for f in die.roles["block"] if BRep_Tool.Surface_s(f).DynamicType().Name() == "Geom_CylindricalSurface"]
    die.roles["block"] = [f for f in die.roles["block"] if not f.IsSame(die.roles["binder"][0])]

    # the drawn pocket: drafted rounded rectangle from above the binder, down to the panel floor
    pw, pd, pr = p.pocket
    z_top = 60.0
    grow = 2 * z_top * math.tan(math.radians(p.pocket_draft))
    drafted = _prism(0.0, 0.0, z_top, 260.0, _rounded_rect(pw + grow, pd + grow, pr + grow / 2), taper=p.pocket_draft, down=True)
    floor = BRepBuilderAPI_MakeFace(_floor_surface(), 1e-7).Face()
    above_floor = BRepPrimAPI_MakePrism(floor, gp_Vec(0.0, 0.0, 400.0)).Shape()
    pocket = BRepAlgoAPI_Common(drafted, above_floor).Shape()
    die.boolean("cut", [pocket], "pocket wall")
    die.roles["floor"] = [f for f in die.roles.pop("pocket wall") if BRep_Tool.Surface_s(f).DynamicType().Name() == "Geom_BSplineSurface"]
    die.roles["pocket wall"] = [f for f in _subshapes(die.shape, TopAbs_FACE)
                                if not any(f.IsSame(g) for k in ("block", "binder", "floor") for g in die.roles[k])]
    die.fillet(die.sharp_edges("binder"), p.punch_radius, "punch radius")
    die.fillet(die.sharp_edges("floor", inner_only=False), p.floor_radius, "floor radius")

    # draw beads on the blank-holder land (tube axis on the binder surface) and pilot holes
    r = p.bead_radius
    beads = []
    half = math.asin(420.0 / R)  # long-side beads: x in [-420, 420], following the crown (a torus R 5000)
    for y0 in (-335.0, -300.0, 300.0, 335.0):
        ax = gp_Ax2(gp_Pnt(0.0, y0, -R), gp_Dir(0, 1, 0), gp_Dir(-math.sin(half), 0, math.cos(half)))
        beads.append(BRepPrimAPI_MakeTorus(ax, R, r, 2 * half).Shape())
        beads += [BRepPrimAPI_MakeSphere(gp_Pnt(s * R * math.sin(half), y0, R * math.cos(half) - R), r).Shape() for s in (-1, 1)]
    for x0 in (-470.0, 470.0):  # short-side beads: straight (the crown's axis is along y), y in [-200, 200]
        z0 = crown_z(x0, p)
        beads.append(cq.Solid.makeCylinder(r, 400.0, cq.Vector(x0, -200.0, z0), cq.Vector(0, 1, 0)).wrapped)
        beads += [BRepPrimAPI_MakeSphere(gp_Pnt(x0, y, z0), r).Shape() for y in (-200.0, 200.0)]
    die.boolean("fuse", beads, "bead")
    holes = [_prism(sx * 545.0, sy * y, 20.0, 60.0, _circle(12.5), down=True) for sx in (-1, 1) for sy in (-1, 1) for y in (120.0, 350.0)]
    die.boolean("cut", holes, "pilot hole")
    die.fillet(die.sharp_edges("binder"), p.land_fillet, "land radius")

    # the panel's features on the floor: embossings (up) and pockets (down), round bosses
    w, d, rc = p.feature
    a = math.tan(math.radians(p.feature_draft))
    emboss, sink, bosses = [], [], []
    for i in range(9):
        for j, y in enumerate((-150.0, -50.0, 50.0, 150.0)):
            x = -300.0 + 75.0 * i
            zf = floor_z(x, y)
            if (i + j) % 2 == 0:  # embossing 12 above the floor; the outline w x d at its top
                h = 32.0
                emboss.append(_prism(x, y, zf - 20.0, h, _rounded_rect(w + 2 * h * a, d + 2 * h * a, rc + h * a), taper=p.feature_draft, end_fillet=4.0))
            else:  # pocket 10 below the floor; the outline w x d at its bottom
                h = 30.0
                sink.append(_prism(x, y, zf + 20.0, h, _rounded_rect(w + 2 * h * a, d + 2 * h * a, rc + h * a), taper=p.feature_draft, down=True, end_fillet=3.0))
    for i in range(8):
        for y in (-100.0, 0.0, 100.0):
            x = -262.5 + 75.0 * i
            bosses.append(_prism(x, y, floor_z(x, y) - 20.0, 30.0, _circle(8.0), end_fillet=3.0))
    die.boolean("fuse", emboss, "embossing")
    die.boolean("fuse", bosses, "boss")
    die.boolean("cut", sink, "floor pocket")
    die.fillet(die.sharp_edges("floor"), p.feature_fillet, "feature radius")
    return die.shape, die.roles


#: short codes of the face roles (the first 3 characters of each face's name)
DIE_ROLES = {"binder": "BND", "punch radius": "PRD", "pocket wall": "PWL", "floor radius": "FRD", "floor": "FLR",
             "bead": "BED", "pilot hole": "PIL", "land radius": "LRD", "embossing": "EMB", "boss": "BOS",
             "floor pocket": "PKT", "feature radius": "FTR"}


@functools.cache
def production_die_faces(p: DieParams = DieParams()) -> dict[str, TopoDS_Shape]:
    """{name: face} of the die's top side, in OCC's face order; a name is role code + index.

    Cached: both IGES modes write the same faces (about 20 s to build)."""
    shape, roles = production_die(p)
    if not BRepCheck_Analyzer(shape).IsValid():
        raise RuntimeError("die: the solid is not valid")
    index: dict[str, TopTools_IndexedMapOfShape] = {}
    for role, faces in roles.items():
        m = TopTools_IndexedMapOfShape()
        for f in faces:
            m.Add(f)
        index[role] = m
    out: dict[str, TopoDS_Shape] = {}
    for f in _subshapes(shape, TopAbs_FACE):
        hits = [role for role, m in index.items() if m.Contains(f)]
        if len(hits) != 1:
            raise RuntimeError(f"die: a face has roles {hits}")
        if hits[0] != "block":
            out[f"{DIE_ROLES[hits[0]]}{len(out) + 1:05d}"] = f
    return out


def _production_die(mode: str) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        faces = production_die_faces()
        export_iges(faces, path, mode, description=f"cadbridge: production-size sheet-metal draw die, working side ({len(faces)} faces: "
                    "crowned binder R5000, drawn pocket with 10 deg draft and R20 punch radius, B-spline panel floor, draw beads, "
                    f"embossings, pockets, bosses, pilot holes, fillets R3-R20), {'NURBS' if mode == 'nurbs' else 'OCC analytic faces'} mode")
    return make


# ---------------------------------------------------------------------- the samples
def _ushape_tool(tool: str) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        faces = tool_faces(UShapeParams())[tool]
        export_iges(faces, path, "nurbs", colors={k: TOOL_COLORS[tool] for k in faces},
                    description=f"cadbridge: NUMISHEET'93 U-shape {tool} contact surfaces (quarter model), NURBS mode")
    return make


def make_tools_nurbs(path: Path) -> None:
    faces = tool_faces(UShapeParams())
    flat = {k: f for tool in faces.values() for k, f in tool.items()}
    colors = {k: TOOL_COLORS[t] for t, d in faces.items() for k in d}
    export_iges(flat, path, "nurbs", colors=colors, description="cadbridge: NUMISHEET'93 U-shape die, punch and blank holder (quarter model), NURBS mode")


def make_tools_analytic(path: Path) -> None:
    faces = tool_faces(UShapeParams())
    flat = {k: f for tool in faces.values() for k, f in tool.items()}
    colors = {k: TOOL_COLORS[t] for t, d in faces.items() for k in d}
    export_iges(flat, path, "analytic", colors=colors, description="cadbridge: NUMISHEET'93 U-shape tools (quarter model), OCC analytic faces mode")


# Appendix A of Neto (2010), entity data exactly as printed (numbers kept as strings).
THESIS_128 = (
    "7,1,3,1,0,0,1,0,0,"
    "0,0,0,0,0.2696129,0.50025292,0.69102833,0.81038681,1,1,1,1,"
    "0,0,1,1,"
    + ",".join(["1"] * 16) + ","
    "-2.804053,-5.16892,0,-3.0315653,-4.0968669,0,-3.0830998,-2.6158131,0,"
    "-2.450814,-0.24658376,0,-1.5993302,1.3546726,0,-1.2423752,3.0707054,0,"
    "-1.1892867,3.9613801,0,-1.250001,4.729729,0,"
    "-2.804053,-5.16892,10,-3.0315653,-4.0968669,10,-3.0830998,-2.6158131,10,"
    "-2.450814,-0.24658376,10,-1.5993302,1.3546726,10,-1.2423752,3.0707054,10,"
    "-1.1892867,3.9613801,10,-1.250001,4.729729,10,"
    "0,1,0,1"
).split(",")


def make_thesis(path: Path) -> None:
    ent = _Entity(128, THESIS_128, label="NURBSURF", subscript=1)
    write_iges_by_hand(path, [ent], ["Translator GID - IGES (entity data of Neto 2010, appendix A;",
                                      "S and G sections reconstructed by cadbridge)"],
                       product="GID", system="GID", author="", organization="CIMNE", max_coord=10.0)


def _exact_face_sample(build: Callable[[], Geom_BSplineSurface], label: str, text: str) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        export_iges({label: _face(build())}, path, "nurbs", description=f"cadbridge: {text}")
    return make


def _rotation(axis: tuple[float, float, float], angle: float) -> list[list[float]]:
    """Rotation matrix (Rodrigues) about a unit axis."""
    x, y, z = axis
    n = math.sqrt(x * x + y * y + z * z)
    x, y, z = x / n, y / n, z / n
    c, s, C = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]


def _matrix_124(rot: list[list[float]], t: tuple[float, float, float]) -> list[float]:
    return [rot[0][0], rot[0][1], rot[0][2], t[0], rot[1][0], rot[1][1], rot[1][2], t[1], rot[2][0], rot[2][1], rot[2][2], t[2]]


#: the two matrices of placed_by_124.igs: (rotation axis, angle, translation)
PLACEMENTS = {
    "T1": ((0.0, 0.0, 1.0), math.radians(30.0), (10.0, 0.0, 5.0)),
    "T2": ((1.0, 1.0, 0.0), math.radians(20.0), (0.0, -4.0, 2.0)),
}


def _placements() -> tuple[_Entity, _Entity]:
    t1 = _Entity(124, _matrix_124(_rotation(*PLACEMENTS["T1"][:2]), PLACEMENTS["T1"][2]))
    t2 = _Entity(124, _matrix_124(_rotation(*PLACEMENTS["T2"][:2]), PLACEMENTS["T2"][2]))
    return t1, t2


def make_placed(path: Path) -> None:
    t1, t2 = _placements()
    s1 = _Entity(128, bspline_128_params(sphere_patch()), transform=1, label="SPHERE")
    s2 = _Entity(128, bspline_128_params(quarter_cylinder()), transform=3, label="CYLINDER")
    write_iges_by_hand(path, [t1, t2, s1, s2], ["cadbridge: two 128 surfaces placed by 124 matrices:",
                                               "DE 5 (sphere patch) by 124 DE 1 (T1), DE 7 (quarter cylinder) by",
                                               "124 DE 3 (T2)."],
                       product="cadbridge placed_by_124", system="cadbridge make_samples.py", author="cadbridge", organization="cadbridge")


def make_chained(path: Path) -> None:
    t1, t2 = _placements()
    t2.transform = 1  # T2 is itself placed by T1: the surface under T2 maps to T1(T2(x)) (IGES 5.3, 4.21)
    s2 = _Entity(128, bspline_128_params(quarter_cylinder()), transform=3, label="CYLINDER")
    write_iges_by_hand(path, [t1, t2, s2], ["cadbridge: a 128 surface (DE 5, quarter cylinder) placed by 124 DE 3",
                                           "(T2), which is itself placed by 124 DE 1 (T1): x -> T1(T2(x)).",
                                           "OpenCASCADE 7.9 applies T2 only."],
                       product="cadbridge placed_by_chained_124", system="cadbridge make_samples.py", author="cadbridge", organization="cadbridge")


def make_hole(path: Path) -> None:
    export_iges({"PLATE": plate_with_hole()}, path, "nurbs", description="cadbridge: plate 100 x 60 with a hole R10 at (30, 25), NURBS mode (144 with an inner boundary)")


SAMPLES: dict[str, Callable[[Path], None]] = {
    "ushape_die_nurbs.igs": _ushape_tool("die"),
    "ushape_punch_nurbs.igs": _ushape_tool("punch"),
    "ushape_blankholder_nurbs.igs": _ushape_tool("blankholder"),
    "ushape_tools_nurbs.igs": make_tools_nurbs,
    "ushape_tools_analytic.igs": make_tools_analytic,
    "thesis_appendix_a.igs": make_thesis,
    "rational_quarter_cylinder.igs": _exact_face_sample(quarter_cylinder, "QCYL", "exact rational quarter cylinder R5 (die shoulder), 20.5 long"),
    "sphere_patch.igs": _exact_face_sample(sphere_patch, "SPHERE", "exact rational sphere patch R10, lon 0-90, lat 0-60 deg"),
    "torus_patch.igs": _exact_face_sample(torus_patch, "TORUS", "exact rational torus patch R20 r5, quarter turn, outer half"),
    "multiple_knots.igs": _exact_face_sample(multiple_knots_surface, "MULTKNOT", "rational bicubic with u knots of multiplicity 2 (C1) and 3 (C0)"),
    "placed_by_124.igs": make_placed,
    "trimmed_hole.igs": make_hole,
    "cone_apex.igs": _exact_face_sample(full_cone, "CONE", "full cone, half angle 30 deg, apex (0, 0, 20) on top (collapsed edge v = 0), 20 tall"),
    "hemisphere_pole.igs": _exact_face_sample(hemisphere, "HEMISPH", "hemisphere R10 about +z, pole (0, 0, 10) a collapsed edge"),
    "revolved_apex.igs": _exact_face_sample(revolved_apex, "REVAPEX", "cubic profile revolved about z, leaving the axis at 50 deg at the apex (0, 0, 15)"),
}

#: The production-size die (issue #8): written only with ``--production`` (about 40 s, 2 x 25
#: MB), kept apart from SAMPLES, which the test suite regenerates and runs every file of.
PRODUCTION_SAMPLES: dict[str, Callable[[Path], None]] = {
    "production_die_nurbs.igs": _production_die("nurbs"),
    "production_die_analytic.igs": _production_die("analytic"),
}


#: Reader test cases that are not samples (OpenCASCADE, the reference of `cadbridge verify`,
#: reads them differently from the IGES standard), written to tests/data/iges/.
TEST_DATA: dict[str, Callable[[Path], None]] = {
    "placed_by_chained_124.igs": make_chained,
}
TEST_DATA_DIR = HERE.parent / "tests" / "data" / "iges"


def counts_table(folder: Path, names: Sequence[str] = tuple(SAMPLES)) -> str:
    """Markdown table: file, size, entity counts."""
    rows = ["| file | bytes | entities (type: count) |", "|---|---:|---|"]
    for name in names:
        p = folder / name
        counts = ", ".join(f"{t}: {n}" for t, n in entity_counts(p).items())
        rows.append(f"| `{name}` | {p.stat().st_size} | {counts} |")
    return "\n".join(rows)


def _replace_between(text: str, a: str, b: str, body: str) -> str:
    if a not in text or b not in text:
        return text
    head, rest = text.split(a, 1)
    _, tail = rest.split(b, 1)
    return f"{head}{a}\n{body}\n{b}{tail}"


def update_readme(folder: Path) -> None:
    """Rewrite the tables between the README markers (the production one if its files exist)."""
    if not README.exists():
        return
    text = _replace_between(README.read_text(), "<!-- counts:start -->", "<!-- counts:end -->", counts_table(folder))
    if all((folder / n).exists() for n in PRODUCTION_SAMPLES):
        text = _replace_between(text, "<!-- production-counts:start -->", "<!-- production-counts:end -->",
                                counts_table(folder, tuple(PRODUCTION_SAMPLES)))
    README.write_text(text)


def main(argv: list[str] | None = None) -> int:
    """make_samples.py [--production] [OUT_DIR]: the samples (and, asked, the production die)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    production = "--production" in argv
    argv = [a for a in argv if a != "--production"]
    out = Path(argv[0]) if argv else HERE
    out.mkdir(parents=True, exist_ok=True)
    written = dict(SAMPLES, **(PRODUCTION_SAMPLES if production else {}))
    for name, make in written.items():
        make(out / name)
    if out == HERE:
        update_readme(out)
        TEST_DATA_DIR.mkdir(parents=True, exist_ok=True)
    for name, make in TEST_DATA.items():
        make((TEST_DATA_DIR if out == HERE else out) / name)
    for name in written:
        print(f"{name:32s} {entity_counts(out / name)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

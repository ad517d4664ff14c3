"""STEP (ISO 10303-21: AP203, AP214, AP242) -> `Model`, through OpenCASCADE.

OCC reads and transfers the file (`STEPCAFControl_Reader`: the product structure with its
names and colours; lengths converted to mm as the file's representation context says,
conversion-based units included). Every face becomes a cadbridge `Face`:

- a face on a plane, cylinder, cone, sphere, torus or an extrusion of a circle or an ellipse:
  its surface built exactly over its loops and its pcurves mapped exactly onto it
  (`cadbridge.step.analytic`: OCC's (u, v) there is an affine image of the natural coordinates
  the IGES reader uses for 190-198), oriented as the face;
- an extrusion of a B-spline curve: its surface as that B-spline swept along a line
  (`ShapeCustom.ConvertToBSpline`: exact, in the same (u, v), its pcurves kept);
- any other face: its surface as an exact NURBS through `BRepBuilderAPI_NurbsConvert`, face by
  face (revolutions and other extrusions convert exactly; the face's pcurves are rewritten
  into the B-spline's parameters by approximation; offset surfaces are approximated), or
  taken as it is on a B-spline. Periodic B-splines are cut to the face's (u, v) box
  (`Geom_BSplineSurface.Segment`: the same parameters, clamped knots), which also moves a
  seam the face straddles off the face;
- its trims from the face's pcurves (`BRep_Tool.CurveOnSurface`, which picks each side of a
  seam edge), as 2D NURBS, loop by loop in the wire's order (`BRepTools_WireExplorer`), the
  outer loop first (the one with the largest (u, v) box: `BRepTools.OuterWire` can name a hole);
- a converted face OCC holds reversed gets its surface's u reversed (pcurves mirrored with
  it), so the model's normal S_u x S_v is the face's outward normal, as in IGES;
- its name is its product's (the assembly instance's where the product has none), its
  colour the face's or else its shape's.

The model's ``trim_delta`` of a face is its largest edge tolerance (OCC's bound on how far
the edges' 3D curves and pcurves disagree): the STEP counterpart of IGES's 2D/3D trim delta.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cadbridge.cad.model import Diagnostic, Face, Model, Trim, TrimLoop, Units
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.curve_pack import PackedCurves
from cadbridge.nurbs.edits import reverse_curve, surface_from_homogeneous
from cadbridge.nurbs.knots import reverse
from cadbridge.nurbs.surface import NurbsSurface
from cadbridge.step.analytic import ELEMENTARY, elementary_face
from cadbridge.step.errors import StepError

__all__ = ["is_step", "occ_step_shape", "originating_system", "read_step"]

MAGIC = b"ISO-10303-21;"


MAX_DELTA_REL = 1e-3
"""A face's trim tolerance (its largest edge tolerance) is at most this x the model size."""
BOX_SAMPLES = 33
"""Points per trim piece from which a loop's (u, v) box is taken (the largest box is the outer loop)."""
PREPROCESSOR = "STEP (ISO 10303-21), read through OpenCASCADE"
"""`Model.preprocessor` of a model read from STEP: how `cadbridge inspect` tells the format."""


def originating_system(path: str | Path) -> str:
    """The header's FILE_NAME originating system (its next-to-last string), or ""."""
    import re

    with open(path, "rb") as fh:
        text = fh.read(20000).decode("latin-1")
    m = re.search(r"FILE_NAME\s*\((.*?)\)\s*;", text, re.S)
    strings = re.findall(r"'((?:[^']|'')*)'", m.group(1)) if m else []
    return strings[-2].strip() if len(strings) >= 2 else ""


def occ_step_shape(path: str | Path):
    """OCC's own reading of the STEP file at ``path``: `STEPControl_Reader`, all roots, lengths
    in mm (`OneShape`); None where OCC cannot read or transfer it. The reference of
    `cadbridge verify` and the "file as OCC reads it" of the mesher's fallback route."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_Reader

    Interface_Static.SetCVal_s("xstep.cascade.unit", "MM")
    reader = STEPControl_Reader()
    if reader.ReadFile(str(path)) != IFSelect_RetDone or reader.TransferRoots() == 0:
        return None
    shape = reader.OneShape()
    return None if shape.IsNull() else shape


def is_step(path: str | Path) -> bool:
    """Whether the file at ``path`` starts (after blanks) with the ISO 10303-21 header."""
    with open(path, "rb") as fh:
        head = fh.read(4096).lstrip(b"\xef\xbb\xbf \t\r\n")
    return head.upper().startswith(MAGIC)


def _knots(knots, mults) -> np.ndarray:
    """Full knot vector of an OCC (knots, multiplicities) pair (TColStd arrays)."""
    k = [knots.Value(i) for i in range(knots.Lower(), knots.Upper() + 1)]
    m = [mults.Value(i) for i in range(mults.Lower(), mults.Upper() + 1)]
    return np.repeat(np.asarray(k, dtype=float), np.asarray(m, dtype=int))


def nurbs_surface(s, shift: tuple[float, float] = (0.0, 0.0)) -> NurbsSurface:
    """cadbridge's NURBS of a non-periodic `Geom_BSplineSurface` ``s`` (same parameters, its
    knots moved by ``shift`` (u, v))."""
    nu, nv = s.NbUPoles(), s.NbVPoles()
    cp = np.empty((nu, nv, 3))
    w = np.ones((nu, nv))
    for i in range(nu):  # loop over poles: OCC hands them out one at a time
        for j in range(nv):
            p = s.Pole(i + 1, j + 1)
            cp[i, j] = (p.X(), p.Y(), p.Z())
            w[i, j] = s.Weight(i + 1, j + 1)
    from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal

    ku, mu = TColStd_Array1OfReal(1, s.NbUKnots()), TColStd_Array1OfInteger(1, s.NbUKnots())
    kv, mv = TColStd_Array1OfReal(1, s.NbVKnots()), TColStd_Array1OfInteger(1, s.NbVKnots())
    s.UKnots(ku)
    s.UMultiplicities(mu)
    s.VKnots(kv)
    s.VMultiplicities(mv)
    rational = s.IsURational() or s.IsVRational()
    out = NurbsSurface(s.UDegree(), s.VDegree(), _knots(ku, mu) + shift[0], _knots(kv, mv) + shift[1], cp,
                       w if rational else None)
    p, q = out.degree_u, out.degree_v
    clamped = all(np.all(k[: d + 1] == k[0]) and np.all(k[-d - 1:] == k[-1])
                  for k, d in ((out.knots_u, p), (out.knots_v, q)))
    if not clamped:  # OCC's unclamped non-periodic knots (NurbsConvert's cylinders): the same surface, clamped
        from cadbridge.nurbs.edits import restrict_surface

        out = restrict_surface(out, out.domain)
    return out


def nurbs_curve2d(c) -> NurbsCurve:
    """cadbridge's 2D NURBS of a non-periodic `Geom2d_BSplineCurve` ``c``."""
    from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal

    n = c.NbPoles()
    cp = np.array([(c.Pole(i).X(), c.Pole(i).Y()) for i in range(1, n + 1)])
    w = np.array([c.Weight(i) for i in range(1, n + 1)])
    k, m = TColStd_Array1OfReal(1, c.NbKnots()), TColStd_Array1OfInteger(1, c.NbKnots())
    c.Knots(k)
    c.Multiplicities(m)
    return NurbsCurve(c.Degree(), _knots(k, m), cp, w if c.IsRational() else None)


def _reversed_u(s: NurbsSurface) -> NurbsSurface:
    """The same surface with u reversed: S'(u, v) = S(a + b - u, v) on the same u range [a, b]."""
    kn, cw = reverse(s.knots_u, s.degree_u, s._pw, axis=0)
    return surface_from_homogeneous(s.degree_u, s.degree_v, kn, s.knots_v, cw)


def _mirrored_u(c: NurbsCurve, a: float, b: float) -> NurbsCurve:
    """Pcurve ``c`` for the surface with u reversed on [a, b]: (u, v) -> (a + b - u, v)."""
    cp = c.control_points.copy()
    cp[:, 0] = (a + b) - cp[:, 0]
    return NurbsCurve(c.degree, c.knots, cp, c.weights if c.rational else None)


def _bspline_surface(face):
    """The face's surface as a non-periodic `Geom_BSplineSurface` with the face's parameters
    (location applied; the face is already NURBS-converted): a periodic direction is cut to
    one period from the face's first parameter (`Segment`; that moves a seam the face
    straddles off it; where OCC shifts the cut by whole periods, the knots are shifted back,
    which changes no point), a bounded one to the face's (u, v) box where that leaves knots
    OCC accepts (the model's size is then the faces', not their surfaces'). Returns the
    surface and the (u, v) shift of its knots to apply."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepTools import BRepTools
    from OCP.Geom import Geom_BSplineSurface

    surf = BRep_Tool.Surface_s(face)  # OCP hands out the most derived type
    if not isinstance(surf, Geom_BSplineSurface):
        raise StepError(f"a face's surface is a {type(surf).__name__}, which NURBS conversion left as it is")
    s = surf.Copy()
    u0, u1, v0, v1 = BRepTools.UVBounds_s(face)
    shift = [0.0, 0.0]
    was = (s.IsUPeriodic(), s.IsVPeriodic())
    box = ((u0, u1), (v0, v1))
    # periodic directions first: cutting the other one (`Segment`) clamps both
    for k in [i for i in (0, 1) if was[i]] + [i for i in (0, 1) if not was[i]]:
        lo, hi = box[k]
        periodic = s.IsUPeriodic() if k == 0 else s.IsVPeriodic()
        a0, a1, b0, b1 = s.Bounds()
        first, last = (a0, a1) if k == 0 else (b0, b1)
        if periodic:
            per = s.UPeriod() if k == 0 else s.VPeriod()
            gap = per - (hi - lo)
            n = np.floor((lo - first) / per + 1e-9)
            if gap <= 1e-9 * per and hi <= last + n * per + 1e-9 * per:  # a closed face, seam and all
                (s.SetUNotPeriodic if k == 0 else s.SetVNotPeriodic)()
                shift[k] = n * per
                continue
            # the period's origin moved to the middle of the gap the face leaves (a knot
            # inserted there, made the origin: the same surface), then clamped: the seam lies
            # off the face, and no node on the face's border has a twin a period away
            start = lo - 0.5 * max(gap, 0.0)
            at = first + np.mod(start - first, per)
            if k == 0:
                s.InsertUKnot(at, 1, 1e-12 * per)
                idx = int(np.argmin([abs(s.UKnot(i) - at) for i in range(1, s.NbUKnots() + 1)])) + 1
                s.SetUOrigin(idx)
                s.SetUNotPeriodic()
            else:
                s.InsertVKnot(at, 1, 1e-12 * per)
                idx = int(np.argmin([abs(s.VKnot(i) - at) for i in range(1, s.NbVKnots() + 1)])) + 1
                s.SetVOrigin(idx)
                s.SetVNotPeriodic()
            got = s.Bounds()[2 * k]
            turns = (start - got) / per
            shift[k] = round(turns) * per if abs(turns - round(turns)) < 1e-6 else 0.0
            continue
        lo, hi = max(lo, first), min(hi, last)
        if not hi - lo > 1e-9 * (last - first) or (lo <= first and hi >= last):
            continue  # the whole range already (or a face box OCC's bounds do not hold)
        trial = s.Copy()
        try:
            if k == 0:
                trial.Segment(lo, hi, b0, b1)
            else:
                trial.Segment(a0, a1, lo, hi)
        except Exception:  # noqa: BLE001 - OCP's Standard_* exceptions share no Python base but Exception
            continue  # knots OCC will not cut there: the whole surface (its box is then the model's)
        s = trial
    return s, tuple(shift)


def _face_loops(face, flip: tuple[float, float] | None) -> tuple[list[list[NurbsCurve]], float]:
    """The trim loops of ``face`` from its pcurves (each a list of 2D NURBS in the face's
    (u, v), mirrored in u on [a, b] where ``flip`` = (a, b)), outer first, and its largest edge
    tolerance."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepTools import BRepTools, BRepTools_WireExplorer
    from OCP.Geom2d import Geom2d_TrimmedCurve
    from OCP.Geom2dConvert import Geom2dConvert
    from OCP.TopAbs import TopAbs_REVERSED, TopAbs_WIRE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    outer = BRepTools.OuterWire_s(face)
    wires = [outer] if not outer.IsNull() else []
    ex = TopExp_Explorer(face, TopAbs_WIRE)
    while ex.More():
        w = TopoDS.Wire_s(ex.Current())
        if outer.IsNull() or not w.IsSame(outer):
            wires.append(w)
        ex.Next()
    wires_pieces: list[tuple[list[NurbsCurve], list[tuple[float, float]]]] = []
    tol = 0.0
    surface = BRep_Tool.Surface_s(face)
    for w in wires:
        curves, joints = [], []  # joints[i]: (vertex tolerance, edge tolerance) where piece i starts
        we = BRepTools_WireExplorer(w, face)
        while we.More():
            e = we.Current()
            tol = max(tol, BRep_Tool.Tolerance_s(e))
            joint = (BRep_Tool.Tolerance_s(we.CurrentVertex()), BRep_Tool.Tolerance_s(e))
            first, last = BRep_Tool.Range_s(e, face)
            c2 = BRep_Tool.CurveOnSurface_s(e, face, first, last)
            if c2 is None or last - first <= 0:
                we.Next()
                continue
            if not c2.IsPeriodic():  # a range a hair outside the curve's own (edge tolerance)
                first, last = max(first, c2.FirstParameter()), min(last, c2.LastParameter())
                if not last > first:
                    we.Next()
                    continue
            backwards = e.Orientation() == TopAbs_REVERSED
            c = _line_piece(c2, first, last, backwards)
            if c is None:
                bs = Geom2dConvert.CurveToBSplineCurve_s(Geom2d_TrimmedCurve(c2, first, last))
                if bs.IsPeriodic():
                    bs.SetNotPeriodic()
                c = nurbs_curve2d(bs)
                if backwards:
                    c = reverse_curve(c)
            curves.append(c)
            joints.append(joint)
            we.Next()
        if curves:
            wires_pieces.append((curves, joints))
    if not wires_pieces:
        return [], tol
    # every piece's ends and BOX_SAMPLES points in one compiled evaluation (the per-curve numpy
    # path cost more than OCC's whole read on faces with many edges); a clamped piece's ends
    # come out as its end control points exactly (`NurbsCurve.evaluate` missed them by an ulp
    # on 372 of the 3 775 pcurves of trj10_b2, trj8_k1-ct and trj8_b1)
    flat = [c for curves, _ in wires_pieces for c in curves]
    pk = PackedCurves(flat)
    ci = np.repeat(np.arange(len(flat)), BOX_SAMPLES)
    s01 = np.tile(np.linspace(0.0, 1.0, BOX_SAMPLES), len(flat))
    t = pk.dom[ci, 0] + s01 * (pk.dom[ci, 1] - pk.dom[ci, 0])
    pts = pk.evaluate(ci, t, 0)[:, 0, :2].reshape(len(flat), BOX_SAMPLES, 2)
    ends = pk.evaluate(np.repeat(np.arange(len(flat)), 2), pk.dom.ravel(), 0)[:, 0, :2].reshape(len(flat), 2, 2)
    loops: list[list[NurbsCurve]] = []
    areas: list[float] = []
    at = 0
    for curves, joints in wires_pieces:
        n = len(curves)
        loop = _bridged(curves, joints, ends[at:at + n], surface)
        box = pts[at:at + n].reshape(-1, 2)
        ext = box.max(axis=0) - box.min(axis=0)
        areas.append(float(ext[0] * ext[1]))
        at += n
        if flip is not None:
            loop = [_mirrored_u(c, *flip) for c in loop]
        loops.append(loop)
    # the outer loop: the one whose (u, v) box is largest (mirroring keeps the boxes' areas).
    # BRepTools.OuterWire can name a hole (K1 from CATIA V5: a planar ring whose inner wire came first)
    k = int(np.argmax(areas))
    return [loops[k]] + loops[:k] + loops[k + 1:], tol


def _line_piece(c2, first: float, last: float, backwards: bool = False) -> NurbsCurve | None:
    """The degree-1 NURBS of pcurve ``c2`` on [first, last] where it is a `Geom2d_Line` (a
    trimmed one read through), else None: what `Geom2dConvert.CurveToBSplineCurve` makes of
    it (poles the line's points at the ends, knots the ends; the same numbers on the
    corpus), without the OCC arrays (about 70 % of an analytic model's pcurves are lines);
    ``backwards``: traversed from last to first, the numbers of `reverse_curve` of it."""
    base = c2
    while type(base).__name__ == "Geom2d_TrimmedCurve":
        base = base.BasisCurve()
    if type(base).__name__ != "Geom2d_Line":
        return None
    a, b = c2.Value(first), c2.Value(last)
    knots, poles = np.array([first, first, last, last]), np.array([[a.X(), a.Y()], [b.X(), b.Y()]])
    if backwards:
        knots, poles = reverse(knots, 1, poles)
    return NurbsCurve(1, knots, poles)


def _bridged(curves: list[NurbsCurve], joints: list[tuple[float, float]], ends: np.ndarray,
             surface) -> list[NurbsCurve]:
    """The pieces of one wire, in order, with a straight (u, v) piece added where a piece ends
    short of the next one's start by more than both edges' tolerances but within the shared
    vertex's (``joints[i]``: (vertex tolerance, edge tolerance) where piece i starts; ``ends``
    (n, 2, 2): each piece's (u, v) at its start and end; 3D gap on ``surface``, OCC's
    `Geom_Surface`).

    OCC's topology joins two edges through their vertex, whose tolerance may cover an edge
    curve that stops short of it (b1 from CASCADE, trj8: an edge on planar face 206 stops
    0.43 mm short; OCC finds the shape valid). The pcurves alone leave the loop open there,
    and an open loop is no wire for the mesher ("Could not fix wire"). The straight piece is
    what the vertex stands for: the shortest join in (u, v)."""
    n = len(curves)
    out: list[NurbsCurve] = []
    for i, c in enumerate(curves):
        out.append(c)
        vertex_tol, edge_tol = joints[(i + 1) % n]
        a, b = ends[i, 1], ends[(i + 1) % n, 0]
        gap = surface.Value(float(a[0]), float(a[1])).Distance(surface.Value(float(b[0]), float(b[1])))
        if max(edge_tol, joints[i][1]) < gap <= 2.0 * vertex_tol:
            out.append(NurbsCurve(1, [0.0, 0.0, 1.0, 1.0], np.array([a, b])))
    return out


def _face_trims(face, flip: tuple[float, float] | None) -> tuple[Trim | None, float]:
    """The `Trim` of ``face`` (`_face_loops`) and its largest edge tolerance."""
    loops, tol = _face_loops(face, flip)
    if not loops:
        return None, tol
    return Trim(TrimLoop(loops[0]), [TrimLoop(lp) for lp in loops[1:]]), tol


def _leaves(shape_tool, label, location, name: str, out: list) -> None:
    """(shape placed, product name) of every simple shape under ``label`` (assemblies walked,
    instance locations composed)."""
    from OCP.TDF import TDF_Label, TDF_LabelSequence

    if shape_tool.IsReference_s(label):
        ref = TDF_Label()
        shape_tool.GetReferredShape_s(label, ref)
        loc = location.Multiplied(shape_tool.GetLocation_s(label))
        _leaves(shape_tool, ref, loc, _label_name(ref) or _label_name(label) or name, out)
        return
    if shape_tool.IsAssembly_s(label):
        comps = TDF_LabelSequence()
        shape_tool.GetComponents_s(label, comps)
        for i in range(1, comps.Length() + 1):  # loop over the assembly's components
            _leaves(shape_tool, comps.Value(i), location, name, out)
        return
    shape = shape_tool.GetShape_s(label)
    if shape.IsNull():
        return
    out.append((shape.Moved(location) if not location.IsIdentity() else shape, _label_name(label) or name))


def _label_name(label) -> str:
    from OCP.TDataStd import TDataStd_Name

    attr = TDataStd_Name()
    if label.FindAttribute(TDataStd_Name.GetID_s(), attr):
        return str(attr.Get().ToExtString()).strip()
    return ""


def _color(color_tool, shapes) -> tuple[float, float, float] | None:
    """The first surface (or generic) colour set on one of ``shapes``, RGB 0..1."""
    from OCP.Quantity import Quantity_Color
    from OCP.XCAFDoc import XCAFDoc_ColorGen, XCAFDoc_ColorSurf

    col = Quantity_Color()
    for sh in shapes:
        for kind in (XCAFDoc_ColorSurf, XCAFDoc_ColorGen):
            try:
                if color_tool.GetColor(sh, kind, col):
                    return (col.Red(), col.Green(), col.Blue())
            except Exception:  # noqa: BLE001 - a shape the colour table does not know
                return None
    return None


def _nurbs_face(src):
    """``src`` with its surface a B-spline and its pcurves in that B-spline's parameters:
    a B-spline face as it is (OCC's conversion of one rewrites its seam's second pcurve
    wrongly: K1 from I-DEAS), an extrusion of a B-spline curve through
    `ShapeCustom.ConvertToBSpline` (exact, its pcurves kept), others through
    `BRepBuilderAPI_NurbsConvert`, or where that
    fails (an extrusion whose knots it cannot space: K1 from MicroStation) through
    `ShapeCustom.ConvertToBSpline` (extrusions, revolutions, offsets, planes) first."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepBuilderAPI import BRepBuilderAPI_NurbsConvert
    from OCP.Geom import Geom_BSplineSurface
    from OCP.ShapeCustom import ShapeCustom
    from OCP.TopoDS import TopoDS

    surface = BRep_Tool.Surface_s(src)
    if isinstance(surface, Geom_BSplineSurface):
        return src
    if _bspline_extrusion(surface):
        # an extrusion of a B-spline curve is that B-spline times a line: ShapeCustom's
        # conversion is exact in the same (u, v) and keeps the pcurves as they are (on the 15
        # such faces of ../shared/cad_corpus/step: pcurves identical, surfaces within 1.4e-14 mm
        # of OCC's extrusion), where BRepBuilderAPI_NurbsConvert approximates every pcurve
        # again: 127 ms against 0.2 ms on a face of K1 from SolidDesigner
        out = TopoDS.Face_s(ShapeCustom.ConvertToBSpline_s(src, True, False, False, False))
        if isinstance(BRep_Tool.Surface_s(out), Geom_BSplineSurface):
            return out
    try:
        return TopoDS.Face_s(BRepBuilderAPI_NurbsConvert(src, True).Shape())
    except Exception as e:  # noqa: BLE001 - OCP's Standard_* exceptions share no Python base but Exception
        first = e
    try:
        out = TopoDS.Face_s(ShapeCustom.ConvertToBSpline_s(src, True, True, True, True))
        if isinstance(BRep_Tool.Surface_s(out), Geom_BSplineSurface):
            return out
        return TopoDS.Face_s(BRepBuilderAPI_NurbsConvert(out, True).Shape())
    except Exception:  # noqa: BLE001 - as above
        raise StepError(f"OCC cannot convert its {type(BRep_Tool.Surface_s(src)).__name__} to a B-spline "
                        f"({first})") from None


def _bspline_extrusion(surface) -> bool:
    """Whether ``surface`` (an OCC Geom_Surface) is a linear extrusion of a B-spline curve."""
    from OCP.Geom import Geom_BSplineCurve, Geom_SurfaceOfLinearExtrusion

    return isinstance(surface, Geom_SurfaceOfLinearExtrusion) and isinstance(surface.BasisCurve(), Geom_BSplineCurve)


def _elementary(src, notes: list, de: int):
    """(surface, trim, edge tolerance) of a face on a plane, cylinder, cone, sphere or torus
    through the exact maps of `cadbridge.step.analytic`, or None for other faces and where its
    loops cannot be mapped (then noted: OCC's NURBS conversion takes the face)."""
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_REVERSED

    surf = BRep_Tool.Surface_s(src)  # located
    basis = surf
    while type(basis).__name__ == "Geom_RectangularTrimmedSurface":
        basis = basis.BasisSurface()
    if type(basis).__name__ not in ELEMENTARY:
        return None
    loops, tol = _face_loops(src, None)
    if not loops:
        return None
    try:
        got = elementary_face(basis, src.Orientation() == TopAbs_REVERSED, loops)
    except ValueError as e:
        notes.append(Diagnostic(f"{type(basis).__name__[4:]} face: its pcurves cannot be mapped exactly ({e}); "
                                f"OCC's NURBS conversion used", de=de))
        return None
    if got is None:  # an extrusion of another curve
        return None
    return got[0], got[1], tol


def read_step(path: str | Path, progress=None) -> Model:
    """The `Model` of the STEP file at ``path`` (module docstring), in mm. Raises `StepError`
    (exit 2 in the CLI) where OCC cannot read the file or it holds no B-rep face
    (tessellated only, external references only)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_NurbsConvert
    from OCP.Geom import Geom_BSplineSurface
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPCAFControl import STEPCAFControl_Reader
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDF import TDF_LabelSequence
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    path = Path(path)
    name = path.name
    if progress is not None:
        progress.stage(f"reading {path} (STEP, through OpenCASCADE)")
    Interface_Static.SetCVal_s("xstep.cascade.unit", "MM")
    reader = STEPCAFControl_Reader()
    reader.SetNameMode(True)
    reader.SetColorMode(True)
    if reader.ReadFile(str(path)) != IFSelect_RetDone:
        raise StepError(f"{name}: OpenCASCADE cannot read this STEP file")
    doc = TDocStd_Document(TCollection_ExtendedString("XmlXCAF"))
    if not reader.Transfer(doc):
        raise StepError(f"{name}: OpenCASCADE transfers no shape from this STEP file")
    shape_tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    color_tool = XCAFDoc_DocumentTool.ColorTool_s(doc.Main())
    free = TDF_LabelSequence()
    shape_tool.GetFreeShapes(free)
    leaves: list = []
    for i in range(1, free.Length() + 1):  # loop over the top-level products
        _leaves(shape_tool, free.Value(i), TopLoc_Location(), "", leaves)
    faces: list[Face] = []
    notes: list[Diagnostic] = []
    bare = 0
    for k, (shape, product) in enumerate(leaves):  # loop over the placed simple shapes
        ex = TopExp_Explorer(shape, TopAbs_FACE)
        while ex.More():  # loop over the shape's faces, in OCC's order
            src = TopoDS.Face_s(ex.Current())
            ex.Next()
            from OCP.BRep import BRep_Tool

            if BRep_Tool.Surface_s(src) is None:
                bare += 1
                continue
            got = _elementary(src, notes, len(faces) + bare + 1)
            if got is not None:
                surface, trims, tol = got
            else:
                try:
                    face = _nurbs_face(src)
                    s, shift = _bspline_surface(face)
                except StepError as e:
                    notes.append(Diagnostic(f"face skipped: {e}", de=len(faces) + bare + 1))
                    continue
                surface = nurbs_surface(s, shift)
                flip = None
                if src.Orientation() == TopAbs_REVERSED:
                    flip = (float(surface.knots_u[0]), float(surface.knots_u[-1]))
                    surface = _reversed_u(surface)
                trims, tol = _face_trims(face, flip)
            f = Face(surface=surface, de=len(faces) + 1, name=product or f"{path.stem}_{k + 1}",
                     color=_color(color_tool, [src, shape]), trims=trims, entity_type=0, surface_type=0)
            f.trim_delta = tol
            faces.append(f)
    model = Model(faces=faces, units=Units(2, "MM", 1.0), resolution=None, filename=name, source=str(path),
                  diagnostics=notes, entity_counts={}, system=originating_system(path), preprocessor=PREPROCESSOR)
    if faces:  # an edge tolerance beyond 1e-3 x size is a defect of OCC's reading, not the trims' accuracy
        cap = MAX_DELTA_REL * model.size()
        wide = [f for f in faces if f.trim_delta is not None and f.trim_delta > cap]
        for f in wide:
            notes.append(Diagnostic(f"face {f.de} ({f.name}): OCC's reading gives an edge tolerance of "
                                    f"{f.trim_delta:.3g}; its trim tolerance is taken as {cap:.3g} (1e-3 x size)", de=f.de))
            f.trim_delta = cap
    if not faces:
        if bare:
            raise StepError(f"{name}: {bare} faces without a surface (tessellated only): no B-rep surface to convert")
        raise StepError(f"{name}: no B-rep face in this file (a product structure whose parts are external "
                        f"files, or curves and points only): nothing to convert")
    return model

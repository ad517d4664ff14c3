"""CAD with a tight turn of the normal inside one face, built with OCP and written as IGES
(faces mode): a sheet that folds back on itself around a small radius (a hairpin). With the
default mesh sizes (the curvature rule's floor, model size / 400) an element spans more than
120 degrees of the turn, which the tool guard refuses (`cadbridge.tool.build.reversed_normal_elements`).
"""

from __future__ import annotations

import math
from pathlib import Path


def hairpin_surface(radius: float = 0.04, turn: float = 130.0, length: float = 50.0, width: float = 2.0):
    """One B-spline surface (OCC Geom_BSplineSurface): in the plane z = 0 a line of
    ``length``, an arc of ``radius`` r about the z axis turning the tangent by ``turn``
    degrees (symmetric about the -x axis, through (-r, 0)) and a line of ``length`` back,
    joined into one C1 B-spline curve, extruded along z by ``width``. Lengths in mm."""
    from OCP.GC import GC_MakeArcOfCircle, GC_MakeSegment
    from OCP.Geom import Geom_RectangularTrimmedSurface, Geom_SurfaceOfLinearExtrusion
    from OCP.GeomConvert import GeomConvert, GeomConvert_CompCurveToBSplineCurve
    from OCP.gp import gp_Dir, gp_Pnt

    r, half = float(radius), math.radians(turn) / 2.0
    pa, pb = math.pi - half, math.pi + half  # polar angles of the arc's ends (upper, lower)
    a = (r * math.cos(pa), r * math.sin(pa))
    b = (r * math.cos(pb), r * math.sin(pb))
    ta = (-math.sin(pa), math.cos(pa))  # direction of travel (counter-clockwise) at a and b
    tb = (-math.sin(pb), math.cos(pb))
    p0 = gp_Pnt(a[0] - length * ta[0], a[1] - length * ta[1], 0.0)
    p3 = gp_Pnt(b[0] + length * tb[0], b[1] + length * tb[1], 0.0)
    pa3, pb3 = gp_Pnt(a[0], a[1], 0.0), gp_Pnt(b[0], b[1], 0.0)
    join = GeomConvert_CompCurveToBSplineCurve(GC_MakeSegment(p0, pa3).Value())
    assert join.Add(GC_MakeArcOfCircle(pa3, gp_Pnt(-r, 0.0, 0.0), pb3).Value(), 1e-9)
    assert join.Add(GC_MakeSegment(pb3, p3).Value(), 1e-9)
    profile = join.BSplineCurve()
    extrusion = Geom_SurfaceOfLinearExtrusion(profile, gp_Dir(0, 0, 1))
    u0, u1 = profile.FirstParameter(), profile.LastParameter()
    return GeomConvert.SurfaceToBSplineSurface_s(Geom_RectangularTrimmedSurface(extrusion, u0, u1, 0.0, width))


def hairpin_face(**kw):
    """The `hairpin_surface` (same arguments) as an untrimmed TopoDS_Face."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace

    return BRepBuilderAPI_MakeFace(hairpin_surface(**kw), 1e-7).Face()


def write_iges(shape, path: str | Path) -> Path:
    """``shape`` written by OCC's IGES writer in faces mode (trimmed surfaces, as die CAD)."""
    from OCP.IGESControl import IGESControl_Writer

    w = IGESControl_Writer("MM", 0)
    w.AddShape(shape)
    w.ComputeModel()
    assert w.Write(str(path))
    return Path(path)


def hairpin_iges(path: str | Path, **kw) -> Path:
    """`hairpin_face` (arguments of `hairpin_surface`) written to ``path`` (IGES)."""
    return write_iges(hairpin_face(**kw), path)

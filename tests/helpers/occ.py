"""OpenCASCADE (OCP) as the tests' reference: reading an IGES file, the faces and edges of a
shape, distances from points, areas, face normals. Written once here for every test that
needs them; OCP is imported inside each function, so a test skips on a missing OCP where it
did before (``pytest.importorskip`` in the test, or its module).

`read_shape` is OCC's IGES reader with its default settings (read.iges.bspline.continuity
left as it is: C0 B-spline surfaces may come back split); `cadbridge.verify.reference.occ_read_shape`
is the reader that keeps them whole.
"""

from __future__ import annotations

import numpy as np


def read_shape(path):
    """OneShape() of all roots of an IGES file read by IGESControl_Reader (default settings)."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.IGESControl import IGESControl_Reader

    r = IGESControl_Reader()
    assert r.ReadFile(str(path)) == IFSelect_RetDone, path
    r.TransferRoots()
    return r.OneShape()


def faces(shape) -> list:
    """The TopoDS_Face of a shape, in TopExp_Explorer order."""
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    out, exp = [], TopExp_Explorer(shape, TopAbs_FACE)
    while exp.More():
        out.append(TopoDS.Face_s(exp.Current()))
        exp.Next()
    return out


def edges(shape) -> list:
    """The TopoDS_Edge of a shape, in TopExp_Explorer order."""
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    out, exp = [], TopExp_Explorer(shape, TopAbs_EDGE)
    while exp.More():
        out.append(TopoDS.Edge_s(exp.Current()))
        exp.Next()
    return out


def read_faces(path) -> list:
    """The faces of an IGES file as OCC reads them (`read_shape`), in its order."""
    return faces(read_shape(path))


def read_surfaces(path) -> list:
    """The faces' surfaces (Geom_Surface, face location applied) of an IGES file."""
    from OCP.BRep import BRep_Tool

    return [BRep_Tool.Surface_s(f) for f in read_faces(path)]


def compound(shapes):
    """One TopoDS_Compound of the shapes (for one distance to all of them)."""
    from OCP.BRep import BRep_Builder
    from OCP.TopoDS import TopoDS_Compound

    c, b = TopoDS_Compound(), BRep_Builder()
    b.MakeCompound(c)
    for s in shapes:
        b.Add(c, s)
    return c


def vertex(x):
    """A TopoDS_Vertex at the point x (3,)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
    from OCP.gp import gp_Pnt

    return BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, x))).Vertex()


def dist_shape_shape(a, b):
    """BRepExtrema_DistShapeShape between two shapes, asserted done (its solutions, supports)."""
    from OCP.BRepExtrema import BRepExtrema_DistShapeShape

    d = BRepExtrema_DistShapeShape(a, b)
    assert d.IsDone()
    return d


def distance(x, shape) -> float:
    """OCC's distance from the point x (3,) to a shape (BRepExtrema_DistShapeShape: a trimmed
    face, an edge, a compound)."""
    from OCP.BRepExtrema import BRepExtrema_DistShapeShape

    return BRepExtrema_DistShapeShape(vertex(x), shape).Value()


def area(shape, eps: float | None = None) -> float:
    """Surface area of a face or shape (BRepGProp.SurfaceProperties): default precision (a
    fixed Gauss rule: off by 0.4 % on a face trimmed by a long Bezier-form spline), or
    adaptive to the relative error ``eps``."""
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    p = GProp_GProps()
    if eps is None:
        BRepGProp.SurfaceProperties_s(shape, p)
    else:
        BRepGProp.SurfaceProperties_s(shape, p, eps)
    return p.Mass()


def face_normal(face, u: float, v: float) -> np.ndarray:
    """Unit normal S_u x S_v of a face's surface at (u, v) (BRepAdaptor_Surface.D1, the face
    location applied, the face orientation not); NaN where S_u x S_v vanishes."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.gp import gp_Pnt, gp_Vec

    p, du, dv = gp_Pnt(), gp_Vec(), gp_Vec()
    BRepAdaptor_Surface(face).D1(u, v, p, du, dv)
    n = np.cross(du.Coord(), dv.Coord())
    ln = np.linalg.norm(n)
    return n / ln if ln > 0 else np.full(3, np.nan)


def surface_normals(surface, u, v) -> np.ndarray:
    """Unit normals S_u x S_v (N, 3) of a Geom_Surface at (u, v) (N,) each (Geom_Surface.D1);
    NaN where S_u x S_v vanishes (a pole, a cone apex: OCC has no normal there)."""
    from OCP.gp import gp_Pnt, gp_Vec

    out = np.full((len(u), 3), np.nan)
    for k, (a, b) in enumerate(zip(np.asarray(u, dtype=float), np.asarray(v, dtype=float))):
        p, du, dv = gp_Pnt(), gp_Vec(), gp_Vec()
        surface.D1(float(a), float(b), p, du, dv)
        n = np.cross(du.Coord(), dv.Coord())
        ln = np.linalg.norm(n)
        if ln > 0:
            out[k] = n / ln
    return out


def surface_distance(surface, x) -> float:
    """OCC's distance from the point x (3,) to an untrimmed Geom_Surface: the nearest
    orthogonal foot (GeomAPI_ProjectPointOnSurf); inf where OCC finds none."""
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    proj = GeomAPI_ProjectPointOnSurf(gp_Pnt(*map(float, x)), surface)
    return proj.LowerDistance() if proj.NbPoints() > 0 else np.inf


def surface_nearest(gs, s, p):
    """Nearest point by OCC: interior extrema (GeomAPI_ProjectPointOnSurf) and boundary minima
    (GeomAPI_ProjectPointOnCurve on the 4 iso-curves, plus the corners). Returns a list of
    (distance, foot (3,), (u, v) or None) sorted by distance, and whether OCC's interior
    search converged."""
    from OCP.GeomAPI import GeomAPI_ProjectPointOnCurve, GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    P = gp_Pnt(*map(float, p))
    cands = []
    u0, u1, v0, v1 = s.domain
    proj = GeomAPI_ProjectPointOnSurf(P, gs)
    interior_done = proj.IsDone() and proj.NbPoints() > 0
    if interior_done:
        for k in range(1, proj.NbPoints() + 1):
            q = proj.Point(k)
            uu, vv = proj.Parameters(k)
            # extrema OCC reports on the domain edge are only approximate there (~1e-8);
            # the edge minima are taken from the iso-curve projections below instead
            if min(abs(uu - u0), abs(uu - u1)) < 1e-9 or min(abs(vv - v0), abs(vv - v1)) < 1e-9:
                continue
            cands.append((proj.Distance(k), np.array([q.X(), q.Y(), q.Z()]), (uu, vv)))
    for iso in (gs.UIso(u0), gs.UIso(u1), gs.VIso(v0), gs.VIso(v1)):
        pc = GeomAPI_ProjectPointOnCurve(P, iso)
        for k in range(1, pc.NbPoints() + 1):
            q = pc.Point(k)
            cands.append((pc.Distance(k), np.array([q.X(), q.Y(), q.Z()]), None))
    for uu, vv in ((u0, v0), (u0, v1), (u1, v0), (u1, v1)):
        q = gs.Value(uu, vv)
        c = np.array([q.X(), q.Y(), q.Z()])
        cands.append((float(np.linalg.norm(c - p)), c, (uu, vv)))
    cands.sort(key=lambda t: t[0])
    return cands, interior_done

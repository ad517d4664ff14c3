"""OpenCASCADE reference for the IGES reader: read a file with OCC and evaluate its surfaces.

This is the yardstick `cadbridge verify` measures our reader against, not a product path:
loops over points are acceptable here. Lengths come out in millimetres (OCC converts the
file's units to its session unit, mm).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from OCP.Bnd import Bnd_Box
from OCP.BRep import BRep_Tool
from OCP.BRepBndLib import BRepBndLib
from OCP.BRepClass import BRepClass_FaceClassifier
from OCP.BRepTools import BRepTools
from OCP.Geom import Geom_Surface
from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
from OCP.GeomLProp import GeomLProp_SLProps
from OCP.gp import gp_Pnt, gp_Pnt2d, gp_Vec
from OCP.IFSelect import IFSelect_RetDone
from OCP.IGESControl import IGESControl_Reader
from OCP.Interface import Interface_Static
from OCP.TopAbs import TopAbs_FACE, TopAbs_IN, TopAbs_ON, TopAbs_REVERSED
from OCP.TopExp import TopExp_Explorer
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS, TopoDS_Face, TopoDS_Shape

__all__ = ["OccFace", "OccReadError", "occ_bspline_curve", "occ_bspline_surface", "occ_eval", "occ_inside", "occ_normal", "occ_project", "occ_read", "occ_read_shape"]


class OccReadError(RuntimeError):
    """OpenCASCADE could not read or transfer an IGES file."""


@dataclass
class OccFace:
    """One face as OCC reads it.

    surface    Geom_Surface in model coordinates (the face location already applied)
    bounds     (u0, u1, v0, v1) of the face in the surface parameters (BRepTools.UVBounds)
    reversed   True if the face orientation is REVERSED (face normal = -Su x Sv)
    kind       class name of the surface ("Geom_BSplineSurface", "Geom_Plane", ...)
    bbox       (2, 3) axis-aligned box of the face
    """

    index: int
    face: TopoDS_Face
    surface: Geom_Surface
    bounds: tuple[float, float, float, float]
    reversed: bool
    kind: str
    bbox: np.ndarray


def occ_read_shape(path: str | os.PathLike, *, keep_continuity: bool = True,
                   surface_curves: int | None = None) -> TopoDS_Shape:
    """Read an IGES file with IGESControl_Reader and return OneShape() (all roots); a STEP
    file with STEPControl_Reader (lengths in mm).

    ``keep_continuity`` sets read.iges.bspline.continuity = 0, so OCC does not split C0
    B-spline surfaces into C1 pieces (its default, 1, does). ``surface_curves``: OCC's
    read.surfacecurve.mode for the read (-2: the parameter-space curves of every 142, -3:
    the model-space ones; None: OCC's default 0, which honours PREF, but not always:
    `cadbridge.verify.soundness._file_preference`).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise OccReadError(f"{path}: no such file")
    from cadbridge.formats import cad_format

    if cad_format(path) == "step":
        return _occ_read_step(path)
    if path.lower().endswith(".brep"):  # OCC's own format: OCC's reading written out (`mesh_source` for STEP)
        from OCP.BRep import BRep_Builder
        from OCP.BRepTools import BRepTools
        from OCP.TopoDS import TopoDS_Shape as _Shape

        shape = _Shape()
        if not BRepTools.Read_s(shape, path, BRep_Builder()) or shape.IsNull():
            raise OccReadError(f"{path}: OpenCASCADE could not read the .brep file")
        return shape
    reader = IGESControl_Reader()  # registers the read.iges.* statics
    old = Interface_Static.IVal_s("read.iges.bspline.continuity")
    old_curves = Interface_Static.IVal_s("read.surfacecurve.mode")
    try:
        if keep_continuity:
            Interface_Static.SetIVal_s("read.iges.bspline.continuity", 0)
        if surface_curves is not None:
            Interface_Static.SetIVal_s("read.surfacecurve.mode", int(surface_curves))
        status = reader.ReadFile(path)
        if status != IFSelect_RetDone:
            raise OccReadError(f"{path}: OpenCASCADE could not read the file (IFSelect status {status})")
        if reader.TransferRoots() == 0:
            raise OccReadError(f"{path}: OpenCASCADE transferred no root entity")
    finally:
        Interface_Static.SetIVal_s("read.iges.bspline.continuity", old)
        Interface_Static.SetIVal_s("read.surfacecurve.mode", old_curves)
    shape = reader.OneShape()
    if shape.IsNull():
        raise OccReadError(f"{path}: OpenCASCADE produced an empty shape")
    return shape


def _occ_read_step(path: str) -> TopoDS_Shape:
    """A STEP file's shape as OCC's STEPControl_Reader transfers it (all roots), in mm."""
    from cadbridge.step.reader import occ_step_shape

    shape = occ_step_shape(path)
    if shape is None:
        raise OccReadError(f"{path}: OpenCASCADE could not read or transfer the file, or produced an empty shape")
    return shape


def occ_read(path: str | os.PathLike, *, keep_continuity: bool = True,
             surface_curves: int | None = None) -> list[OccFace]:
    """All faces of an IGES or STEP file as OCC reads them, in TopExp_Explorer order
    (options as `occ_read_shape`)."""
    shape = occ_read_shape(path, keep_continuity=keep_continuity, surface_curves=surface_curves)
    faces: list[OccFace] = []
    exp = TopExp_Explorer(shape, TopAbs_FACE)
    while exp.More():
        face = TopoDS.Face_s(exp.Current())
        loc = TopLoc_Location()
        surf = BRep_Tool.Surface_s(face, loc)
        if not loc.IsIdentity():
            surf = surf.Transformed(loc.Transformation())
        box = Bnd_Box()
        # the exact box of the face's geometry: OCC's quick box (`BRepBndLib.Add` without a
        # triangulation) can miss most of a face (K1 from SolidDesigner and from CATIA V5:
        # torus fillets boxed as a flat disc at x = 50.8), and the nearest-face searches
        # prune by these boxes
        BRepBndLib.AddOptimal_s(face, box, False, True)
        xmin, ymin, zmin, xmax, ymax, zmax = box.Get()
        faces.append(
            OccFace(
                index=len(faces),
                face=face,
                surface=surf,
                bounds=tuple(BRepTools.UVBounds_s(face)),
                reversed=face.Orientation() == TopAbs_REVERSED,
                kind=type(surf).__name__,
                bbox=np.array([[xmin, ymin, zmin], [xmax, ymax, zmax]]),
            )
        )
        exp.Next()
    return faces


def occ_eval(surface: Geom_Surface, u, v, order: int = 2) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Points and derivatives with Geom_Surface.D0/D1/D2.

    u, v (N,). Returns P (N, 3); D1 (N, 2, 3) = [Su, Sv] if order >= 1;
    D2 (N, 3, 3) = [Suu, Suv, Svv] if order >= 2 (else None).
    """
    u = np.atleast_1d(np.asarray(u, dtype=float))
    v = np.atleast_1d(np.asarray(v, dtype=float))
    n = len(u)
    pos = np.empty((n, 3))
    d1 = np.empty((n, 2, 3)) if order >= 1 else None
    d2 = np.empty((n, 3, 3)) if order >= 2 else None
    p = gp_Pnt()
    vu, vv, vuu, vvv, vuv = gp_Vec(), gp_Vec(), gp_Vec(), gp_Vec(), gp_Vec()
    for k in range(n):
        if order >= 2:
            surface.D2(float(u[k]), float(v[k]), p, vu, vv, vuu, vvv, vuv)
            d2[k] = (vuu.Coord(), vuv.Coord(), vvv.Coord())
            d1[k] = (vu.Coord(), vv.Coord())
        elif order == 1:
            surface.D1(float(u[k]), float(v[k]), p, vu, vv)
            d1[k] = (vu.Coord(), vv.Coord())
        else:
            surface.D0(float(u[k]), float(v[k]), p)
        pos[k] = p.Coord()
    return pos, d1, d2


def occ_normal(surface: Geom_Surface, u, v, tol: float = 1e-12) -> np.ndarray:
    """Unit normals (direction of Su x Sv) from GeomLProp_SLProps; NaN where undefined."""
    u = np.atleast_1d(np.asarray(u, dtype=float))
    v = np.atleast_1d(np.asarray(v, dtype=float))
    out = np.full((len(u), 3), np.nan)
    props = GeomLProp_SLProps(surface, 1, tol)
    for k in range(len(u)):
        props.SetParameters(float(u[k]), float(v[k]))
        if props.IsNormalDefined():
            out[k] = props.Normal().Coord()
    return out


def occ_project(surface: Geom_Surface, points, bounds: tuple[float, float, float, float] | None = None):
    """Orthogonal projection of points (N, 3) with GeomAPI_ProjectPointOnSurf.

    ``bounds`` (u0, u1, v0, v1) restricts the search (else the surface's own bounds; infinite
    surfaces such as planes are fine). Returns u, v (N,), foot (N, 3), distance (N,); NaN
    where OCC found no projection.
    """
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    n = len(pts)
    u = np.full(n, np.nan)
    v = np.full(n, np.nan)
    foot = np.full((n, 3), np.nan)
    dist = np.full(n, np.nan)
    proj = GeomAPI_ProjectPointOnSurf()
    if bounds is None:
        proj.Init(surface, *_finite_bounds(surface))
    else:
        proj.Init(surface, *bounds)
    for k in range(n):
        proj.Perform(gp_Pnt(*pts[k]))
        if proj.IsDone() and proj.NbPoints() > 0:
            uu, vv = proj.LowerDistanceParameters()
            u[k], v[k] = uu, vv
            foot[k] = proj.NearestPoint().Coord()
            dist[k] = proj.LowerDistance()
    # the reused projector (its sample grid made once, in Init) stops short beside a pole: a
    # point 1e-4 rad from the pole of a revolution (K1 from CADDS) came out 7.4e-7 mm off, where
    # a projector made for the point finds 3e-14. Points not on the surface to round-off are
    # projected again so, and the nearer foot kept
    scale = 1e-12 * np.maximum(1.0, np.linalg.norm(pts, axis=1))
    for k in np.flatnonzero(~(dist <= scale)):
        # without explicit bounds (the surface's own): given bounds, even its own, OCC stops short there too
        fresh = GeomAPI_ProjectPointOnSurf(gp_Pnt(*pts[k]), surface, *(bounds or ()))
        if fresh.IsDone() and fresh.NbPoints() > 0 and not fresh.LowerDistance() >= dist[k]:
            u[k], v[k] = fresh.LowerDistanceParameters()
            foot[k] = fresh.NearestPoint().Coord()
            dist[k] = fresh.LowerDistance()
    return u, v, foot, dist


def _finite_bounds(surface: Geom_Surface, big: float = 1e7) -> tuple[float, float, float, float]:
    u0, u1, v0, v1 = surface.Bounds()
    clip = lambda x: max(-big, min(big, x))  # noqa: E731  (planes, extrusions are infinite)
    return clip(u0), clip(u1), clip(v0), clip(v1)


def occ_inside(face: OccFace | TopoDS_Face, u, v, tol: float = 1e-9) -> np.ndarray:
    """Whether (u, v) lie inside the face's trimmed region (BRepClass_FaceClassifier, ON counts)."""
    f = face.face if isinstance(face, OccFace) else face
    u = np.atleast_1d(np.asarray(u, dtype=float))
    v = np.atleast_1d(np.asarray(v, dtype=float))
    out = np.zeros(len(u), dtype=bool)
    for k in range(len(u)):
        state = BRepClass_FaceClassifier(f, gp_Pnt2d(float(u[k]), float(v[k])), tol).State()
        out[k] = state in (TopAbs_IN, TopAbs_ON)
    return out


def _probe(path: str) -> int:
    """Read a file with OCC and return its face count (used to test isolation)."""
    return len(occ_read(path))


if __name__ == "__main__":  # python -m cadbridge.verify.reference FILE: print OCC's faces
    import sys

    for f in occ_read(sys.argv[1]):
        b = ", ".join(f"{x:.6g}" for x in f.bounds)
        print(f"face {f.index}: {f.kind} bounds ({b}) {'reversed' if f.reversed else 'forward'}")


def _knots_mults(knots: np.ndarray):
    """Distinct knots and their multiplicities as OCC 1-based arrays."""
    from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal

    vals, mult = np.unique(np.asarray(knots, dtype=float), return_counts=True)
    k = TColStd_Array1OfReal(1, len(vals))
    m = TColStd_Array1OfInteger(1, len(vals))
    for i, (x, c) in enumerate(zip(vals, mult)):
        k.SetValue(i + 1, float(x))
        m.SetValue(i + 1, int(c))
    return k, m


def occ_bspline_surface(s):
    """OCC `Geom_BSplineSurface` with the poles, weights and knots of a `NurbsSurface`
    (an independent evaluator of the same data; OCC arrays are 1-based)."""
    from OCP.Geom import Geom_BSplineSurface
    from OCP.TColgp import TColgp_Array2OfPnt
    from OCP.TColStd import TColStd_Array2OfReal

    nu, nv = s.shape
    poles = TColgp_Array2OfPnt(1, nu, 1, nv)
    wts = TColStd_Array2OfReal(1, nu, 1, nv)
    for i in range(nu):
        for j in range(nv):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*(float(c) for c in s.control_points[i, j])))
            wts.SetValue(i + 1, j + 1, float(s.weights[i, j]))
    ku, mu = _knots_mults(s.knots_u)
    kv, mv = _knots_mults(s.knots_v)
    return Geom_BSplineSurface(poles, wts, ku, kv, mu, mv, s.degree_u, s.degree_v, False, False)


def occ_bspline_curve(c):
    """OCC `Geom_BSplineCurve` with the poles, weights and knots of a 3D `NurbsCurve`."""
    from OCP.Geom import Geom_BSplineCurve
    from OCP.TColgp import TColgp_Array1OfPnt
    from OCP.TColStd import TColStd_Array1OfReal

    n = len(c.control_points)
    poles = TColgp_Array1OfPnt(1, n)
    wts = TColStd_Array1OfReal(1, n)
    for i in range(n):
        poles.SetValue(i + 1, gp_Pnt(*(float(x) for x in c.control_points[i])))
        wts.SetValue(i + 1, float(c.weights[i]))
    k, m = _knots_mults(c.knots)
    return Geom_BSplineCurve(poles, wts, k, m, c.degree, False)

"""cadbridge's own model as an OpenCASCADE B-rep: the geometry the mesher meshes.

gmsh meshes an OCC shape; cadbridge projects onto its own reading of the file. When gmsh read
the file through OCC's IGES reader, every difference between the two readers (C0 splits,
seams, 120 conventions, trim curves, healed edges) became a mesh off the CAD. Here the shape
is built from the model itself, so mesher and projector see one geometry:

* each `Face` becomes one `TopoDS_Face` on a `Geom_BSplineSurface` with the poles, weights
  and knots of its `NurbsSurface` (so a node's (u, v) in gmsh is its (u, v) on the model);
* its trim loops become wires of edges built from the loops' parameter-space curves (pieces
  that are not NURBS -- `cadbridge.cad.analytic.MappedCurve` / ``InvertedCurve`` over analytic
  surfaces -- through their cubic within `PCURVE_REL_TOL`); untrimmed faces are bounded by their surface's domain;
* OCC's shape healing mends what the file leaves open: `ShapeFix_Wire` (order, gaps,
  degenerate edges at poles and apexes, lacking edges), ``BRepLib.BuildCurves3d`` (the 3D
  curves of the edges, from the pcurves), `ShapeFix_Face` (orientation of the loops, missing
  seams), then `BRepBuilderAPI_Sewing` joins neighbouring faces so the mesh is conforming;
* the faces are written in model order into a compound, so gmsh's surface tag k + 1 is the
  model's face k (`ModelBrep.face_of_tag`).

Every fix the healing made is kept per face (`FaceBuild.fixes`) for ``inspect`` and the
convert summary.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from cadbridge.cad.model import Face, Model
from cadbridge.heal.loop_excursions import default_width
from cadbridge.nurbs.curve import NurbsCurve

__all__ = ["FaceBuild", "ModelBrep", "model_brep", "brep_source", "trim_sew_tolerance", "SEW_TOLERANCE_MM"]

SEW_TOLERANCE_MM = 1e-4
"""Sewing tolerance floor in mm: the tolerance gmsh's import sewed OCC's reading with (OCC's
IGES export of a cylinder leaves its circles ~1e-5 mm apart)."""

EDGE_TOLERANCE = 1e-7
"""Tolerance of the built edges and faces, x model size."""

MAX_CHECKED_POLES = 5000
"""Faces whose pcurves have more poles in all get no `ShapeFix_Face.Perform`, no
`BRepCheck_Analyzer` and no `ShapeFix_Shape` (their orientation is still fixed): these
compare pairs of pcurve pieces, and took 52 s each on PRO19800's face (an inverted trim
through an apex: 34 447 poles). Such a face is meshed as built; the mesher's own checks
still apply."""

PCURVE_REL_TOL = 1e-8
"""Cubic deviation of a non-NURBS trim piece's pcurve (`MappedCurve`, `InvertedCurve`), x the
(u, v) domain diagonal: 100x below the soundness tolerance (nodes on the trimmed face within
1e-6 x size). Not the IGES writer's 1e-10: an inverted trim of PRO20358-W8 then took 15 796
poles (13 s), and OCC's checks of the face another 16 s."""


@dataclass
class FaceBuild:
    """How one model face became an OCC face.

    index   the face's index in ``model.faces``
    valid   `BRepCheck_Analyzer` finds the OCC face valid (None: not checked, its pcurves have
            more than `MAX_CHECKED_POLES` poles)
    fixes   what OCC's shape healing changed, in words (empty: nothing)
    """

    index: int
    valid: bool | None
    fixes: list[str] = field(default_factory=list)


@dataclass
class ModelBrep:
    """The model as one OCC compound of faces (sewn), in model order.

    shape   `TopoDS_Compound` holding the faces (neighbours share their edges)
    faces   one `FaceBuild` per model face
    sew_tolerance  the sewing tolerance used (model units)
    free_edges     edges the sewing left unshared (the model's open boundary, and gaps)
    """

    shape: object
    faces: list[FaceBuild]
    sew_tolerance: float
    free_edges: int

    anchors: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))
    """(F, 9) one row per model face, (u, v, x, y, z, umin, umax, vmin, vmax): S(u, v) at the
    centre of the face's surface domain, and the (u, v) box of the built face
    (``BRepTools::UVBounds``), for the mesher to tell which of its faces is which model face
    (`cadbridge.mesh.generate`'s ``face_anchors``)."""

    def notes(self) -> list[str]:
        """One line per face that the healing changed or that OCC finds invalid."""
        out = []
        for f in self.faces:
            if f.fixes:
                out.append(f"face {f.index}: OCC shape healing: {'; '.join(f.fixes)}")
            if f.valid is False:
                out.append(f"face {f.index}: OCC finds the built face invalid (BRepCheck); meshed as it is")
        return out


def _array1(values, kind: str):
    from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal

    arr = (TColStd_Array1OfInteger if kind == "int" else TColStd_Array1OfReal)(1, len(values))
    for i, x in enumerate(values):
        arr.SetValue(i + 1, int(x) if kind == "int" else float(x))
    return arr


def _knots(knots: np.ndarray):
    """Distinct knots and multiplicities as OCC 1-based arrays."""
    vals, mult = np.unique(np.asarray(knots, dtype=float), return_counts=True)
    return _array1(vals, "real"), _array1(mult, "int")


def occ_surface(s):
    """`Geom_BSplineSurface` with the poles, weights and knots of a `NurbsSurface`."""
    from OCP.Geom import Geom_BSplineSurface
    from OCP.gp import gp_Pnt
    from OCP.TColgp import TColgp_Array2OfPnt
    from OCP.TColStd import TColStd_Array2OfReal

    nu, nv = s.shape
    poles = TColgp_Array2OfPnt(1, nu, 1, nv)
    wts = TColStd_Array2OfReal(1, nu, 1, nv)
    cp, w = np.asarray(s.control_points, dtype=float), np.asarray(s.weights, dtype=float)
    for i in range(nu):
        for j in range(nv):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*cp[i, j, :3].tolist()))
            wts.SetValue(i + 1, j + 1, float(w[i, j]))
    ku, mu = _knots(s.knots_u)
    kv, mv = _knots(s.knots_v)
    return Geom_BSplineSurface(poles, wts, ku, kv, mu, mv, s.degree_u, s.degree_v, False, False)


def occ_pcurve(c, surface) -> tuple[object, float, float]:
    """(`Geom2d_BSplineCurve`, t0, t1) of a trim piece in the (u, v) of ``surface`` (a
    `NurbsSurface`); non-NURBS pieces through their cubic within `PCURVE_REL_TOL` x the
    domain diagonal."""
    from OCP.Geom2d import Geom2d_BSplineCurve
    from OCP.gp import gp_Pnt2d
    from OCP.TColgp import TColgp_Array1OfPnt2d

    if not isinstance(c, NurbsCurve):
        u0, u1, v0, v1 = surface.domain
        tol = PCURVE_REL_TOL * float(np.hypot(u1 - u0, v1 - v0))
        for k in range(4):  # a curve inverted near a pole is noisy in (u, v): looser, up to 1e-6 x domain
            try:
                c = c.to_nurbs(tol=tol * 1e3 ** k)
                break
            except ValueError:
                if k == 3:
                    raise
    cp = np.asarray(c.control_points, dtype=float)
    poles = TColgp_Array1OfPnt2d(1, len(cp))
    for i, p in enumerate(cp):
        poles.SetValue(i + 1, gp_Pnt2d(float(p[0]), float(p[1])))
    k, m = _knots(c.knots)
    t0, t1 = c.domain
    return Geom2d_BSplineCurve(poles, _array1(c.weights, "real"), k, m, int(c.degree), False), float(t0), float(t1)


def _largest_gap(data) -> float:
    """The largest distance from an edge's last vertex to the next edge's first vertex in the
    wire data ``data`` (`ShapeExtend_WireData`, in order), model units."""
    from OCP.BRep import BRep_Tool
    from OCP.ShapeAnalysis import ShapeAnalysis_Edge

    sae = ShapeAnalysis_Edge()
    n = data.NbEdges()
    ends = [(BRep_Tool.Pnt_s(sae.FirstVertex(data.Edge(i))), BRep_Tool.Pnt_s(sae.LastVertex(data.Edge(i))))
            for i in range(1, n + 1)]
    return max((ends[i][1].Distance(ends[(i + 1) % n][0]) for i in range(n)), default=0.0)


def _one_vertex_degenerated(wire) -> tuple[object, int]:
    """``wire`` with each degenerated edge's two vertices made one (its first, its tolerance
    grown to cover the second), and how many edges that changed.

    A trim piece along a pole side of its surface is a closed edge: one vertex at both ends.
    `ShapeFix_Wire.FixConnected` joins each end to its neighbour with a new vertex of its own
    where the neighbour's end is near but not on it, so the edge ends with two vertices at one
    point; `ShapeFix_Wire.FixDegenerated` marks it degenerated as it is. gmsh then cannot make
    the face's loop: "Could not fix wire in surface" where it sews, "The 1D mesh seems not to
    be forming a closed loop" where not (trj8_b1-ec-214.stp, a B-spline dome's pole)."""
    from OCP.BRep import BRep_Builder, BRep_Tool
    from OCP.ShapeBuild import ShapeBuild_ReShape
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_FORWARD
    from OCP.TopExp import TopExp, TopExp_Explorer
    from OCP.TopoDS import TopoDS

    reshape = ShapeBuild_ReShape()
    merged = 0
    ex = TopExp_Explorer(wire, TopAbs_EDGE)
    while ex.More():  # loop over the wire's edges
        e = TopoDS.Edge_s(ex.Current())
        ex.Next()
        a, b = TopExp.FirstVertex_s(e), TopExp.LastVertex_s(e)
        if BRep_Tool.Degenerated_s(e) and not a.IsSame(b):
            gap = BRep_Tool.Pnt_s(a).Distance(BRep_Tool.Pnt_s(b))
            BRep_Builder().UpdateVertex(a, max(BRep_Tool.Tolerance_s(a), gap + BRep_Tool.Tolerance_s(b)))
            reshape.Replace(b.Oriented(TopAbs_FORWARD), a.Oriented(TopAbs_FORWARD))
            merged += 1
    return (TopoDS.Wire_s(reshape.Apply(wire)) if merged else wire), merged


def _face(face: Face, tol: float, resolution: float = 0.0, width: float = 0.0) -> tuple[object, list[str], bool]:
    """The OCC face of one model face, the fixes OCC's healing made on it, and whether it is
    to be checked (`_valid_faces`; None: not, it has more than `MAX_CHECKED_POLES` poles). ``tol``: the
    edges' tolerance; consecutive loop pieces closer than ``resolution`` (the file's minimum
    resolution, IGES global parameter 19: points closer are the same point) are joined;
    a join is reported where it moved an end by more than 1 % of ``resolution``. Where pieces
    are still apart, those closer than ``width`` (the face's trim tolerance,
    `cadbridge.heal.loop_excursions.default_width`) are joined too, and reported."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace
    from OCP.BRepLib import BRepLib
    from OCP.ShapeExtend import ShapeExtend_DONE3, ShapeExtend_DONE4, ShapeExtend_DONE5, ShapeExtend_WireData
    from OCP.ShapeFix import ShapeFix_Face, ShapeFix_Wire
    from OCP.TopoDS import TopoDS_Face

    surface = occ_surface(face.surface)
    u0, u1, v0, v1 = face.surface.domain
    trims = face.trims
    fixes: list[str] = []
    builder = BRep_Builder()
    if trims is None or trims.outer is None:
        occ = BRepBuilderAPI_MakeFace(surface, u0, u1, v0, v1, tol).Face()
        loops = [] if trims is None else list(trims.inner)
    else:
        occ = TopoDS_Face()
        builder.MakeFace(occ, surface, tol)
        loops = [trims.outer] + list(trims.inner)
    poles = 0
    for k, loop in enumerate(loops):
        data = ShapeExtend_WireData()
        for c in loop.curves:
            g2, t0, t1 = occ_pcurve(c, face.surface)
            poles += g2.NbPoles()
            data.Add(BRepBuilderAPI_MakeEdge(g2, surface, t0, t1).Edge())
        fw = ShapeFix_Wire(data.Wire(), occ, tol)
        name = "outer loop" if (k == 0 and trims is not None and trims.outer is not None) else "hole"
        if fw.FixReorder():
            fixes.append(f"{name}: pieces reordered")
        sa = fw.Analyzer()  # the gaps between consecutive pieces, in order
        prec = max(tol, resolution)
        sa.CheckConnected(prec)
        gap = sa.MaxDistance3d()
        if fw.FixConnected(prec) and gap > max(tol, 0.01 * resolution):
            fixes.append(f"{name}: gaps up to {gap:.3g} closed")
        if width > prec and fw.Analyzer().CheckConnected(prec):
            # pieces further apart than the resolution but within the face's trim tolerance (each
            # piece's ends are only as accurate as that): joined, for an open wire is no edge loop
            # to gmsh ("Could not fix wire"; PRO20358-X28, bug8363_f45)
            gap = _largest_gap(fw.WireData())
            if fw.FixConnected(width):
                fixes.append(f"{name}: gaps up to {gap:.3g} closed (wider than the file's resolution, within "
                             f"the face's trim tolerance {width:.3g})")
        if fw.FixDegenerated():
            fixes.append(f"{name}: degenerate edge added (pole or apex)")
        if fw.FixLacking():
            fixes.append(f"{name}: lacking edge added")
        wire, merged = _one_vertex_degenerated(fw.Wire())
        if merged:
            fixes.append(f"{name}: the two vertices of {merged} degenerate edge(s) made one")
        builder.Add(occ, wire)
    BRepLib.BuildCurves3d_s(occ, tol)  # approximations of S(c(t)): the mesher puts its nodes back on S(c(t))
    ff = ShapeFix_Face(occ)
    if ff.FixOrientation():  # Perform() alone leaves a clockwise outer loop as it is
        fixes.append("loop orientation turned")
    if poles > MAX_CHECKED_POLES:
        return ff.Face(), fixes, None
    ff = ShapeFix_Face(ff.Face())
    ff.Perform()
    for status, what in ((ShapeExtend_DONE3, "missing seam added"), (ShapeExtend_DONE4, "small-area loop removed"),
                         (ShapeExtend_DONE5, "natural bounds added")):
        if ff.Status(status):
            fixes.append(what)
    return ff.Face(), fixes, True


FORK_FACES = 64
"""Models with at least this many faces have them built by two processes (`_built_faces`)."""


def _built_faces(model: Model, tol: float, resolution: float, size: float) -> list[list]:
    """[OCC face, fixes, checked] (`_face`) of every model face, in model order.

    OCC builds one face at a time, in one thread: with `FORK_FACES` faces or more the faces
    are built in interleaved chunks shared with one forked copy of this process
    (`cadbridge.common.fork_jobs`; none where one CPU is all there is), each chunk passed
    back as a binary B-rep (``BinTools``). Every chunk takes that way, forked or not, so the
    faces do not depend on the machine: the binary B-rep keeps every double except a line's
    direction, which OCC normalises again on reading (1e-16; trj10_b2's two faces with a
    straight pcurve). A chunk that fails in the forked process is built again here, so its
    error is raised as it would be without the fork. On the analytic production die (1 102
    faces) 6.4 s in one process, 3.4 s so (quiet machine, 2 cores)."""
    import pickle

    from cadbridge.common.fork_jobs import run_jobs

    def build(i: int) -> list:
        f = model.faces[i]
        return list(_face(f, tol, resolution, default_width(f, size)))

    n = len(model.faces)
    if n < FORK_FACES:
        return [build(i) for i in range(n)]
    from OCP.BinTools import BinTools
    from OCP.BRep import BRep_Builder
    from OCP.TopoDS import TopoDS, TopoDS_Compound, TopoDS_Iterator, TopoDS_Shape

    chunks = [list(range(k, n, _CHUNKS)) for k in range(_CHUNKS)]
    with tempfile.TemporaryDirectory(prefix="cadbridge-faces-") as tmp:
        def write(k: int, catch: bool) -> None:  # chunk k's faces to k.bin, their reports to k.pkl
            try:
                faces = [build(i) for i in chunks[k]]
            except Exception:
                if catch:  # in the forked process: built again in this one, which raises
                    return
                raise
            compound = TopoDS_Compound()
            b = BRep_Builder()
            b.MakeCompound(compound)
            for occ, _, _ in faces:
                b.Add(compound, occ)
            if not BinTools.Write_s(compound, str(Path(tmp) / f"{k}.bin")):
                raise OSError(f"could not write the model's faces to {tmp}")
            with open(Path(tmp) / f"{k}.tmp", "wb") as fh:
                pickle.dump([(fixes, checked) for _, fixes, checked in faces], fh)
            os.replace(Path(tmp) / f"{k}.tmp", Path(tmp) / f"{k}.pkl")  # the chunk is complete

        run_jobs([lambda k=k: write(k, True) for k in range(_CHUNKS)])
        built: list = [None] * n
        for k, chunk in enumerate(chunks):
            if not (Path(tmp) / f"{k}.pkl").exists():
                write(k, False)
            shape = TopoDS_Shape()
            if not BinTools.Read_s(shape, str(Path(tmp) / f"{k}.bin")):
                raise OSError(f"could not read the model's faces back from {tmp}")
            with open(Path(tmp) / f"{k}.pkl", "rb") as fh:
                rows = pickle.load(fh)
            it = TopoDS_Iterator(shape)
            for i, (fixes, checked) in zip(chunk, rows):
                face = TopoDS.Face_s(it.Value())
                face.Free(True)  # as built: in no compound yet (the chunk's froze it)
                built[i] = [face, fixes, checked]
                it.Next()
    return built


_CHUNKS = 16
"""Chunks of faces `_built_faces` shares out (faces k, k + 16, ...: costs even out)."""


def _valid_faces(faces: list) -> list[bool]:
    """`BRepCheck_Analyzer`'s verdict on each OCC face of ``faces``: one analysis of their
    compound, in parallel (OCC's own threads), where a face's verdict covers its wires, edges
    and vertices as the analysis of that face alone would (`tests/heal/test_brep.py`). On the
    analytic production die's 1 100 faces before sewing 3.9 s one face at a time, 2.5 s so;
    after sewing 0.5 s and 0.4 s."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.TopoDS import TopoDS_Compound

    if not faces:
        return []
    compound = TopoDS_Compound()
    b = BRep_Builder()
    b.MakeCompound(compound)
    for f in faces:
        b.Add(compound, f)
    check = BRepCheck_Analyzer(compound, True, True)
    return [bool(check.IsValid(f)) for f in faces]


def _made_valid(face) -> object | None:
    """``face`` (invalid by `BRepCheck_Analyzer`) through OCC's whole healing
    (`ShapeFix_Shape`): the one valid face it gives, else None."""
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.ShapeFix import ShapeFix_Shape
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    shape = ShapeFix_Shape(face)
    shape.Perform()
    ex = TopExp_Explorer(shape.Shape(), TopAbs_FACE)
    one = TopoDS.Face_s(ex.Current()) if ex.More() else None
    ex.Next()
    return one if one is not None and not ex.More() and BRepCheck_Analyzer(one).IsValid() else None


def model_brep(model: Model, *, sew_tolerance: float | None = None) -> ModelBrep:
    """``model`` as a sewn OCC compound of faces in model order (module docstring).

    sew_tolerance : model units; default `SEW_TOLERANCE_MM`, the tolerance the mesher sews
        OCC's reading of a file with. Not the file's trim tolerance: sewing ANSA faces whose
        trims miss their surfaces by 0.04 mm at 1.5 x that tolerance gave vertices that wide,
        and the fold lines fragmented into them made faces gmsh folds over itself
        (OCC131-2) or loops that do not close (OCC131-3); wider gaps are closed in the mesh
        (`cadbridge.mesh.cleanup.merge_close_nodes`), as on OCC's reading. Where OCC cannot
        make wires of faces sewn that tightly (Inventor's spring: trims 0.01 apart),
        `trim_sew_tolerance` (`cadbridge.tool.meshing` tries both).
    """
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS, TopoDS_Compound

    size = model.size()
    tol = EDGE_TOLERANCE * size
    if sew_tolerance is None:
        sew_tolerance = SEW_TOLERANCE_MM / model.units.to_mm
    resolution = float(model.resolution) if model.resolution and np.isfinite(model.resolution) else 0.0
    resolution = min(resolution, 1e-4 * size)  # a resolution the size of the part means nothing
    built = _built_faces(model, tol, resolution, size)
    checked = [k for k, (_, _, valid) in enumerate(built) if valid is not None]
    for k, valid in zip(checked, _valid_faces([built[k][0] for k in checked])):
        built[k][2] = valid
        if not valid:  # what the steps of `_face` leave invalid: OCC's whole healing
            one = _made_valid(built[k][0])
            if one is not None:  # one valid face: kept
                built[k][0], built[k][2] = one, True
                built[k][1].append("made valid by ShapeFix_Shape")
    sew = BRepBuilderAPI_Sewing(sew_tolerance)
    for occ, _, _ in built:
        sew.Add(occ)
    sew.Perform()
    faces, reports, again = [], [], []
    for k, (occ, fixes, valid) in enumerate(built):
        out = sew.Modified(occ)
        ex = TopExp_Explorer(out, TopAbs_FACE)  # the sewn face (one face in, one face out)
        sewn = TopoDS.Face_s(ex.Current()) if ex.More() else occ
        faces.append(sewn)
        # checked again only where the sewing changed the face (the check is the build's
        # costliest step on faces with long approximated trims: 7.7 s on PRO20358-W8)
        if valid is not None and sew.IsModified(occ):
            again.append(k)
        reports.append(FaceBuild(k, valid, fixes))
    for k, valid in zip(again, _valid_faces([faces[k] for k in again])):
        reports[k].valid = valid
    compound = TopoDS_Compound()
    b = BRep_Builder()
    b.MakeCompound(compound)
    for f in faces:
        b.Add(compound, f)
    from OCP.BRepTools import BRepTools

    anchors = np.zeros((len(model.faces), 9))
    for k, f in enumerate(model.faces):  # one point and one box per face
        u0, u1, v0, v1 = f.surface.domain
        uv = np.array([0.5 * (u0 + u1), 0.5 * (v0 + v1)])
        anchors[k, :2], anchors[k, 2:5] = uv, f.surface.evaluate(uv[:1], uv[1:])[0]
        anchors[k, 5:] = BRepTools.UVBounds_s(faces[k])  # as gmsh's OCCFace takes its bounds
    return ModelBrep(compound, reports, float(sew_tolerance), int(sew.NbFreeEdges()), anchors)


def trim_sew_tolerance(model: Model) -> float:
    """Sewing tolerance where the file's trims miss each other by more than `SEW_TOLERANCE_MM`
    (model units): 1.5 x the largest trim tolerance of its faces (``Face.trim_delta``: the
    trims miss the surface by that much, so neighbouring edges lie that far apart), at least
    `SEW_TOLERANCE_MM`, at most 1e-3 x the model size."""
    deltas = [f.trim_delta for f in model.faces if f.trim_delta is not None and np.isfinite(f.trim_delta)]
    floor = SEW_TOLERANCE_MM / model.units.to_mm
    return float(min(max(floor, 1.5 * max(deltas, default=0.0)), 1e-3 * model.size()))


@contextmanager
def brep_source(model: Model, *, sew_tolerance: float | None = None,
                brep: ModelBrep | None = None) -> Iterator[tuple[Path, ModelBrep]]:
    """A temporary OCC ``.brep`` file of `model_brep` (``model``, ``sew_tolerance``) for the
    mesher, and the build report; removed on exit. ``brep``: one built before for this model
    (then written as it is)."""
    from OCP.BRepTools import BRepTools

    brep = brep if brep is not None else model_brep(model, sew_tolerance=sew_tolerance)
    stem = Path(model.source or model.filename or "model").stem or "model"
    with tempfile.TemporaryDirectory(prefix="cadbridge-brep-") as tmp:
        path = Path(tmp) / f"{stem}.brep"
        if not BRepTools.Write_s(brep.shape, str(path)):
            raise OSError(f"could not write the model's B-rep to {path}")
        yield path, brep

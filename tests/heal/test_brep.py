"""`cadbridge.heal.brep`: cadbridge's own model as the OCC B-rep the mesher meshes.

References:
- OCC's own reading of the same IGES file (`IGESControl_Reader`): the built faces have its
  trimmed areas (`BRepGProp`, adaptive to 1e-9), face by face, on samples whose faces OCC
  reads soundly (analytic and NURBS, holes, a cone apex, a torus);
- gmsh's evaluation of the written ``.brep`` (gmsh's own OCC): its k-th surface is the model's
  k-th face at the same (u, v), checked at random points of each surface's domain against
  cadbridge's NURBS evaluation (`NurbsSurface.evaluate`), to 1e-9 x size;
- OCC's sewing of OCC's reading at the same tolerance: the same number of free edges;
- the trim-curve cubic's interval cap (`MAX_HERMITE_INTERVALS`): a curve no cubic follows
  within tolerance raises at once instead of doubling its intervals without end (PRO19800's
  hang).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.helpers.occ import faces, read_faces, read_shape

from cadbridge.heal.brep import SEW_TOLERANCE_MM, brep_source, model_brep
from cadbridge.iges import read_iges

pytest.importorskip("OCP")

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"
FILES = ["ushape_tools_nurbs.igs", "trimmed_hole.igs", "cone_apex.igs", "torus_patch.igs", "sphere_patch.igs"]


def _area(face) -> float:
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    g = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, g, 1e-9)
    return g.Mass()


@pytest.mark.parametrize("name", FILES)
def test_built_faces_have_occs_trimmed_areas(name):
    model = read_iges(SAMPLES / name)
    brep = model_brep(model)
    built = faces(brep.shape)
    occ = read_faces(SAMPLES / name)
    assert len(built) == len(model.faces) == len(occ)
    assert all(f.valid for f in brep.faces), [f for f in brep.faces if not f.valid]
    mine, theirs = np.array([_area(f) for f in built]), np.array([_area(f) for f in occ])
    # OCC's reader keeps the file's entity order, as cadbridge's does: face k is face k
    np.testing.assert_allclose(mine, theirs, rtol=1e-6)


@pytest.mark.parametrize("name", ["ushape_tools_nurbs.igs", "trimmed_hole.igs"])
def test_gmsh_surface_k_is_model_face_k(name):
    """Face identity between mesh and model holds by construction: gmsh's surface k + 1 of
    the written .brep evaluates to the model's face k at the same (u, v), and has the
    (u, v) box the B-rep's anchors give it."""
    import gmsh

    model = read_iges(SAMPLES / name)
    size = model.size()
    rng = np.random.default_rng(7)
    with brep_source(model) as (path, brep):
        gmsh.initialize(readConfigFiles=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            gmsh.model.occ.importShapes(str(path))
            gmsh.model.occ.synchronize()
            tags = [t for _, t in gmsh.model.getEntities(2)]
            assert len(tags) == len(model.faces)
            for k, (face, tag) in enumerate(zip(model.faces, tags)):  # loop over the faces
                u0, u1, v0, v1 = face.surface.domain
                uv = np.column_stack([rng.uniform(u0, u1, 20), rng.uniform(v0, v1, 20)])
                theirs = np.array(gmsh.model.getValue(2, tag, uv.ravel().tolist())).reshape(-1, 3)
                mine = face.surface.evaluate(uv[:, 0], uv[:, 1])
                assert np.max(np.linalg.norm(theirs - mine, axis=1)) <= 1e-9 * size, k
                anchor = np.array(gmsh.model.getValue(2, tag, brep.anchors[k, :2].tolist()))
                assert np.linalg.norm(anchor - brep.anchors[k, 2:5]) <= 1e-9 * size
                # the face's (u, v) box, as gmsh's OCC face takes it (`generate._model_faces`)
                lo, hi = gmsh.model.getParametrizationBounds(2, tag)
                np.testing.assert_allclose([lo[0], hi[0], lo[1], hi[1]], brep.anchors[k, 5:],
                                           atol=1e-12 * max(u1 - u0, v1 - v0))
        finally:
            gmsh.finalize()


def test_sewing_leaves_the_free_edges_occs_reading_leaves():
    """The U-shape tools' faces meet edge to edge: sewn at the same tolerance, cadbridge's
    B-rep and OCC's reading of the file keep the same open boundary."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing

    path = SAMPLES / "ushape_tools_nurbs.igs"
    brep = model_brep(read_iges(path))
    sew = BRepBuilderAPI_Sewing(SEW_TOLERANCE_MM)
    sew.Add(read_shape(path))
    sew.Perform()
    assert brep.free_edges == sew.NbFreeEdges() > 0
    assert brep.notes() == []  # a clean CAD file: nothing to heal, nothing reported


def test_trim_cubic_gives_up_at_the_interval_cap():
    """A trim curve no cubic follows (an oscillation far below the sampling) raises at the cap
    instead of bisecting without end."""
    import time

    from cadbridge.cad.analytic import MAX_HERMITE_INTERVALS, _TrimCurve
    from cadbridge.nurbs.curve import NurbsCurve

    class Wiggle(_TrimCurve):  # (t, 1e-3 sin(1e7 t)): smooth, but 1e6 waves on [0, 1]
        def __init__(self):
            self.base = NurbsCurve(3, np.array([0, 0, 0, 0, 1, 1, 1, 1.0]),
                                   np.column_stack([np.linspace(0, 1, 4), np.zeros(4)]), None, (0.0, 1.0))

        @property
        def knots(self):
            return self.base.knots

        def derivatives(self, t, order=1):
            t = np.asarray(t, dtype=float)
            out = np.zeros((len(t), order + 1, 2))
            w = 1e7
            for k in range(order + 1):  # d^k/dt^k of (t, 1e-3 sin(w t))
                out[:, k, 0] = t if k == 0 else (1.0 if k == 1 else 0.0)
                out[:, k, 1] = 1e-3 * w ** k * np.sin(w * t + k * np.pi / 2)
            return out

    start = time.perf_counter()
    with pytest.raises(ValueError, match=f"within {MAX_HERMITE_INTERVALS} intervals"):
        Wiggle().to_nurbs(tol=1e-9)
    assert time.perf_counter() - start < 30  # a limit against the old endless doubling, not a timing


def _plate_with_gaps(gap: float):
    """A 100 x 60 plane face (uv = xy, mm, resolution 0.001) whose four trim lines miss each
    other by ``gap`` at three corners."""
    from cadbridge.cad.model import Face, Trim, TrimLoop
    from cadbridge.nurbs.curve import NurbsCurve
    from cadbridge.nurbs.surface import NurbsSurface

    def line(p, q):
        return NurbsCurve(1, [0, 0, 1, 1], [p, q])

    s = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], [[[0, 0, 0], [0, 60, 0]], [[100, 0, 0], [100, 60, 0]]])
    s = NurbsSurface(1, 1, [0, 0, 100, 100], [0, 0, 60, 60], s.control_points)  # u = x, v = y
    loop = TrimLoop([line((0, 0), (100, 0)), line((100, gap), (100, 60)), line((100 - gap, 60), (0, 60)),
                     line((0, 60 - gap), (0, 0))])
    from cadbridge.cad.model import Model

    return Model(faces=[Face(surface=s, de=1, trims=Trim(loop, []))], resolution=1e-3)


def _gmsh_triangles(model, *, size: float, sew: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """gmsh's triangle mesh of `model_brep` (``model``) at ``size``: nodes (N, 3), triangles
    (T, 3) 0-based. ``sew``: gmsh's Geometry.OCCSewFaces (at `SEW_TOLERANCE_MM`), else gmsh's
    default."""
    import gmsh

    with brep_source(model) as (path, _):
        gmsh.initialize(readConfigFiles=False)
        try:
            gmsh.option.setNumber("General.Terminal", 0)
            if sew is not None:
                gmsh.option.setNumber("Geometry.OCCSewFaces", sew)
                gmsh.option.setNumber("Geometry.Tolerance", SEW_TOLERANCE_MM)
            gmsh.option.setNumber("Mesh.MeshSizeMax", size)
            gmsh.model.occ.importShapes(str(path))
            gmsh.model.occ.synchronize()
            gmsh.model.mesh.generate(2)
            _, xyz, _ = gmsh.model.mesh.getNodes()
            etypes, _, enodes = gmsh.model.mesh.getElements(2)
            tri = np.asarray(enodes[list(etypes).index(2)], dtype=np.int64).reshape(-1, 3) - 1
        finally:
            gmsh.finalize()
    return np.asarray(xyz).reshape(-1, 3), tri


def test_trim_pieces_apart_within_the_trim_tolerance_make_a_closed_wire():
    """Class: consecutive trim pieces that miss each other by more than the file's resolution
    but within the face's trim tolerance (CATIA V4's 122 faces: 0.003 mm at resolution 0.001;
    bug8363_f45: 0.099 mm). OCC's wire stays open at the resolution and gmsh then stops with
    "Could not fix wire in surface 1"; joined within the trim tolerance, gmsh meshes the face,
    and the mesh has the plate's analytic area (6000 mm^2, to the slivers the three joined
    corners cut: gap x element size / 2 each)."""
    model = _plate_with_gaps(0.01)
    brep = model_brep(model)
    assert brep.faces[0].valid
    assert any("gaps up to 0.01 closed" in fix for fix in brep.faces[0].fixes), brep.faces[0].fixes
    xyz, tri = _gmsh_triangles(model, size=10.0)
    a, b, c = xyz[tri[:, 0]], xyz[tri[:, 1]], xyz[tri[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    assert area == pytest.approx(6000.0, abs=3 * 0.5 * 0.01 * 10.0)


def test_trim_pieces_apart_beyond_the_trim_tolerance_stay_apart():
    """A gap wider than the face's trim tolerance (1e-3 x size here: 0.117 mm) is a missing
    piece, not a tolerance: the wire is not closed over it."""
    brep = model_brep(_plate_with_gaps(1.0))
    assert not any("closed" in fix for fix in brep.faces[0].fixes), brep.faces[0].fixes


def _dome_with_pole(gap: float):
    """A quarter cone (B-spline, degree 2 x 1: its row v = 1 of poles is the apex (0, 0, 15)),
    trimmed by its (u, v) square with the pole side as a trim piece of its own, the pieces
    next to it ending ``gap`` short of v = 1 (OCC's vertices there near, not on, the apex)."""
    from cadbridge.cad.model import Face, Model, Trim, TrimLoop
    from cadbridge.nurbs.curve import NurbsCurve
    from cadbridge.nurbs.surface import NurbsSurface

    def line(p, q):
        return NurbsCurve(1, [0, 0, 1, 1], [p, q])

    rim, apex = [[20, 0, 0], [20, 20, 0], [0, 20, 0]], [0, 0, 15]
    s = NurbsSurface(2, 1, [0, 0, 0, 1, 1, 1], [0, 0, 1, 1], [[p, apex] for p in rim])
    loop = TrimLoop([line((1, 1), (0, 1)), line((0, 1 - gap), (0, 0)), line((0, 0), (1, 0)), line((1, 0), (1, 1 - gap))])
    return Model(faces=[Face(surface=s, de=1, trims=Trim(loop, []))])


def test_a_pole_side_trim_piece_keeps_one_vertex():
    """Class: a trim piece along a pole side of its surface (a closed edge) whose neighbours end
    near, not on, the pole: OCC's `ShapeFix_Wire.FixConnected` gave each of its ends a vertex of
    its own, and gmsh then stopped with "Could not fix wire in surface 1" (sewing) or "The 1D
    mesh seems not to be forming a closed loop" (trj8_b1-ec-214.stp: its model route failed
    on every attempt). References: OCC's topology (the degenerated edge has one vertex) and its
    geometry of the built face: the mesh's area is OCC's area of the face (`BRepGProp`) and
    every node lies on OCC's surface (`GeomAPI_ProjectPointOnSurf`)."""
    from OCP.BRep import BRep_Tool
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp, TopExp_Explorer
    from OCP.TopoDS import TopoDS

    model = _dome_with_pole(4e-8)  # the apex vertices ~1e-6 apart: within tolerance, not the same point
    brep = model_brep(model)
    (face,) = faces(brep.shape)
    degenerated = []
    ex = TopExp_Explorer(face, TopAbs_EDGE)
    while ex.More():  # loop over the face's (few) edges
        e = TopoDS.Edge_s(ex.Current())
        ex.Next()
        if BRep_Tool.Degenerated_s(e):
            degenerated.append(TopExp.FirstVertex_s(e).IsSame(TopExp.LastVertex_s(e)))
    assert degenerated and all(degenerated), degenerated
    surface = BRep_Tool.Surface_s(face)
    for sew in (1, 0):  # the model route's attempts: gmsh sews the B-rep again, or not
        xyz, tri = _gmsh_triangles(model, size=2.0, sew=sew)
        a, b, c = xyz[tri[:, 0]], xyz[tri[:, 1]], xyz[tri[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
        assert area == pytest.approx(_area(face), rel=0.01)  # flat triangles of a 2 mm mesh on a 20 mm cone: ~0.3 % short
        off = [GeomAPI_ProjectPointOnSurf(gp_Pnt(*p), surface).LowerDistance() for p in xyz.tolist()]
        assert max(off) <= 1e-6 * model.size()


def _brep_bytes(shape) -> bytes:
    import tempfile

    from OCP.BRepTools import BRepTools

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.brep"
        assert BRepTools.Write_s(shape, str(path))
        return path.read_bytes()


@pytest.mark.parametrize("name", ["ushape_tools_nurbs.igs", "ushape_tools_analytic.igs"])
def test_faces_built_by_two_processes_are_the_faces_built_by_one(name, monkeypatch):
    """The chunked build (`_built_faces`: chunks of faces passed back as binary B-reps) gives
    the same B-rep, to the byte of its written ``.brep``, with one process or with a forked
    second one (the machine's CPU count does not change the tool), and the same fixes and
    validity as the faces built directly. Reference: the same model built in one process."""
    import cadbridge.common.fork_jobs as fork_jobs
    import cadbridge.heal.brep as brep

    model = read_iges(SAMPLES / name)
    monkeypatch.setattr(brep, "FORK_FACES", 10 ** 9)
    direct = model_brep(model)
    monkeypatch.setattr(brep, "FORK_FACES", 1)
    monkeypatch.setattr(fork_jobs, "_available_cpus", lambda: 1)
    one = model_brep(model)
    monkeypatch.setattr(fork_jobs, "_available_cpus", lambda: 2)
    two = model_brep(model)
    assert _brep_bytes(one.shape) == _brep_bytes(two.shape)
    assert [(f.valid, f.fixes) for f in direct.faces] == [(f.valid, f.fixes) for f in one.faces] == [
        (f.valid, f.fixes) for f in two.faces]
    assert len(model.faces) > 1 and direct.free_edges == one.free_edges == two.free_edges
    assert _brep_bytes(direct.shape) == _brep_bytes(one.shape)  # no straight pcurve here: every double kept


def test_a_face_that_fails_in_the_forked_build_raises_its_own_error(monkeypatch):
    """A face whose build raises (here a ValueError, as a trim no cubic follows does) raises
    that error from `model_brep` with the fork too, not the fork's JobError: the route's
    fallback (`cadbridge.tool.meshing._mesh_model_brep`) catches it by type."""
    import cadbridge.heal.brep as brep

    model = read_iges(SAMPLES / "ushape_tools_nurbs.igs")
    bad = model.faces[len(model.faces) // 2]
    real = brep._face

    def failing(face, *args, **kw):
        if face is bad:
            raise ValueError("no cubic follows this trim")
        return real(face, *args, **kw)

    monkeypatch.setattr(brep, "_face", failing)
    monkeypatch.setattr(brep, "FORK_FACES", 1)
    with pytest.raises(ValueError, match="no cubic follows"):
        model_brep(model)


def test_one_check_of_all_faces_gives_each_faces_own_verdict():
    """`_valid_faces` (one parallel `BRepCheck_Analyzer` over the faces' compound) gives each
    face the verdict of checking it alone, an invalid face included (a face whose only edge
    has lost its SameParameter flag). Reference: `BRepCheck_Analyzer` of each face."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from cadbridge.heal.brep import _valid_faces

    model = read_iges(SAMPLES / "ushape_tools_nurbs.igs")
    built = faces(model_brep(model).shape)
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Copy

    broken = TopoDS.Face_s(BRepBuilderAPI_Copy(built[1]).Shape())
    edge = TopoDS.Edge_s(TopExp_Explorer(broken, TopAbs_EDGE).Current())
    BRep_Builder().SameParameter(edge, False)
    every = built + [broken]
    alone = [BRepCheck_Analyzer(f).IsValid() for f in every]
    assert alone[-1] is False and all(alone[:-1])
    assert _valid_faces(every) == alone

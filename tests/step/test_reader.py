"""`cadbridge.step.read_step` and `cadbridge.formats.read_cad`: STEP files into the same `Model`.

References:
- OCC's own reading of the same file (`STEPControl_Reader`): the faces cadbridge builds from
  its model (`cadbridge.heal.brep.model_brep`: our NURBS surfaces and our (u, v) trims) have
  OCC's trimmed areas, face by face (`BRepGProp`, adaptive); `cadbridge.verify` finds every
  face's surface on OCC's to 1e-9 x size with normals within 1e-9 rad;
- the same part written in mm and in inch (OCC's STEP writer, ``write.step.unit``): cadbridge
  reads both in mm, with the same bounding box;
- the corpus README's expected refusals (tessellated only, external references only): exit 2
  with one line, nothing written.
The generated part (cadquery): a plate with filleted corners and a hole (planes, cylinders:
analytic faces that `BRepBuilderAPI_NurbsConvert` turns into B-splines with their pcurves),
its bottom edges rounded (tori), and a spherical dome.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OCP")
cq = pytest.importorskip("cadquery")

from tests.helpers.occ import area, faces  # noqa: E402

from cadbridge.formats import cad_format, read_cad  # noqa: E402
from cadbridge.heal.brep import model_brep  # noqa: E402
from cadbridge.step import StepError, is_step, read_step  # noqa: E402
from cadbridge.verify.reference import occ_read_shape as read_shape  # noqa: E402 - OCC's STEPControl_Reader

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT.parent / "shared" / "cad_corpus" / "step"


def _part():
    plate = (cq.Workplane("XY").box(60, 40, 8).edges("|Z").fillet(6).faces(">Z").workplane().hole(10)
             .faces("<Z").edges("%CIRCLE").fillet(1.0))
    dome = cq.Workplane("XY").workplane(offset=4).center(15, 0).sphere(8).intersect(
        cq.Workplane("XY").workplane(offset=4).center(15, 0).box(30, 30, 20, centered=(True, True, False)))
    return plate.union(dome).val()


def _write(shape, path: Path, unit: str = "MM") -> Path:
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    w = STEPControl_Writer()
    Interface_Static.SetCVal_s("write.step.unit", unit)
    try:
        w.Transfer(shape.wrapped, STEPControl_AsIs)
        assert w.Write(str(path)) == IFSelect_RetDone
    finally:
        Interface_Static.SetCVal_s("write.step.unit", "MM")
    return path


@pytest.fixture(scope="module")
def part_files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("step")
    shape = _part()
    return {"mm": _write(shape, d / "part_mm.step"), "inch": _write(shape, d / "part_inch.stp", "IN")}


def test_faces_have_occs_trimmed_areas(part_files):
    path = part_files["mm"]
    model = read_step(path)
    theirs = faces(read_shape(path))
    assert len(model.faces) == len(theirs) > 8
    for f in model.faces:  # clamped knots (OCC's NURBS conversion of a cylinder gives unclamped ones)
        s = f.surface
        for k, d in ((s.knots_u, s.degree_u), (s.knots_v, s.degree_v)):
            assert np.all(k[: d + 1] == k[0]) and np.all(k[-d - 1:] == k[-1])
    built = model_brep(model)
    mine = np.array([area(f, 1e-9) for f in faces(built.shape)])
    ref = np.array([area(f, 1e-9) for f in theirs])
    # one product, one solid: cadbridge keeps OCC's face order. The pcurves of the tori, which
    # OCC's NURBS conversion approximates (the surfaces are exact), move areas by 2e-7
    np.testing.assert_allclose(mine, ref, rtol=1e-6)


def test_verify_finds_every_face_on_occs(part_files):
    from cadbridge.verify.faces import verify

    report = verify(part_files["mm"], isolate=False)
    assert report.faces and all(f.passed for f in report.faces), [f for f in report.faces if not f.passed][:2]
    assert max(f.pos_dev for f in report.faces) <= 1e-9
    assert max(f.ang_dev for f in report.faces) <= 1e-9


def test_inch_file_reads_in_mm(part_files):
    """The part written in inch reads in mm: its faces have the mm file's areas (mm^2)."""
    mm, inch = read_step(part_files["mm"]), read_step(part_files["inch"])
    assert inch.units.to_mm == 1.0 and len(inch.faces) == len(mm.faces)
    a = np.array([area(f, 1e-9) for f in faces(model_brep(mm).shape)])
    b = np.array([area(f, 1e-9) for f in faces(model_brep(inch).shape)])
    np.testing.assert_allclose(b, a, rtol=1e-7)
    np.testing.assert_allclose(inch.bbox(), mm.bbox(), atol=1e-9 * mm.size())


def test_format_is_told_by_content(part_files, tmp_path):
    step_as_igs = tmp_path / "really_step.igs"
    step_as_igs.write_bytes(part_files["mm"].read_bytes())
    assert is_step(step_as_igs) and cad_format(step_as_igs) == "step"
    assert len(read_cad(step_as_igs).faces) == len(read_step(part_files["mm"]).faces)
    iges = ROOT / "iges_samples" / "trimmed_hole.igs"
    assert cad_format(iges) == "iges" and read_cad(iges).faces


def test_convert_step_is_sound(part_files, tmp_path):
    """`cadbridge convert part.step` exits 0 and its tool is sound against OCC's shape."""
    from cadbridge.verify.soundness import tool_soundness

    out = tmp_path / "out"
    res = subprocess.run([sys.executable, "-m", "cadbridge", "-q", "convert", str(part_files["mm"]), "-o", str(out),
                          "--element", "tri"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-400:]
    report = tool_soundness(part_files["mm"], sorted(out.glob("*.nagata")))
    assert report.sound, report.line()


@pytest.mark.skipif(not CORPUS.is_dir(), reason="shared/cad_corpus not present")
@pytest.mark.parametrize(("name", "why"), [("nist_ftc_08_asme1_ap242-2.stp", "tessellated only"),
                                           ("trj4_xr1-pe-214.stp", "external files")])
def test_refusals(name: str, why: str, tmp_path):
    with pytest.raises(StepError, match=why):
        read_step(CORPUS / name)
    out = tmp_path / "out"
    res = subprocess.run([sys.executable, "-m", "cadbridge", "convert", str(CORPUS / name), "-o", str(out)], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    lines = [ln for ln in res.stderr.splitlines() if not ln.startswith("cadbridge convert [")]
    assert res.returncode == 2 and len(lines) == 1 and why in lines[0] and "CADBRIDGE_DEBUG" not in lines[0], lines
    assert not out.exists()


@pytest.mark.skipif(not CORPUS.is_dir(), reason="shared/cad_corpus not present")
def test_microstation_k1_converts_soundly_and_quietly(tmp_path):
    """K1 from MicroStation: OCC's NURBS conversion dropped its full-cylinder face and cut its
    elliptic fillet (an extrusion crossing the ellipse's seam) to 77 %; read through the exact
    maps every face is there, `convert` exits 0 with a tool sound by OCC's measure
    (`tool_soundness`), and no numpy warning reaches the user (a degenerate edge's
    parameter bounds of +-1e308 overflowed in `_curve_shape`)."""
    out = tmp_path / "out"
    res = subprocess.run([sys.executable, "-m", "cadbridge", "convert", str(CORPUS / "trj6_k1-md-214.stp"), "-o",
                          str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-400:]
    assert "warning:" not in res.stderr, [ln for ln in res.stderr.splitlines() if "warning:" in ln]
    from cadbridge.verify.soundness import tool_soundness

    report = tool_soundness(CORPUS / "trj6_k1-md-214.stp", sorted(out.glob("*.nagata")))
    assert report.sound, report.line()


def test_file_route_meshes_occs_reading(part_files):
    """The fallback route ("the file as OCC reads it") of a STEP file meshes OCC's reading
    written as a .brep (gmsh's own STEP import finds no surface in some files): its nodes lie
    on OCC's shape (`BRepExtrema_DistShapeShape`), to 1e-6 x size."""
    from tests.helpers.occ import distance

    from cadbridge.tool.meshing import mesh_for_tools, read_healed

    model, excursions = read_healed(part_files["mm"])
    mesh, _ = mesh_for_tools(part_files["mm"], model, excursions=excursions, element="tri", route="file")
    assert mesh.n_elements > 0
    shape = read_shape(part_files["mm"])
    pick = np.linspace(0, len(mesh.nodes) - 1, 40).astype(int)
    assert max(distance(mesh.nodes[i], shape) for i in pick) <= 1e-6 * model.size()


def test_inspect_names_the_format(part_files):
    """`cadbridge inspect` on STEP: the format, no IGES entity table, the trim tolerance as
    the largest edge tolerance of OCC's reading (which it is: `BRep_Tool.Tolerance`)."""
    from cadbridge.cli.inspect import format_inspect

    text = format_inspect(read_step(part_files["mm"]))
    assert "read through OpenCASCADE" in text and "\nentities" not in text
    assert "largest edge tolerance" in text


@pytest.mark.skipif(not CORPUS.is_dir(), reason="shared/cad_corpus not present")
def test_wild_edge_tolerance_is_capped_with_a_note(monkeypatch):
    """K1 from Unigraphics: OCC's NURBS conversion of its extrusion faces gives one face an edge
    tolerance of 34 mm (21 % of the model). Read through the exact maps (`cadbridge.step.analytic`)
    the edges keep the file's own tolerance (< 1e-4 x size) and no cap applies; through the
    conversion (the route of every other surface type, forced here) the tolerance, taken as the
    face's trim tolerance, made `check_trim_agreement` refuse a file OCC finds valid: it is capped
    at 1e-3 x size, and the note says so (reference: OCC's own `BRep_Tool.Tolerance` of that
    face's edges)."""
    import cadbridge.step.reader as reader
    from cadbridge.step.reader import MAX_DELTA_REL

    if not (CORPUS / "trj8_k1-ug-214.stp").is_file():
        pytest.skip("shared/cad_corpus not present")
    model = read_step(CORPUS / "trj8_k1-ug-214.stp")
    assert max(f.trim_delta for f in model.faces) <= 1e-4 * model.size()
    assert not any("edge tolerance of" in d.message for d in model.diagnostics)
    monkeypatch.setattr(reader, "_elementary", lambda src, notes, de: None)
    model = read_step(CORPUS / "trj8_k1-ug-214.stp")
    cap = MAX_DELTA_REL * model.size()
    assert max(f.trim_delta for f in model.faces) <= cap * (1 + 1e-12)
    assert any("edge tolerance of" in d.message for d in model.diagnostics)


def _box(loop):
    pts = np.vstack([c.evaluate(np.linspace(c.domain[0], c.domain[1], 65)) for c in loop.curves])
    return pts.min(axis=0), pts.max(axis=0)


@pytest.mark.parametrize("which", ["generated", "trj8_k1-ct-214.stp"])
def test_outer_loop_encloses_the_holes(which, part_files):
    """Every face's outer trim loop holds its holes: each hole's (u, v) box lies inside the
    outer loop's (reference: the boxes of the exact curves, densely sampled). OCC's
    `BRepTools.OuterWire` named the inner wire of a planar ring of K1 from CATIA V5 (face 13)."""
    if which == "generated":
        path = part_files["mm"]
    else:
        path = CORPUS / which
        if not path.is_file():
            pytest.skip("shared/cad_corpus not present")
    model = read_step(path)
    holed = [f for f in model.faces if f.trims is not None and f.trims.inner]
    assert holed
    for f in holed:
        lo, hi = _box(f.trims.outer)
        for h in f.trims.inner:
            a, b = _box(h)
            tol = 1e-9 * float(np.linalg.norm(hi - lo))
            assert np.all(a >= lo - tol) and np.all(b <= hi + tol), (f.de, lo, hi, a, b)


def test_a_wire_gap_its_vertex_covers_is_bridged():
    """Class of defect: an edge curve that stops short of its vertex, the vertex's tolerance
    covering the gap (b1 from CASCADE: 0.43 mm on planar face 206; OCC finds it valid). The
    pcurves alone leave the loop open; `_bridged` adds the straight (u, v) piece the vertex
    stands for. Reference: analytic distances on OCC's plane z = 0 (3D gap = (u, v) gap)."""
    from OCP.Geom import Geom_Plane
    from OCP.gp import gp_Dir, gp_Pnt

    from cadbridge.nurbs.curve import NurbsCurve
    from cadbridge.step.reader import _bridged

    plane = Geom_Plane(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1))

    def line(a, b):
        return NurbsCurve(1, [0, 0, 1, 1], np.array([a, b], dtype=float))

    # a square whose right side stops 0.4 short of the corner (10, 10)
    square = [line([0, 0], [10, 0]), line([10, 0], [10, 9.6]), line([10, 10], [0, 10]), line([0, 10], [0, 0])]
    covered = [(1e-7, 1e-7), (1e-7, 1e-7), (0.25, 1e-7), (1e-7, 1e-7)]  # the corner's tolerance 0.25: 2 x 0.25 >= 0.4

    def piece_ends(curves):
        return np.array([c.evaluate(np.array(c.domain)) for c in curves])

    out = _bridged(square, covered, piece_ends(square), plane)
    assert len(out) == 5
    ends = np.array([[c.evaluate(np.array([t]))[0] for t in c.domain] for c in out])  # (5, 2, 2)
    np.testing.assert_allclose(ends[2], [[10, 9.6], [10, 10]], atol=1e-15)  # the bridge
    np.testing.assert_allclose(ends[:, 1], np.roll(ends[:, 0], -1, axis=0), atol=1e-15)  # closed
    # not covered: the vertex's tolerance below half the gap (OCC's wire is open too)
    assert len(_bridged(square, [(1e-7, 1e-7), (1e-7, 1e-7), (0.15, 1e-7), (1e-7, 1e-7)], piece_ends(square), plane)) == 4
    # within the edges' own tolerance: left to the B-rep healing (no piece of 1e-8)
    near = [line([0, 0], [10, 0]), line([10, 0], [10, 10 - 1e-8]), line([10, 10], [0, 10]), line([0, 10], [0, 0])]
    assert len(_bridged(near, [(0.25, 1e-7)] * 4, piece_ends(near), plane)) == 4


@pytest.mark.skipif(not (CORPUS / "trj8_b1-ec-214.stp").is_file(), reason="corpus not present")
def test_b1_face_206_closes_through_its_vertex():
    """b1 from CASCADE, face 206 (index 205): OCC's own edges on it leave a 0.43 mm gap between
    two consecutive edges (`BRepAdaptor_Curve` ends, the reference), within twice the shared
    vertex's tolerance; cadbridge's loop closes it with one straight piece of that length."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepAdaptor import BRepAdaptor_Curve
    from OCP.BRepTools import BRepTools_WireExplorer
    from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED, TopAbs_WIRE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from cadbridge.step.reader import occ_step_shape

    path = CORPUS / "trj8_b1-ec-214.stp"
    ex = TopExp_Explorer(occ_step_shape(path), TopAbs_FACE)
    for _ in range(205):
        ex.Next()
    face = TopoDS.Face_s(ex.Current())
    wires = TopExp_Explorer(face, TopAbs_WIRE)
    assert wires.More()
    ends, vertex_tol = [], []  # the face's one wire
    while wires.More():
        we = BRepTools_WireExplorer(TopoDS.Wire_s(wires.Current()), face)
        while we.More():
            c = BRepAdaptor_Curve(we.Current())
            a, b = c.Value(c.FirstParameter()), c.Value(c.LastParameter())
            ends.append((b, a) if we.Current().Orientation() == TopAbs_REVERSED else (a, b))
            vertex_tol.append(BRep_Tool.Tolerance_s(we.CurrentVertex()))  # where this edge starts
            we.Next()
        wires.Next()
    occ_gap = [ends[i][1].Distance(ends[(i + 1) % len(ends)][0]) for i in range(len(ends))]
    k = int(np.argmax(occ_gap))
    assert 0.4 < occ_gap[k] <= 2 * vertex_tol[(k + 1) % len(ends)]
    model = read_step(path)
    f = model.faces[205]
    loop = f.trims.outer.curves
    assert len(loop) == len(ends) + 1
    x = [f.surface.evaluate(*c.evaluate(np.array(c.domain)).T) for c in loop]  # (2, 3) per piece
    steps = [np.linalg.norm(x[i][1] - x[(i + 1) % len(x)][0]) for i in range(len(x))]
    assert max(steps) < 1e-4  # closed
    lengths = [np.linalg.norm(p[1] - p[0]) for p in x]
    assert min(abs(L - occ_gap[k]) for L in lengths) < 1e-6


SPLINE = [(0, 0), (12, 9), (25, 4), (38, 14), (50, 0)]


@pytest.fixture(scope="module")
def spline_prism(tmp_path_factory) -> Path:
    """A prism over a closed outline of a B-spline arc and two lines (cadquery: its side face
    on the spline is OCC's Geom_SurfaceOfLinearExtrusion of a B-spline curve), written by
    OCC's STEP writer."""
    shape = cq.Workplane("XY").spline(SPLINE, includeCurrent=False).lineTo(25, -20).close().extrude(15).val()
    return _write(shape, tmp_path_factory.mktemp("prism") / "spline_prism.step")


def test_bspline_extrusion_keeps_its_pcurves(spline_prism):
    """An extrusion of a B-spline curve becomes a B-spline exactly, in the same (u, v): the
    converted face's pcurves are OCC's own, value for value (BRepBuilderAPI_NurbsConvert
    approximates them again), its surface OCC's extrusion at every pcurve point (1e-12 x
    size). The model's trimmed areas: the planes' OCC's; the side face's the analytic
    arc length x height (OCC's area of the extrusion face itself is 0.57 % too large)."""
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from cadbridge.step.reader import _bspline_extrusion, _nurbs_face

    shape = read_shape(spline_prism)
    sides = [f for f in faces(shape) if _bspline_extrusion(BRep_Tool.Surface_s(f))]
    assert len(sides) == 1
    src = sides[0]
    out = _nurbs_face(src)
    s_src, s_out = BRep_Tool.Surface_s(src), BRep_Tool.Surface_s(out)
    assert type(s_out).__name__ == "Geom_BSplineSurface"
    ea, eb = TopExp_Explorer(src, TopAbs_EDGE), TopExp_Explorer(out, TopAbs_EDGE)
    checked = 0
    while ea.More():
        a, b = TopoDS.Edge_s(ea.Current()), TopoDS.Edge_s(eb.Current())
        ea.Next()
        eb.Next()
        ca, cb = BRep_Tool.CurveOnSurface_s(a, src, 0.0, 0.0), BRep_Tool.CurveOnSurface_s(b, out, 0.0, 0.0)
        lo, hi = BRep_Tool.Range_s(a, src)
        for t in np.linspace(lo, hi, 11):
            pa, pb = ca.Value(t), cb.Value(t)
            assert (pa.X(), pa.Y()) == (pb.X(), pb.Y())
            assert s_src.Value(pa.X(), pa.Y()).Distance(s_out.Value(pb.X(), pb.Y())) <= 1e-12 * 60
            checked += 1
    assert checked >= 44
    from OCP.BRepAdaptor import BRepAdaptor_Curve
    from OCP.GCPnts import GCPnts_AbscissaPoint

    model = read_step(spline_prism)
    mine = np.array([area(f, 1e-9) for f in faces(model_brep(model).shape)])
    ref = np.array([area(f, 1e-9) for f in faces(shape)])
    side = [i for i, f in enumerate(faces(shape)) if f.IsSame(src)][0]
    spline = cq.Workplane("XY").spline(SPLINE, includeCurrent=False).val()
    ref[side] = 15.0 * GCPnts_AbscissaPoint.Length_s(BRepAdaptor_Curve(spline.wrapped), 1e-12)
    np.testing.assert_allclose(mine, ref, rtol=1e-6)


def test_line_pcurves_are_occs_conversion():
    """`_line_piece` (a pcurve that is a Geom2d_Line, also behind a trimmed curve) gives the
    numbers of OCC's own conversion, `Geom2dConvert.CurveToBSplineCurve` of the trimmed line
    (reference), exactly, and backwards those of `reverse_curve` of that; other curves are
    left to it (None)."""
    from OCP.Geom2d import Geom2d_Circle, Geom2d_Line, Geom2d_TrimmedCurve
    from OCP.Geom2dConvert import Geom2dConvert
    from OCP.gp import gp_Ax2d, gp_Dir2d, gp_Pnt2d

    from cadbridge.nurbs.edits import reverse_curve
    from cadbridge.step.reader import _line_piece, nurbs_curve2d

    line = Geom2d_Line(gp_Pnt2d(0.3, -1.7), gp_Dir2d(0.6, 0.8))
    for c2, (a, b) in ((line, (-2.25, 7.125)), (Geom2d_TrimmedCurve(line, -5.0, 9.0), (0.1, 3.3))):
        got = _line_piece(c2, a, b)
        ref = nurbs_curve2d(Geom2dConvert.CurveToBSplineCurve_s(Geom2d_TrimmedCurve(c2, a, b)))
        assert got.degree == ref.degree == 1
        assert np.array_equal(got.knots, ref.knots)
        assert np.array_equal(got.control_points, ref.control_points)
        back, ref_back = _line_piece(c2, a, b, True), reverse_curve(ref)  # a REVERSED edge's piece
        assert np.array_equal(back.knots, ref_back.knots)
        assert np.array_equal(back.control_points, ref_back.control_points)
    assert _line_piece(Geom2d_Circle(gp_Ax2d(gp_Pnt2d(0, 0), gp_Dir2d(1, 0)), 2.0), 0.0, 1.0) is None

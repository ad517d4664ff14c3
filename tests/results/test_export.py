"""Results on the exact CAD, part 2 (issue 9): two faces sharing an edge (the U-shape die's
wall, radius and land), the IGES band export read back by OpenCASCADE, the `cadbridge map`
command end to end and its bad-input behaviour. References: the die's analytic geometry
(R 5 radius centred at x = 41, z = -5 between the wall x = 36 and the land z = 0) and OCC
(IGESCAFControl_Reader, BRepGProp.SurfaceProperties)."""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest

pytest.importorskip("OCP")

from cadbridge.cli import PROGRESS_LINE  # noqa: E402
from cadbridge.results import map_results  # noqa: E402


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def die(tmp_path_factory):
    """The U-shape die (quarter model) as NURBS IGES, our model of it and a gmsh triangle
    mesh of 2 mm with a smooth synthetic contact pressure peaking on the radius."""
    import meshio

    from cadbridge.iges import read_iges
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.ushape.geometry import export_iges, tool_faces

    d = tmp_path_factory.mktemp("die")
    cad = d / "die.igs"
    export_iges(tool_faces()["die"], cad, mode="nurbs", description="cadbridge test: U-shape die")
    model = read_iges(cad)
    mesh = mesh_cad(cad, element="tri", size=2.0)
    x = mesh.nodes
    p = 12 * np.exp(-((x[:, 0] - 40.0) ** 2 + (x[:, 2] + 1.0) ** 2) / 60) * (1 + 0.25 * np.cos(x[:, 1] / 4)) \
        + 0.03 * (x[:, 0] - 36) - 0.02 * x[:, 2]
    res = d / "die_result.vtu"
    meshio.write(res, meshio.Mesh(x, [(b.type, b.data) for b in mesh.cells], point_data={"pressure": p}))
    return {"dir": d, "cad": cad, "model": model, "mesh": mesh, "p": p, "result": res}


def occ_faces(path):
    """Faces of an IGES file as OCC's XCAF reader sees them: (area by BRepGProp with
    eps 1e-10, sRGB colour or None, name or None), in file order."""
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.IGESCAFControl import IGESCAFControl_Reader
    from OCP.Quantity import Quantity_Color, Quantity_TOC_sRGB
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDF import TDF_Label, TDF_LabelSequence
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS
    from OCP.XCAFDoc import XCAFDoc_ColorType, XCAFDoc_DocumentTool

    doc = TDocStd_Document(TCollection_ExtendedString("XmlXCAF"))
    r = IGESCAFControl_Reader()
    r.SetColorMode(True)
    r.SetNameMode(True)
    assert r.ReadFile(str(path)) == IFSelect_RetDone
    assert r.Transfer(doc)
    st = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    ct = XCAFDoc_DocumentTool.ColorTool_s(doc.Main())
    free = TDF_LabelSequence()
    st.GetFreeShapes(free)
    out = []

    def walk(lab):
        shape = st.GetShape_s(lab)
        subs = TDF_LabelSequence()
        st.GetComponents_s(lab, subs)
        if subs.Length():
            for i in range(1, subs.Length() + 1):
                walk(subs.Value(i))
            return
        exp = TopExp_Explorer(shape, TopAbs_FACE)
        while exp.More():
            f = TopoDS.Face_s(exp.Current())
            g = GProp_GProps()
            BRepGProp.SurfaceProperties_s(f, g, 1e-10)
            col = Quantity_Color()
            rgb = None
            for ctype in (XCAFDoc_ColorType.XCAFDoc_ColorSurf, XCAFDoc_ColorType.XCAFDoc_ColorGen):
                if ct.GetColor(f, ctype, col) or ct.GetColor(shape, ctype, col):
                    rgb = tuple(col.Values(Quantity_TOC_sRGB))
                    break
            name = None
            fl = TDF_Label()
            st.Search(f, fl)
            attr = TDataStd_Name()
            for l2 in (fl, lab):
                if not l2.IsNull() and l2.FindAttribute(TDataStd_Name.GetID_s(), attr):
                    name = attr.Get().ToExtString()
                    break
            out.append((g.Mass(), rgb, name))
            exp.Next()

    for i in range(1, free.Length() + 1):
        walk(free.Value(i))
    return out


# ----------------------------------------------------------------------------- two faces
def test_lines_meet_at_one_point_on_shared_face_edges(die):
    """Lines crossing the wall/radius and radius/land edges meet there at one point: the gap
    between the two faces' (u, v) of the crossing is <= 1e-9 x size, and the point lies on the
    analytic edge (x = 36, z = -5 or x = 41, z = 0). Points on the radius lie on the R 5
    cylinder about (x, z) = (41, -5) (reference: the die's analytic geometry)."""
    model, mesh = die["model"], die["mesh"]
    size = model.size()
    m = map_results(mesh, die["p"], model, field_name="pressure")
    c = m.contour(10)
    L = c.lines
    names = np.array([f.name for f in model.faces])
    assert set(names) == {"DIEWALL", "DIERAD", "DIELAND"}
    changes = L.face[L.joints] != L.joint_face
    assert changes.sum() >= 4  # several lines run over both edges
    assert np.max(L.joint_gap) <= 1e-9 * size
    jp = L.points[L.joints[changes]]
    pair = {frozenset(p) for p in zip(names[L.face[L.joints[changes]]], names[L.joint_face[changes]])}
    assert pair <= {frozenset({"DIEWALL", "DIERAD"}), frozenset({"DIERAD", "DIELAND"})}
    on_wall_edge = np.hypot(jp[:, 0] - 36.0, jp[:, 2] + 5.0)
    on_land_edge = np.hypot(jp[:, 0] - 41.0, jp[:, 2])
    assert np.all(np.minimum(on_wall_edge, on_land_edge) <= 1e-9 * size)
    rad = names[L.face] == "DIERAD"
    assert np.allclose(np.hypot(L.points[rad, 0] - 41.0, L.points[rad, 2] + 5.0), 5.0, rtol=0, atol=1e-12 * size)
    # every face's bands add up to its exact area (the mesh covers the faces; reference:
    # the planes' rectangles and the quarter cylinder's R pi / 2 x 20.5)
    fa = c.bands.face_area.sum(axis=0)
    width = 20.5
    exact = {"DIEWALL": 75.0 * width, "DIERAD": 5.0 * np.pi / 2 * width, "DIELAND": 149.0 * width}
    for k, n in enumerate(names):
        assert np.isclose(fa[k], exact[n], rtol=1e-9), n


# ----------------------------------------------------------------------------- IGES
@pytest.mark.parametrize("case", ["die", "cylinder"])
def test_iges_bands_read_by_occ(case, die, tmp_path):
    """The bands file: OCC reads one face per CSV row; per CAD face, OCC's band areas add up to
    OCC's area of that CAD face (rel 1e-6); each band face's area (rel 1e-6: OCC's own
    integration over polygon-trimmed B-spline faces is good to ~1e-7 here, where ours agrees
    with Green's theorem to 1e-10, see test_mapping.py), colour and name are what
    band_faces.csv says. Reference: OpenCASCADE."""
    from cadbridge.results.export import write_bands_iges, write_csv

    if case == "die":
        m = map_results(die["mesh"], die["p"], die["model"], field_name="pressure")
        cad_faces = occ_faces(die["cad"])
        cad_area = {name: a for a, _, name in cad_faces}
    else:
        from tests.results.test_mapping import cylinder_case

        model, mesh = cylinder_case(tri=True)
        m = map_results(mesh, mesh.nodes[:, 2] + 0.3 * mesh.nodes[:, 0], model, field_name="p")
        cad_area = {"CYL": 2 * np.pi * 2.0 * 3.0}  # analytic lateral area
    c = m.contour(7)
    path = tmp_path / "bands.igs"
    rows = write_bands_iges(path, c)
    write_csv(tmp_path, c, rows)
    with open(tmp_path / "band_faces.csv") as fh:
        table = list(csv.DictReader(fh))
    got = occ_faces(path)
    assert len(got) == len(table)
    sums: dict[str, float] = {}
    for row, (area, rgb, name) in zip(table, got):
        assert name == row["name"]
        assert rgb is not None and np.allclose(rgb, [float(row["r"]), float(row["g"]), float(row["b"])], atol=1e-6)
        assert np.isclose(area, float(row["area"]), rtol=1e-6)
        sums[row["face_name"]] = sums.get(row["face_name"], 0.0) + area
    assert set(sums) == set(cad_area)
    for k, a in sums.items():
        assert np.isclose(a, cad_area[k], rtol=1e-6), k
    # one 314 colour per level range present
    bands = {row["band"] for row in table}
    colours = {row["color"] for row in table}
    assert len(colours) == len(bands)


# ----------------------------------------------------------------------------- CLI
@pytest.fixture
def run(capsys):
    """`cadbridge ...` in this process: (exit code, stdout, stderr)."""
    from types import SimpleNamespace

    from cadbridge.cli import main

    def _run(*args):
        capsys.readouterr()
        code = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return SimpleNamespace(returncode=code, stdout=out, stderr=err)

    return _run


def test_cli_end_to_end_and_relevel(die, tmp_path, run):
    """cadbridge map writes the VTUs, IGES, CSVs, PNG and summary; its band areas are the
    library's (same numbers, round-trip precision); no NaN in any VTU; a second run into
    the same folder with other levels reuses the stored mapping."""
    import meshio

    out = tmp_path / "map"
    r = run("map", die["result"], "--cad", die["cad"], "--field", "pressure", "-o", out)
    assert r.returncode == 0, r.stderr
    for f in ("die_result_cad.vtu", "die_result_lines.vtu", "die_result_bands.igs", "bands.csv", "band_faces.csv",
              "lines.csv", "die_result.png", "summary.json", "mapping.npz"):
        assert (out / f).is_file(), f
    for f in ("die_result_cad.vtu", "die_result_lines.vtu"):
        v = meshio.read(out / f)
        assert np.all(np.isfinite(v.points))
        for a in v.point_data.values():
            assert np.all(np.isfinite(a))
    m = map_results(die["mesh"], die["p"], die["model"], field_name="pressure")
    ref = m.contour(8).bands
    with open(out / "bands.csv") as fh:
        rows = list(csv.DictReader(row for row in fh if not row.startswith("#")))
    assert [int(x["band"]) for x in rows] == np.flatnonzero(ref.present).tolist()
    assert np.allclose([float(x["area"]) for x in rows], ref.area[ref.present], rtol=1e-12)
    r2 = run("map", die["result"], "--cad", die["cad"], "--field", "pressure", "-o", out, "--levels", "0,2,4,8,16")
    assert r2.returncode == 0, r2.stderr
    assert "reused" in r2.stdout
    with open(out / "bands.csv") as fh:
        rows = list(csv.DictReader(row for row in fh if not row.startswith("#")))
    assert [x["range"] for x in rows][:4] == ["0 .. 2", "2 .. 4", "4 .. 8", "8 .. 16"]


def test_cli_mesh_off_the_cad_names_farthest_nodes_and_writes_nothing(die, tmp_path, run):
    """A result mesh lifted 0.5 mm off part of the die: exit 1, one line naming the farthest
    nodes and their distance, and no output folder."""
    import meshio

    x = die["mesh"].nodes.copy()
    lift = x[:, 0] > 150.0
    x[lift, 2] += 0.5
    bad = tmp_path / "off.vtu"
    meshio.write(bad, meshio.Mesh(x, [(b.type, b.data) for b in die["mesh"].cells], point_data={"pressure": die["p"]}))
    out = tmp_path / "never"
    r = run("map", bad, "--cad", die["cad"], "--field", "pressure", "-o", out)
    assert r.returncode == 1
    err = [ln for ln in r.stderr.strip().splitlines() if not re.match(PROGRESS_LINE, ln)]
    assert len(err) == 1 and "does not lie on" in err[0] and "distance 0.5" in err[0]
    first = int(err[0].split("node ")[1].split()[0])
    assert lift[first]
    assert not out.exists()


def test_cli_bad_field(die, tmp_path, run):
    """An absent field, bad levels: exit 2, one line, nothing written."""
    out = tmp_path / "x"
    r = run("map", die["result"], "--cad", die["cad"], "--field", "wear", "-o", out)
    assert r.returncode == 2 and "wear" in r.stderr and "pressure (point)" in r.stderr
    r = run("map", die["result"], "--cad", die["cad"], "--field", "pressure", "-o", out, "--levels", "3,2")
    assert r.returncode == 2 and "increasing" in r.stderr
    assert not out.exists()


# ----------------------------------------------------------------------------- curved trims
def _segment_area(R: float, d: float) -> float:
    """Area of the part of a disc of radius R beyond a chord at distance d from its centre."""
    d = np.clip(d, -R, R)
    return R * R * np.arccos(d / R) - d * np.sqrt(R * R - d * d)


def test_bands_follow_curved_trims_exactly(tmp_path):
    """trimmed_hole.igs: a 100 x 60 plate with an R 10 hole at (30, 25), gmsh triangles of
    4 mm whose border chords cut the hole. f = x: the bands are strips minus the hole's
    slices. Reference: analytic (strip area minus the circle segments): exact (rel 1e-12) for
    levels that miss the hole and for the total; levels across the hole within 1e-4 (between
    a border chord and the circle the field is carried out from the chord, so there the band
    border leaves x = c by the chord's sagitta). OCC reading the IGES bands measures the same
    regions: per face and in sum rel 1e-9. Lines ending at the hole end on the circle."""
    from pathlib import Path

    from cadbridge.iges import read_iges
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.results.export import write_bands_iges, write_csv

    path = Path(__file__).resolve().parents[2] / "iges_samples" / "trimmed_hole.igs"
    model = read_iges(path)
    mesh = mesh_cad(path, element="tri", size=4.0)
    m = map_results(mesh, mesh.nodes[:, 0], model, field_name="x")
    assert len(m.arcs) > 0
    R, cx = 10.0, 30.0

    def analytic(levels):
        edges = np.array([0.0, *levels, 100.0])
        hole = np.array([_segment_area(R, a - cx) - _segment_area(R, b - cx) for a, b in zip(edges[:-1], edges[1:])])
        return np.diff(edges) * 60.0 - hole

    c = m.contour([15.0, 45.0, 60.0])
    assert np.allclose(c.bands.area, analytic([15.0, 45.0, 60.0]), rtol=1e-12)
    levels = [15.0, 25.0, 33.0, 60.0]
    c = m.contour(levels)
    assert np.allclose(c.bands.area, analytic(levels), rtol=1e-4)
    assert np.isclose(c.bands.area.sum(), 100 * 60 - np.pi * R * R, rtol=1e-12)
    for i in range(len(c.lines)):  # lines ending near the hole end on it
        p = c.lines.line(i)["points"]
        for q in (p[0], p[-1]):
            r = np.hypot(q[0] - cx, q[1] - 25.0)
            assert abs(r - R) <= 1e-9 or r > R + 1.0
    rows = write_bands_iges(tmp_path / "b.igs", c)
    write_csv(tmp_path, c, rows)
    got = occ_faces(tmp_path / "b.igs")
    assert len(got) == len(rows)
    for row, (area, _, name) in zip(rows, got):
        assert name == row["name"] and np.isclose(area, row["area"], rtol=1e-9)
    assert np.isclose(sum(g[0] for g in got), 100 * 60 - np.pi * R * R, rtol=1e-9)
    # the CAD tessellation ends at the circle too: no point inside the hole
    from cadbridge.results.export import tessellate

    pts = tessellate(m, chord_tol=1e-3)[0]
    assert np.min(np.hypot(pts[:, 0] - cx, pts[:, 1] - 25.0)) >= R - 1e-9

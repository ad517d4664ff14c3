"""Levels equal to nodal values (issue 34): a level through node rows, along a seam, through
a pole, and fields constant on whole elements at a level (zero pressure regions, a field
clamped at a limit). Every piecewise linear field here is exact between the nodes, so the
references are analytic: band areas, the lines' positions, and OpenCASCADE's reading of the
band IGES (IGESCAFControl_Reader, BRepGProp) summing to the CAD area."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("OCP")

from cadbridge.mesh.mesh import CellBlock, Mesh  # noqa: E402
from cadbridge.cad.model import Face, Model  # noqa: E402
from cadbridge.nurbs.construct import cylinder_patch  # noqa: E402
from cadbridge.results import map_results  # noqa: E402
from tests.results.test_export import occ_faces  # noqa: E402
from tests.results.test_mapping import cylinder_case, plane_case, sphere_case  # noqa: E402


def _ring_mesh(R: float, z: np.ndarray, nt: int, offset: float, angle: float = 2 * np.pi, flip: bool = False) -> Mesh:
    """Triangles on node rings of a cylinder about +z: nt nodes per ring at angles offset +
    k angle / nt (a closed ring for a full turn, nt + 1 nodes on an open strip otherwise),
    rings at heights z (n,); each quad split along one diagonal (the other with ``flip``)."""
    closed = np.isclose(angle, 2 * np.pi)
    n_th = nt if closed else nt + 1
    th = offset + np.arange(n_th) * angle / nt
    T, Z = np.meshgrid(th, z, indexing="ij")
    nodes = np.column_stack([R * np.cos(T).ravel(), R * np.sin(T).ravel(), Z.ravel()])
    idx = np.arange(len(nodes)).reshape(n_th, len(z))
    nxt = np.roll(idx, -1, axis=0) if closed else idx[1:]
    idx = idx if closed else idx[:-1]
    q = np.column_stack([idx[:, :-1].ravel(), nxt[:, :-1].ravel(), nxt[:, 1:].ravel(), idx[:, 1:].ravel()])
    split = ([0, 1, 3], [1, 2, 3]) if flip else ([0, 1, 2], [0, 2, 3])
    return Mesh(nodes, [CellBlock("triangle", np.vstack([q[:, split[0]], q[:, split[1]]]))])


def _level_of_points(lines) -> np.ndarray:
    return lines.levels[np.repeat(lines.level, np.diff(lines.offsets))]


def _occ_bands(contours, tmp_path) -> tuple[list[float], list[dict]]:
    """The bands written as IGES and read back by OCC: OCC's face areas and our CSV rows;
    OCC reads one face per row and measures each row's area (rel 1e-6)."""
    from cadbridge.results.export import write_bands_iges

    path = tmp_path / "bands.igs"
    rows = write_bands_iges(path, contours)
    got = [a for a, _, _ in occ_faces(path)]
    assert len(got) == len(rows)
    for a, row in zip(got, rows):
        assert np.isclose(a, row["area"], rtol=1e-6), row
    return got, rows


# ----------------------------------------------------------------------------- the cylinder
@pytest.fixture(scope="module")
def occ_cylinder(tmp_path_factory):
    """The lateral face of OCC's cylinder R 20, z 10 .. 60 (one face, one seam) as NURBS IGES,
    read back, and OCC's area of that face."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeCylinder
    from OCP.GeomAbs import GeomAbs_Cylinder
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from cadbridge.iges import read_iges
    from cadbridge.ushape.geometry import export_iges

    shape = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(0, 0, 10), gp_Dir(0, 0, 1)), 20.0, 50.0).Shape()
    exp = TopExp_Explorer(shape, TopAbs_FACE)
    while BRepAdaptor_Surface(TopoDS.Face_s(exp.Current())).GetType() != GeomAbs_Cylinder:
        exp.Next()
    path = tmp_path_factory.mktemp("cyl") / "cylinder.igs"
    export_iges({"CYL": TopoDS.Face_s(exp.Current())}, path, "nurbs")
    (cad_area, _, _), = occ_faces(path)
    return read_iges(path), cad_area


@pytest.mark.parametrize("offset", [0.3, 0.0])
def test_full_cylinder_level_on_a_node_ring(occ_cylinder, offset, tmp_path):
    """Issue 34: OCC's cylinder R 20 x 50, 48 x 11 node rings (elements across the seam for
    offset 0.3, nodes on it for 0), f = z, levels 0, 22, 35, 70 (35 is a node ring).
    References: analytic band areas 2 pi R dz (rel 1e-9); OCC's areas of the band IGES faces,
    one per band, summing to OCC's area of the CAD face and to 2 pi R H (rel 1e-6); the lines
    are the circles z = c (1e-12 x size), each one closed line through the seam."""
    model, cad_area = occ_cylinder
    R, z0, z1 = 20.0, 10.0, 60.0
    mesh = _ring_mesh(R, np.linspace(z0, z1, 11), 48, offset)
    assert 35.0 in mesh.nodes[:, 2]
    m = map_results(mesh, mesh.nodes[:, 2], model, field_name="z")
    levels = [0.0, 22.0, 35.0, 70.0]
    c = m.contour(levels)
    exact = 2 * np.pi * R * np.diff(np.clip([-np.inf, *levels, np.inf], z0, z1))
    assert np.allclose(c.bands.area, exact, rtol=1e-9, atol=0)
    got, rows = _occ_bands(c, tmp_path)
    assert sorted(r["band"] for r in rows) == [1, 2, 3]  # one face per band: no slivers, no splits
    assert np.isclose(sum(got), cad_area, rtol=1e-6) and np.isclose(sum(got), 2 * np.pi * R * (z1 - z0), rtol=1e-6)
    L = c.lines
    assert sorted(L.level.tolist()) == [1, 2] and L.closed.all()
    assert np.max(np.abs(L.points[:, 2] - _level_of_points(L))) <= 1e-12 * model.size()
    assert np.allclose(L.lengths(), 2 * np.pi * R, rtol=1e-4)


def test_full_cylinder_level_through_the_seam_cuts(occ_cylinder, tmp_path):
    """OCC's cylinder R 20 x 50, 36 nodes per ring half a step off the seam, so every diagonal
    across the seam is cut at its midpoint, where f = z takes the level 32.5 between the rings
    30 and 35. Both triangles along such a diagonal must see the one value of the cut.
    References: analytic band areas 2 pi R dz (rel 1e-9); the line z = 32.5 is one closed
    circle through the seam (z = c within 1e-12 x size, length 2 pi R); OCC's band faces, one
    per band, sum to 2 pi R H (rel 1e-6)."""
    model, cad_area = occ_cylinder
    R, z0, z1 = 20.0, 10.0, 60.0
    mesh = _ring_mesh(R, np.linspace(z0, z1, 11), 36, np.pi / 36, flip=True)
    m = map_results(mesh, mesh.nodes[:, 2], model, field_name="z")
    levels = [0.0, 22.0, 32.5, 70.0]
    c = m.contour(levels)
    exact = 2 * np.pi * R * np.diff(np.clip([-np.inf, *levels, np.inf], z0, z1))
    assert np.allclose(c.bands.area, exact, rtol=1e-9, atol=0)
    L = c.lines
    assert sorted(L.level.tolist()) == [1, 2] and L.closed.all()
    assert np.max(np.abs(L.points[:, 2] - _level_of_points(L))) <= 1e-12 * model.size()
    assert np.allclose(L.lengths(), 2 * np.pi * R, rtol=1e-4)
    got, rows = _occ_bands(c, tmp_path)
    assert sorted(r["band"] for r in rows) == [1, 2, 3]
    assert np.isclose(sum(got), 2 * np.pi * R * (z1 - z0), rtol=1e-6)


def test_cylinder_level_through_element_centres_on_the_seam(tmp_path):
    """NURBS cylinder R 2, H 3, quads half a step off the seam, so the seam runs through their
    centres (split vertices whose value is the mean of the corners), f = z, levels 0.25 and
    1.75 (mid-rows: through those centres) and 0.5 (a node row). The seam cut must keep a
    centre on the seam line as it is (no second point of another name beside it).
    References: analytic band areas 2 pi R dz (rel 1e-9), one region per band; the lines
    are closed circles z = c (1e-12 x size); OCC's band faces sum to 2 pi R H (rel 1e-6)."""
    R, H = 2.0, 3.0
    model, mesh = cylinder_case(R, H, nt=24, offset=np.pi / 24)
    m = map_results(mesh, mesh.nodes[:, 2], model)
    levels = [0.25, 0.5, 1.75]
    c = m.contour(levels)
    assert np.allclose(c.bands.area, 2 * np.pi * R * np.diff([0.0, *levels, H]), rtol=1e-9, atol=0)
    assert sorted(r.band for r in c.bands.regions()) == [0, 1, 2, 3]
    L = c.lines
    assert len(L) == 3 and L.closed.all()
    assert np.max(np.abs(L.points[:, 2] - _level_of_points(L))) <= 1e-12 * model.size()
    got, _ = _occ_bands(c, tmp_path)
    assert np.isclose(sum(got), 2 * np.pi * R * H, rtol=1e-6)


# ----------------------------------------------------------------------------- plane
@pytest.mark.parametrize("case", ["clamped", "zero region"])
def test_plane_plateaus_and_levels_on_node_columns(case, tmp_path):
    """Regular plane grid (x = 1 + k / 4 over 1 .. 5, 3 wide, quads and triangles), fields
    constant over whole elements: f = min(x, 4) (clamped at a level that is not the top one)
    or f = max(x - 3, 0) (zero over x <= 3, levels from 0). Reference: analytic -- a value
    equal to a level counts as above it, so the plateau min(x, 4) = 4 is the band 4 .. 4.5 and
    the zero region is the band 0 .. 1: areas 3 x length (rel 1e-9), straight lines x = c of
    length 3 only where two bands meet; OCC's band faces sum to the plate's 12 (rel 1e-6)."""
    model, mesh = plane_case(jitter=0.0)
    x = mesh.nodes[:, 0]
    if case == "clamped":
        f, levels = np.minimum(x, 4.0), [2.0, 3.0, 4.0, 4.5]
        exact, line_x = [3.0, 3.0, 3.0, 3.0, 0.0], [2.0, 3.0, 4.0]
    else:
        f, levels = np.maximum(x - 3.0, 0.0), [0.0, 1.0, 2.0]
        exact, line_x = [0.0, 9.0, 3.0, 0.0], [4.0]
    c = map_results(mesh, f, model).contour(levels)
    assert np.allclose(c.bands.area, exact, rtol=1e-9, atol=1e-12)
    L = c.lines
    assert len(L) == len(line_x) and not L.closed.any()
    xs = [L.line(i)["points"][:, 0] for i in range(len(L))]
    assert np.allclose(sorted(x[0] for x in xs), line_x, rtol=0, atol=1e-12)
    assert all(np.ptp(x) <= 1e-12 for x in xs)
    assert np.allclose(L.lengths(), 3.0, rtol=1e-12)
    got, rows = _occ_bands(c, tmp_path)
    assert len(rows) == int(np.count_nonzero(exact))
    assert np.isclose(sum(got), 12.0, rtol=1e-6)


# ----------------------------------------------------------------------------- cylinders
def test_half_cylinder_levels_on_node_rings(tmp_path):
    """Half cylinder R 2, H 3 (open in both directions), triangles on 13 x 7 node rings, f = z
    with levels on rings 1, 3 and 5 and at the top edge z = 3. Reference: analytic -- bands
    pi R dz (rel 1e-9), open lines z = c of length pi R, none at the top edge; OCC's band
    faces sum to pi R H (rel 1e-6)."""
    R, H = 2.0, 3.0
    model = Model(faces=[Face(cylinder_patch(R, H, np.pi), de=1, name="HALF")])
    mesh = _ring_mesh(R, np.linspace(0.0, H, 7), 12, 0.0, angle=np.pi)
    c = map_results(mesh, mesh.nodes[:, 2], model).contour([0.5, 1.5, 2.5, 3.0])
    assert np.allclose(c.bands.area, np.pi * R * np.array([0.5, 1.0, 1.0, 0.5, 0.0]), rtol=1e-9, atol=1e-12)
    L = c.lines
    assert sorted(L.level.tolist()) == [0, 1, 2] and not L.closed.any()
    assert np.max(np.abs(L.points[:, 2] - _level_of_points(L))) <= 1e-12 * model.size()
    assert np.allclose(L.lengths(), np.pi * R, rtol=1e-4)
    got, _ = _occ_bands(c, tmp_path)
    assert len(got) == 4 and np.isclose(sum(got), np.pi * R * H, rtol=1e-6)


@pytest.mark.parametrize("top", [False, True])
def test_cylinder_plateau_at_a_level(top, tmp_path):
    """Full NURBS cylinder R 2, H 3, nodes on the seam, f = min(z, 2): constant over the
    elements above z = 2. Reference: analytic -- with 2 an inner level the plateau is the
    band 2 .. 2.5 (2 pi R x 1) and the line z = 2 is its closed border; with 2 the top level
    the plateau joins the band below it (no line at 2). Band areas rel 1e-9; OCC's band faces
    sum to 2 pi R H (rel 1e-6)."""
    R, H = 2.0, 3.0
    model, mesh = cylinder_case(R, H, nt=16, offset=0.0, tri=True)
    m = map_results(mesh, np.minimum(mesh.nodes[:, 2], 2.0), model)
    if top:
        c = m.contour([0.5, 2.0])
        exact, line_levels = [0.5, 2.5, 0.0], [0.5]
    else:
        c = m.contour([0.5, 2.0, 2.5])
        exact, line_levels = [0.5, 1.5, 1.0, 0.0], [0.5, 2.0]
    assert np.allclose(c.bands.area, 2 * np.pi * R * np.array(exact), rtol=1e-9, atol=1e-12)
    L = c.lines
    assert sorted(c.levels[L.level].tolist()) == line_levels and L.closed.all()
    assert np.max(np.abs(L.points[:, 2] - _level_of_points(L))) <= 1e-12 * model.size()
    got, _ = _occ_bands(c, tmp_path)
    assert np.isclose(sum(got), 2 * np.pi * R * H, rtol=1e-6)


def test_cylinder_level_along_the_seam(tmp_path):
    """Full NURBS cylinder R 2, H 3, nodes on the seam, f = y (0 on the seam and on the node
    column opposite it), levels -2, 0, 2. Reference: analytic -- the halves y < 0 and y > 0
    are the two bands, pi R H each (rel 1e-9); the lines at 0 are the straight seam and
    opposite lines (x = +-R, y = 0, length H), none at the extremes; OCC's band faces sum to
    2 pi R H (rel 1e-6)."""
    R, H = 2.0, 3.0
    model, mesh = cylinder_case(R, H, nt=16, offset=0.0, tri=True)
    f = np.round(mesh.nodes[:, 1], 12)  # sin(pi) is 1.2e-16: the opposite column at 0 too
    c = map_results(mesh, f, model).contour([-R, 0.0, R])
    assert np.allclose(c.bands.area, [0.0, np.pi * R * H, np.pi * R * H, 0.0], rtol=1e-9, atol=1e-12)
    L = c.lines
    assert len(L) == 2 and (L.level == 1).all() and not L.closed.any()
    assert np.max(np.abs(L.points[:, 1])) <= 1e-12 * model.size()
    assert sorted(np.round(L.points[L.offsets[:-1], 0], 9).tolist()) == [-R, R]
    assert np.allclose(L.lengths(), H, rtol=1e-12)
    got, _ = _occ_bands(c, tmp_path)
    assert np.isclose(sum(got), 2 * np.pi * R * H, rtol=1e-6)


# ----------------------------------------------------------------------------- sphere
def test_sphere_level_through_both_poles(tmp_path):
    """Sphere R 1.5, poles in the mesh, meridians every 15 degrees from 0, f = x (0 at both
    poles and on the meridians at 90 and 270 degrees), levels -R, 0, R. Reference: analytic --
    the hemispheres x < 0 and x > 0 are the bands, 2 pi R^2 each (rel 1e-9); the line at 0 is
    one closed great circle through both poles (x = 0, length 2 pi R within the chord
    tolerance); OCC's band faces sum to 4 pi R^2 (rel 1e-6)."""
    R = 1.5
    model, mesh, _ = sphere_case(R, offset=0.0)
    f = np.round(mesh.nodes[:, 0], 12)
    assert np.count_nonzero(f == 0.0) == 2 * 11 + 2  # two meridians and the poles
    m = map_results(mesh, f, model)
    c = m.contour([-R, 0.0, R])
    for a in (c.lines.points, c.lines.u, c.lines.v, c.bands.area):
        assert np.all(np.isfinite(a))
    assert np.allclose(c.bands.area, [0.0, 2 * np.pi * R**2, 2 * np.pi * R**2, 0.0], rtol=1e-9, atol=1e-12)
    L = c.lines
    assert len(L) == 1 and L.closed.all() and L.level[0] == 1
    assert np.max(np.abs(L.points[:, 0])) <= 1e-12 * model.size()
    assert np.max(np.abs(L.points[:, 2])) >= R * (1 - 1e-12)  # through the poles
    assert np.isclose(L.lengths()[0], 2 * np.pi * R, rtol=1e-4)
    got, _ = _occ_bands(c, tmp_path)
    assert np.isclose(sum(got), 4 * np.pi * R**2, rtol=1e-6)


def test_sphere_plateau_over_pole_quads(tmp_path):
    """Sphere R 1.5 whose pole elements are quads (pole + three ring nodes: in (u, v) a
    pentagon split at its centre), f = min(z, 0.8001): constant over the cap above the row
    z = 1.0607, poles included (0.8001 is a value whose rounded mean of five copies is 1 ulp
    off: the centre values must still be exactly 0.8001). Reference: analytic -- the zone
    formula 2 pi R dz: the plateau is the band 0.8001 .. 1.2 (the cap above the row), the
    band below reaches from the equator to that row (rel 1e-9); the lines are the parallels at
    the equator and at the row; OCC's band faces sum to 4 pi R^2 (rel 1e-6)."""
    R, c = 1.5, 0.8001
    model, mesh, lat = sphere_case(R)
    tri, quad = mesh.cells[0].data, mesh.cells[1].data
    nlon = len(tri) // 2
    south, north = tri[0, 0], tri[-1, 2]
    ring0, ring1 = tri[:nlon, 2], tri[nlon:, 0]  # the first and last rows, in fan order
    j = np.arange(0, nlon, 2)
    j1, j2 = (j + 1) % nlon, (j + 2) % nlon
    pole_quads = np.vstack([np.column_stack([np.full(len(j), south), ring0[j2], ring0[j1], ring0[j]]),
                            np.column_stack([ring1[j], ring1[j1], ring1[j2], np.full(len(j), north)])])
    qmesh = Mesh(mesh.nodes, [CellBlock("quad", np.vstack([quad, pole_quads]))])
    m = map_results(qmesh, np.minimum(qmesh.nodes[:, 2], c), model)
    assert m.pole.sum() == 2
    plateau = np.all(np.abs(m.tri_f - c) <= 1e-12, axis=1)
    at_pole = np.isin(m.tri_key, [north]).any(axis=1) & plateau
    assert at_pole.sum() >= 3 * len(j) and np.all(m.tri_f[plateau] == c)  # centre values exact
    row = R * np.sin(lat[8])
    cc = m.contour([0.0, c, 1.2])
    zone = 2 * np.pi * R * np.array([R, row, R - row, 0.0])
    assert np.allclose(cc.bands.area, zone, rtol=1e-9, atol=1e-12)
    L = cc.lines
    assert len(L) == 2 and L.closed.all()
    z_line = np.where(L.level == 0, 0.0, row)
    assert np.max(np.abs(L.points[:, 2] - np.repeat(z_line, np.diff(L.offsets)))) <= 1e-12 * model.size()
    got, _ = _occ_bands(cc, tmp_path)
    assert np.isclose(sum(got), 4 * np.pi * R**2, rtol=1e-6)


def test_level_on_a_curved_trim(tmp_path):
    """trimmed_hole.igs (100 x 60 plate, R 10 hole at (30, 25)), gmsh 4 mm triangles, f = the
    distance r from the hole's centre (exactly 10 at the nodes on the circle), levels 5, 10:
    the border chords on the circle lie on the top level, whose value counts as below it,
    while the triangles along them are above it. The slivers between those chords and the
    circle belong to their triangles' band. Reference: analytic -- everything is the band
    > 10, the plate minus the hole (rel 1e-12), the band 5 .. 10 is empty (not a negative
    sliver sum); no line (the level only touches the border); OCC reads one band face of the
    same area (rel 1e-9)."""
    from pathlib import Path

    from cadbridge.iges import read_iges
    from cadbridge.mesh.generate import mesh_cad

    path = Path(__file__).resolve().parents[2] / "iges_samples" / "trimmed_hole.igs"
    model = read_iges(path)
    mesh = mesh_cad(path, element="tri", size=4.0)
    r = np.hypot(mesh.nodes[:, 0] - 30.0, mesh.nodes[:, 1] - 25.0)
    on = np.abs(r - 10.0) <= 1e-9
    m = map_results(mesh, np.where(on, 10.0, r), model)
    assert on.sum() >= 8 and len(m.arcs) == on.sum()
    c = m.contour([5.0, 10.0])
    total = 100 * 60 - np.pi * 10**2
    assert c.bands.area[0] == 0 and c.bands.area[1] == 0 and np.isclose(c.bands.area[2], total, rtol=1e-12)
    assert len(c.lines) == 0
    got, _ = _occ_bands(c, tmp_path)
    assert len(got) == 1 and np.isclose(got[0], total, rtol=1e-9)

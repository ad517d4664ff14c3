"""Results on the exact CAD (issue 9, Hawkins 1989): contour lines and bands of nodal fields
mapped onto NURBS faces. Every reference is analytic (plane, cylinder, sphere, the U-shape
die's radius and land) or OpenCASCADE (tests/results/test_export.py)."""

from __future__ import annotations

import numpy as np
import pytest

from cadbridge.mesh.mesh import CellBlock, Mesh
from cadbridge.cad.model import Face, Model
from cadbridge.nurbs.construct import cylinder_patch, plane_surface, sphere_patch
from cadbridge.results import make_levels, map_results


# ----------------------------------------------------------------------------- geometry
def plane_case(seed: int = 3, jitter: float = 0.07):
    """A tilted plane patch (point (1, 2, 3), normal (0, 0.6, 0.8), u along +x over 0..4,
    v over 0..3) meshed with quads on one half and triangles on the other, the inner nodes
    moved by up to ``jitter`` each way (0: a regular grid, x = 1 + k / 4)."""
    s = plane_surface((1.0, 2.0, 3.0), (0.0, 0.6, 0.8), (1.0, 0.0, 0.0), (0.0, 4.0), (0.0, 3.0))
    model = Model(faces=[Face(s, de=1, name="PLANE")])
    nu, nv = 17, 11
    u, v = np.meshgrid(np.linspace(0, 4, nu), np.linspace(0, 3, nv), indexing="ij")
    rng = np.random.default_rng(seed)
    inner = (u > 0) & (u < 4) & (v > 0) & (v < 3)
    u = u + inner * rng.uniform(-jitter, jitter, u.shape)
    v = v + inner * rng.uniform(-jitter, jitter, v.shape)
    w = np.cross((0.0, 0.6, 0.8), (1.0, 0.0, 0.0))
    nodes = np.array([1.0, 2.0, 3.0]) + u.reshape(-1, 1) * np.array([1.0, 0, 0]) + v.reshape(-1, 1) * w
    idx = np.arange(nu * nv).reshape(nu, nv)
    q = np.column_stack([idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()])
    half = (np.arange(nu - 1)[:, None] < (nu - 1) // 2).repeat(nv - 1, axis=1).ravel()
    tri = np.vstack([q[~half][:, [0, 1, 2]], q[~half][:, [0, 2, 3]]])
    return model, Mesh(nodes, [CellBlock("quad", q[half]), CellBlock("triangle", tri)])


def cylinder_case(R=2.0, H=3.0, nt=24, nz=6, offset=0.3, tri=False):
    """The closed NURBS cylinder (seam at angle 0) and a ring mesh whose nodes start at angle
    ``offset``, so elements straddle the seam."""
    model = Model(faces=[Face(cylinder_patch(R, H), de=1, name="CYL")])
    th = offset + np.arange(nt) * 2 * np.pi / nt
    T, Z = np.meshgrid(th, np.linspace(0, H, nz + 1), indexing="ij")
    nodes = np.column_stack([R * np.cos(T).ravel(), R * np.sin(T).ravel(), Z.ravel()])
    idx = np.arange(len(nodes)).reshape(nt, nz + 1)
    nxt = np.roll(idx, -1, axis=0)
    q = np.column_stack([idx[:, :-1].ravel(), nxt[:, :-1].ravel(), nxt[:, 1:].ravel(), idx[:, 1:].ravel()])
    cells = [CellBlock("triangle", np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))] if tri else [CellBlock("quad", q)]
    return model, Mesh(nodes, cells)


def sphere_case(R=1.5, nlat=12, offset=0.2):
    """The NURBS sphere (poles at u = 0 and u = pi, seam in v) and a latitude/longitude mesh
    with one node at each pole (triangle fans) and quads between."""
    model = Model(faces=[Face(sphere_patch(R), de=1, name="SPHERE")])
    nlon = 2 * nlat
    lat = np.linspace(-np.pi / 2, np.pi / 2, nlat + 1)[1:-1]
    lon = offset + np.arange(nlon) * 2 * np.pi / nlon
    La, Lo = np.meshgrid(lat, lon, indexing="ij")
    ring = np.column_stack([R * (np.cos(La) * np.cos(Lo)).ravel(), R * (np.cos(La) * np.sin(Lo)).ravel(),
                            R * np.sin(La).ravel()])
    nodes = np.vstack([ring, [[0, 0, -R], [0, 0, R]]])
    s, n = len(ring), len(ring) + 1
    idx = np.arange(len(ring)).reshape(nlat - 1, nlon)
    nxt = np.roll(idx, -1, axis=1)
    q = np.column_stack([idx[:-1].ravel(), nxt[:-1].ravel(), nxt[1:].ravel(), idx[1:].ravel()])
    fans = np.vstack([np.column_stack([np.full(nlon, s), nxt[0], idx[0]]),
                      np.column_stack([idx[-1], nxt[-1], np.full(nlon, n)])])
    return model, Mesh(nodes, [CellBlock("triangle", fans), CellBlock("quad", q)]), lat


def _level_of_points(lines):
    return lines.levels[np.repeat(lines.level, np.diff(lines.offsets))]


# ----------------------------------------------------------------------------- plane
def test_plane_lines_are_exact_iso_x_and_band_areas_analytic():
    """Plane, f = x. Reference: analytic. Contour points have x = c within 1e-12 x size;
    band areas are (b - a) x 3 (the patch is 3 long across x), rel 1e-9; each line runs
    straight across the patch and has both ends on its border."""
    model, mesh = plane_case()
    m = map_results(mesh, mesh.nodes[:, 0], model, field_name="x")
    levels = [1.3, 2.0, 2.55, 4.2]
    c = m.contour(levels)
    size = model.size()
    L = c.lines
    assert len(L) == 4  # one line per level
    assert np.max(np.abs(L.points[:, 0] - _level_of_points(L))) <= 1e-12 * size
    assert not L.closed.any()
    edges = np.array([1.3, 2.0, 2.55, 4.2])
    exact = np.concatenate([[edges[0] - 1.0], np.diff(edges), [5.0 - edges[-1]]]) * 3.0
    assert np.allclose(c.bands.area, exact, rtol=1e-9, atol=0)
    # the band regions are the rectangles [a, b] x [0, 3] in (u, v) = (x - 1, v)
    for r in c.bands.regions():
        lo, hi = c.bands.lower[r.band], c.bands.upper[r.band]
        assert r.holes == []
        assert np.isclose(r.outer[:, 0].min(), max(lo - 1.0, 0.0), atol=1e-12)
        assert np.isclose(r.outer[:, 0].max(), min(hi - 1.0, 4.0), atol=1e-12)


def test_plane_levels_through_nodes_and_equal_bands():
    """Levels equal to node values (x = 2 at a mesh line of the unjittered border) and the
    default equal bands: every band area is still analytic (reference: (b - a) x 3)."""
    model, mesh = plane_case(seed=5)
    m = map_results(mesh, mesh.nodes[:, 0], model)
    c = m.contour(8)
    assert np.allclose(c.levels, np.linspace(1.0, 5.0, 9))
    assert np.allclose(c.bands.area[1:9], 0.5 * 3.0, rtol=1e-9)
    assert c.bands.area[0] == 0 and c.bands.area[9] == 0
    assert np.max(np.abs(c.lines.points[:, 0] - _level_of_points(c.lines))) <= 1e-12 * model.size()
    # one straight line across the strip per interior level (levels through border nodes
    # give no zero-length pieces; none at the data's minimum and maximum)
    assert sorted(c.lines.level.tolist()) == list(range(1, 8))
    assert np.allclose(c.lines.lengths(), 3.0, rtol=1e-12)


# ----------------------------------------------------------------------------- cylinder
@pytest.mark.parametrize("tri", [False, True])
def test_cylinder_seam_lines_closed_and_areas(tri):
    """Closed cylinder R 2, H 3, f = z along the axis, elements straddling the seam.
    Reference: analytic. Contour points have z = c (1e-12 x size); each line is one closed
    loop around the axis (through the seam) of length 2 pi R (polyline, within the chord
    tolerance); band areas are 2 pi R dz and sum to the lateral area 2 pi R H (rel 1e-9)."""
    R, H = 2.0, 3.0
    model, mesh = cylinder_case(R, H, tri=tri)
    m = map_results(mesh, mesh.nodes[:, 2], model, field_name="z")
    levels = [0.7, 1.5, 2.2]
    c = m.contour(levels)
    size = model.size()
    L = c.lines
    assert len(L) == 3 and L.closed.all()
    assert np.max(np.abs(L.points[:, 2] - _level_of_points(L))) <= 1e-12 * size
    assert np.allclose(np.hypot(L.points[:, 0], L.points[:, 1]), R, rtol=1e-12)
    assert np.allclose(L.lengths(), 2 * np.pi * R, rtol=1e-4)
    assert len(L.joints) >= 3 and L.joint_gap.max() <= 1e-12 * size  # the seam crossings
    exact = 2 * np.pi * R * np.diff(np.concatenate([[0.0], levels, [H]]))
    assert np.allclose(c.bands.area, exact, rtol=1e-9)
    assert np.isclose(c.bands.area.sum(), 2 * np.pi * R * H, rtol=1e-9)
    # one region per band, covering the whole angular domain (the seam is no border)
    regs = c.bands.regions()
    assert sorted(r.band for r in regs) == [0, 1, 2, 3]
    for r in regs:
        assert np.isclose(r.outer[:, 1].min(), 0.0) and np.isclose(r.outer[:, 1].max(), 2 * np.pi)
    assert m.seam.sum() == 0  # no node sits on the seam here; elements straddle it


def test_cylinder_band_regions_area_by_greens_theorem():
    """Band regions of a field that is not constant along the seam (f = z + 0.3 x): the top
    band is cut by the seam into two regions in (u, v). Reference: Green's theorem on each
    region's (u, v) loops, area = -R * loop integral of theta(v) du (the cylinder's area
    element is R theta'(v) du dv, theta the exact angle of the rational parametrisation),
    20-point Gauss per loop edge: rel 1e-9."""
    from cadbridge.nurbs.construct import revolved_v_to_angle

    R = 2.0
    model, mesh = cylinder_case(R, 3.0, tri=True)
    m = map_results(mesh, mesh.nodes[:, 2] + 0.3 * mesh.nodes[:, 0], model)
    c = m.contour(7)
    x, w = np.polynomial.legendre.leggauss(20)
    t = 0.5 * (x + 1)

    def green(loop):
        p, q = loop, np.roll(loop, -1, axis=0)
        v = p[:, 1:2] + t[None, :] * (q[:, 1:2] - p[:, 1:2])
        th = revolved_v_to_angle(v.ravel(), 0.0, 2 * np.pi).reshape(v.shape)
        return float(-R * np.sum((th @ (0.5 * w)) * (q[:, 0] - p[:, 0])))

    regs = c.bands.regions()
    assert len(regs) > len({r.band for r in regs})  # some band has two regions
    for r in regs:
        ref = green(r.outer) + sum(green(h) for h in r.holes)
        assert np.isclose(r.area, ref, rtol=1e-9)


def test_cylinder_nodes_on_the_seam_keep_both_parameters():
    """Mesh nodes exactly on the seam (offset 0): they are seam nodes, the elements on either
    side see them at angle 0 and 2 pi, and the results are those of the analytic cylinder."""
    R, H = 1.0, 2.0
    model, mesh = cylinder_case(R, H, nt=16, nz=4, offset=0.0)
    m = map_results(mesh, mesh.nodes[:, 2] ** 2, model)
    seam_nodes = np.flatnonzero(m.seam)
    assert len(seam_nodes) == 5
    quads = mesh.cells[0].data
    angles = m.corner_uv[0][..., 1][np.isin(quads, seam_nodes)]
    assert np.isclose(angles.min(), 0.0) and np.isclose(angles.max(), 2 * np.pi)
    levels = [0.25, 1.0, 2.25]  # z = 0.5, 1, 1.5: node rows, so the lines are exact circles
    c = m.contour(levels)
    assert c.lines.closed.all() and len(c.lines) == 3
    assert np.max(np.abs(c.lines.points[:, 2] ** 2 - _level_of_points(c.lines))) <= 1e-12
    assert np.isclose(c.bands.area.sum(), 2 * np.pi * R * H, rtol=1e-9)
    assert np.allclose(c.bands.area[:4], 2 * np.pi * R * 0.5, rtol=1e-9)


# ----------------------------------------------------------------------------- sphere
def test_sphere_poles_zone_areas():
    """Sphere R 1.5 with both poles in the mesh, f = z. Reference: the spherical zone formula
    A = 2 pi R dz. No NaN anywhere; the bands cover the sphere (4 pi R^2, rel 1e-9); with
    levels at the mesh's latitude rows the lines are exact parallels, so every zone is exact
    (rel 1e-9)."""
    R = 1.5
    model, mesh, lat = sphere_case(R)
    m = map_results(mesh, mesh.nodes[:, 2], model, field_name="z")
    assert m.pole.sum() == 2
    levels = R * np.sin(lat[[1, 4, 8]])
    c = m.contour(levels)
    for a in (m.tri_uv, m.tri_area, c.lines.points, c.lines.u, c.lines.v, c.bands.area):
        assert np.all(np.isfinite(a))
    exact = 2 * np.pi * R * np.diff(np.concatenate([[-R], levels, [R]]))
    assert np.allclose(c.bands.area, exact, rtol=1e-9)
    assert np.isclose(c.bands.area.sum(), 4 * np.pi * R**2, rtol=1e-9)
    assert c.lines.closed.all() and len(c.lines) == 3
    assert np.max(np.abs(c.lines.points[:, 2] - _level_of_points(c.lines))) <= 1e-12 * model.size()
    # the caps reach the poles: the band loops run along the pole lines u = 0 and u = pi
    regs = {r.band: r for r in c.bands.regions()}
    assert np.isclose(regs[0].outer[:, 0].min(), 0.0) and np.isclose(regs[3].outer[:, 0].max(), np.pi)


def test_sphere_levels_between_nodes_converge():
    """Levels between the latitude rows: the field, linear between nodes, puts the contour
    lines O(h^2) off the exact parallels. Reference: z = c and the zone formula. The largest
    |z - c| of the line points drops by more than 4x per halving of h (second order), and
    every zone area is within 2 pi R (d_lower + d_upper) of the formula (d: its boundary
    lines' largest |z - c|; the zone formula bounds the strip between a line and its
    parallel)."""
    R = 1.5
    levels = np.array([-1.0, 0.0, 0.5, 1.2])
    exact = 2 * np.pi * R * np.diff(np.concatenate([[-R], levels, [R]]))
    dev = []
    for nlat in (10, 20, 40):
        model, mesh, _ = sphere_case(R, nlat=nlat)
        c = map_results(mesh, mesh.nodes[:, 2], model).contour(levels)
        assert np.isclose(c.bands.area.sum(), 4 * np.pi * R**2, rtol=1e-9)
        L = c.lines
        d = np.zeros(len(levels))
        np.maximum.at(d, np.repeat(L.level, np.diff(L.offsets)), np.abs(L.points[:, 2] - _level_of_points(L)))
        bound = 2 * np.pi * R * (np.concatenate([[0.0], d]) + np.concatenate([d, [0.0]]))
        assert np.all(np.abs(c.bands.area - exact) <= bound * (1 + 1e-9) + 1e-12)
        dev.append(d.max())
    assert dev[0] / dev[1] > 4 and dev[1] / dev[2] > 4


# ----------------------------------------------------------------------------- levels
def test_levels_and_range():
    """--levels n gives n equal bands over the data range or --min/--max; explicit levels
    must increase; a range beyond the data makes the open bands hold the rest."""
    v = np.array([0.0, 3.0, 10.0])
    assert np.allclose(make_levels(v, 5), [0, 2, 4, 6, 8, 10])
    assert np.allclose(make_levels(v, 2, 2.0, 6.0), [2, 4, 6])
    assert np.allclose(make_levels(v, [0, 5, 10, 20], None, 12.0), [0, 5, 10])
    with pytest.raises(ValueError):
        make_levels(v, [0, 5, 5])
    with pytest.raises(ValueError):
        make_levels(v, 0)
    model, mesh = plane_case()
    c = map_results(mesh, mesh.nodes[:, 0], model).contour(2, vmin=2.0, vmax=4.0)
    # reference: analytic, x from 1 to 5 on a strip 3 wide
    assert np.allclose(c.bands.area, [3.0, 3.0, 3.0, 3.0], rtol=1e-9)
    assert c.bands.label(0) == "< 2" and c.bands.label(3) == "> 4"


def test_relevelling_reuses_the_mapping(monkeypatch):
    """Contouring again does not invert a single node: the projection is not called (the
    timing ratio is measured in benchmarks/bench_results.py)."""
    model, mesh = cylinder_case()
    m = map_results(mesh, mesh.nodes[:, 2], model)
    import cadbridge.normals.cad as cad
    import cadbridge.cad.search as search

    def boom(*a, **k):
        raise AssertionError("projection repeated")

    monkeypatch.setattr(search, "project_points", boom)
    monkeypatch.setattr(cad, "project_points", boom)
    a = m.contour(4).bands.area
    b = m.contour([0.5, 1.0, 2.9]).bands.area
    assert np.isclose(a.sum(), b.sum(), rtol=1e-12)


# ----------------------------------------------------------------------------- fields
def test_cell_values_become_area_weighted_nodal_values(tmp_path):
    """Cell data f_e = x of the element centroid on the plane: the area-weighted nodal average
    of a linear function over a symmetric patch of elements; reference: hand computation on
    a 2 x 1 strip of unit squares, and the source says so."""
    import meshio

    from cadbridge.results.fields import read_results

    nodes = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0], [0, 1, 0], [1, 1, 0], [3, 1, 0]], float)
    quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4]])
    p = tmp_path / "cells.vtu"
    meshio.write(p, meshio.Mesh(nodes, [("quad", quads)], cell_data={"p": [np.array([1.0, 4.0])]}))
    mesh, f = read_results(p, "p")
    # node 1 touches both: (1 x 1 + 2 x 4) / 3 = 3
    assert np.allclose(f.values, [1, 3, 4, 1, 3, 4])
    assert "area-weighted" in f.source
    with pytest.raises(ValueError, match="not found"):
        read_results(p, "q")


def test_torus_two_seams():
    """Torus R 3, r 1 (closed in both directions, the corner element crosses both seams),
    f = z. Reference: analytic. The bands cover 4 pi^2 R r (rel 1e-9), every line is closed;
    with levels at node rows phi_a < phi_b (both in (-pi/2, pi/2)) the band between is the two
    strips phi in [phi_a, phi_b] and [pi - phi_b, pi - phi_a]: 4 pi r R (phi_b - phi_a)."""
    from cadbridge.nurbs.construct import torus_patch

    R, r = 3.0, 1.0
    model = Model(faces=[Face(torus_patch(R, r), de=1, name="TORUS")])
    nt, ns = 16, 32
    ph = np.pi / 2 + np.pi / nt + np.arange(nt) * 2 * np.pi / nt  # rows symmetric about phi = pi / 2
    th = 0.2 + np.arange(ns) * 2 * np.pi / ns
    P, T = np.meshgrid(ph, th, indexing="ij")
    rho = R + r * np.cos(P)
    nodes = np.column_stack([(rho * np.cos(T)).ravel(), (rho * np.sin(T)).ravel(), (r * np.sin(P)).ravel()])
    idx = np.arange(nt * ns).reshape(nt, ns)
    q = np.column_stack([idx.ravel(), np.roll(idx, -1, 0).ravel(), np.roll(np.roll(idx, -1, 0), -1, 1).ravel(),
                         np.roll(idx, -1, 1).ravel()])
    m = map_results(Mesh(nodes, [CellBlock("quad", q)]), nodes[:, 2], model)
    assert m.topology[0].closed == (True, True)
    phi_a, phi_b = ph[10] - 2 * np.pi, ph[12] - 2 * np.pi  # pi - phi are rows too
    c = m.contour(r * np.sin([phi_a, phi_b]))
    assert np.isclose(c.bands.area.sum(), 4 * np.pi**2 * R * r, rtol=1e-9)
    assert np.isclose(c.bands.area[1], 4 * np.pi * r * R * (phi_b - phi_a), rtol=1e-9)
    assert c.lines.closed.all() and len(c.lines) == 4

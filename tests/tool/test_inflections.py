"""Inflection lines, Nagata edge admissibility and nodes moved onto inflections (issue 12).

References: an extruded cubic whose inflection is known in closed form (z = t^3 - 1.2 t^2,
inflection at t = 0.4); circular arcs (the Nagata edge with exact normals has the circle's
end tangents, so its bend is the arc angle); the thesis' S-shaped NURBS surface of appendix
A (the IGES file of its Fig. 57 study, `iges_samples/thesis_appendix_a.igs`) meshed
uniformly with 3 x 5 quadrilaterals, measured against the exact surface.
"""

from pathlib import Path

import numpy as np
import pytest

from cadbridge.mesh.mesh import CellBlock, Mesh
from cadbridge.nagata import NagataMesh
from cadbridge.nagata.admissibility import edge_admissibility
from cadbridge.nurbs.construct import cylinder_patch
from cadbridge.nurbs.curvature import normal_curvature
from cadbridge.nurbs.inflections import control_polygon_inflections, inflection_lines, segment_inflections
from cadbridge.nurbs.surface import NurbsSurface

SAMPLES = Path(__file__).parents[2] / "iges_samples"


def cubic_strip() -> NurbsSurface:
    """x = 10 t, z = 10 (t^3 - 1.2 t^2) (Bernstein coefficients 0, 0, -0.4, -0.2), extruded
    4 along y: the curve's inflection is at t = 0.4 (z'' = 6 t - 2.4 = 0) exactly."""
    cx = np.array([0, 1 / 3, 2 / 3, 1.0]) * 10
    cz = np.array([0, 0, -0.4, -0.2]) * 10
    cp = np.zeros((4, 2, 3))
    cp[:, :, 0] = cx[:, None]
    cp[:, :, 2] = cz[:, None]
    cp[:, 1, 1] = 4.0
    return NurbsSurface(3, 1, [0, 0, 0, 0, 1, 1, 1, 1], [0, 0, 1, 1], cp)


def test_inflection_line_of_cubic_strip():
    s = cubic_strip()
    lines = inflection_lines(s, "u")
    assert len(lines) == 1 and lines[0].iso
    assert lines[0].value == pytest.approx(0.4, abs=1e-10)
    assert inflection_lines(s, "v") == []  # straight along y
    # along oblique (u, v) segments the normal curvature of the extrusion is that of the curve
    # times cos^2 of the angle: it changes sign at u = 0.4 too
    t = segment_inflections(s, [[0.1, 0.0], [0.9, 1.0]], [[0.7, 1.0], [0.2, 0.0]])
    assert 0.1 + t[0] * 0.6 == pytest.approx(0.4, abs=1e-10)
    assert 0.9 - t[1] * 0.7 == pytest.approx(0.4, abs=1e-10)
    assert np.isnan(segment_inflections(s, [[0.5, 0.0]], [[0.9, 1.0]])[0])


def test_control_polygon_estimate_is_near_but_not_exact():
    """Thesis Fig. 59: the polygon leg across the turning sign change crosses the curve near
    the inflection; the curvature bisection is exact, the polygon estimate is not (which is
    why the mesher uses the curvature)."""
    s = cubic_strip()
    est = control_polygon_inflections(s, "u", 0.5)
    assert len(est) == 1
    assert abs(est[0] - 0.4) < 0.1
    assert abs(est[0] - 0.4) > 1e-3
    from cadbridge.iges import read_iges

    a = read_iges(SAMPLES / "thesis_appendix_a.igs").faces[0].surface
    exact = inflection_lines(a, "u")[0].value
    est = control_polygon_inflections(a, "u", 0.5)
    assert len(est) == 1 and abs(est[0] - exact) < 0.03


def test_cylinder_has_no_inflection():
    """The straight direction has k_n of round-off size only: no inflection there."""
    s = cylinder_patch(5.0, 10.0, np.pi / 2)
    assert inflection_lines(s, "u") == [] and inflection_lines(s, "v") == []


def _arc_mesh(angle_deg: float) -> NagataMesh:
    """One quad over a cylinder R 5, its curved edges spanning ``angle_deg``, exact normals."""
    a = np.radians(angle_deg)
    R = 5.0
    ang = np.array([0.0, a, a, 0.0])
    y = np.array([0.0, 0.0, 3.0, 3.0])
    x = np.column_stack([R * np.cos(ang), y, R * np.sin(ang)])
    n = np.column_stack([np.cos(ang), np.zeros(4), np.sin(ang)])
    return NagataMesh(x, np.array([[0, 1, 2, 3]]), n)


@pytest.mark.parametrize("angle", [30.0, 90.0])
def test_circle_edges_admissible_with_arc_bend(angle):
    adm = edge_admissibility(_arc_mesh(angle))
    assert adm.admissible.all() and adm.element_ok.all()
    curved = np.abs(adm.bend_deg) > 1e-9
    assert curved.sum() == 2 and np.allclose(adm.bend_deg[curved], angle, atol=1e-9)


def test_sharp_bend_and_inflected_edges_are_inadmissible():
    adm = edge_admissibility(_arc_mesh(150.0))
    assert not adm.element_ok.all() and np.any(adm.bend_mask)
    # an edge across the inflection of z = x^3 from x = -1 to 1.5: the chord (2.5, 4.375),
    # slope 1.75, lies below the tangents at both ends (slopes 3 and 6.75)
    x = np.array([[-1.0, 0, -1], [1.5, 0, 3.375], [1.5, 1, 3.375], [-1.0, 1, -1]])
    n = np.array([[-3.0, 0, 1], [-6.75, 0, 1], [-6.75, 0, 1], [-3.0, 0, 1]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    adm = edge_admissibility(NagataMesh(x, np.array([[0, 1, 2, 3]]), n))
    assert adm.inflected.sum() == 2 and not adm.element_ok[0]
    assert all(r.startswith("inflected") for r in adm.reasons()[adm.inflected])


def _appendix_a_grid(nu: int, nv: int):
    from cadbridge.iges import read_iges

    m = read_iges(SAMPLES / "thesis_appendix_a.igs")
    s = m.faces[0].surface
    U, V = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    x = s.evaluate(U.ravel(), V.ravel())
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    n00 = (i * (nv + 1) + j).ravel()
    q = np.column_stack([n00, n00 + nv + 1, n00 + nv + 2, n00 + 1])
    return m, Mesh(x, [CellBlock("quad", q)], name="s")


def _errors(mesh, model):
    from cadbridge.normals.cad import cad_normals
    from cadbridge.tool.build import CadProjector, build_tool

    cn = cad_normals(mesh, model)
    t = build_tool("s", mesh, cn.normals, cn.corner_normals, "cad", model=model, grid=16,
                   projector=CadProjector(model), element_face=cn.element_face)
    e = np.zeros(mesh.n_elements)
    np.maximum.at(e, t.grid["element"], np.abs(t.grid["surface_error"]))
    return cn, t, e


def test_thesis_s_surface_3x5_straddled_patches_and_moved_nodes():
    """Thesis Fig. 57/58: the S surface meshed uniformly, 3 elements across the S (u) and 5
    along its straight direction: the 5 centre patches straddle the inflection (u = 0.5715)
    and carry by far the largest shape error. Moving their nodes onto the inflection line
    leaves no edge across it and lowers the max error."""
    from cadbridge.tool.inflection_nodes import inflection_edges, move_nodes_to_inflections

    model, mesh = _appendix_a_grid(3, 5)
    cn, tool, e = _errors(mesh, model)
    edges, face, t = inflection_edges(mesh, model, cn)
    u_star = inflection_lines(model.faces[0].surface, "u")[0].value
    # the 6 u-edges of the centre column (u 1/3 -> 2/3), inflection at (u* - 1/3) / (1/3)
    assert len(edges) == 6 and np.allclose(t, (u_star - 1 / 3) * 3, atol=1e-9)
    centre = np.arange(5, 10)  # elements of the centre column
    assert e[centre].min() > 5 * np.delete(e, centre).max()
    from cadbridge.tool.inflection_nodes import inadmissible_elements

    bad = inadmissible_elements(mesh, model, cn, tool.nagata)
    assert sorted(bad) == centre.tolist() and all("straddles an inflection" in r for r in bad.values())
    moved_mesh, moves = move_nodes_to_inflections(mesh, model, cn)
    assert len(moves) == 6
    for mv in moves:  # on the inflection line: k_n along u vanishes there
        k = normal_curvature(model.faces[0].surface, [mv.uv_new[0]], [mv.uv_new[1]], [1.0], [0.0])
        assert abs(k[0]) < 1e-9
    cn2, tool2, e2 = _errors(moved_mesh, model)
    assert len(inflection_edges(moved_mesh, model, cn2)[0]) == 0
    assert e2.max() < 0.5 * e.max()
    assert edge_admissibility(tool2.nagata).element_ok.all()
    assert inadmissible_elements(moved_mesh, model, cn2, tool2.nagata) == {}


def test_adaptive_s_surface_meets_tolerance_with_no_inadmissible_patch():
    """With inflection handling the adaptive mesh of the S surface holds t = 0.01 (measured
    on the denser check grid), the inflection line is a mesh edge and no patch is
    inadmissible or straddles the inflection."""
    from cadbridge.tool.inflection_nodes import inflection_edges
    from cadbridge.normals.cad import cad_normals
    from cadbridge.tool.refine import refine_mesh

    r = refine_mesh(SAMPLES / "thesis_appendix_a.igs", 0.01)
    assert r.met and r.check["max_error"] <= 0.01
    assert any("inflection line u = 0.5715" in a for a in r.actions)
    for t in r.tools:
        assert edge_admissibility(t.nagata).element_ok.all()
    from cadbridge.iges import read_iges

    model = read_iges(SAMPLES / "thesis_appendix_a.igs")
    cn = cad_normals(r.mesh, model)
    assert len(inflection_edges(r.mesh, model, cn)[0]) == 0

"""Meshing IGES CAD with gmsh (cadbridge.mesh.generate.mesh_cad).

CAD is built with OCP inside the tests and exported to IGES (faces mode, like die CAD).
References: the analytic geometry (cylinder radius, planes), gmsh's own evaluation of the
CAD surfaces at the reported (u, v), topology invariants (closed shell -> no boundary
edges, Euler characteristic 2), and the requested division counts.
"""

import numpy as np
import pytest

pytest.importorskip("gmsh")
OCP = pytest.importorskip("OCP")

from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeWire  # noqa: E402
from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCylinder, BRepPrimAPI_MakePrism  # noqa: E402
from OCP.GC import GC_MakeArcOfCircle, GC_MakeSegment  # noqa: E402
from OCP.gp import gp_Ax3, gp_Cylinder, gp_Dir, gp_Pnt, gp_Vec  # noqa: E402
from OCP.IGESControl import IGESControl_Writer  # noqa: E402

from cadbridge.mesh import MeshError, mesh_cad  # noqa: E402
from cadbridge.mesh import topology as T  # noqa: E402

R, L = 5.0, 40.0


def write_iges(shape, path):
    w = IGESControl_Writer("MM", 0)  # faces mode (trimmed surfaces), as typical die CAD
    w.AddShape(shape)
    w.ComputeModel()
    assert w.Write(str(path))
    return path


@pytest.fixture(scope="module")
def cad(tmp_path_factory):
    d = tmp_path_factory.mktemp("cad")
    # quarter-cylinder shell, axis z, radius R, 0 <= theta <= pi/2, 0 <= z <= L
    qc = BRepBuilderAPI_MakeFace(gp_Cylinder(gp_Ax3(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1)), R), 0, np.pi / 2, 0, L).Face()
    # U-die-like sheet: flange z=0 (x in [-30, 0]), fillet radius R centred (0, y, R),
    # flange x=R (z in [R, R+20]); extruded along y by L
    p = [gp_Pnt(-30, 0, 0), gp_Pnt(0, 0, 0), gp_Pnt(R * np.sin(np.pi / 4), 0, R - R * np.cos(np.pi / 4)),
         gp_Pnt(R, 0, R), gp_Pnt(R, 0, R + 20)]
    wire = BRepBuilderAPI_MakeWire(
        BRepBuilderAPI_MakeEdge(GC_MakeSegment(p[0], p[1]).Value()).Edge(),
        BRepBuilderAPI_MakeEdge(GC_MakeArcOfCircle(p[1], p[2], p[3]).Value()).Edge(),
        BRepBuilderAPI_MakeEdge(GC_MakeSegment(p[3], p[4]).Value()).Edge(),
    ).Wire()
    bracket = BRepPrimAPI_MakePrism(wire, gp_Vec(0, L, 0)).Shape()
    return {
        "qc": write_iges(qc, d / "quarter_cylinder.igs"),
        "bracket": write_iges(bracket, d / "bracket.igs"),
        "box": write_iges(BRepPrimAPI_MakeBox(10, 20, 30).Shape(), d / "box.igs"),
        "cyl": write_iges(BRepPrimAPI_MakeCylinder(R, 10).Shape(), d / "cylinder.igs"),
    }


def test_structured_quarter_cylinder_divisions_and_nodes_on_cad(cad):
    m = mesh_cad(cad["qc"], element="quad", structured=True, radius_divisions=3, length_divisions=1)
    # exactly 3 elements across the radius and 1 along the length: 3 quads, 4 x 2 nodes
    assert [b.type for b in m.cells] == ["quad"] and m.n_elements == 3 and m.n_nodes == 8
    x = m.nodes
    assert np.abs(np.hypot(x[:, 0], x[:, 1]) - R).max() < 1e-9  # on the analytic cylinder
    assert sorted(np.unique(np.round(x[:, 2], 9)).tolist()) == [0.0, L]
    theta = np.sort(np.unique(np.round(np.arctan2(x[:, 1], x[:, 0]), 9)))
    np.testing.assert_allclose(theta, np.linspace(0, np.pi / 2, 4), atol=1e-9)  # uniform arcs
    # the same with triangles: transfinite gives 3 x 1 cells, 2 triangles each
    mt = mesh_cad(cad["qc"], element="tri", structured=True, radius_divisions=3, length_divisions=1)
    assert mt.n_nodes == 8 and mt.n_elements == 6


def test_structured_bracket_fillet_and_consistent_shared_curves(cad):
    size = 5.0
    m = mesh_cad(cad["bracket"], element="quad", structured=True, size=size, radius_divisions=3, length_divisions=1)
    assert [b.type for b in m.cells] == ["quad"]
    ent = m.cell_data["element_entity"]
    # per face: fillet 3 x 1, flanges ceil(30/5) x 1 and ceil(20/5) x 1
    assert sorted(np.bincount(ent)[1:].tolist()) == [3, 4, 6]
    t = T.edge_table(m)
    assert (t.counts <= 2).all() and (t.counts == 1).sum() == 2 * (3 + 6 + 4) + 2  # conforming strip
    # fillet nodes lie on the cylinder (x^2 + (z - R)^2 = R^2 for x in [0, R], z in [0, R])
    fil = np.unique(m.quads[ent == np.bincount(ent).tolist().index(3)])
    xf = m.nodes[fil]
    assert np.abs(np.hypot(xf[:, 0], xf[:, 2] - R) - R).max() < 1e-9
    # and without length_divisions the length direction follows size: ceil(40/5) = 8
    m8 = mesh_cad(cad["bracket"], element="quad", structured=True, size=size, radius_divisions=3)
    assert m8.n_elements == (3 + 6 + 4) * 8


def test_quad_mode_gives_only_quads(cad):
    for key in ("bracket", "box", "cyl"):
        m = mesh_cad(cad[key], element="quad")
        assert [b.type for b in m.cells] == ["quad"], key
        assert len(T.non_manifold_edges(m)) == 0
        assert np.all(T.element_areas(m) > 0)


@pytest.mark.parametrize("key", ["box", "cyl"])
def test_tri_mode_closed_shell_is_watertight(cad, key):
    m = mesh_cad(cad[key], element="tri")
    t = T.edge_table(m)
    # reference: a closed, conforming, manifold surface has every edge shared by exactly 2
    # triangles and Euler characteristic V - E + F = 2 (sphere topology)
    assert (t.counts == 2).all()
    assert m.n_nodes - len(t.edges) + m.n_elements == 2
    # gmsh orients each face along the OCC face normal; orient_consistently must agree
    fixed, _ = T.orient_consistently(m, outward=True)
    assert len(T.orientation_conflicts(fixed)) == 0
    if key == "box":  # area: 2 (10*20 + 10*30 + 20*30)
        assert np.isclose(T.element_areas(m).sum(), 2 * (200 + 300 + 600))
        x = m.nodes
        on_plane = np.isclose(x, 0, atol=1e-9) | np.isclose(x, [10, 20, 30], atol=1e-9)
        assert on_plane.any(axis=1).all()


def test_parametric_coords_match_gmsh_evaluation(cad):
    """node_uv evaluated by gmsh on node_entity must give back the node coordinates."""
    import gmsh

    m = mesh_cad(cad["bracket"], element="tri", size=4.0)
    ent, uv = m.point_data["node_entity"], m.point_data["node_uv"]
    assert (ent > 0).all() and np.isfinite(uv).all()
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Geometry.OCCSewFaces", 1)
        gmsh.option.setNumber("Geometry.Tolerance", 1e-4)
        gmsh.model.occ.importShapes(str(cad["bracket"]))
        gmsh.model.occ.synchronize()
        for s in np.unique(ent):
            sel = ent == s
            xyz = np.asarray(gmsh.model.getValue(2, int(s), uv[sel].ravel())).reshape(-1, 3)
            np.testing.assert_allclose(xyz, m.nodes[sel], atol=1e-8)
    finally:
        gmsh.finalize()


def test_gmsh_state_is_released_and_errors_name_file(cad, tmp_path):
    import gmsh

    mesh_cad(cad["qc"], size=10.0)
    assert not gmsh.isInitialized()
    # caller-owned gmsh session: our model is removed and options are restored
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("mine")
        before = gmsh.option.getNumber("Mesh.MeshSizeMax")
        mesh_cad(cad["qc"], size=10.0)
        assert gmsh.model.getCurrent() == "mine"
        assert gmsh.option.getNumber("Mesh.MeshSizeMax") == before
        assert gmsh.model.getEntities() == []
    finally:
        gmsh.finalize()
    bad = tmp_path / "bad.igs"
    bad.write_text("not an iges file\n")
    with pytest.raises(MeshError, match=r"bad\.igs"):
        mesh_cad(bad)
    assert not gmsh.isInitialized()
    with pytest.raises(MeshError, match=r"missing\.igs: no such file"):
        mesh_cad(tmp_path / "missing.igs")
    with pytest.raises(MeshError, match="element must be"):
        mesh_cad(cad["qc"], element="hex")


@pytest.mark.parametrize("name", ["rational_quarter_cylinder.igs", "sphere_patch.igs", "torus_patch.igs", "trimmed_hole.igs"])
def test_quad_mode_has_no_flat_corners(name):
    """Unstructured quad meshes of the curved samples have no corner angle above 150 degrees
    (reference: corner angles computed from the node coordinates); flat 180-degree corners
    make Nagata patch normals undefined."""
    from pathlib import Path

    from cadbridge.mesh.generate import mesh_cad

    mesh = mesh_cad(Path(__file__).parents[2] / "iges_samples" / name, element="quad")
    x = mesh.nodes[mesh.quads]
    for k in range(4):
        a = x[:, (k - 1) % 4] - x[:, k]
        b = x[:, (k + 1) % 4] - x[:, k]
        cos = np.einsum("ij,ij->i", a, b) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 150.0


def test_meshing_leaves_sigpipe_ignored(tmp_path):
    """After mesh_cad a write to a closed pipe raises BrokenPipeError (Python's behaviour)
    instead of killing the process: gmsh resets SIGPIPE to terminate at the C level.
    Reference: the same write in a fresh interpreter. Run in a subprocess so a regression
    cannot take pytest down."""
    import subprocess
    import sys
    from pathlib import Path

    sample = Path(__file__).parents[2] / "iges_samples" / "ushape_die_nurbs.igs"
    code = (
        "import os\n"
        "from cadbridge.mesh.generate import mesh_cad\n"
        f"mesh_cad({str(sample)!r}, element='quad')\n"
        "r, w = os.pipe(); os.close(r)\n"
        "try:\n    os.write(w, b'x')\nexcept BrokenPipeError:\n    print('broken pipe raised')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "broken pipe raised" in res.stdout

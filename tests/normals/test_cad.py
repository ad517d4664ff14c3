"""Exact CAD normals at mesh nodes (cadbridge.normals.cad.cad_normals).

References:
- analytic geometry: the samples rational_quarter_cylinder / sphere_patch / torus_patch are
  exact rational NURBS of OCC's Geom_CylindricalSurface (axis (41, y, -5) along y, R 5),
  Geom_SphericalSurface (centre 0, R 10) and Geom_ToroidalSurface (axis z, R 20, r 5)
  (iges_samples/make_samples.py); the normal at the foot of a node is the radial direction
  from the axis / centre / tube centre circle, whatever the node's offset from the surface.
- a box and an L-bracket built with OCP (sharp 90 degree edges, faces on coordinate planes:
  exact face normals +-e_i), meshed with gmsh; the U-shape die (tangent-continuous land -
  radius - wall) for edges that must not be creases.
- hand-made meshes for the bad-input cases (messages checked for node / element numbers).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges
from cadbridge.mesh import CellBlock, Mesh, MeshError, MeshWarning
from cadbridge.cad.model import Model
from cadbridge.normals.cad import ProjectionError, cad_normals
from cadbridge.nurbs.project import BEYOND_TOLERANCE
from cadbridge.cad.search import project_points

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


def _mesh_cad(path, **kw):
    pytest.importorskip("gmsh")
    from cadbridge.mesh.generate import mesh_cad

    return mesh_cad(path, **kw)


def _element_normals(mesh: Mesh) -> list[np.ndarray]:
    out = []
    for b in mesh.cells:
        x = mesh.nodes[b.data]
        n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        out.append(n / np.linalg.norm(n, axis=1, keepdims=True))
    return out


# ================================================================ analytic surfaces
def _cylinder_normal(x):
    d = np.column_stack([x[:, 0] - 41.0, np.zeros(len(x)), x[:, 2] + 5.0])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _sphere_normal(x):
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _torus_normal(x):
    rho = np.linalg.norm(x[:, :2], axis=1, keepdims=True)
    c = np.column_stack([20.0 * x[:, :2] / rho, np.zeros(len(x))])
    d = x - c
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize(
    "fname,normal",
    [("rational_quarter_cylinder.igs", _cylinder_normal), ("sphere_patch.igs", _sphere_normal),
     ("torus_patch.igs", _torus_normal)],
    ids=["cylinder", "sphere", "torus"],
)
def test_analytic_normals(fname, normal):
    """Reference: analytic normal (radial direction) of the exact cylinder / sphere / torus,
    to 1e-12; one sign for the whole mesh (the winding chooses it)."""
    path = SAMPLES / fname
    model = read_iges(path)
    mesh = _mesh_cad(path, element="tri", size=model.size() / 15)
    cn = cad_normals(mesh, model)
    ref = normal(mesh.nodes)
    sign = np.sign(np.einsum("ij,ij->i", cn.normals, ref))
    assert np.all(sign == sign[0])
    err = np.linalg.norm(cn.normals - sign[0] * ref, axis=1)
    assert err.max() <= 1e-12, f"{fname}: max normal error {err.max():.3g}"
    assert not cn.has_creases
    assert cn.distance.max() <= 1e-9 * model.size()
    for en, cnb in zip(_element_normals(mesh), cn.corner_normals):  # orientation follows winding
        assert np.all(np.einsum("ij,ikj->ik", en, cnb) > 0)


# ================================================================ creases
@pytest.fixture(scope="module")
def sharp_cad(tmp_path_factory):
    pytest.importorskip("OCP")
    pytest.importorskip("gmsh")
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Fuse
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox
    from OCP.gp import gp_Pnt

    from cadbridge.ushape import export_iges

    d = tmp_path_factory.mktemp("sharp")
    box = BRepPrimAPI_MakeBox(10.0, 20.0, 30.0).Shape()
    # L-shaped bracket: a solid L (two boxes fused) has a re-entrant (concave) 90 degree edge
    a = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), gp_Pnt(40, 20, 5)).Shape()
    b = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), gp_Pnt(5, 20, 30)).Shape()
    fuse = BRepAlgoAPI_Fuse(a, b)
    fuse.SimplifyResult()
    paths = {"box": d / "box.igs", "bracket": d / "bracket.igs"}
    export_iges({"box": box}, paths["box"], mode="nurbs")
    export_iges({"bracket": fuse.Shape()}, paths["bracket"], mode="nurbs")
    return paths


def _axis_normal_check(mesh, cn):
    """Corner normals at crease nodes are +-e_i exactly and agree with their element."""
    ens = _element_normals(mesh)
    for en, cnb, blk, ef in zip(ens, cn.corner_normals, mesh.cells, cn.element_face):
        # orientation: each corner normal on the side of its element's normal
        assert np.all(np.einsum("ij,ikj->ik", en, cnb) > 0)
        cr = cn.crease[blk.data]
        e_i, k_i = np.nonzero(cr)
        v = cnb[e_i, k_i]
        # exact face normal: one component +-1, the others 0 (to 1e-12)
        assert np.all(np.abs(np.abs(v).max(axis=1) - 1.0) <= 1e-12)
        assert np.all(np.sort(np.abs(v), axis=1)[:, :2] <= 1e-12)
        # ... and it is the normal of the element's own face (element normal direction)
        assert np.all(np.abs(v - np.round(en[e_i])) <= 1e-12)


@pytest.mark.parametrize("which", ["box", "bracket"])
def test_sharp_edges_are_creases(sharp_cad, which):
    """Reference: the box / L-bracket faces lie on coordinate planes, so the exact normals are
    +-e_i; a node is a crease node iff it lies on an edge between two faces (gmsh's node_entity
    and the geometry tell which)."""
    path = sharp_cad[which]
    model = read_iges(path)
    mesh = _mesh_cad(path, element="tri", size=model.size() / 12)
    cn = cad_normals(mesh, model)
    x = mesh.nodes
    # nodes on a sharp edge: on two face planes of different orientation (coordinates of the
    # planes x = c, y = c, z = c the faces lie on)
    on = np.zeros((len(x), 3), dtype=bool)
    for k in range(3):
        vals = np.unique([f.surface.control_points[..., k].flat[0] for f in model.faces
                          if np.ptp(f.surface.control_points[..., k]) == 0])
        on[:, k] = np.min(np.abs(x[:, k][:, None] - vals[None, :]), axis=1) <= 1e-9
    edge_nodes = on.sum(axis=1) >= 2
    assert np.array_equal(cn.crease, edge_nodes), (
        f"{which}: crease flags differ at nodes {np.nonzero(cn.crease != edge_nodes)[0][:10]}")
    assert cn.crease.sum() > 10
    _axis_normal_check(mesh, cn)
    # flip reverses every node and corner normal, creases unchanged
    fl = cad_normals(mesh, model, flip=True)
    assert np.array_equal(fl.normals, -cn.normals)
    for a, b in zip(fl.corner_normals, cn.corner_normals):
        assert np.array_equal(a, -b)
    assert np.array_equal(fl.crease, cn.crease)


def test_tangent_edges_are_not_creases():
    """Reference: the U-shape die land - shoulder radius - wall are tangent-continuous
    (NUMISHEET'93 geometry): no node is a crease, the node normals on the shared edges equal
    the plane normals of the lands exactly."""
    path = SAMPLES / "ushape_die_nurbs.igs"
    model = read_iges(path)
    mesh = _mesh_cad(path, element="tri", size=4.0)
    cn = cad_normals(mesh, model)
    assert not cn.has_creases
    for en, cnb in zip(_element_normals(mesh), cn.corner_normals):
        assert np.all(np.einsum("ij,ikj->ik", en, cnb) > 0)
    x = mesh.nodes
    on_land_edge = (np.abs(x[:, 0] - 41.0) <= 1e-9) & (np.abs(x[:, 2]) <= 1e-9)  # land meets radius
    on_wall_edge = (np.abs(x[:, 0] - 36.0) <= 1e-9) & (np.abs(x[:, 2] + 5.0) <= 1e-9)  # wall meets radius
    assert on_land_edge.sum() >= 3 and on_wall_edge.sum() >= 3
    nl = cn.normals[on_land_edge]
    assert np.all(np.abs(np.abs(nl[:, 2]) - 1.0) <= 1e-12)
    nw = cn.normals[on_wall_edge]
    assert np.all(np.abs(np.abs(nw[:, 0]) - 1.0) <= 1e-12)


# ================================================================ bad input
def _plate_model():
    return read_iges(SAMPLES / "trimmed_hole.igs")  # plane z = 0, 100 x 60, hole R10 at (30, 25)


def _strip(z=0.0):
    """Two triangles on the plate, consistent winding (normal +z)."""
    nodes = np.array([[60.0, 40, z], [70, 40, z], [70, 50, z], [60, 50, z]])
    return Mesh(nodes, [CellBlock("triangle", np.array([[0, 1, 2], [0, 2, 3]]))])


def test_far_node_named():
    """Reference: geometry (plate z = 0): a node 5 above it is 5 away."""
    m = _strip()
    m.nodes[2, 2] = 5.0
    with pytest.raises(ProjectionError, match=r"node 2 at .* distance 5\b") as ei:
        cad_normals(m, _plate_model())
    assert ei.value.nodes.tolist() == [2]
    cn = cad_normals(m, _plate_model(), allow_far=True)
    assert cn.status[2] == BEYOND_TOLERANCE and abs(cn.distance[2] - 5.0) < 1e-12
    assert np.allclose(np.abs(cn.normals[:, 2]), 1.0)


def test_inconsistent_orientation_named_and_oriented():
    """Reference: winding by construction: element 1 reversed against element 0."""
    m = _strip()
    bad = Mesh(m.nodes, [CellBlock("triangle", np.array([[0, 1, 2], [0, 3, 2]]))])
    with pytest.raises(MeshError, match=r"elements 0 and 1"):
        cad_normals(bad, _plate_model())
    cn = cad_normals(bad, _plate_model(), orient=True)
    assert cn.flipped.tolist() == [False, True]
    assert np.array_equal(cn.mesh.cells[0].data, [[0, 1, 2], [0, 2, 3]])
    assert np.allclose(cn.normals, [0, 0, 1], atol=1e-15)
    assert np.allclose(cn.corner_normals[0], [0, 0, 1], atol=1e-15)


def test_non_manifold_edge_warns_and_keeps_corner_normals():
    """Reference: the box (OCP): a fin element standing on the edge (0, 1) of a face makes a
    non-manifold edge; each corner keeps its own face's normal (+-e_i)."""
    pytest.importorskip("OCP")
    import tempfile

    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox

    from cadbridge.ushape import export_iges

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "box.igs"
        export_iges({"box": BRepPrimAPI_MakeBox(10.0, 10.0, 10.0).Shape()}, p, mode="nurbs")
        model = read_iges(p)
    # face z = 0 (two triangles), face y = 0 (one triangle on the edge), and a third element
    # on the same edge (0, 1), lying in y = 0 on the other side: edge (0, 1) has 3 elements
    nodes = np.array([[2.0, 0, 0], [8, 0, 0], [8, 6, 0], [2, 6, 0], [5, 0, 4]])
    tri = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 0, 4]])
    mesh = Mesh(nodes, [CellBlock("triangle", tri)])
    with pytest.warns(MeshWarning, match=r"nodes 0 and 1: shared by elements \[0, 2, 3\]"):
        cn = cad_normals(mesh, model, allow_far=False)
    assert cn.non_manifold.tolist() == [[0, 1]]
    c = cn.corner_normals[0]
    assert np.allclose(c[0], [0, 0, -1], atol=1e-12) and np.allclose(c[2, :2], [0, -1, 0], atol=1e-12)
    assert np.allclose(c[3, :2], [0, 1, 0], atol=1e-12)
    assert cn.crease[[0, 1]].all()
    with pytest.warns(MeshWarning):
        fl = cad_normals(mesh, model, flip=True)  # flip reverses every corner, fins included
    assert np.array_equal(fl.corner_normals[0], -c)


def test_empty_model():
    with pytest.raises(ValueError, match="no faces"):
        cad_normals(_strip(), Model(faces=[]))
    with pytest.raises(ValueError, match="no faces|empty model"):
        project_points(np.zeros((1, 3)), Model(faces=[]))


def test_no_warning_on_clean_mesh():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cn = cad_normals(_strip(), _plate_model())
    assert cn.non_manifold.shape == (0, 2) and not cn.flipped.any()

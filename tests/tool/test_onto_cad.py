"""Mesh nodes the mesher left off their trimmed face are moved onto it (`cadbridge.tool.onto_cad`;
issue 32: the mesher's mesh lies on the geometry cadbridge projects onto).

Class of defect: a node on its face's surface but outside the face's trim curve (gmsh's
smoothing in a narrow part of a face; K1 from CATIA V5, trj8_k1-ct-214, had four 0.0031 mm
outside, checked in the slow corpus test, tests/cli/test_corpus_convert.py). Here the class is
made on purpose: nodes of cadbridge's own mesh of iges_samples/trimmed_hole.igs (plane z = 0,
hole R 10 at (30, 25)) pushed into the hole.

References: the analytic circle (the foot of a point inside the hole is on the circle, along
the radius), OCC's distance from the node to the trimmed face of the file
(`BRepExtrema_DistShapeShape`), and the sign of the elements' area vectors (analytic).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gmsh")

from cadbridge.cad.search import CONVERGED, FAILED, ON_BOUNDARY  # noqa: E402
from cadbridge.mesh.mesh import CellBlock, Mesh  # noqa: E402
from cadbridge.tool.build import tools_from_mesh  # noqa: E402
from cadbridge.tool.meshing import mesh_for_tools, read_healed  # noqa: E402
from cadbridge.tool.onto_cad import SNAP_REL, moved_note, onto_cad  # noqa: E402

HOLE = Path(__file__).resolve().parents[2] / "iges_samples" / "trimmed_hole.igs"
CENTRE, RADIUS = np.array([30.0, 25.0, 0.0]), 10.0
PUSH = 0.01  # mm into the hole: 8.6e-5 x size, within convert's projection tolerance


def _occ_distance(path: Path, points: np.ndarray) -> np.ndarray:
    """OCC's distance from each point (K, 3) to the faces of the file as OCC reads it."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
    from OCP.BRepExtrema import BRepExtrema_DistShapeShape
    from OCP.gp import gp_Pnt
    from OCP.IGESControl import IGESControl_Reader

    r = IGESControl_Reader()
    r.ReadFile(str(path))
    r.TransferRoots()
    shape = r.OneShape()
    out = []
    for p in points:
        d = BRepExtrema_DistShapeShape(BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, p))).Vertex(), shape)
        out.append(d.Value())
    return np.array(out)


@pytest.fixture(scope="module")
def pushed():
    """(model, the mesh with its hole's nodes pushed PUSH into the hole, the pushed nodes)."""
    model, excursions = read_healed(HOLE)
    mesh, _ = mesh_for_tools(HOLE, model, excursions=excursions, element="tri", size=5.0)
    x = mesh.nodes.copy()
    r = np.linalg.norm(x[:, :2] - CENTRE[:2], axis=1)
    on_hole = np.flatnonzero(np.abs(r - RADIUS) < 1e-6)
    assert len(on_hole) >= 8
    x[on_hole, :2] = CENTRE[:2] + (x[on_hole, :2] - CENTRE[:2]) * ((RADIUS - PUSH) / r[on_hole])[:, None]
    mesh.nodes = x
    return model, mesh, on_hole


def test_nodes_inside_a_hole_go_back_onto_its_circle(pushed):
    """convert's own mesh (``meshed_per_face``): the pushed nodes end on the circle, OCC finds
    them on the trimmed face, the tool says how many moved and how far, and no other node moved."""
    model, mesh, on_hole = pushed
    before = _occ_distance(HOLE, mesh.nodes[on_hole])
    assert np.allclose(before, PUSH, rtol=1e-6)
    (tool,) = tools_from_mesh(mesh, model, meshed_per_face=True, orient=True, measure=False)
    x = tool.mesh.nodes
    assert len(x) == len(mesh.nodes)  # one tool of all nodes, in the mesh's order
    r = np.linalg.norm(x[on_hole, :2] - CENTRE[:2], axis=1)
    assert np.max(np.abs(r - RADIUS)) < 1e-9 * model.size()
    assert np.max(_occ_distance(HOLE, x[on_hole])) < 1e-9 * model.size()
    others = np.setdiff1d(np.arange(len(x)), on_hole)
    assert np.array_equal(x[others], mesh.nodes[others])
    assert len(tool.moved_nodes) == len(on_hole) and np.allclose(tool.moved_nodes, PUSH, rtol=1e-6)
    assert np.all(tool.node_distance[on_hole] == 0.0)
    note = moved_note(tool.name, tool.moved_nodes)
    assert f"{len(on_hole)} mesh nodes" in note and "0.01" in note


def test_a_users_mesh_keeps_its_nodes(pushed):
    """A mesh cadbridge did not make face by face: its nodes stay where they are (the pushed
    ones PUSH from the CAD, as OCC measures)."""
    model, mesh, on_hole = pushed
    (tool,) = tools_from_mesh(mesh, model, meshed_per_face=False, orient=True, measure=False)
    assert np.array_equal(tool.mesh.nodes, mesh.nodes)
    assert tool.moved_nodes is None
    assert np.allclose(_occ_distance(HOLE, tool.mesh.nodes[on_hole]), PUSH, rtol=1e-6)


def test_a_move_that_turns_an_element_over_is_not_made():
    """Two triangles in z = 0 wound +z, each node's foot on a trim boundary of face 0: a foot
    across the opposite edge would reverse the first's area vector, so that node stays; a foot
    that keeps both +z is taken. Left alone: a node within SNAP_REL x size of its foot, one
    whose projection failed, one above its face (a converged foot), and one whose foot is on
    another face than an element around it."""
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    mesh = Mesh(nodes=x, cells=[CellBlock("triangle", np.array([[0, 1, 2], [1, 3, 2]]))])
    status = np.full(4, ON_BOUNDARY, dtype=np.int8)
    face, elements = np.zeros(4, dtype=np.int64), [np.zeros(2, dtype=np.int64)]
    foot = x.copy()
    foot[2] = [0.6, -0.5, 0.0]  # across edge 0-1: triangle (0, 1, 2) would face -z
    dist = np.linalg.norm(foot - x, axis=1)
    out, moved = onto_cad(mesh, foot, dist, status, 1.0, node_face=face, element_face=elements)
    assert out is mesh and len(moved) == 0 and moved.kept == 1

    foot[2] = [0.0, 0.9, 0.0]
    foot[3] = [1.0, 1.0, 0.5 * SNAP_REL]  # on the CAD already
    foot[1] = [1.05, 0.0, 0.0]
    status[0], foot[0] = FAILED, [0.0, 0.0, 0.3]
    dist = np.linalg.norm(foot - x, axis=1)
    out, moved = onto_cad(mesh, foot, dist, status, 1.0, node_face=face, element_face=elements)
    assert moved.nodes.tolist() == [1, 2] and np.allclose(moved.distance, [0.05, 0.1])
    assert np.array_equal(out.nodes[[1, 2]], foot[[1, 2]]) and np.array_equal(out.nodes[[0, 3]], x[[0, 3]])
    assert np.array_equal(mesh.nodes, x)  # the input mesh is not changed
    tri = out.cells[0].data
    area_z = np.cross(out.nodes[tri[:, 1]] - out.nodes[tri[:, 0]], out.nodes[tri[:, 2]] - out.nodes[tri[:, 0]])[:, 2]
    assert np.all(area_z > 0)

    above = status.copy()
    above[1] = CONVERGED  # node 1 above its face: stays
    _, moved = onto_cad(mesh, foot, dist, above, 1.0, node_face=face, element_face=elements)
    assert moved.nodes.tolist() == [2]
    other = face.copy()
    other[2] = 1  # node 2's foot on face 1, its elements on face 0: stays
    _, moved = onto_cad(mesh, foot, dist, status, 1.0, node_face=other, element_face=elements)
    assert moved.nodes.tolist() == [1]

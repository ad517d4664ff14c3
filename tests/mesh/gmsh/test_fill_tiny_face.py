"""A face gmsh fails on that is smaller than mesh_cad's node-merge tolerance
(`cadbridge.mesh.gmsh.empty_faces._fill_tiny_face`).

The production die in analytic mode: OCC's fragment with a crease curve leaves gmsh surface
1131, a sliver 1.3e-4 x 7e-7 mm of the binder's surface of revolution whose vertex tolerance
exceeds the face, so its two curves do not close in (u, v); gmsh's periodic mesher fails on it
and the (u, v) fill could not close its loop (convert exited 2). Here the same situation, built
small with gmsh's OCC kernel: a 10 x 10 square and, sharing its edge, a 1e-5 square that is
declared failed. References (round trip through gmsh's OCC geometry, independent of the fill):
the square's OCC area (getMass) and its free-edge length (the square's perimeter, 40).
"""

from __future__ import annotations

import numpy as np
import pytest


def test_face_below_merge_tolerance_is_filled_and_merged_away():
    gmsh = pytest.importorskip("gmsh")
    from cadbridge.mesh.cleanup import merge_close_nodes
    from cadbridge.mesh.gmsh.empty_faces import fill_empty_faces
    from cadbridge.mesh.generate import MERGE_TOLERANCE
    from cadbridge.mesh.mesh import Mesh
    from cadbridge.mesh.topology import boundary_edges, edge_table

    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        big = gmsh.model.occ.addRectangle(0, 0, 0, 10, 10)
        tiny = gmsh.model.occ.addRectangle(10, 0, 0, 1e-5, 1e-5)
        gmsh.model.occ.fragment([(2, big)], [(2, tiny)])
        gmsh.model.occ.synchronize()
        surfaces = [t for _, t in gmsh.model.getEntities(2)]
        areas = {t: gmsh.model.occ.getMass(2, t) for t in surfaces}
        small = min(areas, key=areas.get)
        size = 0.5
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.model.mesh.generate(2)
        gmsh.model.mesh.clear([(2, small)])
        notes = fill_empty_faces(gmsh, surfaces, size=size, curvature_elements=0, element="tri",
                                 subdivided=False, label="t", failed={small: "Impossible to mesh"},
                                 merge_tolerance=MERGE_TOLERANCE * size)
        assert len(notes) == 1 and "sliver" in notes[0] and "gmsh failed (Impossible to mesh)" in notes[0]
        assert any(len(t) for t in gmsh.model.mesh.getElements(2, small)[1])  # _check_all_meshed holds
        tags, x, _ = gmsh.model.mesh.getNodes()
        pos = np.full(int(max(tags)) + 1, -1)
        pos[np.asarray(tags, dtype=np.int64)] = np.arange(len(tags))
        tri = np.concatenate([np.asarray(gmsh.model.mesh.getElementsByType(2, t)[1], dtype=np.int64)
                              for t in surfaces]).reshape(-1, 3)
        mesh = Mesh(np.asarray(x, dtype=float).reshape(-1, 3), [("triangle", pos[tri])])
        area_ref = areas[[t for t in surfaces if t != small][0]]
    finally:
        gmsh.finalize()
    merged, report = merge_close_nodes(mesh, MERGE_TOLERANCE * size)
    assert report.dropped >= 2  # the fan over the sliver collapses
    xm, t = merged.nodes, merged.triangles
    area = 0.5 * np.linalg.norm(np.cross(xm[t[:, 1]] - xm[t[:, 0]], xm[t[:, 2]] - xm[t[:, 0]]), axis=1).sum()
    assert abs(area - area_ref) < 1e-9 * area_ref
    table = edge_table(merged)
    assert table.counts.max() <= 2
    b = boundary_edges(merged, table)
    blen = np.linalg.norm(xm[b[:, 1]] - xm[b[:, 0]], axis=1).sum()
    assert abs(blen - 40.0) < 1e-3  # the square's perimeter: no crack left where the sliver was

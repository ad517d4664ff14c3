"""The quad mesh's first attempt (recombined triangles at the target size) is skipped when it
cannot close without triangles, and tried only on a few faces first.

References: Euler's formula for a triangulated face, T = 2 V - B - 2 + 2 holes, so the number
of triangles gmsh makes on a face has the parity of its boundary nodes (checked against gmsh's
own triangulation, face by face); a seam counts twice. The end result is compared with the same
call made without the probe (the old order: the whole model meshed, then the subdivision).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gmsh")


def _cylinder(sess, size: float) -> list[int]:
    g = sess.gmsh
    g.model.occ.addCylinder(0, 0, 0, 0, 0, 10, 3)
    g.model.occ.synchronize()
    sess.set("Mesh.MeshSizeMax", size)
    return [t for _, t in g.model.getEntities(2)]


def test_boundary_nodes_have_the_parity_of_gmsh_triangles():
    from cadbridge.mesh.generate import _boundary_nodes
    from cadbridge.mesh.gmsh.session import GmshSession

    for size in (1.3, 1.1, 0.9):
        with GmshSession() as sess:
            g = sess.gmsh
            surfaces = _cylinder(sess, size)
            g.model.mesh.generate(1)
            b = _boundary_nodes(g, surfaces)
            g.model.mesh.generate(2)
            tris = np.array([sum(len(t) for t in g.model.mesh.getElements(2, s)[1]) for s in surfaces])
            assert np.array_equal(b % 2, tris % 2), (size, b, tris)
            # the lateral face: its two circles and the seam twice
            curves = [c for _, c in g.model.getBoundary([(2, surfaces[0])], combined=False, oriented=False)]
            assert len(curves) == 4 and len(set(curves)) == 3
            assert b[0] == sum(len(g.model.mesh.getElements(1, c)[1][0]) for c in curves)


def test_odd_faces_skip_the_first_attempt():
    from cadbridge.mesh.generate import _all_quads_possible, _boundary_nodes
    from cadbridge.mesh.gmsh.session import GmshSession

    with GmshSession() as sess:
        g = sess.gmsh
        surfaces = _cylinder(sess, 1.3)
        sess.set("Mesh.MeshOnlyEmpty", 1)
        g.model.mesh.generate(1)
        odd = _boundary_nodes(g, surfaces) % 2 == 1
        assert odd.any()  # the disks: 15 nodes each at this size
        assert not _all_quads_possible(g, sess, surfaces, {})
        assert not any(len(g.model.mesh.getElements(2, s)[0]) for s in surfaces)  # nothing meshed in vain


@pytest.mark.parametrize("name", ["ushape_tools_nurbs.igs", "multiple_knots.igs", "thesis_appendix_a.igs"])
def test_the_probe_changes_no_mesh(name, monkeypatch):
    # reference: mesh_cad without the probe (every surface meshed before the triangles are counted)
    from pathlib import Path

    from cadbridge.mesh import generate as G

    path = Path(__file__).parents[2] / "iges_samples" / name
    probed = G.mesh_cad(path, element="quad", curvature_elements=12)
    monkeypatch.setattr(G, "ALL_QUAD_PROBES", ())
    monkeypatch.setattr(G, "_boundary_nodes", lambda g, s: np.zeros(len(s), dtype=np.int64))
    plain = G.mesh_cad(path, element="quad", curvature_elements=12)
    assert len(probed.triangles) == len(plain.triangles) == 0
    np.testing.assert_array_equal(probed.nodes, plain.nodes)
    for a, b in zip(probed.cells, plain.cells):
        np.testing.assert_array_equal(a.data, b.data)

"""cadbridge's all-quad subdivision (`cadbridge.mesh.gmsh.subdivide`) against gmsh's own.

Reference: gmsh's ``Mesh.SubdivisionAlgorithm`` 1 on the same first-order mesh (gmsh splits the
same elements the same way and places the new nodes with OCC's closest-point search). The
shapes have seams (cylinder, torus, sphere, cone), poles (sphere) and an apex (cone): a
midpoint interpolated across a seam or from a pole's arbitrary parameter must still land
where gmsh's does.
"""

from __future__ import annotations

import numpy as np
import pytest

gmsh = pytest.importorskip("gmsh")

from scipy.spatial import cKDTree  # noqa: E402

from cadbridge.mesh.gmsh.subdivide import subdivide_to_quads  # noqa: E402

SIZE = 2.0


def _mesh(subdivide_in_gmsh: bool):
    """(nodes by dimension {1: (N, 3), 2: (M, 3)}, quads (Q, 4, 3) as corner coordinates, the
    surface nodes' (u, v) consistency max |S(u, v) - x| over nodes new in the subdivision)."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Verbosity", 1)
        gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, 10, 5)
        gmsh.model.occ.addTorus(20, 0, 0, 5, 2)
        gmsh.model.occ.addSphere(0, 20, 0, 4)
        gmsh.model.occ.addCone(20, 20, 0, 0, 0, 8, 4, 0)
        gmsh.model.occ.synchronize()
        for name, value in (("Mesh.MeshSizeMax", SIZE), ("Mesh.RecombineAll", 1), ("Mesh.Algorithm", 5),
                            ("Mesh.Smoothing", 1), ("Mesh.SubdivisionAlgorithm", int(subdivide_in_gmsh))):
            gmsh.option.setNumber(name, value)
        gmsh.model.mesh.generate(2)
        before = set(np.asarray(gmsh.model.mesh.getNodes()[0]).tolist())
        if not subdivide_in_gmsh:
            assert subdivide_to_quads(gmsh)
        nodes, worst = {}, 0.0
        for dim in (1, 2):
            xs = []
            for _, t in gmsh.model.getEntities(dim):
                tags, x, par = gmsh.model.mesh.getNodes(dim, t, includeBoundary=False, returnParametricCoord=True)
                x = np.asarray(x, dtype=float).reshape(-1, 3)
                xs.append(x)
                new = np.array([tag not in before for tag in tags.tolist()], dtype=bool)
                if np.any(new) and not subdivide_in_gmsh:
                    s = np.asarray(gmsh.model.getValue(dim, t, list(par)), dtype=float).reshape(-1, 3)
                    worst = max(worst, float(np.max(np.linalg.norm(s[new] - x[new], axis=1))))
            nodes[dim] = np.concatenate(xs)
        tags, x, _ = gmsh.model.mesh.getNodes()
        at = dict(zip(np.asarray(tags).tolist(), np.asarray(x, dtype=float).reshape(-1, 3)))
        quads = []
        for _, s in gmsh.model.getEntities(2):
            types, _, conn = gmsh.model.mesh.getElements(2, s)
            assert list(types) == [3]  # quads only
            quads += [[at[n] for n in q] for q in np.asarray(conn[0]).reshape(-1, 4).tolist()]
        return nodes, np.asarray(quads), worst
    finally:
        gmsh.finalize()


def test_the_split_is_gmsh_s_with_its_nodes_on_the_geometry():
    ref, ref_quads, _ = _mesh(True)
    ours, quads, worst = _mesh(False)
    assert len(quads) == len(ref_quads)
    for dim in (1, 2):
        assert len(ours[dim]) == len(ref[dim])
    # curve midpoints: on these circles and lines the chord-projection midpoint is gmsh's
    # equal-arc one
    d1, _ = cKDTree(ref[1]).query(ours[1])
    assert d1.max() < 1e-9 * SIZE
    # surface midpoints and centres: OCC's nearest point and ours agree to the search's accuracy
    d2, _ = cKDTree(ref[2]).query(ours[2])
    assert d2.max() < 1e-3 * SIZE
    assert worst < 1e-9 * SIZE  # every new node is S(its parameters)
    # the same quads, wound the same way: (corner set, normal) matched through the centroids
    key = cKDTree(ref_quads.mean(axis=1))
    d, i = key.query(quads.mean(axis=1))
    assert d.max() < 1e-3 * SIZE

    def normals(q):
        return np.cross(q[:, 2] - q[:, 0], q[:, 3] - q[:, 1])

    assert np.all(np.einsum("ij,ij->i", normals(quads), normals(ref_quads[i])) > 0)

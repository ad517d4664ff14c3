"""Corner normals that differ by round-off only are one normal (`NagataMesh`, `SAME_NORMAL`).

A smooth seam's normal evaluated at u0 by the elements on one side and at u1 by those on the
other differs by ~1e-17 (STEP bug24595: a converted cone's seam meeting its end plane). Taken
as two normals, the seam edge became half a crease and the convert guard called its elements
straddling. Reference: the edge coefficient of the published two-normal formula (Nagata
2005 eq. 15, `edge_coefficient`) with the one normal, and a mesh with no crease edge.
"""

from __future__ import annotations

import numpy as np

from cadbridge.nagata.edge import edge_coefficient
from cadbridge.nagata.mesh import NagataMesh


def _two_triangles(eps: float):
    """Two triangles of a quarter cylinder (radius 1, axis z) sharing the edge (0, 1); the
    corner normals of the second triangle perturbed by ``eps`` at node 0."""
    a = np.radians([0.0, 20.0, -20.0])
    nodes = np.array([[np.cos(a[0]), np.sin(a[0]), 0.0], [np.cos(a[0]), np.sin(a[0]), 1.0],
                      [np.cos(a[1]), np.sin(a[1]), 0.5], [np.cos(a[2]), np.sin(a[2]), 0.5]])
    radial = nodes * np.array([1.0, 1.0, 0.0])
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    tris = np.array([[0, 1, 2], [1, 0, 3]])
    corner = radial[tris].copy()
    corner[1, 1] += np.array([0.0, eps, 0.0])  # node 0 in the second triangle
    return nodes, tris, corner, radial


def test_roundoff_is_no_crease():
    nodes, tris, corner, radial = _two_triangles(1e-17 + 2e-16)
    nm = NagataMesh(nodes, tris, corner)
    assert len(nm.crease_edges) == 0 and len(nm.half_crease_edges) == 0
    c = edge_coefficient(nodes[[0]], nodes[[1]], radial[[0]], radial[[1]], nm.eps)[0]
    edge = int(np.flatnonzero((nm.edges["edges"] == [0, 1]).all(axis=1))[0])
    inst = np.flatnonzero(nm.edges["inst_edge"] == edge)
    assert inst.size == 2
    np.testing.assert_allclose(nm.tri_edge_coefficients[0, 0], c, atol=1e-14)


def test_a_real_crease_stays_one():
    nodes, tris, corner, _ = _two_triangles(1e-3)
    nm = NagataMesh(nodes, tris, corner)
    assert len(nm.crease_edges) == 1

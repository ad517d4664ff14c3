"""Nagata patches in the singular edge case c = -d (a tangent vanishes at one end).

Setting (thesis §5.2, "without planes"): a strip of three quads over a 90° arc of radius R,
one element along the axis; the two boundary nodes carry the normal of their only element
(perpendicular to its chord), the inner nodes the exact normal. Nagata's edge coefficient
of the outer elements is then exactly c = -d: the edge is the straight chord, parametrised
so that it stops at the inner node. References: the polyhedral chord (analytic) and the
element normal, which is the limit normal along a straight edge.
"""

import numpy as np

from cadbridge.nagata import NagataMesh, edge_coefficient
from cadbridge.normals.estimators import estimate_normals

R = 5.0


def _strip():
    ang = np.radians([0.0, 30.0, 60.0, 90.0])
    ring = np.column_stack([R * np.cos(ang), R * np.sin(ang)])
    nodes = np.array([[x, y0, z] for (x, z) in ring for y0 in (0.0, 20.5)])
    # node 2k at y = 0, 2k+1 at y = 20.5; quads x00 x10 x11 x01 with eta along the arc
    quads = np.array([[2 * k, 2 * k + 2, 2 * k + 3, 2 * k + 1] for k in range(3)])
    return nodes, quads


def test_outer_edge_coefficient_is_minus_chord():
    """c = -d exactly when n0 is the chord's element normal and n1 the exact normal."""
    nodes, quads = _strip()
    n = estimate_normals(nodes, quads, method="mwe")
    # edge from the boundary node 0 (element normal) to the inner node 2 (exact normal)
    c = edge_coefficient(nodes[[0]], nodes[[2]], n[[0]], n[[2]])
    d = nodes[2] - nodes[0]
    assert np.allclose(c[0], -d, atol=1e-12 * R)


def test_outer_patches_are_the_chord_with_limit_normals():
    """The outer patches coincide with the flat quads and their normal is the element
    normal everywhere, including the edge where x_eta vanishes (limit normal)."""
    nodes, quads = _strip()
    n = estimate_normals(nodes, quads, method="mwe")
    nm = NagataMesh(nodes, quads, n)
    t = np.linspace(0.0, 1.0, 41)
    for e in (0, 2):
        eta, zeta = np.meshgrid(t, t, indexing="ij")
        pts, nrm = nm.evaluate(np.full(eta.size, e), eta.ravel(), zeta.ravel())
        a, b = nodes[quads[e, 0]], nodes[quads[e, 1]]
        # every point lies on the flat quad (the plane through the chord and the y axis)
        n_el = np.cross(b - a, [0.0, 1.0, 0.0])
        n_el /= np.linalg.norm(n_el)
        assert np.max(np.abs((pts - a) @ n_el)) < 1e-12 * R
        # normals are finite, unit and equal to the element normal (up to orientation)
        assert np.all(np.isfinite(nrm))
        assert np.allclose(np.abs(nrm @ n_el), 1.0, atol=1e-12)


def test_limit_normal_is_oriented_like_the_patch():
    """At the degenerate edge the normal keeps the orientation of the rest of the patch."""
    nodes, quads = _strip()
    n = estimate_normals(nodes, quads, method="mwe")
    nm = NagataMesh(nodes, quads, n)
    for e in (0, 2):
        _, inside = nm.evaluate([e], [0.5], [0.5])
        for eta in (0.0, 1.0):
            _, edge = nm.evaluate([e, e], [eta, eta], [0.0, 1.0])
            assert np.all(edge @ inside[0] > 0.999999)

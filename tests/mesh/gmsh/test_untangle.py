"""`cadbridge.mesh.gmsh.untangle`: free nodes moved until no element is inverted.

References: the exact area of the square the meshes cover (a mesh whose elements are all
counter-clockwise and use only the square's boundary nodes on its border covers it once, so
their areas add up to 1), and the analytic sine of a rhombus' corners.
"""

from __future__ import annotations

import math

import numpy as np

from cadbridge.mesh.gmsh.untangle import corner_sines, untangle


def _grid(n: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Unit square, n x n quads, counter-clockwise; points reordered boundary first.
    Returns (points (N, 2), quads (n^2, 4), number of boundary points)."""
    t = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel()])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    q = np.column_stack([idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()])
    on = (p == 0.0).any(axis=1) | (p == 1.0).any(axis=1)
    order = np.r_[np.flatnonzero(on), np.flatnonzero(~on)]
    new = np.empty_like(order)
    new[order] = np.arange(len(order))
    return p[order], new[q], int(on.sum())


def _area(p: np.ndarray, e: np.ndarray) -> np.ndarray:
    a = p[e]
    return 0.5 * np.sum(a[..., 0] * np.roll(a[..., 1], -1, axis=1) - np.roll(a[..., 0], -1, axis=1) * a[..., 1],
                        axis=1)


def test_corner_sines_of_a_rhombus_are_the_sines_of_its_angles():
    a = math.radians(50.0)
    p = np.array([[0, 0], [1, 0], [1 + math.cos(a), math.sin(a)], [math.cos(a), math.sin(a)]])
    s = corner_sines(p, np.array([[0, 1, 2, 3]]))
    np.testing.assert_allclose(s[0], [math.sin(a), math.sin(math.pi - a), math.sin(a), math.sin(math.pi - a)],
                               rtol=1e-14)
    assert (corner_sines(p, np.array([[0, 3, 2, 1]])) < 0).all()  # clockwise: every corner negative


def test_a_node_dragged_over_its_neighbours_is_moved_back_inside():
    p, q, nb = _grid(6)
    k = nb + 7  # an interior node, pushed across the next column of nodes
    p_bad = p.copy()
    p_bad[k] += [0.3, 0.05]
    assert (corner_sines(p_bad, q).min(axis=1) <= 0).sum() >= 2  # the reference mesh is tangled
    p_new, left = untangle(p_bad, [q], nb)
    assert left == 0
    assert (corner_sines(p_new, q).min(axis=1) > 0).all()
    np.testing.assert_array_equal(p_new[:nb], p[:nb])  # the boundary stays
    np.testing.assert_allclose(_area(p_new, q).sum(), 1.0, rtol=1e-12)
    assert (_area(p_new, q) > 0).all()


def test_triangles_and_quads_together_and_a_good_mesh_left_alone():
    p, q, nb = _grid(4)
    tris = np.concatenate([q[:2][:, [0, 1, 2]], q[:2][:, [0, 2, 3]]])  # the first two quads split
    quads = q[2:]
    p2, left = untangle(p, [tris, quads], nb)
    assert left == 0
    np.testing.assert_array_equal(p2, p)  # every corner a right angle or 45 degrees: nothing to do
    bad = p.copy()
    bad[nb] = [0.9, 0.9]  # the first interior node thrown to the far corner
    p3, left = untangle(bad, [tris, quads], nb)
    assert left == 0
    total = _area(p3, tris).sum() + _area(p3, quads).sum()
    np.testing.assert_allclose(total, 1.0, rtol=1e-12)

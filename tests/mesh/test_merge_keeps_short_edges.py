"""The node merge after gmsh's all-quad subdivision keeps short CAD edges and drops folds.

The production die's quad failure at crease 130 (docs/production_die.md, "NURBS quad"): the
floor meets FTR00131 and FTR00132 in three CAD vertices 0.0077 and 0.0123 mm apart (the ends
of OCC's sliver fillet spans). The quad fallback meshes at twice the size and subdivides: a
midpoint on each short edge and on each needle triangle's long sides, 0.0038-0.006 mm from
its neighbours. `merge_close_nodes` at 1e-4 x size (7.2e-3 mm) joined the whole chain, 0.02
mm of boundary, into one node and folded the elements there: non-manifold edges. Here that
situation by hand (gmsh's subdivision: each triangle into three quads at its edge midpoints
and centroid), and the two rules that undo it: CAD vertices (``anchors``) farther apart
than the tolerance stay apart, and triangles the merge lays onto each other are dropped.
Reference: the connectivity and positions worked out by hand, and the edge table
(`non_manifold_edges`).
"""

from __future__ import annotations

import numpy as np

from cadbridge.mesh.cleanup import merge_close_nodes
from cadbridge.mesh.mesh import CellBlock, Mesh
from cadbridge.mesh.topology import non_manifold_edges

TOL = 1e-4 * 72.46  # the die's merge tolerance: 1e-4 x its default size (diagonal / 20)


def _subdivide(x: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """gmsh's all-quad subdivision of triangles (T, 3) on nodes (N, 3): (nodes, quads (3T, 4)),
    shared edge midpoints made once."""
    pts = [p for p in x]
    mid: dict[tuple[int, int], int] = {}

    def m(a: int, b: int) -> int:
        k = (min(a, b), max(a, b))
        if k not in mid:
            mid[k] = len(pts)
            pts.append(0.5 * (x[a] + x[b]))
        return mid[k]

    quads = []
    for a, b, c in tri:  # loop over the few hand-made triangles
        g = len(pts)
        pts.append((x[a] + x[b] + x[c]) / 3.0)
        ab, bc, ca = m(a, b), m(b, c), m(c, a)
        quads += [[a, ab, g, ca], [b, bc, g, ab], [c, ca, g, bc]]
    return np.array(pts), np.array(quads)


def _die_corner() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two faces (y > 0, y < 0) meeting along CAD vertices A, B, C at x = 0, 0.0077, 0.02
    (the die's 0.0077 and 0.0123 mm edges), each short edge the base of a needle to a far
    node, subdivided: (nodes, quads, CAD vertex indices)."""
    x = np.array([[0, 0, 0], [0.0077, 0, 0], [0.02, 0, 0],  # A B C
                  [-3, 0, 0], [3, 0, 0], [0.01, 1.5, 0], [0.01, -1.5, 0]], dtype=float)  # L R P Q
    A, B, C, L, R, P, Q = range(7)
    tri = np.array([[A, B, P], [B, C, P], [L, A, P], [C, R, P],  # above, counter-clockwise
                    [B, A, Q], [C, B, Q], [A, L, Q], [R, C, Q]])  # below
    nodes, quads = _subdivide(x, tri)
    return nodes, quads, np.arange(7)


def test_the_closure_alone_joins_the_die_corner_into_one_node():
    # the old merge: full tolerance, no anchors: the chain A..C and the midpoints between
    # join, 0.02 mm of CAD boundary in one node
    nodes, quads, _ = _die_corner()
    mesh = Mesh(nodes, [CellBlock("quad", quads)])
    assert len(non_manifold_edges(mesh).edges) == 0  # subdivided, it is manifold
    out, rep = merge_close_nodes(mesh, TOL)
    assert np.sum(np.linalg.norm(out.nodes - [0.01, 0, 0], axis=1) < 0.011) == 1
    assert rep.merged >= 4


def test_subdivided_merge_keeps_the_cad_vertices_and_stays_manifold():
    # mesh_cad after the subdivision: half the tolerance (every distance of the coarse mesh
    # halved) and the CAD vertices as anchors: A, B, C and all other nodes stay
    nodes, quads, anchors = _die_corner()
    mesh = Mesh(nodes, [CellBlock("quad", quads)])
    out, rep = merge_close_nodes(mesh, TOL / 2, anchors=anchors)
    assert rep.merged == 0
    assert len(non_manifold_edges(out).edges) == 0
    np.testing.assert_array_equal(out.nodes[:7], nodes[:7])


def test_anchors_split_a_chain_of_steps_below_the_tolerance():
    # CAD vertices 0, 6, 12 (x 1e-3) with midpoints 3e-3 from them, tolerance 3.6e-3: the
    # closure makes one cluster of the five; with the vertices as anchors each stays and each
    # midpoint joins its nearest vertex
    x = np.array([[0, 0, 0], [0.006, 0, 0], [0.012, 0, 0], [0.0029, 0, 0], [0.0089, 0, 0],
                  [0.006, 1, 0]], dtype=float)
    tri = np.array([[0, 3, 5], [3, 1, 5], [1, 4, 5], [4, 2, 5]])
    mesh = Mesh(x, [CellBlock("triangle", tri)])
    out, rep = merge_close_nodes(mesh, 0.0036)
    assert rep.merged == 4 and len(rep.where) == 1  # one node for the whole chain
    out, rep = merge_close_nodes(mesh, 0.0036, anchors=np.array([0, 1, 2, 5]))
    assert rep.merged == 2 and len(rep.where) == 2
    np.testing.assert_array_equal(out.nodes, x[[0, 1, 2, 5]])
    # node 3 (2.9e-3 from node 0) joined 0, node 4 (2.9e-3 from node 1, 3.1e-3 from 2) joined 1
    assert sorted(map(tuple, np.sort(out.cells[0].data, axis=1))) == [(0, 1, 3), (1, 2, 3)]


def test_anchors_within_the_tolerance_still_merge():
    # two CAD vertices closer than the tolerance (the die's 0.0035 mm edge) are one node
    x = np.array([[0, 0, 0], [0.0035, 0, 0], [0.00175, 0, 0], [0, 1, 0]], dtype=float)
    mesh = Mesh(x, [CellBlock("triangle", np.array([[0, 2, 3], [2, 1, 3]]))])
    out, rep = merge_close_nodes(mesh, 0.0036, anchors=np.array([0, 1, 3]))
    assert rep.merged == 2 and len(out.nodes) == 2 and rep.dropped == 2


def test_folded_triangles_are_dropped(monkeypatch):
    # the die's 0.0035 mm edge A-B (below the tolerance), base of a needle to N: merged, the
    # needle's sub-quads become triangles on the same nodes wound both ways (zero area
    # between them): they go, and every edge left is shared by at most two elements
    from cadbridge.mesh import cleanup

    x = np.array([[0, 0, 0], [0.0035, 0, 0], [0.00175, 1.5, 0], [-3, 0, 0], [3, 0, 0], [0.0, -1.5, 0]], dtype=float)
    A, B, N, L, R, S = range(6)
    tri = np.array([[A, B, N], [L, A, N], [B, R, N], [B, A, S], [A, L, S], [R, B, S]])
    nodes, quads = _subdivide(x, tri)
    mesh = Mesh(nodes, [CellBlock("quad", quads)])
    out, rep = merge_close_nodes(mesh, TOL / 2, anchors=np.arange(6))
    assert len(non_manifold_edges(out).edges) == 0
    key = [tuple(sorted(e)) for b in out.cells for e in b.data.tolist()]
    assert len(set(key)) == len(key)  # no two elements on the same nodes
    monkeypatch.setattr(cleanup, "_drop_folds", lambda blocks, take: 0)  # without the rule
    folded, _ = merge_close_nodes(mesh, TOL / 2, anchors=np.arange(6))
    assert len(non_manifold_edges(folded).edges) > 0


def test_a_doubled_triangle_of_one_winding_keeps_one():
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1e-9, 0, 0]], dtype=float)
    tri = np.array([[0, 1, 2], [3, 1, 2], [1, 0, 2][::-1]])  # 0 = 3 after the merge; the third reversed
    mesh = Mesh(x, [CellBlock("triangle", tri)], cell_data={"element_entity": np.array([5, 6, 7])})
    out, rep = merge_close_nodes(mesh, 1e-6)
    # (0, 1, 2) twice and (2, 0, 1) = (0, 1, 2) again, all one winding: one triangle stays
    assert len(out.cells[0].data) == 1 and rep.dropped == 2
    np.testing.assert_array_equal(out.cell_data["element_entity"], [5])

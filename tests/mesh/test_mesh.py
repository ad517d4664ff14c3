"""Mesh container and topology tests.

References: analytic counts for structured n x m grids (edges n(m+1) + m(n+1), boundary
2(n+m), areas), Euler's formula, and hand-built defective meshes (non-manifold fin,
flipped elements) whose defects are known by construction.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cadbridge.mesh import CellBlock, Mesh, MeshError
from cadbridge.mesh import topology as T


def grid(nx: int, ny: int, *, tri: bool = False, mixed: bool = False, h: float = 1.0) -> Mesh:
    """Structured nx x ny grid of unit squares (scaled by h) in the z = 0 plane, CCW (+z)."""
    x, y = np.meshgrid(np.arange(nx + 1) * h, np.arange(ny + 1) * h, indexing="ij")
    nodes = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    I, J = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"))
    idx = lambda i, j: i * (ny + 1) + j  # noqa: E731
    q = np.column_stack([idx(I, J), idx(I + 1, J), idx(I + 1, J + 1), idx(I, J + 1)])
    if tri:
        return Mesh(nodes, [CellBlock("triangle", np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))])
    if mixed:
        k = len(q) // 2
        t = q[k:]
        return Mesh(nodes, [("quad", q[:k]), ("triangle", np.concatenate([t[:, [0, 1, 2]], t[:, [0, 2, 3]]]))])
    return Mesh(nodes, [CellBlock("quad", q)])


# ----------------------------------------------------------------------------- container
def test_container_blocks_offsets_and_properties():
    m = grid(4, 3, mixed=True)  # 6 quads, 12 triangles
    assert m.n_elements == 18 and m.n_nodes == 20
    assert m.element_offsets.tolist() == [0, 6, 18]
    assert m.quads.shape == (6, 4) and m.triangles.shape == (12, 3)
    assert [off for off, _ in m.elements()] == [0, 6]
    assert m.locate(7) == (1, 1)
    assert np.array_equal(m.element_nodes(7), m.cells[1].data[1])
    P = m.padded()
    assert (P[6:, 3] == -1).all() and (P[:6] >= 0).all()
    assert m.element_types.tolist() == [4] * 6 + [3] * 12


def test_validation_names_element_and_node():
    nodes = np.zeros((4, 3))
    with pytest.raises(MeshError, match=r"element 3 .*references node 7"):
        Mesh(nodes, [("triangle", [[0, 1, 2], [1, 2, 3]]), ("quad", [[0, 1, 2, 3], [0, 1, 2, 7]])])
    with pytest.raises(MeshError, match=r"element 1 .*repeats a node"):
        Mesh(nodes, [("triangle", [[0, 1, 2], [1, 1, 3]])])
    with pytest.raises(MeshError, match=r"shape \(E, 4\)"):
        Mesh(nodes, [("quad", [[0, 1, 2]])])
    with pytest.raises(MeshError, match="unsupported cell type"):
        Mesh(nodes, [("tetra", [[0, 1, 2, 3]])])
    bad = nodes.copy()
    bad[2, 1] = np.nan
    with pytest.raises(MeshError, match="node 2 has non-finite"):
        Mesh(bad, [("triangle", [[0, 1, 2]])])
    with pytest.raises(MeshError, match=r"point_data\['a'\]"):
        Mesh(nodes, [("triangle", [[0, 1, 2]])], point_data={"a": np.zeros(3)})
    assert issubclass(MeshError, ValueError)


def test_remove_unused_nodes_renumbers_and_keeps_point_data():
    nodes = np.arange(18.0).reshape(6, 3)
    m = Mesh(nodes, [("triangle", [[1, 3, 5]])], point_data={"id": np.arange(6)})
    r, old = m.remove_unused_nodes()
    assert old.tolist() == [1, 3, 5]
    assert r.cells[0].data.tolist() == [[0, 1, 2]]
    assert np.array_equal(r.nodes, nodes[[1, 3, 5]]) and r.point_data["id"].tolist() == [1, 3, 5]


# ----------------------------------------------------------------------------- topology
@settings(max_examples=25, deadline=None)
@given(nx=st.integers(1, 12), ny=st.integers(1, 12), kind=st.sampled_from(["quad", "tri", "mixed"]))
def test_grid_edge_and_boundary_counts_are_analytic(nx, ny, kind):
    m = grid(nx, ny, tri=kind == "tri", mixed=kind == "mixed")
    t = T.edge_table(m)
    n_diag = {"quad": 0, "tri": nx * ny, "mixed": nx * ny - (nx * ny) // 2}[kind]
    # reference: a structured grid has nx(ny+1) + ny(nx+1) grid lines (+ one diagonal per split cell)
    assert len(t.edges) == nx * (ny + 1) + ny * (nx + 1) + n_diag
    assert (t.edges[:, 0] < t.edges[:, 1]).all()
    b = T.boundary_edges(m)
    assert len(b) == 2 * (nx + ny)
    # boundary nodes are exactly those on the square's border; loop is CCW (surface on the left)
    on_border = lambda p: np.isclose(p[:, 0], 0) | np.isclose(p[:, 0], nx) | np.isclose(p[:, 1], 0) | np.isclose(p[:, 1], ny)  # noqa: E731
    assert on_border(m.nodes[b[:, 0]]).all() and on_border(m.nodes[b[:, 1]]).all()
    d = m.nodes[b[:, 1]] - m.nodes[b[:, 0]]
    mid = 0.5 * (m.nodes[b[:, 1]] + m.nodes[b[:, 0]]) - np.array([nx / 2, ny / 2, 0])
    assert (np.cross(mid, d)[:, 2] > 0).all()
    # Euler: V - E + F = 1 for a disc
    assert m.n_nodes - len(t.edges) + m.n_elements == 1
    assert len(T.non_manifold_edges(m)) == 0 and len(T.orientation_conflicts(m)) == 0
    # areas (reference: nx*ny unit squares) and normals (+z)
    assert np.isclose(T.element_areas(m).sum(), nx * ny)
    assert np.allclose(T.element_normals(m), [0, 0, 1])


def test_edge_incidence_and_node_adjacency():
    m = grid(3, 2)
    t = T.edge_table(m)
    counts = np.diff(t.ptr)
    assert np.array_equal(counts, t.counts)
    interior = np.flatnonzero(t.counts == 2)
    # every interior edge's two elements really contain both its nodes
    for e in interior:
        for el in t.elements_of(e):
            assert set(t.edges[e]) <= set(m.element_nodes(el).tolist())
    ptr, el = T.node_elements(m)
    valence = np.diff(ptr)
    # reference: a 3x2 quad grid has corner valence 1, border 2, interior 4
    assert np.bincount(valence).tolist() == [0, 4, 6, 0, 2]
    centre = 1 * 3 + 1  # node (1, 1)
    assert set(el[ptr[centre] : ptr[centre + 1]].tolist()) == {0, 1, 2, 3}


def test_non_manifold_fin_is_detected_and_named():
    # three quads sharing the edge (0, 1) along the x axis: a "fin"
    nodes = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1, -1, 0], [0, -1, 0], [1, 0, 1], [0, 0, 1]], float)
    m = Mesh(nodes, [("quad", [[0, 1, 2, 3], [1, 0, 5, 4], [0, 1, 6, 7]])])
    rep = T.non_manifold_edges(m)
    assert len(rep) == 1 and rep.edges.tolist() == [[0, 1]]
    assert rep.elements[0].tolist() == [0, 1, 2]
    assert "edge (0, 1) shared by 3 elements [0, 1, 2]" in str(rep)
    with pytest.raises(MeshError, match=r"nodes 0 and 1: shared by elements \[0, 1, 2\]"):
        T.check_manifold(m)


def test_inconsistent_orientation_detected_and_repaired():
    m = grid(5, 4, mixed=True)
    rng = np.random.default_rng(0)
    flip = rng.random(m.n_elements) < 0.4
    flip[0] = False  # seed keeps its orientation
    bad = T.flip_elements(m, flip)
    conf = T.orientation_conflicts(bad)
    # reference: a pair conflicts iff exactly one of two neighbours was flipped
    t = T.edge_table(m)
    i0 = t.ptr[:-1][t.counts == 2]
    a, b = t.elems[i0], t.elems[i0 + 1]
    expected = {tuple(sorted(p)) for p in zip(a[flip[a] != flip[b]], b[flip[a] != flip[b]])}
    assert {tuple(p) for p in conf.tolist()} == expected and len(expected) > 0
    fixed, flipped = T.orient_consistently(bad)
    assert len(T.orientation_conflicts(fixed)) == 0
    assert np.array_equal(flipped, flip)  # exactly the flipped elements are flipped back
    assert np.allclose(T.element_normals(fixed), [0, 0, 1])


def test_orient_components_separately_and_outward():
    # closed cube surface with random flips: outward=True must give outward normals
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    idx = lambda x, y, z: 4 * x + 2 * y + z  # noqa: E731
    quads = [
        [idx(0, 0, 0), idx(0, 1, 0), idx(1, 1, 0), idx(1, 0, 0)],  # z=0, normal -z
        [idx(0, 0, 1), idx(1, 0, 1), idx(1, 1, 1), idx(0, 1, 1)],  # z=1, +z
        [idx(0, 0, 0), idx(1, 0, 0), idx(1, 0, 1), idx(0, 0, 1)],  # y=0, -y
        [idx(0, 1, 0), idx(0, 1, 1), idx(1, 1, 1), idx(1, 1, 0)],  # y=1, +y
        [idx(0, 0, 0), idx(0, 0, 1), idx(0, 1, 1), idx(0, 1, 0)],  # x=0, -x
        [idx(1, 0, 0), idx(1, 1, 0), idx(1, 1, 1), idx(1, 0, 1)],  # x=1, +x
    ]
    cube = Mesh(v, [("quad", quads)])
    assert len(T.boundary_edges(cube)) == 0 and len(T.orientation_conflicts(cube)) == 0
    inward = T.flip_elements(cube, np.ones(6, bool))
    fixed, _ = T.orient_consistently(T.flip_elements(inward, np.array([0, 1, 0, 1, 1, 0], bool)), outward=True)
    c = T._corner_points(fixed)[0] * 0 + (fixed.nodes[fixed.quads].mean(axis=1) - 0.5)
    assert (np.einsum("ij,ij->i", T.element_normals(fixed), c) > 0).all()
    # two disjoint grids: two components, each oriented on its own
    g = grid(2, 2)
    two = Mesh(np.vstack([g.nodes, g.nodes + [0, 0, 5]]), [("quad", np.vstack([g.quads, g.quads + g.n_nodes]))])
    n, lab = T.connected_components(two)
    assert n == 2 and lab.tolist() == [0] * 4 + [1] * 4
    fl = np.zeros(8, bool)
    fl[[1, 5, 6]] = True
    fixed2, flipped2 = T.orient_consistently(T.flip_elements(two, fl))
    assert len(T.orientation_conflicts(fixed2)) == 0 and np.array_equal(flipped2, fl)


def test_moebius_strip_cannot_be_oriented():
    n = 12
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    top = np.column_stack([np.cos(th), np.sin(th), 0.2 * np.ones(n)])
    bot = top * [1, 1, -1]
    nodes = np.vstack([top, bot])
    i = np.arange(n)
    j = (i + 1) % n
    q = np.column_stack([i, j, j + n, i + n])
    q[-1] = [n - 1, n, 0, 2 * n - 1]  # half twist: last quad joins top to bottom
    m = Mesh(nodes, [("quad", q)])
    with pytest.raises(MeshError, match="cannot orient consistently: elements"):
        T.orient_consistently(m)
    with pytest.warns(UserWarning):
        T.orient_consistently(m, strict=False)


def test_quad_normal_and_area_analytic():
    # planar trapezoid: area (a + b) h / 2; skew quad: normal from the diagonals
    nodes = np.array([[0, 0, 0], [4, 0, 0], [3, 2, 0], [1, 2, 0], [0, 0, 1], [1, 0, 0], [1, 1, 1], [0, 1, 0]], float)
    m = Mesh(nodes, [("quad", [[0, 1, 2, 3], [4, 5, 6, 7]])])
    A = T.element_areas(m)
    assert np.isclose(A[0], (4 + 2) * 2 / 2)
    n = T.element_normals(m)
    d1, d2 = nodes[6] - nodes[4], nodes[7] - nodes[5]
    ref = np.cross(d1, d2) / np.linalg.norm(np.cross(d1, d2))
    assert np.allclose(n[0], [0, 0, 1]) and np.allclose(n[1], ref)
    with pytest.raises(MeshError, match="element 0 is degenerate"):
        T.element_normals(Mesh(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float), [("triangle", [[0, 1, 2]])]))

"""`edge_table` (compiled counting sort over the cell blocks) against a plain numpy
reference built from `halfedges`: a stable lexsort of the sorted node pairs, np.unique."""

import numpy as np
import pytest

from cadbridge.mesh.mesh import CellBlock, Mesh
from cadbridge.mesh.topology import edge_table, halfedges


def _reference(mesh: Mesh) -> dict:
    """The edge table by definition: sides sorted stably by (min node, max node)."""
    src, dst, elem, side = halfedges(mesh)
    lo, hi = np.minimum(src, dst), np.maximum(src, dst)
    order = np.lexsort((hi, lo))  # stable: ties keep side (element-major) order
    pairs = np.column_stack([lo[order], hi[order]])
    edges, first, inv, counts = np.unique(pairs, axis=0, return_index=True, return_inverse=True,
                                          return_counts=True)
    side_edge = np.empty(len(src), dtype=np.int64)
    side_edge[order] = inv.ravel()
    return dict(edges=edges, counts=counts, ptr=np.concatenate([[0], np.cumsum(counts)]),
                elems=elem[order], forward=(src < dst)[order], side=side[order], side_edge=side_edge)


def _random_mesh(rng, n_nodes: int) -> Mesh:
    blocks = []
    for _ in range(int(rng.integers(1, 4))):
        k = int(rng.choice([3, 4]))
        rows = np.argsort(rng.random((int(rng.integers(0, 60)), n_nodes)), axis=1)[:, :k]
        blocks.append(CellBlock("triangle" if k == 3 else "quad", rows))
    return Mesh(rng.random((n_nodes, 3)), blocks)


@pytest.mark.parametrize("seed", range(40))
def test_edge_table_matches_numpy_reference(seed):
    # random mixed tri/quad blocks on few nodes: many shared, boundary and non-manifold
    # edges, unused nodes, empty blocks
    rng = np.random.default_rng(seed)
    mesh = _random_mesh(rng, int(rng.integers(4, 25)))
    t, ref = edge_table(mesh), _reference(mesh)
    for name, want in ref.items():
        got = getattr(t, name)
        assert got.shape == np.shape(want), name
        assert np.array_equal(got, want), name
    assert t.edges.dtype == np.int64 and t.forward.dtype == bool and t.elems.dtype == np.int64


def test_edge_table_structured_grid():
    # a 2 x 2 quad grid split into a quad block and a triangle block: 12 + 2 edges by count
    quads = CellBlock("quad", [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6]])
    tris = CellBlock("triangle", [[4, 5, 8], [4, 8, 7]])
    mesh = Mesh(np.random.default_rng(0).random((9, 3)), [quads, tris])
    t = edge_table(mesh)
    assert len(t.edges) == 13  # 12 grid edges + the diagonal (4, 8)
    assert int((t.counts == 2).sum()) == 5 and int((t.counts == 1).sum()) == 8
    m = int(np.flatnonzero((t.edges == [4, 8]).all(axis=1))[0])
    assert t.elements_of(m).tolist() == [3, 4]
    assert t.forward[t.ptr[m]:t.ptr[m + 1]].tolist() == [False, True]  # 8->4 in elem 3, 4->8 in 4


def test_edge_table_empty_mesh():
    t = edge_table(Mesh(np.zeros((3, 3)), []))
    assert t.edges.shape == (0, 2) and t.ptr.tolist() == [0]

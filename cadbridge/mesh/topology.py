"""Mesh topology: edges, boundary, non-manifold edges, adjacency, orientation, geometry.

All functions are vectorised over elements (numpy / scipy.sparse); element indices are the
global element numbering of `Mesh` (blocks in order), node indices are 0-based.

Terms: a *side* (half-edge) is edge j of element e traversed in the element's node order,
``(n_j, n_{j+1 mod k})``; an *edge* is a sorted node pair shared by one or more sides.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from cadbridge.mesh.mesh import CellBlock, Mesh, MeshError

__all__ = [
    "EdgeTable",
    "EdgeReport",
    "halfedges",
    "edge_table",
    "unique_edges",
    "boundary_edges",
    "non_manifold_edges",
    "check_manifold",
    "node_elements",
    "element_adjacency",
    "connected_components",
    "orientation_conflicts",
    "flip_elements",
    "orient_consistently",
    "element_normals",
    "element_areas",
]


def halfedges(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All element sides, element-major (element 0 side 0, 0/1, ...).

    Returns ``src, dst, elem, side``, each (H,) int64, H = 3 E_tri + 4 E_quad.
    """
    src, dst, elem, side = [], [], [], []
    for off, blk in mesh.elements():
        d = blk.data
        k = blk.nodes_per_element
        src.append(d.ravel())
        dst.append(np.roll(d, -1, axis=1).ravel())
        elem.append(np.repeat(np.arange(off, off + len(d), dtype=np.int64), k))
        side.append(np.tile(np.arange(k, dtype=np.int64), len(d)))
    if not src:
        z = np.empty(0, dtype=np.int64)
        return z, z, z, z
    return tuple(np.concatenate(a).astype(np.int64) for a in (src, dst, elem, side))  # type: ignore[return-value]


@dataclass(frozen=True, eq=False)
class EdgeTable:
    """Unique edges and their edge -> element incidence (CSR).

    edges   : (M, 2) int64 sorted node pairs (edges[:, 0] < edges[:, 1]), lexicographic.
    counts  : (M,) number of element sides on each edge (1 boundary, 2 manifold, >2 non-manifold).
    ptr     : (M + 1,) CSR pointer into ``elems`` / ``forward`` / ``side``.
    elems   : (H,) elements using each edge, grouped by edge, ascending element index.
    forward : (H,) bool, True if that element traverses the edge edges[m, 0] -> edges[m, 1].
    side    : (H,) local side index of the edge in that element.
    side_edge : (H,) edge index of each side in `halfedges` (element-major) order.
    """

    edges: np.ndarray
    counts: np.ndarray
    ptr: np.ndarray
    elems: np.ndarray
    forward: np.ndarray
    side: np.ndarray
    side_edge: np.ndarray

    def elements_of(self, m: int) -> np.ndarray:
        """Elements using edge m."""
        return self.elems[self.ptr[m] : self.ptr[m + 1]]


@numba.njit(cache=True, nogil=True)
def _count_lo(cells, cnt):  # pragma: no cover - compiled
    """cnt[lo + 1] += 1 for every side of the (E, k) elements ``cells`` (lo = smaller node)."""
    k = cells.shape[1]
    for e in range(cells.shape[0]):
        for j in range(k):
            a, b = cells[e, j], cells[e, (j + 1) % k]
            cnt[min(a, b) + 1] += 1


@numba.njit(cache=True, nogil=True)
def _scatter_by_lo(cells, e0, h0, pos, hi, elems, forward, side, hidx):  # pragma: no cover - compiled
    """Place every side of ``cells`` (global elements from e0, sides from h0, element-major)
    at pos[lo] (then pos[lo] += 1): sides bucketed by lo, in side order within a bucket."""
    k = cells.shape[1]
    h = h0
    for e in range(cells.shape[0]):
        for j in range(k):
            a, b = cells[e, j], cells[e, (j + 1) % k]
            lo = min(a, b)
            t = pos[lo]
            pos[lo] = t + 1
            hi[t] = max(a, b)
            elems[t] = e0 + e
            forward[t] = a < b
            side[t] = j
            hidx[t] = h
            h += 1


@numba.njit(cache=True, nogil=True)
def _group_edges(start, hi, elems, forward, side, hidx, side_edge):  # pragma: no cover - compiled
    """Sort each lo bucket start[i]:start[i + 1] by hi, stably (insertion sort: a node has a
    few sides), so the sides are in lexicographic (lo, hi) order with ties in side order;
    number the edges; return edges (M, 2), counts (M,), ptr (M + 1,) (side_edge filled)."""
    n = start.shape[0] - 1
    m = 0
    for i in range(n):
        a, b = start[i], start[i + 1]
        for t in range(a + 1, b):
            x = hi[t]
            if x >= hi[t - 1]:
                continue
            ve, vf, vs, vh = elems[t], forward[t], side[t], hidx[t]
            s = t
            while s > a and hi[s - 1] > x:
                hi[s], elems[s], forward[s], side[s], hidx[s] = hi[s - 1], elems[s - 1], forward[s - 1], side[s - 1], hidx[s - 1]
                s -= 1
            hi[s], elems[s], forward[s], side[s], hidx[s] = x, ve, vf, vs, vh
        for t in range(a, b):
            if t == a or hi[t] != hi[t - 1]:
                m += 1
    edges = np.empty((m, 2), dtype=np.int64)
    counts = np.zeros(m, dtype=np.int64)
    ptr = np.empty(m + 1, dtype=np.int64)
    ptr[0] = 0
    g = -1
    for i in range(n):
        a, b = start[i], start[i + 1]
        for t in range(a, b):
            if t == a or hi[t] != hi[t - 1]:
                g += 1
                edges[g, 0] = i
                edges[g, 1] = hi[t]
                ptr[g] = t
            counts[g] += 1
            side_edge[hidx[t]] = g
    ptr[m] = start[n]
    return edges, counts, ptr


def edge_table(mesh: Mesh) -> EdgeTable:
    """Build the `EdgeTable` of a mesh in O(H + N), H element sides, N nodes.

    Compiled passes over the cell blocks (no (H,) side arrays of `halfedges`): a counting
    sort of the sides by their smaller node, then each node's few sides sorted by the other
    node, stably: the order of a stable argsort of the key lo * N + hi (sides grouped by
    edge, lexicographic; within an edge in side order, i.e. ascending element).
    """
    blocks = [(off, np.ascontiguousarray(blk.data, dtype=np.int64)) for off, blk in mesh.elements()]
    h = sum(c.size for _, c in blocks)
    if h == 0:
        z = np.empty(0, dtype=np.int64)
        return EdgeTable(np.empty((0, 2), np.int64), z, np.zeros(1, np.int64), z, z.astype(bool), z, z)
    n = max(int(mesh.n_nodes), 1)
    start = np.zeros(n + 1, dtype=np.int64)
    for _, c in blocks:
        if len(c):
            _count_lo(c, start)
    np.cumsum(start, out=start)
    pos = start[:-1].copy()
    hi = np.empty(h, dtype=np.int64)
    elems = np.empty(h, dtype=np.int64)
    forward = np.empty(h, dtype=bool)
    side = np.empty(h, dtype=np.int64)
    hidx = np.empty(h, dtype=np.int64)
    h0 = 0
    for off, c in blocks:
        if len(c):
            _scatter_by_lo(c, off, h0, pos, hi, elems, forward, side, hidx)
        h0 += c.size
    side_edge = np.empty(h, dtype=np.int64)
    edges, counts, ptr = _group_edges(start, hi, elems, forward, side, hidx, side_edge)
    return EdgeTable(edges=edges, counts=counts, ptr=ptr, elems=elems, forward=forward, side=side,
                     side_edge=side_edge)


def unique_edges(mesh: Mesh) -> np.ndarray:
    """(M, 2) int64 sorted node pairs of all edges."""
    return edge_table(mesh).edges


def boundary_edges(mesh: Mesh, table: EdgeTable | None = None) -> np.ndarray:
    """(B, 2) int64 edges used by exactly one element, oriented as that element traverses them.

    For a consistently oriented surface the boundary loops run counter-clockwise about the
    normal (the surface lies to the left).
    """
    t = edge_table(mesh) if table is None else table
    m = np.flatnonzero(t.counts == 1)
    e = t.edges[m]
    fwd = t.forward[t.ptr[m]]
    return np.where(fwd[:, None], e, e[:, ::-1])


@dataclass(frozen=True, eq=False)
class EdgeReport:
    """Edges with a list of the elements using each (e.g. non-manifold edges).

    edges : (K, 2) sorted node pairs; elements : K arrays of global element indices.
    """

    edges: np.ndarray
    elements: list[np.ndarray]

    def __len__(self) -> int:
        return int(len(self.edges))

    def __bool__(self) -> bool:
        return len(self) > 0

    def __str__(self) -> str:
        lines = [
            f"edge ({a}, {b}) shared by {len(el)} elements {el.tolist()}"
            for (a, b), el in zip(self.edges.tolist(), self.elements)
        ]
        return "\n".join(lines) if lines else "no edges"


def non_manifold_edges(mesh: Mesh, table: EdgeTable | None = None) -> EdgeReport:
    """Edges shared by more than two elements, with the elements on each."""
    t = edge_table(mesh) if table is None else table
    m = np.flatnonzero(t.counts > 2)
    els = [t.elems[t.ptr[i] : t.ptr[i + 1]] for i in m]  # loop over the (few) bad edges only
    return EdgeReport(t.edges[m], els)


def check_manifold(mesh: Mesh) -> None:
    """Raise `MeshError` naming the first non-manifold edge and its elements, if any."""
    rep = non_manifold_edges(mesh)
    if rep:
        (a, b), el = rep.edges[0].tolist(), rep.elements[0].tolist()
        more = f" (and {len(rep) - 1} more non-manifold edges)" if len(rep) > 1 else ""
        raise MeshError(
            f"non-manifold edge between nodes {a} and {b}: shared by elements {el}{more}"
        )


def node_elements(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Node -> element adjacency in CSR form.

    Returns ``ptr`` (N + 1,) and ``elems`` (H,): the elements touching node i are
    ``elems[ptr[i]:ptr[i + 1]]`` (ascending).
    """
    src, _, elem, _ = halfedges(mesh)
    order = np.lexsort((elem, src))
    counts = np.bincount(src, minlength=mesh.n_nodes)
    ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return ptr, elem[order]


def element_adjacency(mesh: Mesh, table: EdgeTable | None = None, *, manifold_only: bool = False) -> sp.csr_matrix:
    """(E, E) symmetric sparse dual graph: elements sharing an edge.

    With ``manifold_only`` only edges with exactly two elements connect elements.
    """
    t = edge_table(mesh) if table is None else table
    ne = mesh.n_elements
    sel = (t.counts == 2) if manifold_only else (t.counts >= 2)
    m = np.flatnonzero(sel)
    # all pairs of elements on each edge: for manifold edges that's one pair; for
    # non-manifold edges connect every element to the first one (enough for connectivity).
    c = t.counts[m]
    first = np.repeat(t.elems[t.ptr[m]], c - 1)
    idx = np.repeat(t.ptr[m], c - 1) + _ranges(c - 1) + 1
    other = t.elems[idx]
    a = np.concatenate([first, other])
    b = np.concatenate([other, first])
    g = sp.coo_matrix((np.ones(a.size, dtype=np.int8), (a, b)), shape=(ne, ne)).tocsr()
    g.data[:] = 1
    return g


def _ranges(c: np.ndarray) -> np.ndarray:
    """Concatenated aranges: [0..c0-1, 0..c1-1, ...] for counts c (vectorised)."""
    c = np.asarray(c, dtype=np.int64)
    tot = int(c.sum())
    if tot == 0:
        return np.empty(0, dtype=np.int64)
    starts = np.repeat(np.cumsum(c) - c, c)
    return np.arange(tot, dtype=np.int64) - starts


def connected_components(mesh: Mesh) -> tuple[int, np.ndarray]:
    """Edge-connected components of the elements.

    Returns ``(n_components, labels)`` with labels (E,) int64; components are numbered in
    order of their lowest element index.
    """
    g = element_adjacency(mesh)
    n, lab = csgraph.connected_components(g, directed=False)
    # renumber by first occurrence so labels are deterministic
    _, first = np.unique(lab, return_index=True)
    rank = np.empty(n, dtype=np.int64)
    rank[np.argsort(np.argsort(first))] = np.arange(n)
    return int(n), rank[lab].astype(np.int64)


def orientation_conflicts(mesh: Mesh, table: EdgeTable | None = None) -> np.ndarray:
    """(K, 2) int64 pairs of elements (ascending in each row) that share a manifold edge and
    traverse it in the same direction (inconsistent orientation). Non-manifold and boundary
    edges are not checked."""
    t = edge_table(mesh) if table is None else table
    m = np.flatnonzero(t.counts == 2)
    i0 = t.ptr[m]
    bad = t.forward[i0] == t.forward[i0 + 1]
    pairs = np.column_stack([t.elems[i0[bad]], t.elems[i0[bad] + 1]])
    return np.unique(np.sort(pairs, axis=1), axis=0) if pairs.size else pairs.reshape(0, 2)


def flip_elements(mesh: Mesh, mask: np.ndarray) -> Mesh:
    """Reverse the orientation of elements where ``mask`` (E,) is True.

    The first node is kept: triangle (a, b, c) -> (a, c, b); quad (a, b, c, d) -> (a, d, c, b).
    point_data / cell_data are kept.
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (mesh.n_elements,):
        raise MeshError(f"flip mask must have shape ({mesh.n_elements},), got {mask.shape}")
    blocks = []
    for off, blk in mesh.elements():
        d = blk.data.copy()
        f = mask[off : off + len(d)]
        d[f, 1:] = d[f, :0:-1]
        blocks.append(CellBlock(blk.type, d))
    return Mesh(mesh.nodes, blocks, dict(mesh.point_data), dict(mesh.cell_data), mesh.name)


def orient_consistently(
    mesh: Mesh, *, outward: bool = False, strict: bool = True
) -> tuple[Mesh, np.ndarray]:
    """Flip elements so neighbours across every manifold edge agree in orientation.

    Per edge-connected component (through manifold edges) the lowest-numbered element keeps
    its orientation; the others are flipped by a breadth-first traversal of the dual graph
    (scipy BFS from a virtual root joined to every component's seed, then the flip parity
    along the BFS tree by pointer jumping: O(E log depth), no Python loop over elements).

    outward : for components that are closed (no boundary edge), additionally flip the
        whole component if its enclosed signed volume is negative, so normals point out.
    strict : if conflicts remain (non-orientable surface, e.g. a Moebius strip, or a local
        fold), raise `MeshError` naming an offending element pair; else warn.

    Returns ``(new_mesh, flipped)`` with flipped (E,) bool.
    """
    t = edge_table(mesh)
    ne = mesh.n_elements
    if ne == 0:
        return mesh, np.zeros(0, dtype=bool)
    m = np.flatnonzero(t.counts == 2)
    i0 = t.ptr[m]
    a, b = t.elems[i0], t.elems[i0 + 1]
    same = (t.forward[i0] == t.forward[i0 + 1]).astype(np.int8)  # 1: must flip relative
    keep = a != b
    a, b, same = a[keep], b[keep], same[keep]
    # dedupe element pairs sharing more than one edge (keep the first label)
    key = np.minimum(a, b) * ne + np.maximum(a, b)
    _, first = np.unique(key, return_index=True)
    a, b, same = a[first], b[first], same[first]
    g = sp.coo_matrix(
        (np.concatenate([same, same]) + 1, (np.concatenate([a, b]), np.concatenate([b, a]))),
        shape=(ne, ne),
    ).tocsr()
    ncomp, lab = csgraph.connected_components(g, directed=False)
    seeds = np.unique(lab, return_index=True)[1]
    # virtual root = node ne, linked to each component's lowest element (label 0 -> data 1)
    root = ne
    gg = sp.bmat(
        [
            [g, sp.csr_matrix((np.ones(ncomp), (seeds, np.zeros(ncomp))), shape=(ne, 1))],
            [sp.csr_matrix((np.ones(ncomp), (np.zeros(ncomp), seeds)), shape=(1, ne)), None],
        ],
        format="csr",
    )
    _, pred = csgraph.breadth_first_order(gg, root, directed=False, return_predecessors=True)
    pred = pred.astype(np.int64)
    anc = np.where(pred < 0, root, pred)  # root's own predecessor is itself
    anc[root] = root
    nodes = np.arange(ne + 1)
    lbl = np.zeros(ne + 1, dtype=np.int8)
    nonroot = anc != nodes
    lbl[nonroot] = (np.asarray(gg[nodes[nonroot], anc[nonroot]]).ravel() - 1).astype(np.int8)
    par = lbl.copy()
    while np.any(anc != root):
        par = par ^ par[anc]
        anc = anc[anc]
    flipped = par[:ne].astype(bool)
    out = flip_elements(mesh, flipped)
    if outward:
        boundary_el = np.zeros(ne, dtype=bool)
        bm = np.flatnonzero(t.counts == 1)
        boundary_el[t.elems[t.ptr[bm]]] = True
        closed = np.bincount(lab, weights=boundary_el, minlength=ncomp) == 0
        vol = np.bincount(lab, weights=_signed_volume_terms(out), minlength=ncomp)
        turn = closed & (vol < 0)
        if turn.any():
            extra = turn[lab]
            flipped ^= extra
            out = flip_elements(out, extra)
    bad = orientation_conflicts(out)
    if len(bad):
        msg = (
            f"cannot orient consistently: elements {bad[0, 0]} and {bad[0, 1]} still traverse "
            f"their shared edge in the same direction ({len(bad)} such pairs; non-orientable "
            f"surface?)"
        )
        if strict:
            raise MeshError(msg)
        warnings.warn(msg, stacklevel=2)
    return out, flipped


def _corner_points(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Padded corner coordinates p0..p3 (E, 3) and is_quad (E,); triangles repeat p0 as p3."""
    P = mesh.padded()
    isq = P[:, 3] >= 0
    P3 = np.where(isq, P[:, 3], P[:, 0])
    X = mesh.nodes
    return X[P[:, 0]], X[P[:, 1]], X[P[:, 2]], X[P3], isq


def _signed_volume_terms(mesh: Mesh) -> np.ndarray:
    """(E,) contribution of each element to the enclosed signed volume (divergence theorem;
    quads split along diagonal 0-2)."""
    p0, p1, p2, p3, isq = _corner_points(mesh)
    v = np.einsum("ij,ij->i", p0, np.cross(p1, p2)) / 6.0
    v += np.where(isq, np.einsum("ij,ij->i", p0, np.cross(p2, p3)) / 6.0, 0.0)
    return v


def element_normals(mesh: Mesh, *, unit: bool = True) -> np.ndarray:
    """(E, 3) element normals following the node order (right-hand rule).

    Triangles: (p1 - p0) x (p2 - p0); quads: the cross product of the diagonals
    (p2 - p0) x (p3 - p1). Unnormalised, both have length 2 * area for planar elements. With ``unit`` they are normalised, and a zero normal
    (degenerate element) raises `MeshError` naming the element.
    """
    p0, p1, p2, p3, isq = _corner_points(mesh)
    n = np.cross(p1 - p0, p2 - p0)
    if isq.any():
        n[isq] = np.cross(p2[isq] - p0[isq], p3[isq] - p1[isq])
    if not unit:
        return n
    L = np.linalg.norm(n, axis=1)
    scale = np.abs(mesh.nodes).max() if mesh.n_nodes else 1.0
    bad = np.flatnonzero(~(L > 1e-300 + 1e-14 * scale * scale))
    if bad.size:
        raise MeshError(
            f"element {bad[0]} is degenerate (zero normal), nodes {mesh.padded()[bad[0]][: 4 if isq[bad[0]] else 3].tolist()}"
        )
    return n / L[:, None]


def element_areas(mesh: Mesh) -> np.ndarray:
    """(E,) element areas (model units^2); quads as the sum of triangles (0,1,2) and (0,2,3)."""
    p0, p1, p2, p3, isq = _corner_points(mesh)
    a = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    a += np.where(isq, 0.5 * np.linalg.norm(np.cross(p2 - p0, p3 - p0), axis=1), 0.0)
    return a

"""Mesh clean-up: merge nodes that lie closer together than a tolerance.

Real CAD has faces that pinch to a point (two boundary curves touching, e.g. the ground end
of a spring) and edges far shorter than the element size. gmsh then grades its nodes down
to ~1e-13 apart and lays sliver triangles over each other there, which no normal can
repair. Nodes closer than a tolerance that the CAD itself cannot resolve are one node:
merging them collapses the slivers, and the elements that lose a corner are dropped
(triangles) or become triangles (quads). The result says what was done, for the report.

No gmsh / OCC imports here (core module).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from cadbridge.mesh.mesh import CellBlock, Mesh

__all__ = ["MergeReport", "merge_close_nodes"]


@dataclass(frozen=True)
class MergeReport:
    """What `merge_close_nodes` did: ``merged`` nodes removed (joined to a neighbour),
    ``dropped`` elements removed (collapsed), ``to_triangles`` quads that lost one corner,
    ``where`` (K, 3) one point per merged cluster, ``tol`` the distance used (model units)."""

    merged: int
    dropped: int
    to_triangles: int
    where: np.ndarray
    tol: float

    def __bool__(self) -> bool:
        return self.merged > 0

    def summary(self) -> str:
        if not self.merged:
            return "no nodes closer than %.3g" % self.tol
        pts = "; ".join("(%.6g, %.6g, %.6g)" % tuple(p) for p in self.where[:3])
        more = f" and {len(self.where) - 3} more" if len(self.where) > 3 else ""
        return (f"merged {self.merged} nodes closer than {self.tol:.3g} into {len(self.where)} "
                f"(pinched faces or edges shorter than the tolerance, at {pts}{more}); "
                f"dropped {self.dropped} collapsed elements, {self.to_triangles} quads became triangles")


def merge_close_nodes(mesh: Mesh, tol: float, anchors: np.ndarray | None = None) -> tuple[Mesh, MergeReport]:
    """Join nodes closer than ``tol`` (clusters by transitive closure) and drop the elements
    that collapse.

    ``anchors`` (A,) node indices at CAD vertices (gmsh points): a cluster that would join
    anchors farther apart than ``tol`` (a chain of short CAD edges whose segments are each
    below ``tol``) is split instead: anchors join only through anchors within ``tol``, and
    each other node of the cluster joins its nearest anchor (`_split_at_anchors`).

    The surviving node of a cluster is its lowest index (its position and point data are
    kept; nodes are renumbered compactly). Triangles with a repeated node are dropped; quads
    with one repeated node become triangles (a new triangle block), with more they are
    dropped. Two triangles left on the same three nodes are a fold: both are dropped if
    wound oppositely, one if alike (`_drop_folds`). Cell data follow their elements. Returns
    the new mesh and a `MergeReport`.
    """
    x = mesh.nodes
    n = len(x)
    pairs = cKDTree(x).query_pairs(tol, output_type="ndarray") if n else np.zeros((0, 2), int)
    if len(pairs) == 0:
        return mesh, MergeReport(0, 0, 0, np.zeros((0, 3)), tol)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(g, directed=False)
    if anchors is not None and len(anchors):
        label = _split_at_anchors(x, pairs, label, np.unique(np.asarray(anchors, dtype=np.int64)))
    rep = np.full(label.max() + 1, n, dtype=np.int64)
    np.minimum.at(rep, label, np.arange(n))
    target = rep[label]                                   # (N,) surviving original node
    keep = target == np.arange(n)
    new_id = np.cumsum(keep) - 1
    remap = new_id[target]
    sizes = np.bincount(label)
    clusters = np.flatnonzero(sizes > 1)
    where = x[rep[clusters]]

    blocks, cell_take, tri_from_quad = [], [], []
    offsets = np.concatenate([[0], np.cumsum([len(b.data) for b in mesh.cells])])
    dropped = 0
    for b, off in zip(mesh.cells, offsets[:-1]):
        c = remap[b.data]
        ids = off + np.arange(len(c))
        s = np.sort(c, axis=1)
        distinct = 1 + (np.diff(s, axis=1) != 0).sum(axis=1)
        k = c.shape[1]
        ok = distinct == k
        blocks.append(CellBlock(b.type, c[ok]))
        cell_take.append(ids[ok])
        if b.type == "quad":
            tri, three = collapsed_quads(c)
            tri_from_quad.append((tri, ids[three]))
            dropped += int(len(c) - ok.sum() - three.sum())
        else:
            dropped += int((~ok).sum())
    for tri, ids in tri_from_quad:
        if len(tri):
            blocks.append(CellBlock("triangle", tri))
            cell_take.append(ids)
    dropped += _drop_folds(blocks, cell_take)
    to_tri = sum(len(b.data) for b in blocks[len(mesh.cells):])
    blocks = [b for b in blocks if len(b.data)] or blocks[:1]
    take = np.concatenate(cell_take) if cell_take else np.zeros(0, dtype=np.int64)
    out = Mesh(
        nodes=x[keep],
        cells=blocks,
        point_data={k: np.asarray(v)[keep] for k, v in mesh.point_data.items()},
        cell_data={k: np.asarray(v)[take] for k, v in mesh.cell_data.items()},
        name=mesh.name,
    )
    return out, MergeReport(int(n - keep.sum()), dropped, to_tri, where, float(tol))


def collapsed_quads(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quads (Q, 4) with one edge collapsed (two cyclically adjacent corners on one node, e.g.
    gmsh's [a, p, p, b] at a pole): (the triangles of their other three corners in cyclic
    order (T, 3), which quads those are (Q,) bool). A quad with a merged diagonal (a, b, a, d)
    or more repeats has no area and is not among them."""
    same = q == np.roll(q, -1, axis=1)
    distinct = 1 + (np.diff(np.sort(q, axis=1), axis=1) != 0).sum(axis=1)
    three = (distinct == 3) & same.any(axis=1)
    return q[three][~same[three]].reshape(-1, 3), three


def _drop_folds(blocks: list[CellBlock], cell_take: list[np.ndarray]) -> int:
    """Drop, in place, the triangles the merge made coincident: of two triangles on the same
    three nodes wound oppositely (a needle triangle collapsed with its subdivision: the halves
    of two of its sub-quads fold onto each other, zero area) both, of the same winding all but
    the first. Returns how many were dropped."""
    tri = [k for k, b in enumerate(blocks) if b.type == "triangle" and len(b.data)]
    if not tri:
        return 0
    t = np.concatenate([blocks[k].data for k in tri])
    key = np.sort(t, axis=1)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if count.max() < 2:
        return 0
    # winding: the rotation that starts at the smallest node; equal to the sorted row or not
    r = np.argmin(t, axis=1)
    rot = t[np.arange(len(t))[:, None], (r[:, None] + np.arange(3)) % 3]
    up = (rot == key).all(axis=1)
    n_up = np.bincount(inv, weights=up, minlength=len(count)).astype(np.int64)
    # a set keeps one element of its more frequent winding (folded pairs cancel), none if even
    keep = count[inv] == 1
    cand = np.flatnonzero((count[inv] > 1) & (2 * n_up != count)[inv] & (up == (2 * n_up > count)[inv]))
    if len(cand):
        _, firsts = np.unique(inv[cand], return_index=True)
        keep[cand[firsts]] = True
    off = 0
    n_drop = 0
    for k in tri:
        m = len(blocks[k].data)
        kk = keep[off : off + m]
        n_drop += int((~kk).sum())
        blocks[k] = CellBlock("triangle", blocks[k].data[kk])
        cell_take[k] = cell_take[k][kk]
        off += m
    return n_drop


def _split_at_anchors(x: np.ndarray, pairs: np.ndarray, label: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Cluster labels (N,) with every cluster of ``label`` that holds two anchors not joined
    by anchor-to-anchor pairs split: one cluster per group of anchors (transitive closure of
    the ``pairs`` (P, 2) between anchors), each other node of the cluster in the group of its
    nearest anchor (of that cluster; ``x`` (N, 3)). The all-quad subdivision halves a 0.0077
    mm CAD edge of the production die into steps below the merge tolerance (7.2e-3 mm), and
    the closure then joined it with its 0.0123 mm neighbour edge, 0.02 mm of boundary, into
    one node: non-manifold edges. Split, the CAD vertices stay and each half-step node joins
    one of them."""
    n = len(x)
    is_a = np.zeros(n, dtype=bool)
    is_a[anchors] = True
    n_anchor = np.bincount(label[anchors], minlength=label.max() + 1)
    aa = pairs[is_a[pairs[:, 0]] & is_a[pairs[:, 1]]]
    _, group = connected_components(coo_matrix((np.ones(len(aa)), (aa[:, 0], aa[:, 1])), shape=(n, n)),
                                    directed=False)
    out = label.copy()
    nxt = label.max() + 1
    for c in np.flatnonzero(n_anchor >= 2):  # loop over the (few) clusters holding several anchors
        a = anchors[label[anchors] == c]
        if len(np.unique(group[a])) == 1:
            continue  # its anchors are one group: one cluster, as before
        members = np.flatnonzero(label == c)
        _, near = cKDTree(x[a]).query(x[members])
        _, gid = np.unique(group[a], return_inverse=True)  # anchor -> its group, 0..G-1
        out[members] = nxt + gid[near]
        nxt += int(gid.max()) + 1
    return out

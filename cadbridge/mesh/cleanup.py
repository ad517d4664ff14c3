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


def merge_close_nodes(mesh: Mesh, tol: float) -> tuple[Mesh, MergeReport]:
    """Join nodes closer than ``tol`` (clusters by transitive closure) and drop the elements
    that collapse.

    The surviving node of a cluster is its lowest index (its position and point data are
    kept; nodes are renumbered compactly). Triangles with a repeated node are dropped; quads
    with one repeated node become triangles (a new triangle block), with more they are
    dropped. Cell data follow their elements. Returns the new mesh and a `MergeReport`.
    """
    x = mesh.nodes
    n = len(x)
    pairs = cKDTree(x).query_pairs(tol, output_type="ndarray") if n else np.zeros((0, 2), int)
    if len(pairs) == 0:
        return mesh, MergeReport(0, 0, 0, np.zeros((0, 3)), tol)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(g, directed=False)
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
            # one edge collapsed (two cyclically adjacent corners merged): a triangle of the
            # other three in their cyclic order; a merged diagonal (a, b, a, d) has no area
            rep_next = c == np.roll(c, -1, axis=1)
            three = (distinct == 3) & rep_next.any(axis=1)
            q, m = c[three], rep_next[three]
            tri = q[~m].reshape(-1, 3)
            tri_from_quad.append((tri, ids[three]))
            dropped += int(len(c) - ok.sum() - three.sum())
        else:
            dropped += int((~ok).sum())
    to_tri = 0
    for tri, ids in tri_from_quad:
        if len(tri):
            blocks.append(CellBlock("triangle", tri))
            cell_take.append(ids)
            to_tri += len(tri)
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

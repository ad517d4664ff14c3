"""Move mesh nodes onto the inflection lines of the CAD where Nagata edges are inflected.

An inflected edge (`cadbridge.nagata.admissibility`: the chord on the same side of both end
tangent planes) has an inflection of the surface between its nodes, and a quadratic edge
cannot hold it (thesis §6.2.2, Figs. 56-58). For every such edge whose two nodes lie on the
same face, the inflection along the edge is located on the exact surface
(`cadbridge.nurbs.inflections.segment_inflections`, bisection of the normal curvature along
the edge's (u, v) direction) and the nearer end node is moved onto it, in the face's (u, v),
so it stays on the CAD. A node moves at most once per call; it is left where it is when it

* lies on a face border or a crease (shared by elements of several faces): the border is a
  curve the mesh must keep;
* lies on the mesh boundary, unless the face is untrimmed, the node is on a domain edge of
  its face and the move runs along that edge (the node slides along the boundary);
* would turn one of its elements inside out (polygon normal against the CAD normal).

Returns the new mesh and a list of what was done, one `NodeMove` per node.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cadbridge.mesh.mesh import CellBlock, Mesh

__all__ = ["NodeMove", "inadmissible_elements", "inflection_edges", "move_nodes_to_inflections"]


@dataclass
class NodeMove:
    """Node ``node`` (0-based) moved along edge (a, b) from ``old`` to ``new`` (3,) model
    coordinates, on face ``face`` from (u, v) ``uv_old`` to ``uv_new``; ``distance`` moved."""

    node: int
    edge: tuple[int, int]
    face: int
    uv_old: tuple[float, float]
    uv_new: tuple[float, float]
    old: np.ndarray
    new: np.ndarray
    distance: float

    def __str__(self) -> str:
        return (f"node {self.node + 1} moved {self.distance:.4g} onto the inflection line of face {self.face} "
                f"(edge {self.edge[0] + 1}-{self.edge[1] + 1}, (u, v) {self.uv_old[0]:.6g}, {self.uv_old[1]:.6g} -> "
                f"{self.uv_new[0]:.6g}, {self.uv_new[1]:.6g})")


def inflection_edges(mesh: Mesh, model, cn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mesh edges whose two nodes lie on one face with an inflection of that face between
    them: the normal curvature along the edge's (u, v) segment changes sign on the exact
    surface (`segment_inflections`). Edges on a plane or along a straight direction have
    none. Returns node pairs (K, 2), face (K,), parameter t (K,) of the inflection along
    the edge from its first node."""
    from cadbridge.mesh.topology import unique_edges
    from cadbridge.nurbs.inflections import segment_inflections

    e = np.asarray(unique_edges(mesh), dtype=np.int64).reshape(-1, 2)
    a, b = e[:, 0], e[:, 1]
    keep = (cn.face[a] == cn.face[b]) & (cn.face[a] >= 0)
    e, a, b = e[keep], a[keep], b[keep]
    t = np.full(len(e), np.nan)
    length = np.linalg.norm(mesh.nodes[b] - mesh.nodes[a], axis=1)
    for f in np.unique(cn.face[a]):  # loop over faces, vectorised over their edges
        sel = np.flatnonzero(cn.face[a] == f)
        # k_n below 1e-7 / edge length bends the edge by < 1e-8 of its length: straight
        t[sel] = segment_inflections(model.faces[f].surface, np.column_stack([cn.u[a[sel]], cn.v[a[sel]]]),
                                     np.column_stack([cn.u[b[sel]], cn.v[b[sel]]]),
                                     k_zero=1e-7 / np.maximum(length[sel], 1e-300))
    ok = np.isfinite(t)
    return e[ok], cn.face[a[ok]], t[ok]


def move_nodes_to_inflections(mesh: Mesh, model, cn, adm=None) -> tuple[Mesh, list[NodeMove]]:
    """Nodes of the edges that straddle an inflection of the CAD (`inflection_edges`) and,
    if ``adm`` (`EdgeAdmissibility` of a `NagataMesh` over ``mesh`` with the corner normals
    of ``cn``, a `cadbridge.normals.cad.CadNormals`) is given, of its inflected edges, moved
    onto the inflection (module docs). Returns (mesh with moved nodes, moves)."""
    from cadbridge.mesh.topology import boundary_edges
    from cadbridge.nurbs.inflections import segment_inflections

    blocks = [np.asarray(b.data) for b in mesh.cells]
    ef = np.concatenate(cn.element_face)
    n = len(mesh.nodes)
    # faces touching each node (elements' faces): more than one -> face border, fixed
    node_faces_min = np.full(n, np.iinfo(np.int64).max)
    node_faces_max = np.full(n, -1)
    start = 0
    for b in blocks:
        f = np.repeat(ef[start:start + len(b)], b.shape[1])
        np.minimum.at(node_faces_min, b.ravel(), f)
        np.maximum.at(node_faces_max, b.ravel(), f)
        start += len(b)
    fixed = (node_faces_min != node_faces_max) | np.asarray(cn.crease, bool)
    on_boundary = np.zeros(n, bool)
    be = boundary_edges(mesh)
    on_boundary[np.asarray(be).ravel()] = True
    edges = inflection_edges(mesh, model, cn)[0]
    if adm is not None:
        edges = np.unique(np.vstack([np.sort(edges, axis=1), adm.edges[adm.inflected]]), axis=0)
    a, b = edges[:, 0], edges[:, 1]
    same = (cn.face[a] == cn.face[b]) & (cn.face[a] >= 0)
    edges, a, b = edges[same], a[same], b[same]
    moves: list[NodeMove] = []
    if len(edges) == 0:
        return mesh, moves
    new_nodes = mesh.nodes.copy()
    uv = np.column_stack([cn.u, cn.v])
    moved = np.zeros(n, bool)
    for f in np.unique(cn.face[a]):  # loop over the faces concerned, vectorised over edges
        sel = np.flatnonzero(cn.face[a] == f)
        face = model.faces[f]
        s = face.surface
        t = segment_inflections(s, uv[a[sel]], uv[b[sel]])
        u0, u1, v0, v1 = s.domain
        eu, ev = 1e-9 * (u1 - u0), 1e-9 * (v1 - v0)
        for k in range(len(sel)):  # loop over the (few) inflected edges of this face
            if not np.isfinite(t[k]):
                continue
            i = sel[k]
            near, tt = (a[i], t[k]) if t[k] < 0.5 else (b[i], 1.0 - t[k])
            far = b[i] if near == a[i] else a[i]
            if moved[near] or fixed[near]:
                continue
            target = uv[near] + tt * (uv[far] - uv[near])
            if on_boundary[near]:
                if face.trims is not None:
                    continue
                du, dv = target - uv[near]
                on_u = min(abs(uv[near, 0] - u0), abs(uv[near, 0] - u1)) <= eu
                on_v = min(abs(uv[near, 1] - v0), abs(uv[near, 1] - v1)) <= ev
                if not ((on_u and abs(du) <= eu) or (on_v and abs(dv) <= ev)) or (on_u and on_v):
                    continue
            x_new = s.evaluate(target[:1], target[1:])[0]
            if not _keeps_orientation(blocks, new_nodes, near, x_new, s.normal(target[:1], target[1:])[0], cn):
                continue
            moves.append(NodeMove(int(near), (int(a[i]), int(b[i])), int(f), tuple(map(float, uv[near])),
                                  tuple(map(float, target)), new_nodes[near].copy(), x_new,
                                  float(np.linalg.norm(x_new - new_nodes[near]))))
            new_nodes[near] = x_new
            uv[near] = target
            moved[near] = True
    if not moves:
        return mesh, moves
    # gmsh's (u, v) of the moved nodes no longer hold (and no NaN may reach a file): dropped
    pd = {k: np.array(v, copy=True) for k, v in mesh.point_data.items() if k != "node_uv"}
    out = Mesh(new_nodes, [CellBlock(c.type, np.asarray(c.data)) for c in mesh.cells], point_data=pd,
               cell_data=dict(mesh.cell_data), name=mesh.name)
    return out, moves


def _keeps_orientation(blocks, nodes, node, x_new, n_new, cn) -> bool:
    """True if moving ``node`` to ``x_new`` turns none of its elements inside out (the sign of
    the polygon normal against the CAD normal at the node stays)."""
    for b in blocks:  # loop over the (one or two) blocks
        rows = np.flatnonzero(np.any(b == node, axis=1))
        if not len(rows):
            continue
        conn = b[rows]

        def winding(x):
            if conn.shape[1] == 3:
                return np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
            return np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 1])

        x = nodes[conn]
        before = winding(x) @ n_new
        x = x.copy()
        x[conn == node] = x_new
        after = winding(x) @ n_new
        if np.any(np.sign(after) != np.sign(before)) or np.any(after == 0):
            return False
    return True


def inadmissible_elements(mesh: Mesh, model, cn, nm, max_bend: float = 100.0) -> dict[int, str]:
    """Elements of ``mesh`` (global ids, block order; ``nm`` its `NagataMesh` with the corner
    normals of ``cn``) that one quadratic patch cannot describe, with the reason: an edge
    across an inflection of the CAD (`inflection_edges`), or an edge that fails
    `cadbridge.nagata.admissibility` (inflected chord, not monotone, sharp bend)."""
    from cadbridge.nagata.admissibility import edge_admissibility

    out: dict[int, str] = {}
    adm = edge_admissibility(nm, max_bend=max_bend)
    topo = nm.edges
    reasons = adm.reasons()
    bad = ~adm.admissible[topo["inst_edge"]]
    for el, ed in zip(topo["inst_elem"][bad], topo["inst_edge"][bad]):  # loop over the (few) bad instances
        a, b = adm.edges[ed]
        out.setdefault(int(el), f"edge {a + 1}-{b + 1}: {reasons[ed]}")
    e, face, t = inflection_edges(mesh, model, cn)
    if len(e):
        key = lambda p, q: np.minimum(p, q) * np.int64(len(mesh.nodes)) + np.maximum(p, q)  # noqa: E731
        k_all = key(topo["edges"][:, 0], topo["edges"][:, 1])
        k_bad = key(e[:, 0], e[:, 1])
        pos = {int(k): i for i, k in enumerate(k_bad)}
        hit = np.isin(k_all[topo["inst_edge"]], k_bad)
        for el, ed in zip(topo["inst_elem"][hit], topo["inst_edge"][hit]):
            i = pos[int(k_all[ed])]
            out.setdefault(int(el), f"edge {e[i, 0] + 1}-{e[i, 1] + 1} straddles an inflection line of face {face[i]} "
                                    f"(at {t[i]:.3f} of the edge)")
    return out
